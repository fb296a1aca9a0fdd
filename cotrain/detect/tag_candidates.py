"""Tag pass, stage 1: candidates (:mod:`cotrain.detect.tag_pass`, step 1).

Takes a frame's grey image (H, W) and its image circle (``allowed`` (H, W) bool); gives the
fitted saddle points inside it, strongest first (:func:`tag_candidates`), with the distance to
the rim, the image's blurs and the candidates' edge rays (:class:`_Candidates`,
:func:`_candidates_of`), and each candidate's nearest candidates along its edge rays, reached
along an edge (:class:`RayNeighbours`, :func:`axis_neighbours`), from which the seeds and the
growth take their steps.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import NamedTuple

import cv2
import numba
import numpy as np
from scipy.spatial import cKDTree

from cotrain.detect.saddle import fit_saddles, saddle_response, smooth_cached, smooth_for, window_half
from cotrain.detect.sampling import beside_points, corner_rays, values_at
from cotrain.detect.tag_config import TagConfig


def tag_candidates(
    grey: np.ndarray,
    allowed: np.ndarray,
    cfg: TagConfig,
    smoothed: dict[int, np.ndarray],
    rim_dist: np.ndarray,
    response: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Fitted saddle points inside ``allowed`` (H, W), strongest first; ``response``: the image's
    :func:`saddle_response` at ``cfg.response_sigma`` where it is computed already.

    Returns xy (K, 2) and the response (K,)."""
    D = saddle_response(grey, cfg.response_sigma) if response is None else response
    peak = (D >= cv2.dilate(D, np.ones((3, 3), np.uint8))) & (D > cfg.min_response) & allowed
    ys, xs = np.nonzero(peak)
    r = D[ys, xs]
    order = np.argsort(-r)[: cfg.max_candidates]
    xy0 = np.stack([xs[order], ys[order]], 1).astype(np.float64)
    r = r[order].astype(np.float64)
    if len(xy0) < 2:
        return np.zeros((0, 2)), np.zeros(0)
    d, _ = cKDTree(xy0).query(xy0, k=2)
    halves = window_half(np.maximum(d[:, 1], 2.0))
    xy, ok = np.zeros_like(xy0), np.zeros(len(xy0), bool)
    # The point-symmetry test looser than the grid pass's: in a tag of 8-12 px the crossing square
    # (2-4 px) ends inside the smallest window, and its far corner breaks the symmetry.
    gcfg = replace(cfg.grid, min_symmetry=cfg.complete.min_symmetry)
    for h in np.unique(halves):
        m = halves == h
        xy[m], ok[m], _ = fit_saddles(grey, smoothed, xy0[m], int(h), gcfg, rim_dist)
    keep = np.nonzero(ok)[0]
    drop = np.zeros(len(keep), bool)
    for i, j in sorted(cKDTree(xy[keep]).query_pairs(cfg.grid.merge_radius_px)):
        if not drop[i]:
            drop[j] = True
    keep = keep[~drop]
    return xy[keep], r[keep]


class RayNeighbours(NamedTuple):
    """Every candidate's nearest candidates along its edge rays (:func:`axis_neighbours`)."""

    step: np.ndarray  # (K, axis, way (+, -), option, 2) step vectors to them, NaN where there are fewer
    index: np.ndarray  # (K, axis, way, option) their indices, -1 where there are fewer


