"""Sequence folders carry their target: written with it, read back with it, a contradicting
--target refused."""

import json

import numpy as np
import pytest

from calib_eval.benchmark.rigs import SynthSpec, make_sequence, paper_config
from calib_eval.cli import run as calib_cli
from cotrain.io.sequence import SequenceError, load_sequence, write_sequence
from cotrain.targets import Checkerboard, TargetConfig, same_target


@pytest.fixture(scope="module")
def synth_seq(tmp_path_factory):
    seq, _ = make_sequence(paper_config("FoV200_60"), SynthSpec(n_frames=12), seed=3)
    root = write_sequence(seq, tmp_path_factory.mktemp("seq") / "seq")
    return seq, root


def test_round_trip_keeps_target_and_observations(synth_seq):
    seq, root = synth_seq
    back = load_sequence(root)
    assert same_target(back.target, Checkerboard())
    assert len(back.observations) == len(seq.observations)
    a, b = seq.observations[0], back.observations[0]
    assert np.array_equal(a.ids, b.ids) and np.allclose(a.q, b.q)
    assert back.subset({(b.cam, b.view)}).target is back.target


def test_other_board_is_read_from_the_detections(tmp_path):
    board = Checkerboard(TargetConfig(squares_x=8, squares_y=6, square_size=0.03))
    seq, _ = make_sequence(paper_config("FoV200_60"), SynthSpec(n_frames=8, target=board.cfg), seed=4)
    root = write_sequence(seq, tmp_path / "seq")
    det = json.loads((root / "cam0" / "detections.json").read_text())
    assert det["target"] == board.to_json()
    assert same_target(load_sequence(root).target, board)


def test_contradicting_target_is_one_line(synth_seq):
    _, root = synth_seq
    with pytest.raises(SequenceError, match="contradicts") as e:
        load_sequence(root, target=Checkerboard(TargetConfig(squares_x=8)))
    assert "\n" not in str(e.value)
    # The same board given again is fine.
    assert same_target(load_sequence(root, target=Checkerboard()).target, Checkerboard())


def _copy_with(root, dest, edit):
    """A copy of sequence ``root`` whose detections pass through ``edit(camera name, detection dict)``."""
    for cam in ("cam0", "cam1"):
        (dest / cam).mkdir(parents=True)
        (dest / cam / "timestamps.csv").write_text((root / cam / "timestamps.csv").read_text())
        det = json.loads((root / cam / "detections.json").read_text())
        edit(cam, det)
        (dest / cam / "detections.json").write_text(json.dumps(det))
    return dest


def test_detections_without_target(tmp_path, synth_seq):
    _, root = synth_seq
    bare = _copy_with(root, tmp_path / "bare", lambda cam, det: det.pop("target"))
    with pytest.raises(SequenceError, match="pass --target"):
        load_sequence(bare)
    assert same_target(load_sequence(bare, target=Checkerboard()).target, Checkerboard())


def test_cameras_that_disagree(tmp_path, synth_seq):
    _, root = synth_seq
    mixed = _copy_with(root, tmp_path / "mixed", lambda cam, det: det["target"].update(squares_x=8) if cam == "cam1" else None)
    with pytest.raises(SequenceError, match="differs"):
        load_sequence(mixed)


def test_calibrate_cli_refuses_a_contradicting_target(synth_seq, tmp_path, capsys):
    _, root = synth_seq
    t = tmp_path / "kalibr.yaml"
    t.write_text("target_type: checkerboard\ntargetCols: 7\ntargetRows: 6\nrowSpacingMeters: 0.04\ncolSpacingMeters: 0.04\n")
    rc = calib_cli(["calibrate", str(root), "--fov", "200", "--target", str(t), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "contradicts" in err and len(err.splitlines()) == 1
