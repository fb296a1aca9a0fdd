"""The calibrator on noisy synthetic data, as mrcal's test-calibration-basic does it.

A stereo FoV220_90 kb4 rig observes the board in 60 frames; every observed corner gets
Gaussian noise of sigma px per coordinate. At the least-squares optimum the residuals are
(I - J J^+) n, so their per-coordinate RMS is sigma sqrt((N - P) / N) (N residuals, P free
parameters): a solver that stops early, a wrong Jacobian or a biased model shows as a larger
spread, an overfit (or a mis-counted problem) as a smaller one. The ground truth must be
recovered within tolerances that scale with sigma. Two noise levels, same seed: the noise draws
are the same numbers scaled, so the residuals scale with sigma too.
"""

import math

import numpy as np
import pytest
import torch

from calib_eval.benchmark.rigs import SynthSpec, make_sequence, paper_config
from calib_eval.calibration.calibrator import CalibConfig, calibrate
from cotrain.geometry import cameras

SIGMAS = (0.3, 1.0)
N_FRAMES = 60
SEED = 0
_cache: dict[float, dict] = {}


def _board_points(seq, spec) -> np.ndarray:
    target = getattr(seq, "target", None)
    if target is None:  # sequences that do not carry their target
        from cotrain.targets import make_target

        target = make_target(spec.target)
    return target.points().numpy()


def _run(sigma: float) -> dict:
    """Calibrate the noisy sequence once per sigma; residuals recomputed from the result."""
    if sigma in _cache:
        return _cache[sigma]
    rig = paper_config("FoV220_90")
    spec = SynthSpec(n_frames=N_FRAMES, noise_px=sigma)
    seq, gt = make_sequence(rig, spec, seed=SEED)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # small dense blocks: threads only contend on a shared machine
    try:
        res = calibrate(seq, CalibConfig(model="kb4", fov=rig.fov))
    finally:
        torch.set_num_threads(threads)
    P_board = _board_points(seq, spec).copy()
    # The calibrator estimates the board's warp (flat here, so close to 0): the residuals are
    # recomputed on the board as it was estimated (mrcal's two-term warp, independent math).
    lo, hi = P_board[:, :2].min(0), P_board[:, :2].max(0)
    u = (2 * P_board[:, :2] - (lo + hi)) / (hi - lo)
    P_board[:, 2] += (1 - u * u) @ res.warp_m
    r, cam = [], []
    for o in seq.observations:
        if o.view not in res.T_rig_board:
            continue
        T = res.T_cam_rig[o.cam] @ res.T_rig_board[o.view]
        pc = P_board[o.ids] @ T[:3, :3].T + T[:3, 3]
        q, ok = cameras.project(res.model[o.cam], torch.from_numpy(pc), torch.from_numpy(np.asarray(res.intrinsics[o.cam])))
        assert bool(ok.all())
        r.append(o.q - q.numpy())
        cam.append(np.full(len(o.ids), o.cam))
    out = {"rig": rig, "seq": seq, "gt": gt, "res": res, "r": np.concatenate(r), "cam": np.concatenate(cam)}
    _cache[sigma] = out
    return out


def _n_params(res) -> int:
    C = len(res.model)
    n_intr = sum(cameras.get_model(m).n_params for m in res.model)
    return n_intr + 6 * (C - 1) + 6 * len(res.T_rig_board) + 2  # cam0 is the rig frame (the gauge); 2: the board's warp


