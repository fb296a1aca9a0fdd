"""Stage 7, verification: every identified corner checked against its neighbours and the print.

- :func:`neighbour_check`: a corner off where the maps of its nearest identified corners put it is
  dropped (both passes), unless so many miss that the maps are at fault;
- :func:`print_check` (the AprilGrid): a corner that a grid neighbour's print matches better is
  dropped, and completion may find it where it is;
- :func:`print_moved` (the AprilGrid): a corner its neighbours put some pixels away, where the
  print matches better, is set aside for completion to place.

Thresholds: :class:`cotrain.detect.print_model.CompletionConfig`.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from cotrain.detect.image_circle import EquidistantLens, PlaneMaps
from cotrain.detect.print_model import MIN_INSIDE, CompletionConfig, local_maps, print_correlations, smallest_step
from cotrain.targets import Target


def nearest_others(P: np.ndarray, support: np.ndarray, n: int) -> np.ndarray:
    """(K, n) indices of the ``n`` points of ``support`` (K,) bool nearest each of the K board points
    P (K, 2) (distinct: corner ids), the point itself left out."""
    sup = np.nonzero(support)[0]
    _, near = cKDTree(P[sup]).query(P, k=n + 1)
    near = sup[near.reshape(len(P), -1)]
    own = near == np.arange(len(P))[:, None]  # a point of the support finds itself first (distance 0)
    return np.where(own.any(1)[:, None], np.roll(near, -1, 1), near)[:, :n]


def neighbour_check(
    board: Target,
    ids: np.ndarray,
    xy: np.ndarray,
    neighbours: int,
    max_misfit: float,
    lens: EquidistantLens | None = None,
    max_share: float = 1.0,
    worst_misfit: float = math.inf,
    worst_rounds: int = 0,
) -> np.ndarray:
    """(K,) bool: which identified corners ``ids`` (K,) at ``xy`` (K, 2) lie where the ``neighbours``
    other corners nearest them on the board put them: the map of those corners (:func:`local_maps`;
    with ``lens``, the homography of their rays, so the fisheye's bend is the lens's) must carry the
    corner's board point to within ``max_misfit`` of the local square (the shorter image of one
    board step there) of its position. A corner the growth took at an occluder's edge (a T-junction
    a fraction of a square off), or at the end of a row slid by one square, misses it. A wrong
    corner bends its neighbours' maps, so the check runs twice, the second time with the maps of
    the corners the first kept. Then, up to ``worst_rounds`` times, the one corner that misses
    most goes where it misses by more than ``worst_misfit`` and another corner that does too
    misses by less than half as much without it: a wrong corner at a row's end (a T-junction at
    an occluder's edge) and its right neighbour bend each other's maps about alike, and only once
    the wrong one is gone does the other fit. Corners without a posed map (under four
    others, all on a line) are kept, and so are all of them where more than ``max_share`` would
    be dropped: then the maps are at fault, not the corners (no lens to take the bend out, and a
    bend no homography follows)."""
    K = len(ids)
    keep = np.ones(K, bool)
    if min(neighbours, K - 1) < 4:
        return keep
    P = board.board_xy()[ids]
    step = smallest_step(board)

    def misfit(support: np.ndarray) -> np.ndarray:
        near = nearest_others(P, support, min(neighbours, int(support.sum()) - 1))
        to_image, posed = local_maps(P[near], xy[near], lens)
        q0, *ends = np.moveaxis(to_image(P[:, None] + np.array([[0.0, 0.0], [step, 0.0], [0.0, step]])), 1, 0)
        square = np.minimum(np.linalg.norm(ends[0] - q0, axis=1), np.linalg.norm(ends[1] - q0, axis=1))
        off = np.linalg.norm(q0 - xy, axis=1) / np.maximum(square, 1e-9)
        return np.where(posed & np.isfinite(off), off, 0.0)

    off, support = misfit(keep), keep  # each corner's misfit, from the maps of the corners in support
    keep = ~(off > max_misfit)
    if not keep.all() and min(neighbours, int(keep.sum()) - 1) >= 4:
        off, support = misfit(keep), keep
        keep = ~(off > max_misfit)
    for _ in range(worst_rounds):
        if min(neighbours, int(keep.sum()) - 1) < 5:
            break
        if not np.array_equal(support, keep):
            off, support = misfit(keep), keep
        kept_off = np.where(keep, off, 0.0)
        worst = int(np.argmax(kept_off))
        if not kept_off[worst] > worst_misfit:
            break
        without = keep.copy()
        without[worst] = False
        off_without = misfit(without)
        bent = (kept_off > worst_misfit) & (np.where(without, off_without, np.inf) < kept_off / 2)
        if not bent.any():
            break  # no other corner it bent: a corner the lens guess fits less well, not a wrong one
        keep, off, support = without, off_without, without
    return keep if np.mean(~keep) <= max_share else np.ones(K, bool)


def neighbour_maps(
    P: np.ndarray, xy: np.ndarray, support: np.ndarray, n: int, lens: EquidistantLens | None = None
) -> tuple[PlaneMaps, np.ndarray, np.ndarray]:
    """Each corner's map from its ``n`` nearest other corners of ``support`` (K,) bool on the board
    (board points P (K, 2), image points xy (K, 2); :func:`local_maps`, through ``lens`` where
    given): the K maps, which were posed (K,) bool, and where each puts its own corner (K, 2)."""
    near = nearest_others(P, support, n)
    to_image, posed = local_maps(P[near], xy[near], lens)
    return to_image, posed, to_image(P[:, None])[:, 0]


def print_check(
    sm: np.ndarray,
    rim_dist: np.ndarray,
    board: Target,
    ids: np.ndarray,
    xy: np.ndarray,
    cfg: CompletionConfig,
    strict: np.ndarray | None = None,
    min_corr: float = -1.0,
    lens: EquidistantLens | None = None,
) -> np.ndarray:
    """(K,) bool: which identified corners ``ids`` (K,) at ``xy`` (K, 2) the print does not
    contradict. Each corner's surroundings in ``sm`` (H, W; blurred as for :func:`print_correlation`)
    are sampled through the homography of the ``cfg.neighbours`` other identified corners nearest
    it on the board (with ``lens``, of their rays: :func:`local_maps`), moved onto it, and
    correlated with the print around it and around each of its eight grid neighbours (the patch
    of :func:`print_patches`). A corner is contradicted where a
    neighbour's print matches better than its own (by more than ``cfg.check_margin_large``
    in tags ``cfg.small_tag_px`` wide or more, where it is also contradicted by any better
    match once its own correlation is under ``cfg.check_min_corr_large``): a corner the lattice put
    one crossing square over (the square's other corner, where a gap of 2-3 px collapses or glare
    washes it out), a tag corner read at the wrong end of its gap, or one grown onto no junction of
    the print at all (squeezed tags at a sharpened frame's rim). A wrong corner bends the
    homographies of the corners around it, so the corners are checked twice, the second time with
    homographies of the corners the first check kept (a corner the first pass dropped may pass the second). Grid neighbours
    printed exactly as the corner is (a checkerboard's diagonal ones) are left out of the
    comparison. ``strict`` (K,) bool: corners held to any better match whatever their tag's
    width and to a correlation of ``min_corr`` with their own print, and dropped where they
    cannot be checked; the others are kept where they cannot be (fewer than four other corners
    around, a homography not posed, under a fifth of the patch inside the image circle)."""
    K = len(ids)
    strict = np.zeros(K, bool) if strict is None else np.asarray(strict, bool)
    if min(cfg.neighbours, K - 1) < 4:
        return ~strict
    keep = _uncontradicted(sm, rim_dist, board, ids, xy, np.ones(K, bool), strict, cfg, min_corr, lens)
    if keep.all() or min(cfg.neighbours, int(keep.sum()) - 1) < 4:
        return keep
    return _uncontradicted(sm, rim_dist, board, ids, xy, keep, strict, cfg, min_corr, lens)


def _uncontradicted(
    sm: np.ndarray,
    rim_dist: np.ndarray,
    board: Target,
    ids: np.ndarray,
    xy: np.ndarray,
    support: np.ndarray,
    strict: np.ndarray,
    cfg: CompletionConfig,
    min_corr: float = -1.0,
    lens: EquidistantLens | None = None,
) -> np.ndarray:
    """One pass of :func:`print_check`, each corner's homography fitted to the nearest corners of
    ``support`` (K,) bool other than itself."""
    n = min(cfg.neighbours, int(support.sum()) - 1)
    kP = board.board_xy()[ids]
    to_image, posed, q0 = neighbour_maps(kP, xy, support, n, lens)
    # The patch through each corner's homography, moved so that the corner lands on its position.
    q0 = q0[:, None]  # (K, 1, 2)
    corr, other_ok, inside = print_correlations(sm, rim_dist, board, to_image, xy - q0[:, 0], ids, cfg)
    enough = (inside >= MIN_INSIDE) & posed & np.isfinite(q0[:, 0, 0])
    other = np.where(other_ok, corr[:, 1:], -np.inf).max(1)
    # The tag's width there (px): the shorter image of a tag side along the board's axes (NaN: large).
    ends = to_image(kP[:, None] + np.array([[board.spacing, 0.0], [0.0, board.spacing]]))
    side = np.linalg.norm(ends - q0, axis=2).min(1)
    large = ~(side < cfg.small_tag_px) & ~strict
    margin = np.where(large, cfg.check_margin_large, 0.0)
    beaten = (other > corr[:, 0] + margin) | (large & (corr[:, 0] < cfg.check_min_corr_large) & (other > corr[:, 0]))
    return (~enough & ~strict) | (enough & ~beaten & ((corr[:, 0] >= min_corr) | ~strict))


def print_moved(
    sm: np.ndarray,
    rim_dist: np.ndarray,
    board: Target,
    ids: np.ndarray,
    xy: np.ndarray,
    cfg: CompletionConfig,
    lens: EquidistantLens | None = None,
) -> np.ndarray:
    """(K,) bool: which identified corners ``ids`` (K,) at ``xy`` (K, 2) lie ``cfg.moved_px`` or
    more from where the map of the ``cfg.neighbours`` other corners nearest them on the board puts
    them (:func:`local_maps`, through ``lens`` where given), while the image of ``sm`` (H, W)
    sampled through that map matches the print around the corner better by more than
    ``cfg.moved_margin`` there than moved onto the corner (each over at least :data:`MIN_INSIDE`
    of the patch inside the image circle). Such a corner is most likely no junction of the board:
    the growth slid a step along an edge (a tag's border running into the board's rim or the black
    beyond the image circle, where the print check's patch is cut short and its neighbours' prints
    fit no better). As in :func:`print_check`, the corners are judged twice, the second time with
    maps of the corners the first did not judge moved, and only a corner both judge moved is: a
    moved corner bends its neighbours' maps too (where fewer than four corners are left for the
    second, the first's judgement stands). All False where fewer than four other corners support
    a map."""
    K = len(ids)
    moved = np.zeros(K, bool)
    if cfg.moved_px <= 0 or min(cfg.neighbours, K - 1) < 4:
        return moved
    moved = _moved(sm, rim_dist, board, ids, xy, np.ones(K, bool), cfg, lens)
    if not moved.any() or min(cfg.neighbours, K - int(moved.sum()) - 1) < 4:
        return moved
    return moved & _moved(sm, rim_dist, board, ids, xy, ~moved, cfg, lens)


def _moved(
    sm: np.ndarray,
    rim_dist: np.ndarray,
    board: Target,
    ids: np.ndarray,
    xy: np.ndarray,
    support: np.ndarray,
    cfg: CompletionConfig,
    lens: EquidistantLens | None,
) -> np.ndarray:
    """One pass of :func:`print_moved`, each corner's map fitted to the nearest corners of
    ``support`` (K,) bool other than itself."""
    to_image, posed, q0 = neighbour_maps(board.board_xy()[ids], xy, support, min(cfg.neighbours, int(support.sum()) - 1), lens)
    far = np.nonzero(posed & np.isfinite(q0[:, 0]) & (np.linalg.norm(xy - q0, axis=1) >= cfg.moved_px))[0]
    moved = np.zeros(len(ids), bool)
    if not len(far):
        return moved
    maps = to_image.take(far)
    at_corner, _, in_corner = print_correlations(sm, rim_dist, board, maps, xy[far] - q0[far], ids[far], cfg)
    at_map, _, in_map = print_correlations(sm, rim_dist, board, maps, np.zeros((len(far), 2)), ids[far], cfg)
    moved[far] = (at_map[:, 0] > at_corner[:, 0] + cfg.moved_margin) & (in_map >= MIN_INSIDE) & (in_corner >= MIN_INSIDE)
    return moved


def own_print_corr(
    sm: np.ndarray,
    rim_dist: np.ndarray,
    board: Target,
    ids: np.ndarray,
    xy: np.ndarray,
    which: np.ndarray,
    cfg: CompletionConfig,
    lens: EquidistantLens | None = None,
) -> np.ndarray:
    """(n,) the print correlation of corners ``which`` (n,) (indices into ``ids`` (K,) at ``xy``
    (K, 2)) where they lie, the image of ``sm`` (H, W) sampled through the map of the
    ``cfg.neighbours`` other corners nearest each on the board (:func:`neighbour_maps`) moved onto
    it; NaN where no map is posed or under :data:`MIN_INSIDE` of the patch lies inside the image
    circle (and all NaN where fewer than four other corners support a map)."""
    which = np.asarray(which, int)
    out = np.full(len(which), np.nan)
    n = min(cfg.neighbours, len(ids) - 1)
    if n < 4 or not len(which):
        return out
    to_image, posed, q0 = neighbour_maps(board.board_xy()[ids], xy, np.ones(len(ids), bool), n, lens)
    corr, _, inside = print_correlations(sm, rim_dist, board, to_image.take(which), xy[which] - q0[which], ids[which], cfg)
    good = posed[which] & np.isfinite(q0[which, 0]) & (inside >= MIN_INSIDE)
    out[good] = corr[good, 0]
    return out
