"""How far a calibration can be trusted, against synthetic ground truth (issue 63).

- The stated sigma is honest: over repeated noise draws of one rig, the spread of the estimates
  matches the sigma the covariance states, and the true errors fall within 2 sigma as often as a
  Gaussian's do (mrcal's test-calibration-uncertainty, in miniature).
- Each injected cause is named, with its camera: an unsynchronised camera (its offset measured
  within 1 ms, and corrected with ``time_offset="auto"``), a bent board (its bend measured within
  0.5 mm), a lens the model does not fit, too few views; a clean rig gets ``trust``.
- report.json carries the contract of docs/conventions.md; the CLI prints the verdict last.
"""

import json
import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from calib_eval.benchmark.rigs import SynthSpec, bent_points, make_sequence, paper_config
from calib_eval.calibration.calibrator import CalibConfig, calibrate
from calib_eval.calibration.publish import publish
from calib_eval.calibration.solver import warp_basis
from calib_eval.calibration.trust import TrustConfig, assess
from calib_eval.cli import run as calib_cli
from calib_eval.cli import time_offset_option
from cotrain.geometry import cameras
from cotrain.io.sequence import write_sequence

RIG = "FoV220_90"


@pytest.fixture(scope="module", autouse=True)
def single_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)  # small dense blocks: threads only contend on a shared machine
    yield
    torch.set_num_threads(n)


def _calibrate(spec: SynthSpec, seed: int, rig=None, **cfg):
    rig = rig or paper_config(RIG)
    seq, gt = make_sequence(rig, spec, seed=seed)
    c = CalibConfig(model="kb4", fov=rig.fov, **cfg)
    res = calibrate(seq, c)
    assert res.success, res.reason
    return seq, gt, res, c


def _codes(trust) -> dict[str, set]:
    out: dict[str, set] = {}
    for c in trust.verdict.causes:
        out.setdefault(c.code, set()).add(c.camera)
    return out


def test_warp_basis_is_mrcal_two_term_warp():
    """1 at the corner grid's centre, 0 on its edges, (1 - x^2) and (1 - y^2) in between."""
    P = np.array([[0.0, 0.0, 0], [0.4, 0.2, 0], [0.2, 0.1, 0], [0.1, 0.2, 0], [0.3, 0.15, 0]])
    b = warp_basis(P, P)
    np.testing.assert_allclose(b[:3], [[0.0, 0.0], [0.0, 0.0], [1.0, 1.0]], atol=1e-15)
    np.testing.assert_allclose(b[3:], [[0.75, 0.0], [0.75, 0.75]], atol=1e-15)


def test_stated_sigma_matches_the_spread_over_noise_draws():
    """One rig, ten noise draws: per parameter, the standard deviation of the estimates over the
    draws against the sigma each draw states (median), and the true errors against 2 sigma."""
    rig = paper_config(RIG)
    est, sig, z = [], [], []
    for k in range(10):
        seq, gt = make_sequence(rig, SynthSpec(n_frames=60, noise_px=0.3), seed=0)
        rng = np.random.default_rng(100 + k)  # the same views and corners, a new noise draw
        for o in seq.observations:
            T = gt.T_cam_rig[o.cam] @ gt.T_rig_board[o.view]
            pc = seq.target.points().numpy()[o.ids] @ T[:3, :3].T + T[:3, 3]
            o.q = cameras.project("kb4", torch.from_numpy(pc), torch.from_numpy(gt.params[o.cam]))[0].numpy() + rng.normal(
                scale=0.3, size=o.q.shape
            )
        res = calibrate(seq, CalibConfig(model="kb4", fov=rig.fov, time_offset="off"))
        t = assess(res, seq, CalibConfig(model="kb4", fov=rig.fov), TrustConfig(compare_models=False))
        u = t.uncertainty
        pu = u.pairs[(0, 1)]
        w = Rotation.from_matrix(gt.T_cam_rig[1][:3, :3] @ res.T_cam_rig[1][:3, :3].T).as_rotvec()
        x = np.r_[res.intrinsics[0][:4], res.intrinsics[1][:4], np.linalg.norm(res.T_cam_rig[1][:3, 3])]
        s = np.r_[u.intrinsics_sigma[0][:4], u.intrinsics_sigma[1][:4], pu.baseline_sigma_m]
        truth = np.r_[gt.params[0][:4], gt.params[1][:4], np.linalg.norm(gt.T_cam_rig[1][:3, 3])]
        est.append(x)
        sig.append(s)
        z.append(np.r_[(x - truth) / s, w / np.radians(pu.rotation_sigma_xyz_deg)])
    ratio = np.std(est, axis=0, ddof=1) / np.median(sig, axis=0)
    # Ten draws estimate a standard deviation to about +-24 % (1 / sqrt(18)), and the parameters are
    # correlated, so the median over them is hardly tighter. Measured on this rig: median 0.69 over
    # ten draws; 0.8 over sixteen (fx, fy 0.6-0.85, cx, cy 0.8-1.3): the stated sigma errs a little
    # on the safe side here. A sigma off by 2x either way fails.
    assert 0.5 < float(np.median(ratio)) < 1.6, ratio
    assert np.all((ratio > 0.3) & (ratio < 2.5)), ratio
    z = np.concatenate(z)
    assert 0.85 <= float((np.abs(z) < 2).mean()), z  # Gaussian: 0.954 (110 values)
    assert 0.5 < float(np.sqrt((z**2).mean())) < 1.6, z  # 1 where sigma is right


