"""Tag pass, stages 5 and 6: placement and boards (:mod:`cotrain.detect.tag_pass`, steps 5-6).

Takes a lattice and its read tag cells (:mod:`cotrain.detect.tag_reading`); gives its placement on
the board (:class:`Placement`, :func:`place_board`: the turn and offset all its read tags support
together), which of its corners that placement is sure of (:func:`verified_corners`) and which
keep their shape (:func:`cells_close`, :func:`rays_agree`), and, over the
placed lattices of a frame (:class:`_Board`), those that agree (:func:`consistent_boards`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from cotrain.detect.lattice import STEPS, Lattice
from cotrain.detect.sampling import corner_rays
from cotrain.detect.tag_config import TagConfig
from cotrain.detect.tag_growth import is_long
from cotrain.detect.tag_reading import TURNS, TagCell, _codes, page_order
from cotrain.targets.aprilgrid import AprilGrid


@functools.lru_cache(maxsize=1)
def _templates() -> np.ndarray:
    """(N_CODES, 36): every code of :func:`_codes` with zero mean and unit RMS, so that a tag's
    ``soft`` (also zero mean, unit RMS) against it gives 36 times their correlation (-36 .. 36;
    about +-6 for a tag that is not this one)."""
    c = _codes() - _codes().mean(1, keepdims=True)
    return c / np.sqrt((c**2).mean(1, keepdims=True))


def tag_corr(soft: np.ndarray, turn: int, tags: np.ndarray) -> np.ndarray:
    """(..., T) correlation (-1 .. 1; Pearson) of read data cells ``soft`` (..., 36; lattice order,
    see :class:`TagLook`) under turn ``turn`` of :data:`TURNS` with the codes of tags (T,)."""
    return page_order(soft, turn) @ _templates()[tags].T / 36


@dataclass
class Placement:
    turn: int  # index into TURNS: board corner grid (c, r) = M (a, b) + offset
    offset: np.ndarray  # (2,) int
    score: float  # summed correlation of the tag cells with the codes this placement puts under them
    margin: float  # score minus the best other placement's
    cells: int  # tag cells read


def tag_under(cells_ab: np.ndarray, turn: int, offset: np.ndarray, board: AprilGrid) -> np.ndarray:
    """(..., n) board tag ids that placements put under lattice tag cells (n, 2) (-1: off the
    board): turn ``turn`` with offsets (..., 2)."""
    cr = (cells_ab + 0.5) @ TURNS[turn].T - 0.5 + np.asarray(offset)[..., None, :]  # the cells' lower corners on the board grid
    cr = np.rint(cr).astype(int)
    x, y = cr[..., 0] // 2, cr[..., 1] // 2
    on = (cr[..., 0] % 2 == 0) & (cr[..., 1] % 2 == 0) & (x >= 0) & (x < board.tc) & (y >= 0) & (y < board.tr)
    return np.where(on, y * board.tc + x, -1)


def place_board(cells: list[TagCell], board: AprilGrid) -> Placement | None:
    """The placement of a lattice on the board that all its read tag cells support together.

    Every turn and offset that puts some cell on some board tag is scored by the correlation of
    the cells' data (-1 .. 1 per cell, 36 per tag) with the codes it puts under them; a cell it puts
    off the board counts -36. Reading all tags jointly, a board whose tags are each too blurred to
    decode alone is still placed; the margin over the runner-up says how surely."""
    cells = [c for c in cells if c.clean]
    if not cells:
        return None
    ab = np.array([c.cell for c in cells])
    soft = np.array([c.look.soft for c in cells])
    c0 = 2 * (np.arange(board.n_tags) % board.tc)
    r0 = 2 * (np.arange(board.n_tags) // board.tc)
    scored = []
    for m, M in enumerate(TURNS):
        corr = 36 * tag_corr(soft, m, np.arange(board.n_tags))  # (n, tags)
        lo = np.stack([c0, r0], 1)[None] + 0.5 - ((ab + 0.5) @ M.T)[:, None]  # (n, tags, 2) offsets
        offs = np.unique(np.rint(lo.reshape(-1, 2)).astype(int), axis=0)  # (P, 2)
        t = tag_under(ab, m, offs, board)  # (P, n)
        on = t >= 0
        gain = np.where(on, corr[np.arange(len(ab))[None], np.maximum(t, 0)], -36.0)
        scored += [(float(g), m, off) for g, off in zip(gain.sum(1), offs)]
    scored.sort(key=lambda x: -x[0])
    best = scored[0]
    second = scored[1][0] if len(scored) > 1 else -36.0 * len(cells)
    return Placement(best[1], best[2], best[0], best[0] - second, len(cells))


def cells_close(lat: Lattice) -> np.ndarray:
    """(K,) bool: corners in a complete lattice cell, or with a neighbour along each lattice axis
    (a corner at the end of a line alone is no corner of the board's grid)."""
    where = lat.where
    ok = np.ones(len(lat.ab), bool)
    for (a, b), k in where.items():
        if any((a + da, b) in where and (a, b + db) in where and (a + da, b + db) in where for da in (-1, 1) for db in (-1, 1)):
            continue
        ok[k] = any((a + d, b) in where for d in (-1, 1)) and any((a, b + d) in where for d in (-1, 1))
    return ok


def rays_agree(lat: Lattice, img: np.ndarray, spacing: float, cfg: TagConfig) -> np.ndarray:
    """(K,) bool: lattice corners whose steps to their lattice neighbours each leave along one of
    the corner's own edge rays (:func:`corner_rays` on ``img`` (H, W)), within
    ``cfg.grid.seed_axis_angle``. The rays are read at ``cfg.complete.ray_radius`` of the local gap: the shortest of
    the corner's gap steps and of its tag sides times ``spacing`` (a corner on the board's outer
    edge has no gap step), and of its lattice neighbours' local gaps. A junction between a tag's
    data cells and its border, taken for a corner, sees its neighbours off its rays; a corner
    without rays fails."""
    where = lat.where
    K = len(lat.ab)
    steps = np.full((K, 4, 2), np.nan)
    gap = np.full(K, np.inf)
    for (a, b), k in where.items():
        for n, (da, db) in enumerate(STEPS):
            m = where.get((a + da, b + db))
            if m is not None:
                steps[k, n] = lat.xy[m] - lat.xy[k]
                length = math.hypot(*steps[k, n])
                gap[k] = min(gap[k], length * spacing if is_long(a if da else b, da or db) else length)
    dist = np.linalg.norm(steps, axis=2)
    # A corner with neighbours along one axis only (a lattice's fringe) takes the gap along the
    # other axis from its neighbours: under foreshortening the two differ several times, and a
    # circle of the larger reaches into the tag's data cells.
    own = gap.copy()
    for (a, b), k in where.items():
        for da, db in STEPS:
            m = where.get((a + da, b + db))
            if m is not None:
                gap[k] = min(gap[k], own[m])
    rays = corner_rays(img, lat.xy, cfg.complete.ray_radius * np.where(np.isfinite(gap), gap, 0.0))
    cos = np.einsum("knd,krd->knr", steps / np.where(np.isnan(dist), 1.0, dist)[..., None], rays)
    best = np.where(np.isnan(cos), -2.0, cos).max(axis=2)  # (K, 4): the nearest ray of each step
    # In the gaps of small tags the circle is at its smallest (1.5 px) and its rays' angles are
    # coarse, while data cells under 1.2 px make no junctions to mistake for corners: a looser angle
    # there (on three sets, FoV recall +0.004 each, no new wrong corner; 40 and 90 deg, or gaps up
    # to 4 px, brought wrong ones).
    shortest = np.where(np.isnan(dist), np.inf, dist).min(axis=1)  # the corner's own shortest step: its gap where it has one
    angle = np.where(shortest < cfg.small_gap_px, cfg.complete.max_ray_angle, cfg.grid.seed_axis_angle)
    ok = (best >= np.cos(np.radians(angle))[:, None]) | np.isnan(dist)
    return ok.all(1) & ~np.isnan(rays[:, 0, 0])


def slipped_corr(cell: TagCell, t: int, turn: int, board: AprilGrid) -> float:
    """The best correlation (-1 .. 1) of a read tag cell with the codes that a lattice slipped by
    one tag (a row or a column either way) would put under it instead of tag t."""
    x, y = t % board.tc, t // board.tc
    others = [(y + dy) * board.tc + x + dx for dx, dy in STEPS if 0 <= x + dx < board.tc and 0 <= y + dy < board.tr]
    if not others:
        return -1.0
    return float(tag_corr(cell.look.soft, turn, np.array(others)).max())


def verified_corners(lat: Lattice, cells: list[TagCell], under: np.ndarray, turn: int, board: AprilGrid, cfg: TagConfig) -> np.ndarray:
    """(K,) bool: the lattice corners whose tag the board's placement is sure of. Every corner
    belongs to one tag (lattice cell (a - a mod 2, b - b mod 2)). A tag that was read (its four
    corners there, big enough, inside the image) must look like a tag and match the code the
    placement puts under it (correlation ``cfg.complete.min_corr``; for tags under ``cfg.complete.small_tag_px``,
    whose cells blur, ``cfg.min_tag_corr_local`` where none of the codes a slip by one tag would
    put there matches better); its corners are dropped otherwise (a lattice that
    slipped by a row there). A tag that could not be read (too small, cut by the rim) keeps its
    corners if a tag beside it (sharing a side, not a corner) matched surely
    (``cfg.complete.sure_corr``; under ``cfg.complete.small_tag_px`` also as it keeps its own
    corners there: by ``cfg.min_tag_corr_local``, no slip matching better), or an unread tag beside one that has, up to
    ``cfg.lend_depth`` tags from the one read (a region of tags too small to read, never across a
    tag that was read and did not match): its ids come through the lattice."""
    good, sure, read = set(), set(), set()
    for c, t in zip(cells, under):
        corr = float(tag_corr(c.look.soft, turn, np.array([t]))[0]) if t >= 0 else -1.0
        blurred = c.side < cfg.complete.small_tag_px  # cells of 2 px or less: blur, not a misprint, lowers the correlation
        slip_margin = corr - slipped_corr(c, t, turn, board) if t >= 0 else -2.0
        local = blurred and corr >= cfg.min_tag_corr_local and slip_margin >= 0.0
        if c.clean and (corr >= cfg.complete.min_corr or local):
            good.add(c.cell)
        read.add(c.cell)
        if c.clean and (corr >= cfg.complete.sure_corr or local):
            sure.add(c.cell)
    cell_of = [(a - a % 2, b - b % 2) for a, b in lat.ab.tolist()]
    unread = set(cell_of) - read

    def beside(c: tuple[int, int], cells: set) -> bool:
        return any((c[0] + 2 * i, c[1] + 2 * j) in cells for i, j in STEPS)

    # Unread tags beside a sure one, and on through unread tags beside those (lend_depth tags in all).
    lent = {c for c in unread if beside(c, sure)}
    front = lent
    for _ in range(cfg.lend_depth - 1):
        front = {c for c in unread - lent if beside(c, front)}
        lent |= front
    keep = np.array([c in good or c in lent for c in cell_of], bool)
    return keep


@dataclass
class _Board:
    lat: Lattice
    ids: np.ndarray  # (K,) corner ids, -1 off the board
    place: Placement
    decoded: list[TagCell]  # cells that decode alone to the tag the placement puts there
    disagree: list[TagCell]  # cells that decode alone to another board tag


def consistent_boards(found: list[_Board], tol_px: float = 2.0) -> tuple[list[_Board], list[_Board]]:
    """The placed lattices that agree, surest placement first: the same board seen as several
    lattices (an occluder splits it, or a join and its parts) is kept where they agree; a lattice
    that claims an id another one already holds elsewhere (a second board), or a place another
    one holds with another id (a slip), is dropped. Returns the kept and the dropped boards."""
    pos: dict[int, np.ndarray] = {}
    dropped: list[_Board] = []
    kept: list[_Board] = []
    for f in sorted(found, key=lambda f: -f.place.margin):
        on = f.ids >= 0
        clash = [i for i, p in zip(f.ids[on].tolist(), f.lat.xy[on]) if i in pos and np.linalg.norm(pos[i] - p) > tol_px]
        if pos and on.any():
            held = list(pos)
            d, k = cKDTree(np.array([pos[i] for i in held])).query(f.lat.xy[on], distance_upper_bound=tol_px)
            clash += [i for i, dd, kk in zip(f.ids[on].tolist(), d, k) if np.isfinite(dd) and held[kk] != i]
        if clash:
            dropped.append(f)
            continue
        kept.append(f)
        for i, p in zip(f.ids[on].tolist(), f.lat.xy[on]):
            pos.setdefault(i, p)
    return kept, dropped