def axis_neighbours(xy: np.ndarray, rays: np.ndarray, tree: cKDTree, img: np.ndarray, cfg: TagConfig) -> RayNeighbours:
    """The nearest candidate along each of a candidate's four edge rays (see :func:`corner_rays`),
    within ``cfg.seed_axis_angle``, reached along an edge (:func:`edges_along`: a tag's own data
    junctions lie in the cone of its side, but not on it), as lattice axes: rays 0 and 2 are axis
    0 (+, -), rays 1 and 3 axis 1. Returns the step vectors to the first ``cfg.ray_options`` such
    candidates, nearest first, and their indices."""
    K = len(xy)
    d, nb = tree.query(xy, k=min(cfg.ray_search, K))
    d, nb = d.reshape(K, -1), nb.reshape(K, -1)
    v = xy[np.minimum(nb, K - 1)] - xy[:, None]  # (K, n, 2), nearest first
    # Per candidate and ray, the nearest ray_tries neighbours in its cone (columns of nb, -1 where fewer).
    cones = _in_cone(v, d, np.nan_to_num(rays), float(np.cos(np.radians(cfg.seed_axis_angle))), cfg.ray_tries)
    out = np.full((K, 2, 2, cfg.ray_options, 2), np.nan)
    idx = np.full((K, 2, 2, cfg.ray_options), -1)
    rows = np.arange(K)
    for r in range(4):
        found = np.zeros(K, int)
        for j in range(cfg.ray_tries):  # the nearest few in the cone, nearest first
            has = (cones[:, r, j] >= 0) & (found < cfg.ray_options)
            if not has.any():
                break
            col = cones[has, r, j]
            step = v[rows[has], col]
            edge = edges_along(img, xy[has], step, cfg.grid.min_saddle_contrast, cfg.ray_edge_depth * d[has, 1])
            k = np.nonzero(has)[0][edge]
            out[k, r % 2, r // 2, found[k]] = step[edge]
            idx[k, r % 2, r // 2, found[k]] = nb[k, col[edge]]
            found[k] += 1
    return RayNeighbours(out, idx)


@numba.njit(cache=True, nogil=True)
def _in_cone(v, d, rays, cos_max, tries):
    """:func:`axis_neighbours`' cones: for each of K candidates' n nearest neighbours (steps v (K, n,
    2) at distances d (K, n), nearest first; a neighbour under 1 px away or missing (inf) is
    none) and each of its four edge rays (rays (K, 4, 2), unit, zero where unknown), the columns
    of the first ``tries`` neighbours whose cosine to the ray exceeds ``cos_max``, nearest first:
    (K, 4, tries), -1 where there are fewer."""
    K, n = d.shape
    out = np.full((K, 4, tries), -1, np.int64)
    for k in range(K):
        for r in range(4):
            rx, ry = rays[k, r, 0], rays[k, r, 1]
            c = 0
            for m in range(n):
                if c == tries:
                    break
                dm = d[k, m]
                if not (np.isfinite(dm) and dm >= 1.0):
                    continue
                if (v[k, m, 0] * rx + v[k, m, 1] * ry) / dm > cos_max:
                    out[k, r, c] = m
                    c += 1
    return out


def edges_along(
    img: np.ndarray, p: np.ndarray, step: np.ndarray, min_contrast: float, max_depth: np.ndarray | float = np.inf
) -> np.ndarray:
    """(K,) bool: whether the segments p -> p + step (K, 2) run along an edge of ``img`` (H, W):
    at a quarter, half and three quarters of the way, the samples 15 % of the segment's length (at
    most ``max_depth`` (K,) px: the border of a tag foreshortened across is narrow) to one side are
    all lighter (or all darker) than those to the other, by ``min_contrast`` on average."""
    n = np.linalg.norm(step, axis=1, keepdims=True)
    normal = np.stack([-step[:, 1], step[:, 0]], 1) / np.maximum(n, 1e-9)
    side = np.maximum(np.minimum(0.15 * n, np.reshape(max_depth, (-1, 1))), 0.8) * normal
    diff = values_at(img, beside_points(p, step, side)) - values_at(img, beside_points(p, step, -side))
    same = (diff > 0).all(1) | (diff < 0).all(1)
    return same & (np.abs(diff.mean(1)) >= min_contrast)


class _Candidates(NamedTuple):
    """What a pass reads off its image before the seeds (:func:`_candidates_of`)."""

    rim_dist: np.ndarray  # (H, W) px to the image circle's rim
    smoothed: dict[int, np.ndarray]  # the image's blurs (saddle.smooth_cached)
    xy: np.ndarray  # (K, 2) fitted saddle points, strongest first (tag_candidates)
    tree: cKDTree | None  # of xy; None where there are fewer than cfg.grid.min_corners
    rays: np.ndarray | None  # (K, 4, 2) their edge rays (sampling.corner_rays)


# The fit windows' half-sizes whose blurs (saddle.smooth_for) a view takes before its candidates
# are fitted, two threads at a time (_candidates_of): the candidates' fits ask for 2-5 and their
# edge rays for 1 in nearly every view (in 62 of the 68 views of 25 evaluation frames all five).
_VIEW_HALVES = (1, 2, 3, 4, 5)


def _candidates_of(grey: np.ndarray, allowed: np.ndarray, cfg: TagConfig) -> _Candidates:
    """The candidates of ``grey`` (H, W) inside ``allowed`` (H, W) bool, with what was read to
    find them (see :class:`_Candidates`).

    The whole-image work before the fits (the distance to the rim, the saddle response, the
    blurs for the fit windows) is OpenCV's, which releases the GIL: where OpenCV may use more than
    one thread, a second thread takes half of it (not in ``detect_files``, whose reading thread or
    worker processes already share the cores and run OpenCV at one thread). The results are the
    same either way."""
    smoothed: dict[int, np.ndarray] = {}
    if cv2.getNumThreads() > 1:
        with ThreadPoolExecutor(max_workers=1) as side:
            rim_job = side.submit(cv2.distanceTransform, allowed.astype(np.uint8), cv2.DIST_L2, 3)
            side_jobs = {h: side.submit(smooth_for, grey, h) for h in _VIEW_HALVES[3:]}
            response = saddle_response(grey, cfg.response_sigma)
            for h in _VIEW_HALVES[:3]:
                smooth_cached(smoothed, grey, h)
            rim_dist = rim_job.result()
            smoothed.update({h: job.result() for h, job in side_jobs.items()})
    else:
        rim_dist = cv2.distanceTransform(allowed.astype(np.uint8), cv2.DIST_L2, 3)
        response = None
    xy, _ = tag_candidates(grey, allowed, cfg, smoothed, rim_dist, response)
    if len(xy) < cfg.grid.min_corners:
        return _Candidates(rim_dist, smoothed, xy, None, None)
    tree = cKDTree(xy)
    near = tree.query(xy, k=2)[0][:, 1]
    rays = corner_rays(smooth_cached(smoothed, grey, 1), xy, cfg.complete.ray_radius * near)
    return _Candidates(rim_dist, smoothed, xy, tree, rays)