def test_clean_rig_is_trusted_and_report_json_carries_the_contract(tmp_path):
    seq, gt, res, cfg = _calibrate(SynthSpec(n_frames=120), seed=1)
    out = publish(res, seq, cfg, tmp_path)
    assert out.trust.verdict.level == "trust", [c.text for c in out.trust.verdict.causes]
    rep = json.loads(out.report.read_text())
    assert rep["verdict"] == {"level": "trust", "causes": []}
    cams = rep["uncertainty"]["cameras"]
    assert len(cams["cam0"]["intrinsics_sigma"]) == 8 and all(s > 0 for s in cams["cam0"]["intrinsics_sigma"])
    assert 0 < cams["cam1"]["projection_sigma_px"]["median"] <= cams["cam1"]["projection_sigma_px"]["p95"] < 0.15
    pair = rep["uncertainty"]["pairs"]["cam0-cam1"]
    assert pair["baseline_m"] == pytest.approx(0.05, abs=5 * pair["baseline_sigma_m"] + 1e-5)
    assert 0 < pair["translation_sigma_m"] < 1e-3 and 0 < pair["rotation_sigma_deg"] < 0.1
    cv = rep["cross_validation"]
    assert cv["ok"] and 0.4 < cv["spread_ratio"] < 1.5
    assert cv["cameras"]["cam0"]["projection_diff_median_px"] < 4 * cv["cameras"]["cam0"]["predicted_median_px"]
    assert set(rep["board"]["deformation_mm"]) == {"x", "y"} and abs(rep["board"]["deformation_mm"]["x"]) < 0.1
    assert set(rep["time_offsets_s"]) == {"cam1"}  # random views: not estimable, stated as such
    assert rep["time_offsets_s"]["cam1"] is None and "not continuous" in rep["time_offsets"]["estimates"]["cam1"]["reason"]
    page = out.page.read_text()
    assert page.index("Verdict: trust") < page.index("How far to trust it") < page.index("Camera pairs")
    assert page.count("data:image/png;base64,") >= 8  # two maps, residuals, histogram, coverage per camera; gamma


