"""Cross-validation: the calibration solved again on disjoint halves of its views.

The views of the final joint solve are split at random into two halves; each half is solved from
the full solution (the same free parameters, the target poses of its own views) and its covariance
computed (:func:`calib_eval.calibration.solver.covariance`). Two independent halves differ by a
vector whose covariance is the sum of theirs, so the spread they show can be held against the
spread the noise model predicts:

- per camera, the projection difference between the halves over the image (px, the same ray
  through both; median, 95th percentile and a map), against its predicted 1-sigma;
- per camera pair, the difference of the halves' relative poses (mm, deg), against its sigma;
- ``spread_ratio``: sqrt(d^T (S_a + S_b)^-1 d / P) over all P camera parameters, 1 where the
  noise model holds; a larger value says the stated sigma is too small (correlated errors: an
  unsynchronised camera, a bent board, a lens the model does not fit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from calib_eval.calibration.solver import Covariance, Params, covariance, solve_params
from calib_eval.calibration.uncertainty import covered, grid_pixels, pair_uncertainty, projection_sigma
from cotrain.geometry import cameras


@dataclass
class CrossValidationConfig:
    repeats: int = 1  # random splits into two halves (each costs two warm-started joint solves)
    seed: int = 0  # of the splits
    iters: int = 40  # LM iterations per half
    min_views: int = 4  # every camera needs this many views in each half, or no cross-validation


@dataclass
class ProjectionDiff:
    """One camera's projection difference between the halves over its image (px)."""

    xs: np.ndarray
    ys: np.ndarray
    diff_px: np.ndarray  # (H', W'), nan outside the covered region
    median_px: float
    p95_px: float
    predicted_median_px: float  # the same statistics of the predicted 1-sigma of the difference
    predicted_p95_px: float


@dataclass
class CrossValidation:
    ok: bool
    reason: str  # why there is none, or "ok"
    splits: int = 0
    spread_ratio: float = math.nan  # sqrt(Mahalanobis^2 / P): 1 where the noise model holds
    n_params: int = 0
    projection: list[ProjectionDiff] = field(default_factory=list)
    pairs: dict[tuple[int, int], dict] = field(default_factory=dict)  # translation_m, rotation_deg and their predicted sigma
    focal_diff_pct: list[float] = field(default_factory=list)  # per camera, largest |fx, fy| difference between halves (%)

    def as_dict(self, names: list[str]) -> dict:
        if not self.ok:
            return {"ok": False, "reason": self.reason}
        return {
            "ok": True,
            "splits": self.splits,
            "spread_ratio": self.spread_ratio,
            "n_params": self.n_params,
            "cameras": {
                names[c]: {
                    "projection_diff_median_px": d.median_px,
                    "projection_diff_p95_px": d.p95_px,
                    "predicted_median_px": d.predicted_median_px,
                    "predicted_p95_px": d.predicted_p95_px,
                    "focal_diff_pct": self.focal_diff_pct[c],
                }
                for c, d in enumerate(self.projection)
            },
            "pairs": {f"{names[a]}-{names[b]}": v for (a, b), v in self.pairs.items()},
        }


def split_views(views: list[int], rng: np.random.Generator) -> tuple[set[int], set[int]]:
    perm = rng.permutation(len(views))
    half = len(views) // 2
    return {views[i] for i in perm[:half]}, {views[i] for i in perm[half:]}


def fit_half(final, models: list[str], keep: set[int], cfg: CrossValidationConfig) -> tuple[Params, Covariance] | None:
    """Solve the final problem restricted to the views ``keep``, from the full solution."""
    used = [o for o in final.used if o.view in keep]
    for c in range(len(models)):
        if sum(1 for o in used if o.cam == c) < cfg.min_views:
            return None
    view_ids = np.asarray(final.views)[final.problem.view]  # (O,) each corner's view id
    sub, rows = final.problem.select(np.isin(view_ids, sorted(keep)))
    p, f = final.params, final.free
    start = Params(p.intr, p.T_cam_rig, p.T_rig_board[rows], p.warp, p.time_offsets)
    half, _ = solve_params(sub, models, start, f, cfg.iters, final.huber)
    return half, covariance(sub, models, half, free=f, huber=final.huber)


def _difference(a: Params, b: Params, cov: Covariance) -> np.ndarray:
    """b - a in the camera block's parametrisation (extrinsics as the left increment a -> b)."""
    L = cov.layout
    d = np.zeros(L.n)
    for c in range(len(a.intr)):
        o, n = L.intr[c]
        if n:
            d[o : o + n] = b.intr[c] - a.intr[c]
        o, n = L.extr[c]
        if n:
            D = b.T_cam_rig[c] @ np.linalg.inv(a.T_cam_rig[c])
            d[o : o + n] = np.r_[Rotation.from_matrix(D[:3, :3]).as_rotvec(), D[:3, 3]]
        o, n = L.time[c]
        if n:
            d[o] = float(b.time_offsets[c] - a.time_offsets[c])
    o, n = L.warp
    if n:
        d[o : o + n] = b.warp - a.warp
    return d


