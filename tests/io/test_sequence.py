"""Sequence folders carry their target: written with it, read back with it, a contradicting
--target refused."""

import json

import numpy as np
import pytest

from calib_eval.benchmark.rigs import SynthSpec, make_sequence, paper_config
from calib_eval.calibration.calibrator import CalibConfig, calibrate
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
    by_key = {(o.cam, o.view): o for o in back.observations}
    for a in seq.observations:
        b = by_key[(a.cam, a.view)]
        assert np.array_equal(a.ids, b.ids) and np.allclose(a.q, b.q)
    assert back.subset({(b.cam, b.view)}).target is back.target


def test_other_board_is_read_from_the_detections_and_calibrated(tmp_path):
    """An 8 x 6 board of 3 cm squares: the detections name it, and the calibrator, given no flag,
    recovers the rig at that scale (a wrong board would scale the baseline or fail)."""
    board = Checkerboard(TargetConfig(squares_x=8, squares_y=6, square_size=0.03))
    rig = paper_config("FoV200_60")
    seq, gt = make_sequence(rig, SynthSpec(n_frames=80, target=board.cfg), seed=4)
    root = write_sequence(seq, tmp_path / "seq")
    det = json.loads((root / "cam0" / "detections.json").read_text())
    assert det["target"] == board.to_json()
    back = load_sequence(root)
    assert same_target(back.target, board)
    res = calibrate(back, CalibConfig(model=rig.model, fov=rig.fov))
    assert res.success, res.reason
    t_err = np.linalg.norm(res.T_cam_rig[1][:3, 3] - gt.T_cam_rig[1][:3, 3])
    assert t_err < 1e-3, t_err


def test_corner_ids_beyond_the_target_are_one_line(tmp_path, synth_seq):
    _, root = synth_seq
    small = Checkerboard(TargetConfig(squares_x=4, squares_y=4))
    bare = _copy_with(root, tmp_path / "bare", lambda cam, det: det.pop("target"))
    with pytest.raises(SequenceError, match="corner id") as e:
        load_sequence(bare, target=small)
    assert "\n" not in str(e.value)


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