@pytest.mark.parametrize("sigma", SIGMAS)
def test_residual_spread_matches_injected_noise(sigma):
    d = _run(sigma)
    res, r = d["res"], d["r"]
    assert res.success, res.reason
    # Every view of the sequence got a pose and no corner was dropped as an outlier (5 sigma).
    assert set(res.T_rig_board) == {o.view for o in d["seq"].observations}
    N, P = r.size, _n_params(res)
    assert N > 20 * P  # a well-determined problem (about 10k residuals, 380 parameters here)
    expected = sigma * math.sqrt((N - P) / N)
    rms = float(np.sqrt((r**2).mean()))
    # Measured: within 0.4 % of the prediction at both levels; the RMS of N Gaussian samples
    # itself scatters by 1 / sqrt(2 N) ~ 0.7 %. 5 % leaves room for the Huber kernel.
    assert rms == pytest.approx(expected, rel=0.05), (rms, expected)
    for k in range(2):  # each pixel coordinate separately, and no bias
        assert float(np.sqrt((r[:, k] ** 2).mean())) == pytest.approx(expected, rel=0.06)
        assert abs(float(r[:, k].mean())) < 4 * sigma / math.sqrt(len(r))
    # The reported per-camera RMS (px, corner error norm) is the one of these residuals.
    for c in range(len(res.model)):
        e2 = (r[d["cam"] == c] ** 2).sum(1)
        assert res.rms_px[c] == pytest.approx(math.sqrt(e2.mean()), rel=1e-6)


def test_residuals_scale_with_the_noise():
    """Same seed at both levels: the noise is the same draw scaled by sigma, so the residuals
    (linear in the noise at a least-squares optimum) are too. Corner by corner the Huber kernel
    (1 px, active on most corners at sigma 1) bends this by 7 % (0.7 % without it)."""
    lo, hi = (_run(s) for s in SIGMAS)
    k = SIGMAS[1] / SIGMAS[0]
    assert lo["r"].shape == hi["r"].shape
    rms_lo, rms_hi = (float(np.sqrt((d["r"] ** 2).mean())) for d in (lo, hi))
    assert rms_hi / rms_lo == pytest.approx(k, rel=0.02)
    # Corner by corner, not only on average.
    diff = hi["r"] - k * lo["r"]
    assert float(np.sqrt((diff**2).mean())) < 0.1 * rms_hi


def _intrinsic_map_error(model: str, est: np.ndarray, ref: np.ndarray, fov: float) -> float:
    """RMS (px) between the estimated and true projections of rays over the whole FoV."""
    th, ph = np.meshgrid(np.linspace(0, math.radians(fov) / 2 * 0.98, 30), np.linspace(0, 2 * np.pi, 36, endpoint=False))
    v = torch.from_numpy(np.c_[(np.sin(th) * np.cos(ph)).ravel(), (np.sin(th) * np.sin(ph)).ravel(), np.cos(th).ravel()])
    qa = cameras.project(model, v, torch.from_numpy(np.asarray(est)))[0]
    qb = cameras.project(model, v, torch.from_numpy(np.asarray(ref)))[0]
    return float(((qa - qb) ** 2).sum(-1).mean().sqrt())


@pytest.mark.parametrize("sigma", SIGMAS)
def test_ground_truth_recovered_within_noise_scaled_tolerances(sigma):
    """Measured at sigma 0.3 / 1.0: focal 0.04 / 0.10 %, principal point 0.12 / 0.36 px,
    baseline 0.03 / 0.16 mm, rotation 0.022 / 0.048 deg."""
    d = _run(sigma)
    res, gt, rig = d["res"], d["gt"], d["rig"]
    assert res.success, res.reason
    m = cameras.get_model("kb4")
    for c in range(2):
        est, ref = np.asarray(res.intrinsics[c]), gt.params[c]
        f_err = max(abs(est[m.index(k)] / ref[m.index(k)] - 1) for k in ("fx", "fy"))
        pp_err = math.hypot(est[m.index("cx")] - ref[m.index("cx")], est[m.index("cy")] - ref[m.index("cy")])
        assert f_err < 0.004 * sigma, (c, f_err)
        assert pp_err < 1.0 * sigma, (c, pp_err)
        assert _intrinsic_map_error("kb4", est, ref, rig.fov) < 1.0 * sigma
    T, Tg = res.T_cam_rig[1], gt.T_cam_rig[1]
    assert np.linalg.norm(T[:3, 3] - Tg[:3, 3]) < 1e-3 * sigma  # metres
    dR = T[:3, :3] @ Tg[:3, :3].T
    assert math.degrees(math.acos(np.clip((np.trace(dR) - 1) / 2, -1, 1))) < 0.15 * sigma
    np.testing.assert_allclose(res.T_cam_rig[0], np.eye(4), atol=1e-12)  # cam0 is the rig
