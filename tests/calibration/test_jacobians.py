"""The calibrator's Jacobians against central finite differences, for every camera model.

``project_with_jacobians`` gives d q / d p and d q / d intrinsics; ``observation_jacobians`` chains them
with the hand-derived d p_c / d (pose increment) of the left retraction ``retract`` that the LM
solver applies to T_cam_rig and T_rig_board. Every block is compared with central differences in
float64 (poses perturbed through ``retract`` itself) on points spread over a 220-240 degree
image, rays beyond 90 degrees off-axis and the optical axis included. The solver is numpy (its
Jacobians central differences, :data:`calib_eval.calibration.solver._FD_STEP`); torch's autograd
through the same camera functions is the independent reference for the projection Jacobians.
"""

import math

import numpy as np
import pytest
import torch

from calib_eval.calibration.solver import observation_jacobians, project_with_jacobians, retract
from cotrain.geometry import cameras, poses

# Per model: FoV (deg) and non-default shape parameters (every parameter plays a part).
CASES = {
    "kb4": (240.0, {"k1": 0.02, "k2": -0.004, "k3": 0.0015, "k4": -0.0002}),
    "ucm": (230.0, {"xi": 1.25}),
    "eucm": (220.0, {"alpha": 0.62, "beta": 1.15}),
    "ds": (240.0, {"xi": -0.12, "alpha": 0.6}),
}
RTOL = 1e-5


def _intrinsics(model: str) -> np.ndarray:
    fov, shape = CASES[model]
    x = cameras.make_camera(model, fov, 1280, 720, radius=400.0, principal=(641.3, 357.8), dtype=np.float64, **shape)
    fx = cameras.get_model(model).index("fx")
    x[fx + 1] *= 1.01  # fy != fx, so the two focal lengths are told apart
    return x


def _rays(model: str, n: int = 40, seed: int = 0) -> np.ndarray:
    """Camera-frame points (n + 1, 3): off-axis angles from 0 to 0.98 of the half FoV (the last
    third beyond 90 degrees), random azimuths and depths, plus one point on the optical axis."""
    rng = np.random.default_rng(seed)
    half = math.radians(CASES[model][0]) / 2
    theta = np.linspace(0.02, 0.98 * half, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    dist = rng.uniform(0.2, 3.0, n)
    v = np.c_[np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)]
    return np.r_[v * dist[:, None], [[0.0, 0.0, 0.7]]]


def _random_pose(rng: np.random.Generator, angle: float = 2.0, trans: float = 0.3) -> np.ndarray:
    w = rng.normal(size=3)
    w = w / np.linalg.norm(w) * rng.uniform(0.1, angle)
    return poses.pose_from_axis_angle(w, rng.normal(scale=trans, size=3))


def _project(model, p, intr):
    return cameras.project(model, p, intr)[0]


def _check(analytic: np.ndarray, numeric: np.ndarray, what: str) -> None:
    """Element-wise rtol plus an absolute floor of 1e-6 of the block's largest entry (per point)."""
    a, n = np.asarray(analytic), np.asarray(numeric)
    scale = np.abs(n).reshape(len(n), -1).max(1)[:, None, None]
    bad = np.abs(a - n) > RTOL * np.abs(n) + 1e-6 * scale
    assert not bad.any(), f"{what}: {bad.sum()} entries differ, worst {np.abs(a - n).max():.3e} (max |J| {scale.max():.3e})"


def _fd_intrinsics(model, p, intr):
    cols = []
    for k in range(intr.size):
        h = 1e-6 * max(1.0, abs(float(intr[k])))
        e = np.zeros_like(intr)
        e[k] = h
        cols.append((_project(model, p, intr + e) - _project(model, p, intr - e)) / (2 * h))
    return np.stack(cols, -1)  # (O, 2, P)