def _projection_diff(model, intr, a: Params, b: Params, ca: Covariance, cb: Covariance, c: int, size, corners) -> ProjectionDiff:
    xs, ys, q = grid_pixels(*size)
    ray, ok = cameras.unproject(model, q, intr)
    qa = cameras.project(model, ray, a.intr[c])[0]
    qb = cameras.project(model, ray, b.intr[c])[0]
    diff = np.where(ok, np.linalg.norm(qa - qb, axis=-1), math.nan)
    span = ca.layout.intr[c]
    pred = projection_sigma(model, intr, ca.block(span) + cb.block(span), q)
    inside = covered(q, corners, np.array([(size[0] - 1) / 2, (size[1] - 1) / 2]))
    diff, pred = np.where(inside, diff, np.nan), np.where(inside, pred, np.nan)
    stat = lambda v: (float(np.nanmedian(v)), float(np.nanpercentile(v, 95))) if np.isfinite(v).any() else (math.nan, math.nan)  # noqa: E731
    return ProjectionDiff(xs, ys, diff.reshape(len(ys), len(xs)), *stat(diff), *stat(pred))


def cross_validate(final, models: list[str], sizes, corners, cfg: CrossValidationConfig) -> CrossValidation:
    """Split, solve both halves, compare. ``sizes`` and ``corners`` as for the uncertainty."""
    rng = np.random.default_rng(cfg.seed)
    C = len(models)
    m2, n_par, diffs, pairs, focal = 0.0, 0, [], {}, [0.0] * C
    for _ in range(cfg.repeats):
        A, B = split_views(final.views, rng)
        fa, fb = fit_half(final, models, A, cfg), fit_half(final, models, B, cfg)
        if fa is None or fb is None:
            return CrossValidation(False, f"a camera has fewer than {cfg.min_views} views in one half of the views")
        (pa, ca), (pb, cb) = fa, fb
        d = _difference(pa, pb, ca)
        S = ca.cov + cb.cov
        m2 += float(d @ np.linalg.lstsq(S, d, rcond=1e-12)[0])
        n_par += len(d)
        diffs.append([_projection_diff(models[c], final.params.intr[c], pa, pb, ca, cb, c, sizes[c], corners[c]) for c in range(C)])
        for c in range(C):
            m = cameras.get_model(models[c])
            for k in ("fx", "fy"):
                i = m.index(k)
                focal[c] = max(focal[c], 100 * abs(float(pb.intr[c][i] / pa.intr[c][i]) - 1))
        if final.free.extr:
            for a in range(C):
                for b in range(a + 1, C):
                    pairs.setdefault((a, b), []).append(_pair_diff(pa, pb, ca, cb, a, b))
    proj = [diffs[0][c] for c in range(C)]  # the first split's maps (the statistics of one split)
    pair_out = {k: {key: float(np.median([x[key] for x in v])) for key in v[0]} for k, v in pairs.items()}
    return CrossValidation(True, "ok", cfg.repeats, math.sqrt(m2 / max(n_par, 1)), n_par, proj, pair_out, focal)


def _pair_diff(pa: Params, pb: Params, ca: Covariance, cb: Covariance, a: int, b: int) -> dict:
    Ta = pa.T_cam_rig[b] @ np.linalg.inv(pa.T_cam_rig[a])
    Tb = pb.T_cam_rig[b] @ np.linalg.inv(pb.T_cam_rig[a])
    ua, ub = pair_uncertainty(ca, pa.T_cam_rig, a, b), pair_uncertainty(cb, pb.T_cam_rig, a, b)
    return {
        "translation_m": float(np.linalg.norm(Tb[:3, 3] - Ta[:3, 3])),
        "rotation_deg": math.degrees(np.linalg.norm(Rotation.from_matrix(Tb[:3, :3] @ Ta[:3, :3].T).as_rotvec())),
        "baseline_m": float(abs(np.linalg.norm(Tb[:3, 3]) - np.linalg.norm(Ta[:3, 3]))),
        "predicted_translation_sigma_m": math.hypot(ua.translation_sigma_m, ub.translation_sigma_m),
        "predicted_rotation_sigma_deg": math.hypot(ua.rotation_sigma_deg, ub.rotation_sigma_deg),
        "predicted_baseline_sigma_m": math.hypot(ua.baseline_sigma_m, ub.baseline_sigma_m),
    }
