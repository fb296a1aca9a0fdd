"""How far a calibration can be trusted from its own data: the covariance of the final solve.

The joint stage's normal equations, the target poses eliminated (Schur complement), scaled by the
measured residual variance (:func:`calib_eval.calibration.solver.covariance`), give the
covariance of every camera parameter. From it:

- a 1-sigma value for every intrinsic (Kalibr order), the board's warp and each time offset;
- per camera pair, the sigma of the baseline (m), of the translation and of the rotation: the
  relative pose T_b_a's error as a translation vector (m) and a rotation vector (deg), each
  reported per axis and as the RMS length of the error vector (``sqrt(trace)``);
- per camera, the projection uncertainty over the image, drawn like mrcal's map: the intrinsics'
  covariance propagated to the pixel a fixed ray projects to (rays fixed in the camera frame, so
  points at infinite range; the extrinsics' share is in the pair sigmas), the worst direction's
  1-sigma (px) on a grid over the image circle. mrcal also carries the reference frame's
  uncertainty into a projection at a finite range; that is not done here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from calib_eval.calibration.solver import Covariance, Params, covariance, project_with_jacobians, retract
from cotrain.geometry import cameras

GRID = (48, 27)  # projection-uncertainty map: pixel samples across x and y (a 16:9 frame at about 27 px for 1280x720)


@dataclass
class PairUncertainty:
    """The relative pose T_b_a of cameras a < b, and its uncertainty."""

    baseline_m: float
    baseline_sigma_m: float
    translation_sigma_m: float  # RMS length of the translation error vector, sqrt(trace)
    rotation_sigma_deg: float  # RMS angle of the rotation error vector, sqrt(trace)
    translation_sigma_xyz_m: np.ndarray  # (3,) per axis of camera b's frame
    rotation_sigma_xyz_deg: np.ndarray  # (3,) per axis of camera b's frame (left increment)
    cov: np.ndarray  # (7, 7) of (t_b_a (m), rotation vector (rad), baseline (m))

    def as_dict(self) -> dict:
        return {
            "baseline_m": self.baseline_m,
            "baseline_sigma_m": self.baseline_sigma_m,
            "translation_sigma_m": self.translation_sigma_m,
            "rotation_sigma_deg": self.rotation_sigma_deg,
            "translation_sigma_xyz_m": self.translation_sigma_xyz_m.tolist(),
            "rotation_sigma_xyz_deg": self.rotation_sigma_xyz_deg.tolist(),
        }


@dataclass
class ProjectionMap:
    """Per-pixel 1-sigma (px, worst direction) of one camera's projection over its image."""

    xs: np.ndarray  # (W',) pixel x of the grid columns
    ys: np.ndarray  # (H',) pixel y of the grid rows
    sigma_px: np.ndarray  # (H', W'); nan outside the region the corners cover
    median_px: float  # over the covered region
    p95_px: float
    max_px: float


@dataclass
class Uncertainty:
    sigma_px: float  # measured corner noise per pixel coordinate (weight 1)
    intrinsics_sigma: list[np.ndarray]  # per camera, Kalibr order
    pairs: dict[tuple[int, int], PairUncertainty]
    projection: list[ProjectionMap]
    warp_sigma_m: np.ndarray | None  # (2,), where the warp was estimated
    time_offsets_sigma_s: dict[int, float] = field(default_factory=dict)  # cameras whose offset was estimated
    cov: Covariance | None = None


def pair_quantities(T_cam_rig: np.ndarray, a: int, b: int, R_ref: np.ndarray) -> np.ndarray:
    """(7,): T_b_a's translation (3, m), its rotation as a vector from ``R_ref`` (3, rad:
    log(R_b_a R_ref^T)) and the baseline |t_b_a| (m)."""
    T = T_cam_rig[b] @ np.linalg.inv(T_cam_rig[a])
    w = Rotation.from_matrix(T[:3, :3] @ R_ref.T).as_rotvec()
    return np.r_[T[:3, 3], w, np.linalg.norm(T[:3, 3])]