def test_unsynchronised_camera_is_named_measured_and_corrected():
    spec = SynthSpec(n_frames=200, motion="continuous", time_offsets_s=(0.0, 0.015))
    seq, gt, res, cfg = _calibrate(spec, seed=2)
    est = res.time_offset_estimates[0]
    assert est.camera == "cam1" and abs(est.value_s - 0.015) < 0.001 and est.sigma_s < 0.001
    t = assess(res, seq, cfg, TrustConfig(compare_models=False))
    assert t.verdict.level == "caution" and _codes(t)["unsynchronised"] == {"cam1"}
    (text,) = [c.text for c in t.verdict.causes if c.code == "unsynchronised"]
    assert "--time-offset auto" in text and abs(float(text.split("about ")[1].split(" ms")[0]) - 15) < 1
    # Corrected: the clean tolerances (focal < 0.5 %, extrinsics < 1 mm / 0.1 deg).
    _, _, fixed, cfg2 = _calibrate(spec, seed=2, time_offset="auto")
    assert abs(fixed.time_offsets_s[1] - 0.015) < 0.001
    assert max(abs(fixed.intrinsics[c][k] / gt.params[c][k] - 1) for c in range(2) for k in (0, 1)) < 0.005
    assert np.linalg.norm(fixed.T_cam_rig[1][:3, 3] - gt.T_cam_rig[1][:3, 3]) < 1e-3
    dR = Rotation.from_matrix(fixed.T_cam_rig[1][:3, :3] @ gt.T_cam_rig[1][:3, :3].T)
    assert math.degrees(np.linalg.norm(dR.as_rotvec())) < 0.1
    t2 = assess(fixed, seq, cfg2, TrustConfig(compare_models=False))
    assert "unsynchronised" not in _codes(t2) and "noise_model" not in _codes(t2)


def test_snapshots_of_unsynchronised_cameras_are_named_without_an_offset():
    """Every 20th frame of a continuous recording (one a second: the ROS calibrator's snapshots):
    no motion between views, so no offset is estimable; the cameras' disagreement names it."""
    seq, gt = make_sequence(paper_config(RIG), SynthSpec(n_frames=1600, motion="continuous", time_offsets_s=(0.0, 0.015)), seed=3)
    seq = seq.subset({(o.cam, o.view) for o in seq.observations if o.view % 20 == 0})
    cfg = CalibConfig(model="kb4", fov=220.0)
    res = calibrate(seq, cfg)
    assert res.success and res.time_offset_estimates[0].value_s is None
    t = assess(res, seq, cfg, TrustConfig(compare_models=False))
    assert "unsynchronised" in _codes(t) and t.tie_test["disagree"]
    assert any("not continuous" in c.text for c in t.verdict.causes if c.code == "unsynchronised")


def test_bent_board_is_measured_and_named():
    seq, gt, res, cfg = _calibrate(SynthSpec(n_frames=120, bend_m=0.003), seed=4)
    assert abs(res.warp_m[0] * 1000 - 3.0) < 0.5 and abs(res.warp_m[1] * 1000) < 0.5
    assert max(abs(res.intrinsics[c][k] / gt.params[c][k] - 1) for c in range(2) for k in (0, 1)) < 0.005
    t = assess(res, seq, cfg, TrustConfig(compare_models=False))
    assert "board_not_flat" in _codes(t)
    # The same board taken as flat: a biased focal length, and no warp reported.
    _, _, flat, _ = _calibrate(SynthSpec(n_frames=120, bend_m=0.003), seed=4, flat_board=True)
    assert np.all(flat.warp_m == 0)
    f_flat = max(abs(flat.intrinsics[c][0] / gt.params[c][0] - 1) for c in range(2))
    f_warp = max(abs(res.intrinsics[c][0] / gt.params[c][0] - 1) for c in range(2))
    assert f_flat > 3 * f_warp


def test_bent_points_are_a_circular_arc():
    from cotrain.targets import TargetConfig, make_target

    board = make_target(TargetConfig())
    P = bent_points(board, 0.003)
    x0, x1 = P[:, 0].min(), P[:, 0].max()
    assert np.allclose(P[np.isclose(P[:, 0], x0), 2], 0) and np.allclose(P[np.isclose(P[:, 0], x1), 2], 0)
    mid = np.abs(P[:, 0] - (x0 + x1) / 2).argmin()
    assert P[mid, 2] == pytest.approx(0.003, abs=1e-6)
    # Every point on one circle: equal distance from the centre below the sagitta.
    a, s = (x1 - x0) / 2, 0.003
    R = (a * a + s * s) / (2 * s)
    d = np.hypot(P[:, 0] - (x0 + x1) / 2, P[:, 2] - (s - R))
    np.testing.assert_allclose(d, R, atol=1e-9)


