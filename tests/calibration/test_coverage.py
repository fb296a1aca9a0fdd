"""Capture guidance from coverage: what is missing, said so a person can act on it."""

import numpy as np

from calib_eval.benchmark.rigs import SynthSpec, make_sequence, paper_config
from calib_eval.calibration.coverage import coverage
from calib_eval.cli import run as calib_cli
from cotrain.io.sequence import Observation, write_sequence


def _restricted(seq, keep):
    """The sequence with only the corners ``keep(cam, q) -> (M,) bool`` accepts."""
    out = []
    for o in seq.observations:
        k = keep(o.cam, o.q)
        if k.sum() >= 6:
            out.append(Observation(o.cam, o.view, o.ids[k], o.q[k], o.weight[k], o.frame))
    seq.observations = out
    return seq


def test_centre_only_camera_is_told_to_reach_the_rim(tmp_path, capsys):
    seq, _ = make_sequence(paper_config("FoV220_90"), SynthSpec(n_frames=120), seed=2)
    centre = np.array([639.5, 359.5])
    seq = _restricted(seq, lambda cam, q: (np.linalg.norm(q - centre, axis=1) < 0.6 * 360) | (cam == 0))
    cov = coverage(seq)
    cam1 = cov.cameras[1]
    assert cam1.max_radius < 0.6 and cov.cameras[0].max_radius > 0.95
    assert any(a.startswith("cam1: no observation beyond 0.") and "near the rim" in a for a in cov.advice)
    assert not any(a.startswith("cam0: no observation beyond") for a in cov.advice)
    # The command prints the same sentences.
    root = write_sequence(seq, tmp_path / "seq")
    assert calib_cli(["coverage", str(root)]) == 0
    assert "cam1: no observation beyond" in capsys.readouterr().out


def test_missing_sector_and_unlinked_cameras():
    seq, _ = make_sequence(paper_config("FoV220_90"), SynthSpec(n_frames=120), seed=2)
    centre = np.array([639.5, 359.5])
    seq = _restricted(seq, lambda cam, q: ~((cam == 0) & (q[:, 0] > centre[0] + 200)))  # cam0: nothing far right
    cov = coverage(seq)
    assert any(a.startswith("cam0: few corners near the rim at the") and "right" in a for a in cov.advice)
    # Keep only a handful of views both cameras see: the extrinsics are under-determined.
    shared = sorted(v for v, obs in seq.by_view().items() if len(obs) == 2)
    drop = set(shared[3:])
    seq.observations = [o for o in seq.observations if not (o.cam == 1 and o.view in drop)]
    cov = coverage(seq)
    assert cov.shared_views[(0, 1)] == 3
    assert any("cam0 and cam1: only 3 views where both see the board" in a for a in cov.advice)