def pair_uncertainty(cov: Covariance, T_cam_rig: np.ndarray, a: int, b: int) -> PairUncertainty:
    """Propagate the two cameras' extrinsic covariance to T_b_a by central differences."""
    L = cov.layout
    cols = [(c, o + k) for c in (a, b) for o, n in [L.extr[c]] for k in range(n)]
    T0 = T_cam_rig[b] @ np.linalg.inv(T_cam_rig[a])
    g0 = pair_quantities(T_cam_rig, a, b, T0[:3, :3])
    J = np.zeros((7, len(cols)))
    h = 1e-7
    for j, (c, col) in enumerate(cols):
        k = col - L.extr[c][0]
        d = np.zeros(6)
        d[k] = h
        Tp, Tm = T_cam_rig.copy(), T_cam_rig.copy()
        Tp[c], Tm[c] = retract(T_cam_rig[c], d), retract(T_cam_rig[c], -d)
        J[:, j] = (pair_quantities(Tp, a, b, T0[:3, :3]) - pair_quantities(Tm, a, b, T0[:3, :3])) / (2 * h)
    idx = [col for _, col in cols]
    S = cov.cov[idx][:, idx] if idx else np.zeros((0, 0))
    P = J @ S @ J.T
    d = np.sqrt(np.clip(np.diagonal(P), 0, None))
    return PairUncertainty(
        float(g0[6]),
        float(d[6]),
        float(math.sqrt(max(np.trace(P[:3, :3]), 0))),
        math.degrees(math.sqrt(max(np.trace(P[3:6, 3:6]), 0))),
        d[:3],
        np.degrees(d[3:6]),
        P,
    )


def projection_sigma(model: str, intr: np.ndarray, cov_intr: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Worst-direction 1-sigma (px) (N,) of the projection of the rays through pixels q (N, 2)
    under the intrinsics' covariance ``cov_intr`` (P, P); nan where a pixel does not unproject."""
    ray, ok = cameras.unproject(model, q, intr)
    _, valid, _, Ji = project_with_jacobians(model, ray, intr)
    Sq = Ji @ cov_intr @ Ji.transpose(0, 2, 1)  # (N, 2, 2)
    lam = np.sqrt(np.maximum(np.linalg.eigvalsh(Sq)[:, -1], 0))
    return np.where(ok & valid, lam, math.nan)


def grid_pixels(width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    xs = np.linspace(0, width - 1, GRID[0])
    ys = np.linspace(0, height - 1, GRID[1])
    X, Y = np.meshgrid(xs, ys)
    return xs, ys, np.c_[X.ravel(), Y.ravel()]


def covered(q_grid: np.ndarray, corners: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(N,) grid pixels inside the region the corners cover: within the 99.5th percentile of the
    corners' radius from the image centre (the calibration says nothing beyond)."""
    if not len(corners):
        return np.zeros(len(q_grid), bool)
    r_max = float(np.percentile(np.linalg.norm(corners - centre, axis=1), 99.5))
    return np.linalg.norm(q_grid - centre, axis=1) <= r_max


def projection_map(model: str, intr: np.ndarray, cov_intr: np.ndarray, width: int, height: int, corners: np.ndarray) -> ProjectionMap:
    xs, ys, q = grid_pixels(width, height)
    s = projection_sigma(model, intr, cov_intr, q)
    inside = covered(q, corners, np.array([(width - 1) / 2, (height - 1) / 2]))
    s = np.where(inside, s, np.nan)
    v = s[np.isfinite(s)]
    stats = (float(np.median(v)), float(np.percentile(v, 95)), float(v.max())) if len(v) else (math.nan,) * 3
    return ProjectionMap(xs, ys, s.reshape(len(ys), len(xs)), *stats)


def uncertainty_of(
    final_problem, models: list[str], params: Params, free, huber: float, sizes: list[tuple[int, int]], corners: list[np.ndarray]
) -> Uncertainty:
    """The uncertainty of a solve. ``sizes``: (width, height) per camera; ``corners``: the pixels
    each camera's calibration used (the region its projection map covers)."""
    cov = covariance(final_problem, models, params, free=free, huber=huber)
    C, L = len(models), cov.layout
    intr_sigma = [cov.sigma(L.intr[c]) for c in range(C)]
    pairs = {(a, b): pair_uncertainty(cov, params.T_cam_rig, a, b) for a in range(C) for b in range(a + 1, C)} if free.extr else {}
    maps = [projection_map(models[c], params.intr[c], cov.block(L.intr[c]), sizes[c][0], sizes[c][1], corners[c]) for c in range(C)]
    warp_sigma = cov.sigma(L.warp) if L.warp[1] else None
    dt_sigma = {c: float(cov.sigma(L.time[c])[0]) for c in range(C) if L.time[c][1]}
    return Uncertainty(cov.sigma_px, intr_sigma, pairs, maps, warp_sigma, dt_sigma, cov)