@pytest.mark.parametrize("model", list(CASES))
def test_projection_jacobians_match_finite_differences(model):
    intr = _intrinsics(model)
    p = _rays(model)
    ang = cameras.off_axis_angle(p)
    assert (ang > math.pi / 2).sum() >= 6 and float(ang.max()) > math.radians(105)  # well beyond 90 degrees
    q, valid, Jp, Ji = project_with_jacobians(model, p, intr)
    assert valid.all()
    assert isinstance(q, np.ndarray) and isinstance(Ji, np.ndarray)
    np.testing.assert_allclose(q, _project(model, p, intr), rtol=0, atol=1e-9)
    # The points land inside the 1280 x 720 image (the FoV's circle of radius 400 px).
    r = np.linalg.norm(q - np.array([641.3, 357.8]), axis=-1)
    assert float(r.max()) < 400 * 1.01 + 5 and float(r.max()) > 300
    assert Jp.shape == (len(p), 2, 3) and Ji.shape == (len(p), 2, intr.size)
    # d q / d p, with steps relative to the point's distance.
    cols = []
    for k in range(3):
        h = 1e-6 * np.linalg.norm(p, axis=-1, keepdims=True)
        e = np.zeros_like(p)
        e[:, k] = 1.0
        cols.append((_project(model, p + h * e, intr) - _project(model, p - h * e, intr)) / (2 * h))
    _check(Jp, np.stack(cols, -1), f"{model} dq/dp")
    _check(Ji, _fd_intrinsics(model, p, intr), f"{model} dq/dintr")
    # Known entries: q is fx * mx + cx, so d q / d cx = (1, 0) and d q / d cy = (0, 1).
    m = cameras.get_model(model)
    np.testing.assert_array_equal(Ji[:, :, m.index("cx")], np.broadcast_to([1.0, 0.0], (len(p), 2)))
    np.testing.assert_array_equal(Ji[:, :, m.index("cy")], np.broadcast_to([0.0, 1.0], (len(p), 2)))


def _autograd_jacobians(model: str, p: np.ndarray, intr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d q / d p (O, 2, 3) and d q / d intr (O, 2, P) by torch's autograd through the same camera
    function (its torch path): two reverse passes, one per pixel coordinate."""
    proj = cameras.get_model(model).project
    p_ = torch.from_numpy(p).requires_grad_(True)
    i_ = torch.from_numpy(intr).expand(len(p), -1).clone().requires_grad_(True)
    q, _ = proj(p_, i_)
    gx = torch.autograd.grad(q[:, 0].sum(), (p_, i_), retain_graph=True)
    gy = torch.autograd.grad(q[:, 1].sum(), (p_, i_))
    return torch.stack([gx[0], gy[0]], 1).numpy(), torch.stack([gx[1], gy[1]], 1).numpy()


@pytest.mark.parametrize("model", list(CASES))
def test_projection_jacobians_match_autograd(model):
    """The numpy Jacobians agree with autograd to 1e-8 relative, with an absolute floor of 1e-11 of
    the block's largest entry (round-off of a central difference of a pixel: about 1e-8 px per unit
    of k1 near the axis, where d q / d k1 itself is small); far below the solver's needs."""
    intr = _intrinsics(model)
    p = _rays(model)
    _, _, Jp, Ji = project_with_jacobians(model, p, intr)
    Jp_ref, Ji_ref = _autograd_jacobians(model, p, intr)
    for a, n, what in ((Jp, Jp_ref, "dq/dp"), (Ji, Ji_ref, "dq/dintr")):
        np.testing.assert_allclose(a, n, rtol=1e-8, atol=1e-11 * np.abs(n).max(), err_msg=f"{model} {what} vs autograd")


