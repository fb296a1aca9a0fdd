"""Initial values for the calibrator: intrinsics from the rough FoV (and a 1-D focal search),
target poses from bearing vectors (valid beyond 90 degrees off-axis: bearings are never divided
by z), and a robust mean of poses for the camera extrinsics.
"""

from __future__ import annotations

import math

import numpy as np

from cotrain.geometry import cameras
from cotrain.io.sequence import Observation
from cotrain.targets import Target, board_points


# --------------------------------------------------------------------------------------------
# Pose initialisation from bearing vectors
# --------------------------------------------------------------------------------------------
def pose_from_bearings(X: np.ndarray, v: np.ndarray) -> np.ndarray | None:
    """T_cam_board of a planar target from board points X (M, 3) with z = 0 and unit bearings v (M, 3).

    DLT on v x (H [x, y, 1]) = 0 with H = [r1 r2 t]; works for rays beyond 90 degrees because
    bearings are never divided by z. Returns None when degenerate.
    """
    if len(X) < 4:
        return None
    m = X[:, :2].mean(0)
    s = np.sqrt(((X[:, :2] - m) ** 2).sum(1).mean()) + 1e-12
    xn = np.c_[(X[:, :2] - m) / s, np.ones(len(X))]
    a, b, c = (v[:, i : i + 1] * xn for i in range(3))  # (M, 3) each: bearing component times x
    z = np.zeros_like(xn)
    rows = np.concatenate([np.c_[z, -c, b], np.c_[c, z, -a], np.c_[-b, a, z]], 0)  # rows of v x (H x) = 0
    _, _, Vt = np.linalg.svd(rows, full_matrices=False)
    H = Vt[-1].reshape(3, 3)
    # Undo the normalisation: x_n = N x with N = [[1/s, 0, -m/s], [0, 1/s, -m/s], [0, 0, 1]].
    N = np.array([[1 / s, 0, -m[0] / s], [0, 1 / s, -m[1] / s], [0, 0, 1]])
    H = H @ N
    scale = (np.linalg.norm(H[:, 0]) + np.linalg.norm(H[:, 1])) / 2
    if scale < 1e-12:
        return None
    H = H / scale
    if np.mean(np.einsum("ij,ij->i", (H @ np.c_[X[:, :2], np.ones(len(X))].T).T, v)) < 0:
        H = -H
    R = np.c_[H[:, 0], H[:, 1], np.cross(H[:, 0], H[:, 1])]
    U, _, Vt2 = np.linalg.svd(R)
    R = U @ np.diag([1, 1, np.linalg.det(U @ Vt2)]) @ Vt2
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = H[:, 2]
    return T


def view_pose(model: str, intr: np.ndarray, o: Observation, board: Target) -> np.ndarray | None:
    v, ok = cameras.unproject(model, np.asarray(o.q, dtype=np.float64), intr)
    if ok.sum() < 4:
        return None
    return pose_from_bearings(board_points(board)[o.ids[ok]], v[ok])


def initial_guess(model: str, fov: float, width: int, height: int, radius: float = 0.0) -> np.ndarray:
    """Intrinsics from the rough FoV and image size: the FoV fills a circle of ``radius`` (default
    half the shorter side) about the image centre; shape parameters at the family's defaults."""
    return cameras.make_camera(model, fov, width, height, radius or min(width, height) / 2.0, dtype=np.float64)


def focal_search(model: str, guess: np.ndarray, obs: list[Observation], board: Target) -> np.ndarray:
    """Scale the guess's focal length to best explain a few views (1-D search, bearing poses)."""
    m = cameras.get_model(model)
    best, best_cost = guess, float("inf")
    for scale in np.exp(np.linspace(math.log(0.4), math.log(2.5), 25)):
        g = guess.copy()
        g[m.index("fx")] *= scale
        g[m.index("fy")] *= scale
        costs = []
        for o in obs[:8]:
            T = view_pose(model, g, o, board)
            if T is None:
                costs.append(1e6)
                continue
            pc = board_points(board)[o.ids] @ T[:3, :3].T + T[:3, 3]
            q, ok = cameras.project(model, pc, g)
            err = np.linalg.norm(q - o.q, axis=1)
            err[~ok] = 1e3
            costs.append(float(np.median(err)))
        c = float(np.median(costs)) if costs else float("inf")
        if c < best_cost:
            best, best_cost = g, c
    return best


def average_pose(Ts: list[np.ndarray]) -> np.ndarray:
    """Robust mean of poses: chordal mean of rotations near the median, median translation."""
    Rs = np.stack([T[:3, :3] for T in Ts])
    ts = np.stack([T[:3, 3] for T in Ts])
    t = np.median(ts, axis=0)
    M = np.median(Rs, axis=0)
    U, _, Vt = np.linalg.svd(M)
    R = U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R, t
    return out