def test_a_lens_the_model_does_not_fit_is_named_with_the_family_that_does():
    rig = paper_config(RIG)
    rig.model, rig.shape = "eucm", {"alpha": 0.7, "beta": 1.5}
    seq, gt, res, cfg = _calibrate(SynthSpec(n_frames=100), seed=5, rig=rig)
    t = assess(res, seq, cfg)
    assert _codes(t).get("camera_model") == {"cam0", "cam1"}
    held = t.model_comparison
    assert set(held) == {"kb4", "ds", "eucm", "ucm"}
    best = {c: min(held, key=lambda m, c=c: held[m][c]) for c in range(2)}
    assert best == {0: "eucm", 1: "eucm"}, held
    assert all("--models eucm" in c.text for c in t.verdict.causes if c.code == "camera_model")
    assert "unsynchronised" not in _codes(t)  # a misfit is not taken for a timing error


def test_too_few_views_are_named():
    seq, gt, res, cfg = _calibrate(SynthSpec(n_frames=12), seed=6)
    t = assess(res, seq, cfg, TrustConfig(compare_models=False))
    assert "few_views" in _codes(t)


def test_time_offset_option_and_cli_last_line(tmp_path, capsys):
    assert time_offset_option(None) == ("estimate", {})
    assert time_offset_option(["auto"]) == ("auto", {})
    assert time_offset_option(["cam1=0.015", "cam2=-0.002"]) == ("off", {1: 0.015, 2: -0.002})
    for bad in (["cam0=0.01"], ["soon"], ["cam1=fast"]):
        with pytest.raises(ValueError):
            time_offset_option(bad)
    seq, _ = make_sequence(paper_config(RIG), SynthSpec(n_frames=60), seed=7)
    write_sequence(seq, tmp_path / "seq")
    assert calib_cli(["calibrate", str(tmp_path / "seq"), "--fov", "220", "--time-offset", "cam0=1", "--out", str(tmp_path / "o")]) == 2
    assert "name cam1, cam2" in capsys.readouterr().err
    code = calib_cli(["calibrate", str(tmp_path / "seq"), "--fov", "220", "--flat-board", "--out", str(tmp_path / "c")])
    out = capsys.readouterr().out.strip().splitlines()
    assert code == 0 and out[-1].startswith("verdict: ")
    rep = json.loads((tmp_path / "c" / "report.json").read_text())
    assert rep["board"]["deformation_mm"] is None and rep["verdict"]["level"] in ("trust", "caution")


def test_offsets_set_by_hand_correct_the_rig():
    spec = SynthSpec(n_frames=160, motion="continuous", time_offsets_s=(0.0, 0.02))
    seq, gt, res, _ = _calibrate(spec, seed=8, time_offsets_s={1: 0.02}, time_offset="off")
    assert res.time_offsets_s[1] == pytest.approx(0.02) and res.time_offset_estimates == []
    assert max(abs(res.intrinsics[c][k] / gt.params[c][k] - 1) for c in range(2) for k in (0, 1)) < 0.005
    assert np.linalg.norm(res.T_cam_rig[1][:3, 3] - gt.T_cam_rig[1][:3, 3]) < 1e-3


def test_one_camera_and_a_failed_calibration_write_strict_json(tmp_path):
    """A single camera (no pairs, no offsets) and a failure (the verdict says fail) both write a
    report.json that strict JSON parsers read (no NaN)."""
    from calib_eval.benchmark.rigs import RigSpec

    def strict(path):
        return json.loads(path.read_text(), parse_constant=lambda c: pytest.fail(f"{c} in {path}"))

    seq, _ = make_sequence(RigSpec(fov=200.0, yaws_deg=[0.0]), SynthSpec(n_frames=40), seed=9)
    cfg = CalibConfig(model="kb4", fov=200.0)
    one = publish(calibrate(seq, cfg), seq, cfg, tmp_path / "one")
    rep = strict(one.report)
    assert rep["verdict"]["level"] in ("trust", "caution") and rep["uncertainty"]["pairs"] == {} and rep["time_offsets_s"] == {}
    bad = CalibConfig(model="kb4", fov=200.0, max_rms_px=0.01)  # no calibration meets 0.01 px
    failed = publish(calibrate(seq, bad), seq, bad, tmp_path / "bad")
    rep = strict(failed.report)
    assert rep["verdict"]["level"] == "fail" and rep["verdict"]["causes"][0]["code"] == "failed" and not rep["success"]
    assert "Verdict: fail" in failed.page.read_text()
