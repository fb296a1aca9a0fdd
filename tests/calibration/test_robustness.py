"""Frame-level robustness: boards placed with the wrong identity (one column off, or a half turn)
are consistent within themselves, so only the rig shows them; the calibrator drops their views and
names them, and the rig comes back as from clean data."""

import numpy as np
import pytest
import torch

from calib_eval.benchmark.benchmark import evaluate_result
from calib_eval.benchmark.rigs import SynthSpec, make_sequence, paper_config
from calib_eval.benchmark.robustness import misidentify
from calib_eval.calibration.calibrator import CalibConfig, calibrate
from calib_eval.calibration.report_html import shared_views, write_report_html


@pytest.fixture(scope="module")
def single_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def test_misidentified_boards_and_gross_corners(single_thread, tmp_path):
    rig = paper_config("FoV220_90")
    seq, gt = make_sequence(rig, SynthSpec(n_frames=160, outlier_rate=0.05), seed=3)
    injected = misidentify(seq, 0.05, np.random.default_rng(0))
    res = calibrate(seq, CalibConfig(model=rig.model, fov=rig.fov))
    assert res.success, res.reason
    r = evaluate_result(res, gt, rig.fov)
    assert r["strict"] and r["ext_mm"] < 1.0 and r["ext_deg"] < 0.1 and r["intr_px"] < 1.0
    named = {d["view"] for d in res.dropped}
    assert len(named & injected) >= 0.9 * len(injected)
    assert len(named - injected) <= 1  # clean views are kept
    assert all("board off the rig" in d["reason"] and d["cameras"] for d in res.dropped)
    # The page a person looks at names them, with the advice and the rig's pairs; it is self-contained.
    page = write_report_html(res, seq, tmp_path).read_text()
    assert f"Dropped views ({len(res.dropped)})" in page and all(f"<td>{d['view']}</td>" in page for d in res.dropped)
    assert "Calibration succeeded" in page and "cam0 - cam1" in page and "What to capture next" in page
    # The gross corners are rejected, named as such on the page, and out of the residual plots.
    from calib_eval.calibration.report_html import residuals

    n_rej = sum(len(v) for v in res.rejected.values())
    assert n_rej > 0 and "<th>corners rejected</th>" in page
    for _, r, rej in residuals(res, seq):
        assert np.median(np.linalg.norm(r[rej], axis=1)) > 8 and np.percentile(np.linalg.norm(r[~rej], axis=1), 99) < 3
    assert page.count("data:image/png;base64,") >= 6 and 'src="http' not in page and "<link" not in page
    assert shared_views(res, seq)[(0, 1)] > 50
    # Without the view test the same sequence fails.
    off = calibrate(seq, CalibConfig(model=rig.model, fov=rig.fov, view_outlier_px=np.inf))
    assert not evaluate_result(off, gt, rig.fov)["strict"]


def test_clean_rig_drops_nothing(single_thread):
    rig = paper_config("FoV200_60")
    seq, _ = make_sequence(rig, SynthSpec(n_frames=80), seed=4)
    res = calibrate(seq, CalibConfig(model=rig.model, fov=rig.fov))
    assert res.success and res.dropped == []


def test_view_test_is_per_camera_and_capped():
    """The per-view test compares each view with its own camera: a poorer camera's ordinary views
    are not dropped, while a camera whose boards are mostly off still has them dropped (the cap)."""
    from calib_eval.calibration.calibrator import _inconsistent_views
    from cotrain.io.sequence import Observation

    rng = np.random.default_rng(0)
    used, err = [], []
    for v in range(40):  # cam0: 0.3 px; cam1: a poorer lens, 1.6 px; cam2: 30 of 40 boards 25 px off
        for c, med in ((0, 0.3), (1, 1.6), (2, 25.0 if v < 30 else 0.4)):
            used.append(Observation(c, v, np.arange(20), np.zeros((20, 2)), np.ones(20), str(v)))
            err.append(np.abs(rng.normal(med, 0.05 * med, 20)))
    used.append(Observation(0, 99, np.arange(20), np.zeros((20, 2)), np.ones(20), "99"))  # one wrong board in cam0
    err.append(np.full(20, 6.0))
    used.append(Observation(1, 98, np.arange(20), np.zeros((20, 2)), np.ones(20), "98"))  # a poor cam1 view, not a wrong board
    err.append(np.full(20, 6.0))  # over 5 x the median of all views (0.4 px), under 5 x cam1's own (1.6 px)
    bad = _inconsistent_views(used, np.concatenate(err), CalibConfig())
    flagged = {(o.cam, o.view) for o, _ in bad}
    assert (0, 99) in flagged
    assert not any(c == 1 for c, _ in flagged)  # 5 x 1.6 = 8 px: cam1's own views stay, (1, 98) included
    assert {(2, v) for v in range(30)} <= flagged  # capped at 10 px although cam2's median is 25 px
    assert not any(c == 2 and v >= 30 for c, v in flagged)