def test_retract_is_a_left_increment():
    rng = np.random.default_rng(3)
    T = _random_pose(rng)
    np.testing.assert_allclose(retract(T, np.zeros(6)), T, rtol=0, atol=1e-15)
    d = rng.normal(scale=0.3, size=6)
    expected = poses.pose_from_axis_angle(d[:3], np.zeros(3)) @ T
    expected[:3, 3] += d[3:]
    out = retract(T, d)
    np.testing.assert_allclose(out, expected, rtol=0, atol=1e-12)
    R = out[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), rtol=0, atol=1e-12)
    # Batched: one increment per pose.
    Ts = np.stack([T, _random_pose(rng)])
    ds = rng.normal(scale=0.1, size=(2, 6))
    out = retract(Ts, ds)
    for i in range(2):
        np.testing.assert_allclose(out[i], retract(Ts[i], ds[i]), rtol=0, atol=1e-14)


def _observations(model: str, seed: int = 1):
    """Per observation: a shared T_cam_rig (expanded), T_rig_board and a board point X (z = 0),
    built so that the points in the camera frame are :func:`_rays` (same spread, beyond 90 deg)."""
    rng = np.random.default_rng(seed)
    p_c = _rays(model, seed=seed)
    n_obs = len(p_c)
    T_cam_rig = _random_pose(rng)
    X = np.c_[rng.uniform(0, 0.4, (n_obs, 2)), np.zeros(n_obs)]
    T_rig_board = []
    for o in range(n_obs):
        T_cam_board = _random_pose(rng, angle=3.0)
        T_cam_board[:3, 3] = p_c[o] - T_cam_board[:3, :3] @ X[o]
        T_rig_board.append(poses.invert(T_cam_rig) @ T_cam_board)
    return np.broadcast_to(T_cam_rig, (n_obs, 4, 4)).copy(), np.stack(T_rig_board), X, p_c


def _q_of(model, intr, T_cam_rig, T_rig_board, X):
    T = T_cam_rig @ T_rig_board
    return _project(model, (T[:, :3, :3] @ X[:, :, None])[..., 0] + T[:, :3, 3], intr)


def _fd_pose(fn, T, h=1e-6):
    """Central differences of fn(T') over the 6 left increments of retract, per observation."""
    cols = []
    for k in range(6):
        d = np.zeros((T.shape[0], 6))
        d[:, k] = h
        cols.append((fn(retract(T, d)) - fn(retract(T, -d))) / (2 * h))
    return np.stack(cols, -1)  # (O, 2, 6)


@pytest.mark.parametrize("model", list(CASES))
def test_pose_and_intrinsic_jacobians_match_finite_differences(model):
    intr = _intrinsics(model)
    T_cam_rig, T_rig_board, X, p_c = _observations(model)
    # The construction puts the points where intended (beyond 90 degrees included).
    T = T_cam_rig @ T_rig_board
    np.testing.assert_allclose((T[:, :3, :3] @ X[:, :, None])[..., 0] + T[:, :3, 3], p_c, rtol=0, atol=1e-12)
    q, Ji, Jc, Jp = observation_jacobians(model, intr, T_cam_rig, T_rig_board, X)
    n_obs, P = len(X), intr.size
    assert q.shape == (n_obs, 2) and Ji.shape == (n_obs, 2, P) and Jc.shape == (n_obs, 2, 6) and Jp.shape == (n_obs, 2, 6)
    np.testing.assert_allclose(q, _q_of(model, intr, T_cam_rig, T_rig_board, X), rtol=0, atol=1e-9)
    _check(Ji, _fd_intrinsics(model, p_c, intr), f"{model} dq/dintr")
    _check(Jc, _fd_pose(lambda Tc: _q_of(model, intr, Tc, T_rig_board, X), T_cam_rig), f"{model} dq/d(cam increment)")
    _check(Jp, _fd_pose(lambda Tb: _q_of(model, intr, T_cam_rig, Tb, X), T_rig_board), f"{model} dq/d(pose increment)")
    # Both pose blocks are non-trivial (a wrong sign or a right increment would show here).
    assert float(np.abs(Jc).max()) > 100 and float(np.abs(Jp).max()) > 100
