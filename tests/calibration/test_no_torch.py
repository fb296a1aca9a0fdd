"""The calibration runs where torch (and kornia, tensorboard, onnx) is not installed: a synthetic
stereo sequence written here (with torch) is calibrated by ``calib-eval calibrate`` in a child
process whose imports of those packages fail, and agrees with the same calibration in this one."""

import json

import numpy as np

from calib_eval.benchmark.rigs import SynthSpec, make_sequence, paper_config
from calib_eval.calibration.calibrator import CalibConfig, calibrate
from cotrain.io.sequence import write_sequence
from tests.blocked_imports import TRAIN_EXTRA, run_without
from tests.paths import ROOT


def test_calibrate_without_torch(tmp_path):
    seq, _ = make_sequence(paper_config("FoV200_60"), SynthSpec(n_frames=40), seed=3)
    root = write_sequence(seq, tmp_path / "seq")
    out = tmp_path / "out"
    args = ["calibrate", str(root), "--fov", "200", "--models", "pinhole-equi", "ds-none", "--out", str(out)]
    done = run_without((*TRAIN_EXTRA, "onnx"), "calib_eval.cli", args, ROOT, check_torch=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "verdict:" in done.stdout
    assert all((out / f).is_file() for f in ("camchain.yaml", "report.json", "report.html"))
    report = json.loads((out / "report.json").read_text())
    res = calibrate(seq, CalibConfig(models=["kb4", "ds"], fov=200))
    assert report["success"] and res.success
    np.testing.assert_allclose(list(report["rms_px"].values()), res.rms_px, rtol=0, atol=1e-9)
