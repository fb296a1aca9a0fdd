"""Coverage- and observability-aware frame selector (paper Sec. IV-C).

Per observation: projective isotropy s_iso (singular-value ratio of the board->image homography's
Jacobian at the board centre) and directed radial span s_drs. Stages: anchors (both gates),
co-visible (time-matched views passing the 0.6-scaled gates in two or more cameras), mono-fill
(monocular views covering weakly observed image cells, 0.6-scaled gates).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from cotrain.io.sequence import Sequence
from cotrain.targets import board_points


@dataclass
class SelectorConfig:
    fov: float = 200.0  # rough FoV (deg); s_drs gate = drs_numerator / fov
    iso_gate: float = 0.3  # s_iso threshold for anchors
    drs_numerator: float = 110.0  # s_drs threshold = this / FoV (paper: 110 / FoV)
    relax: float = 0.6  # gate scale for the co-visible and mono-fill stages
    min_corners: int = 8  # observations with fewer valid corners are dropped
    max_anchors: int = 0  # per-camera budget of anchors (0 = no limit)
    max_covisible: int = 0  # budget of co-visible views (0 = no limit)
    max_monofill: int = 0  # per-camera budget of mono-fill observations (0 = no limit)
    grid_cells: int = 8  # mono-fill coverage grid (cells per side over the usable circle)
    fill_target: int = 20  # a cell counts as weakly observed below this many corners
    centre_fraction: float = 0.05  # below this |u_bar - o| / R the principal direction is used


def isotropy_score(board_xy: np.ndarray, q: np.ndarray, centre_xy: np.ndarray) -> float:
    """s_iso = sigma_min / sigma_max of d(image) / d(board) of the homography at ``centre_xy``.

    board_xy (M, 2) board-plane coordinates, q (M, 2) pixels, centre_xy (2,) the board centre.
    """
    if len(q) < 4:
        return 0.0
    H, _ = cv2.findHomography(board_xy.astype(np.float64), q.astype(np.float64), 0)
    if H is None:
        return 0.0
    x = np.array([centre_xy[0], centre_xy[1], 1.0])
    w = H[2] @ x
    if abs(w) < 1e-12:
        return 0.0
    u = (H[:2] @ x) / w
    J = (H[:2, :2] - np.outer(u, H[2, :2])) / w  # d u / d (X, Y)
    s = np.linalg.svd(J, compute_uv=False)
    return float(s[-1] / s[0]) if s[0] > 0 else 0.0


def radial_span_score(q: np.ndarray, centre: np.ndarray, radius: float, centre_fraction: float = 0.05) -> float:
    """s_drs = (max t_j - min t_j) / 2 with t_j = (u_j - o) . a / R, a the primary radial
    direction (towards the mean corner, or the principal component when that is near o)."""
    if len(q) < 2 or radius <= 0:
        return 0.0
    d = q - centre
    mean = d.mean(0)
    if np.linalg.norm(mean) > centre_fraction * radius:
        a = mean / np.linalg.norm(mean)
    else:
        _, _, Vt = np.linalg.svd(d - mean, full_matrices=False)
        a = Vt[0]
    t = d @ a / radius
    return float((t.max() - t.min()) / 2)


@dataclass
class FrameScore:
    cam: int
    view: int
    frame: str
    n_corners: int
    s_iso: float
    s_drs: float
    stage: str = "dropped"  # anchor, covisible, monofill or dropped
    reason: str = ""
    order: int = -1  # position in the selected sequence


@dataclass
class Selection:
    scores: list[FrameScore]
    keep: set[tuple[int, int]]  # (cam, view) observations kept
    order: dict[int, list[int]]  # per camera, views in the order stage 1 should add them

    def summary(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for s in self.scores:
            out[s.stage] = out.get(s.stage, 0) + 1
        return out


def usable_radius(width: int, height: int, mask_radius: float | None = None) -> float:
    """R: the maximum valid radius from the image centre to the usable fisheye-mask boundary.

    With a measured mask radius use it (clipped to the half-diagonal); with detections only, the
    circle inscribed in the frame's shorter side is the conservative default... unless corners
    were seen farther out, which :func:`select` accounts for."""
    half_diag = 0.5 * math.hypot(width, height)
    return min(mask_radius, half_diag) if mask_radius else min(width, height) / 2.0


def score_observations(seq: Sequence, cfg: SelectorConfig) -> list[FrameScore]:
    if seq.target is None:
        raise ValueError("the sequence names no target (its detections carry none)")
    P = board_points(seq.target)
    centre_xy = P[:, :2].mean(0)
    out = []
    radii = []
    for c, cam in enumerate(seq.cameras):
        r = usable_radius(cam.width, cam.height, cam.mask_radius)
        # Detections farther out than the default prove the usable circle is larger.
        o = np.array([cam.width / 2, cam.height / 2])
        far = [np.linalg.norm(ob.q - o, axis=1).max() for ob in seq.by_camera(c) if len(ob.q)]
        if far and cam.mask_radius is None:
            r = max(r, float(np.percentile(far, 99)))
        radii.append(r)
    for ob in seq.observations:
        cam = seq.cameras[ob.cam]
        o = np.array([cam.width / 2, cam.height / 2])
        ok = np.isfinite(ob.q).all(1)
        q = ob.q[ok]
        ids = ob.ids[ok]
        if len(ids) < cfg.min_corners:
            out.append(FrameScore(ob.cam, ob.view, ob.frame, len(ids), 0.0, 0.0, "dropped", f"only {len(ids)} corners"))
            continue
        s_iso = isotropy_score(P[ids, :2], q, centre_xy)
        s_drs = radial_span_score(q, o, radii[ob.cam], cfg.centre_fraction)
        out.append(FrameScore(ob.cam, ob.view, ob.frame, len(ids), s_iso, s_drs))
    return out


def select(seq: Sequence, cfg: SelectorConfig) -> Selection:
    """Run the three stages; every observation gets a stage and a reason."""
    scores = score_observations(seq, cfg)
    iso_g = cfg.iso_gate
    drs_g = cfg.drs_numerator / cfg.fov
    by_key = {(s.cam, s.view): s for s in scores}
    obs_by_key = {(o.cam, o.view): o for o in seq.observations}
    C = len(seq.cameras)
    order: dict[int, list[int]] = {c: [] for c in range(C)}

    def passes(s: FrameScore, scale: float) -> bool:
        return s.n_corners >= cfg.min_corners and s.s_iso >= iso_g * scale and s.s_drs >= drs_g * scale

    # 1) Anchors: both gates, strongest radial span first.
    for c in range(C):
        cands = sorted((s for s in scores if s.cam == c and passes(s, 1.0)), key=lambda s: -s.s_drs * s.s_iso)
        for i, s in enumerate(cands):
            if cfg.max_anchors and i >= cfg.max_anchors:
                s.reason = "anchor budget reached"
                continue
            s.stage, s.reason = "anchor", f"s_iso {s.s_iso:.2f} >= {iso_g:.2f} and s_drs {s.s_drs:.2f} >= {drs_g:.2f}"
            order[c].append(s.view)

    # 2) Co-visible: views where >= 2 cameras pass the relaxed gates.
    views: dict[int, list[FrameScore]] = {}
    for s in scores:
        views.setdefault(s.view, []).append(s)
    n_cov = 0
    for v in sorted(views):
        good = [s for s in views[v] if passes(s, cfg.relax)]
        if len(good) < 2:
            continue
        if cfg.max_covisible and n_cov >= cfg.max_covisible:
            for s in good:
                if s.stage == "dropped":
                    s.reason = "co-visible budget reached"
            continue
        n_cov += 1
        for s in good:
            if s.stage == "dropped":
                s.stage, s.reason = "covisible", f"co-visible in {len(good)} cameras (relaxed gates)"
                order[s.cam].append(s.view)

    # 3) Mono-fill: cover weakly observed cells of each camera's image.
    for c in range(C):
        cam = seq.cameras[c]
        g = cfg.grid_cells
        counts = np.zeros((g, g))

        def cells(q: np.ndarray, cam=cam, g=g) -> np.ndarray:
            ix = np.clip((q[:, 0] / cam.width * g).astype(int), 0, g - 1)
            iy = np.clip((q[:, 1] / cam.height * g).astype(int), 0, g - 1)
            return iy * g + ix

        for s in scores:
            if s.cam == c and s.stage in ("anchor", "covisible"):
                np.add.at(counts.reshape(-1), cells(obs_by_key[(c, s.view)].q), 1)
        cands = [s for s in scores if s.cam == c and s.stage == "dropped" and passes(s, cfg.relax)]
        added = 0
        while cands and (not cfg.max_monofill or added < cfg.max_monofill):
            gains = []
            for s in cands:
                cl = cells(obs_by_key[(c, s.view)].q)
                gains.append(float(np.sum(np.clip(cfg.fill_target - counts.reshape(-1)[cl], 0, None) > 0)))
            best = int(np.argmax(gains))
            if gains[best] <= 0:
                break
            s = cands.pop(best)
            np.add.at(counts.reshape(-1), cells(obs_by_key[(c, s.view)].q), 1)
            s.stage, s.reason = "monofill", f"adds corners to {int(gains[best])} weakly observed cells"
            order[c].append(s.view)
            added += 1
        for s in cands:
            s.reason = s.reason or "passes the relaxed gates but adds no coverage"

    for s in scores:
        if s.stage == "dropped" and not s.reason:
            fails = []
            if s.s_iso < iso_g * cfg.relax:
                fails.append(f"s_iso {s.s_iso:.2f} < {iso_g * cfg.relax:.2f}")
            if s.s_drs < drs_g * cfg.relax:
                fails.append(f"s_drs {s.s_drs:.2f} < {drs_g * cfg.relax:.2f}")
            s.reason = "; ".join(fails) or "not co-visible and no coverage gain"
    keep = {(s.cam, s.view) for s in scores if s.stage != "dropped"}
    for c in range(C):
        for i, v in enumerate(order[c]):
            by_key[(c, v)].order = i
    return Selection(scores, keep, order)
