"""Lattice growth: checker corners connected into integer lattice coordinates (a, b).

- :func:`grow_lattice`: breadth first from a seed candidate; each missing neighbour is predicted
  one square step along a grid axis (from the last two steps: perspective's cross-ratio and the
  fisheye's bend, see :func:`next_step`) and matched to a candidate or, where the network missed
  it, to a saddle found at the predicted spot, or, in large squares where neither finds one, to
  the candidate the checker edge leaving the corner leads to (:func:`edge_neighbour`); checker
  colours must alternate, and the edge of a black and a white square must run along the step
  (:func:`step_has_edge`);
- :func:`verify_lattice`: a second look at every corner with its final neighbours (refit, straight
  lattice lines, edges along the lines next to the rim); the largest connected part stays;
- :func:`skipped_corners`: whether the lattice was grown with double steps or knight's moves.

The image tests the growth asks (colours, edges along a step) are in :mod:`cotrain.detect.sampling`;
the reported positions are fitted once more by :mod:`cotrain.detect.refinement`.

Lattice axes are oriented so that a x b > 0 in the image (x right, y down), as the board's own
i, j axes are when its printed side is seen. Pixels follow docs/conventions.md (centre of the top-left
pixel at (0, 0)).
"""

from __future__ import annotations

import collections
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from cotrain.detect.grid_config import GridConfig
from cotrain.detect.image_circle import CIRCLE_INSIDE_PX
from cotrain.detect.saddle import fit_saddles, pixel_index, smooth_cached, window_half, window_reach
from cotrain.detect.sampling import diag_contrast, step_has_edge, values_at

STEPS = ((1, 0), (-1, 0), (0, 1), (0, -1))  # the four lattice neighbours (da, db); origin: code/table, not a threshold


@dataclass(frozen=True)
class Lattice:
    xy: np.ndarray  # (K, 2) corner pixels
    ab: np.ndarray  # (K, 2) integer lattice coordinates, distinct
    filled: np.ndarray  # (K,) True where the corner was found by a saddle search at its predicted spot, not among the candidates

    @functools.cached_property
    def where(self) -> dict[tuple[int, int], int]:
        """Index of every lattice coordinate: ``where[(a, b)]`` is its corner's row in xy / ab (in
        the order of ab). Built once; a Lattice is not changed after it is made."""
        return {tuple(t): k for k, t in enumerate(self.ab.tolist())}


def _fill_alternates(img: np.ndarray, pred: np.ndarray, ea: np.ndarray, eb: np.ndarray, parent: float, cfg: GridConfig) -> bool:
    """Whether the checker colours already alternate at a predicted spot ``pred`` (2,) against
    the parent corner's quadrant contrast ``parent`` (by ``cfg.min_alternation``, as a new corner's must): only then
    is a saddle searched there. Beyond the board's last corners they do not, and those failing
    searches were most of the growth's time."""
    pc = diag_contrast(img, pred, ea, eb, cfg.diag_offset)
    return pc * parent < 0 and abs(pc) >= cfg.min_alternation * abs(parent)


# --------------------------------------------------------------------------------------------
# Growth
# --------------------------------------------------------------------------------------------
def _cross(u: np.ndarray, v: np.ndarray) -> float:
    return float(u[0] * v[1] - u[1] * v[0])


def next_step(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The image step after steps ``u`` then ``v`` (2,) along one lattice line.

    Equal steps on the board seen in perspective keep their cross-ratio: with step lengths
    d0 = |u|, d1 = |v| the next one is d1 (d0 + d1) / (3 d0 - d1) (clamped to 0.5 .. 2 d1), and
    the fisheye bends the line by about the same angle again (clamped to 30 deg). (Scalar float
    arithmetic: it runs once per corner of every growth.)"""
    ux, uy, vx, vy = float(u[0]), float(u[1]), float(v[0]), float(v[1])
    d0, d1 = math.hypot(ux, uy), math.hypot(vx, vy)
    den = 3 * d0 - d1
    ratio = min(max((d0 + d1) / den, 0.5), 2.0) if den > 0 else 2.0
    turn = min(max(math.atan2(ux * vy - uy * vx, ux * vx + uy * vy), -math.pi / 6), math.pi / 6)
    c, s = math.cos(turn), math.sin(turn)
    return np.array([ratio * (c * vx - s * vy), ratio * (s * vx + c * vy)])


def match_corner(
    pred: np.ndarray,
    r: float,
    xy: np.ndarray,
    used: set[int],
    grey: np.ndarray,
    smoothed: dict[int, np.ndarray],
    half: int,
    cfg: GridConfig,
    rim_dist: np.ndarray | None = None,
    worth_fitting: Callable[[], bool] | None = None,
) -> tuple[np.ndarray | None, bool]:
    """The corner at a predicted spot ``pred`` (2,): the nearest candidate of xy (K, 2) within
    ``r`` not yet offered (``used`` gains it), otherwise a saddle fitted there in a window of
    half-size ``half`` that lands within ``r`` (only if ``worth_fitting()`` says so, when given).
    Returns (point or None, found by the fit).

    A candidate is offered once: if the growth's checks refuse it here, it is doubtful and is not
    tried again from another corner (measured: offering it again lets wrong corners into small
    squares)."""
    d = xy - pred  # the nearest candidate: brute force over a few dozen is 3x faster than the tree's query
    d2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]
    j = int(d2.argmin())
    if math.sqrt(d2[j]) < r and j not in used:
        used.add(j)
        return xy[j], False
    if worth_fitting is not None and not worth_fitting():
        return None, False
    q, ok, _ = fit_saddles(grey, smoothed, pred[None], half, cfg, rim_dist)
    if ok[0] and math.hypot(q[0, 0] - pred[0], q[0, 1] - pred[1]) < r:
        return q[0], True
    return None, False


def _bright_side(da: int, db: int, sa: np.ndarray, sb: np.ndarray) -> np.ndarray:
    """Unit vector across a step (da, db) from a corner with steps sa, sb (2,): the side that is
    bright where the corner's quadrant contrast (:func:`diag_contrast`) is positive."""
    ox, oy = -(da * float(sb[0]) + db * float(sa[0])), -(da * float(sb[1]) + db * float(sa[1]))  # scalar: once per step tried
    n = max(math.hypot(ox, oy), 1e-9)
    return np.array([ox / n, oy / n])


def edge_neighbour(
    img: np.ndarray,
    p: np.ndarray,
    v: np.ndarray,
    o: np.ndarray,
    parent: float,
    xy: np.ndarray,
    axes: np.ndarray,
    tree: cKDTree,
    used: set[int],
    cfg: GridConfig,
) -> np.ndarray | None:
    """The lattice neighbour of corner p (2,) about one step ``v`` (2,) away, found by following
    the checker edge that leaves p along v where the step's prediction found nothing: the nearest
    candidate of xy (K, 2) not yet offered (``used`` gains it) at ``cfg.walk_min_steps`` to
    ``cfg.walk_max_steps`` of v's length, within ``cfg.walk_angle`` of its direction, with one of
    its own edge directions (axes (K, 2, 2)) along the step, and the checker edge along the step
    (:func:`step_has_edge`; ``o``, ``parent``: the bright side and the parent's quadrant contrast).
    Where squares grow or shrink fast (a board close to a fisheye's rim) the predicted step is
    stale; the edge between two neighbours is not. The growth's own colour, edge and crowding tests
    still apply to what this returns."""
    len_v = math.hypot(v[0], v[1])
    lo, hi = cfg.walk_min_steps, cfg.walk_max_steps
    cos_step, cos_axis = math.cos(math.radians(cfg.walk_angle)), math.cos(math.radians(cfg.seed_axis_angle))
    best = None
    for j in tree.query_ball_point(p, hi * len_v):
        w = xy[j] - p
        n = math.hypot(w[0], w[1])
        if j in used or n < lo * len_v or (best is not None and n >= best[0]):
            continue
        if w[0] * v[0] + w[1] * v[1] < cos_step * n * len_v or np.abs(axes[j] @ w).max() < cos_axis * n:
            continue
        if step_has_edge(img, p, xy[j], o, cfg.step_edge_depth * min(n, len_v), parent, cfg):
            best = (n, j)
    if best is None:
        return None
    used.add(best[1])
    return xy[best[1]]


def _bent_neighbour(
    p0: np.ndarray, u: np.ndarray, dist: np.ndarray, idx: np.ndarray, xy: np.ndarray, cfg: GridConfig
) -> tuple[float, np.ndarray] | None:
    """A seed's neighbour along its edge direction u (2,) where none lies within
    ``cfg.seed_axis_angle`` of it: the nearest candidate of xy (K, 2) (``idx``, at ``dist``, nearest
    first) at least ``cfg.seed_bend_px`` away and within ``cfg.seed_bend_angle`` of +-u. Near a
    fisheye's rim the sides of a square of 40-120 px bend by tens of degrees between its corners;
    the growth's colour and edge tests judge the step as any other. Returns (distance, step) or None."""
    if cfg.seed_bend_angle <= 0:
        return None
    cos_bend = math.cos(math.radians(cfg.seed_bend_angle))
    for n, j in zip(dist, idx):
        if np.isfinite(n) and n >= cfg.seed_bend_px and abs(float((xy[j] - p0) @ u)) >= cos_bend * n:
            return float(n), xy[j] - p0
    return None


def _seed_steps(xy: np.ndarray, axes: np.ndarray, seed: int, tree: cKDTree, cfg: GridConfig) -> tuple[np.ndarray, np.ndarray] | None:
    """The seed's two steps (2,) each: to the nearest candidate along each of its edge directions
    (within ``cfg.seed_axis_angle``, or bent, :func:`_bent_neighbour`), oriented so that a x b > 0;
    None where one is missing or the two are parallel (both edge directions found the same
    neighbour)."""
    p0 = xy[seed]
    d, nb = tree.query(p0, k=min(9, len(xy)))
    cos_seed = np.cos(np.radians(cfg.seed_axis_angle))
    steps = []
    for u in axes[seed]:
        best = None
        ux, uy = float(u[0]), float(u[1])
        for sgn in (1, -1):
            for dist, j in zip(d[1:], nb[1:]):
                if not np.isfinite(dist) or dist < 1.0:
                    continue
                v = xy[j] - p0
                if sgn * (float(v[0]) * ux + float(v[1]) * uy) / dist > cos_seed and (best is None or dist < best[0]):
                    best = (dist, sgn * v)
        if best is None:
            best = _bent_neighbour(p0, u, d[1:], nb[1:], xy, cfg)
        if best is None:
            return None
        steps.append(best[1])
    sa, sb = steps
    if _cross(sa, sb) == 0:
        return None  # parallel steps span no lattice (nearly parallel ones are left to the growth's own checks)
    if _cross(sa, sb) < 0:
        sa, sb = sb, sa
    return sa, sb


def _remeasured(where: dict, pts: list, a: int, b: int, sa: np.ndarray, sb: np.ndarray, cfg: GridConfig) -> tuple[np.ndarray, np.ndarray]:
    """Corner (a, b)'s steps as its neighbours placed by now measure them: inherited along a row
    from its parent, the step across is stale where the lattice bends (near a fisheye's rim it
    turns by tens of degrees in a few squares). Small squares keep theirs (their neighbours'
    positions are noisier than the inherited step)."""
    k = where[(a, b)]
    pairs = ((where.get((a + 1, b)), where.get((a - 1, b))), (where.get((a, b + 1)), where.get((a, b - 1))))
    for axis, (m_f, m_b) in enumerate(pairs):
        if m_f is not None or m_b is not None:
            s_ = pts[m_f] - pts[k] if m_f is not None else pts[k] - pts[m_b]
            if math.hypot(s_[0], s_[1]) >= cfg.large_square_px:
                sa, sb = (s_, sb) if axis == 0 else (sa, s_)
    return sa, sb


def _predicted(where: dict, pts: list, a: int, b: int, da: int, db: int, sa: np.ndarray, sb: np.ndarray, cfg: GridConfig):
    """Where corner (a + da, b + db) should be: (v, pred, len_v), the step (2,) from (a, b) (from
    the last two steps: perspective's cross-ratio and the fisheye's bend), the predicted point
    (2,), averaged with the perpendicular neighbours' own steps along (da, db), and the step's
    length; None where those predictions disagree by over ``cfg.agree_radius`` of a step."""
    hypot = math.hypot
    k, t = where[(a, b)], (a + da, b + db)
    back = where.get((a - da, b - db))
    v = pts[k] - pts[back] if back is not None else da * sa + db * sb
    back2 = where.get((a - 2 * da, b - 2 * db))
    if back is not None and back2 is not None:
        v = next_step(pts[back] - pts[back2], v)
    preds = [pts[k] + v]
    for side in ((db, da), (-db, -da)):  # the perpendicular neighbours' own steps along (da, db)
        m0, m1 = where.get((a + side[0], b + side[1])), where.get((t[0] + side[0], t[1] + side[1]))
        if m0 is not None and m1 is not None:
            preds.append(pts[k] + pts[m1] - pts[m0])
    pred = preds[0] if len(preds) == 1 else np.array([sum(p_[0] for p_ in preds), sum(p_[1] for p_ in preds)]) / len(preds)
    len_v = hypot(v[0], v[1])
    if len(preds) > 1 and max(hypot(p_[0] - pred[0], p_[1] - pred[1]) for p_ in preds) > cfg.agree_radius * len_v:
        return None
    return v, pred, len_v


def _step_across(where: dict, pts: list, t: tuple[int, int], da: int, db: int, sa, sb, found, len_new: float, cfg: GridConfig):
    """The step across at the new corner t (2,): the parent's, scaled as the step along changed
    (where squares grow or shrink fast, near a fisheye's rim, an inherited step goes stale), or
    measured where t already has a neighbour across."""
    along, across = (sa, sb) if da else (sb, sa)
    across = across * min(max(len_new / max(math.hypot(along[0], along[1]), 1e-9), cfg.min_step_ratio), cfg.max_step_ratio)
    for sgn in (1, -1):
        m = where.get((t[0] + sgn * abs(db), t[1] + sgn * abs(da)))
        if m is not None:
            return sgn * (pts[m] - found)
    return across


def _crowded(placed: np.ndarray, found: np.ndarray, short: float, len_v: float, cfg: GridConfig) -> bool:
    """Whether a corner ``found`` (2,) would sit on top of one already ``placed`` (K, 2). Measured
    against the square's smaller side ``short`` (on a board seen obliquely the next corner across
    is much nearer than the step), except in small squares (measured against the step ``len_v``),
    where a diagonal slip is then let through."""
    crowd = short if short >= cfg.crowd_small_factor * cfg.min_step_px else len_v
    d = placed - found
    return bool(np.sqrt((d * d).sum(1).min()) < cfg.crowd_radius * crowd)


def _checker_step(sm1: np.ndarray, p, found, na, nbv, bright, side_px: float, parent: float, cfg: GridConfig) -> float | None:
    """The new corner's checker contrast (:func:`diag_contrast` along its steps ``na``, ``nbv``),
    or None where the step from ``p`` to ``found`` has no checker edge along it (off the board, or
    a knight's move; its depth ``cfg.step_edge_depth`` of the square's smaller side ``side_px``)
    or the colours do not alternate with the ``parent``'s (a slipped row or column, or not this
    board)."""
    if not step_has_edge(sm1, p, found, bright, cfg.step_edge_depth * side_px, parent, cfg):
        return None
    pc = diag_contrast(sm1, found, na, nbv, cfg.diag_offset)
    if pc * parent >= 0 or abs(pc) < cfg.min_alternation * abs(parent):
        return None
    return pc


class _Growing(NamedTuple):
    """What :func:`grow_lattice` grows among: the candidates and the image."""

    xy: np.ndarray  # (K, 2) candidates
    axes: np.ndarray  # (K, 2, 2) their edge directions
    tree: cKDTree  # over xy
    grey: np.ndarray  # (H, W) image
    sm1: np.ndarray  # (H, W) the image blurred for the colour and edge tests
    smoothed: dict[int, np.ndarray]  # blurs by fit window (saddle.smooth_cached)
    rim_dist: np.ndarray | None  # (H, W) distance to the rim, px
    used: set[int]  # candidates taken by the lattice (filled in as it grows)
    cfg: GridConfig


def _neighbour(g: _Growing, p, pred, v, len_v: float, short: float, dab, sab, bright, parent: float):
    """The corner found for the prediction ``pred`` (2,) one step ``v`` from ``p`` along lattice
    direction ``dab`` = (da, db) (steps ``sab`` = (sa, sb) at p): the candidate within
    ``cfg.match_radius`` of a step, or a saddle searched for there
    (:func:`match_corner`), or in large squares the one the checker edge leaving ``p`` leads to
    (:func:`edge_neighbour`). Returns (found (2,) or None, whether a search found it, the step's
    length: the walk measures it)."""
    (da, db), (sa, sb), cfg = dab, sab, g.cfg
    pa, pb = (v * da if da else sa), (v * db if db else sb)
    worth_fitting = functools.partial(_fill_alternates, g.sm1, pred, pa, pb, parent, cfg)
    r = cfg.match_radius * len_v
    found, was_filled = match_corner(pred, r, g.xy, g.used, g.grey, g.smoothed, window_half(short), cfg, g.rim_dist, worth_fitting)
    if found is None and short >= cfg.large_square_px:
        found = edge_neighbour(g.sm1, p, v, bright, parent, g.xy, g.axes, g.tree, g.used, cfg)
        if found is not None:
            was_filled = False
            len_v = math.hypot(found[0] - p[0], found[1] - p[1])  # the walk measured the step
    return found, was_filled, len_v


def grow_lattice(
    xy: np.ndarray,
    axes: np.ndarray,
    seed: int,
    grey: np.ndarray,
    cfg: GridConfig,
    smoothed: dict[int, np.ndarray],
    rim_dist: np.ndarray | None = None,
) -> Lattice | None:
    """Breadth-first lattice growth from candidate ``seed`` among candidates xy (K, 2) with edge
    directions axes (K, 2, 2) (see :func:`cotrain.detect.saddle.saddle_fit`) on the image grey
    (H, W); corners found by the saddle search are fitted with ``rim_dist`` (H, W). None when the
    seed has no two neighbours along its edges or no checker colours.

    Lattice axes are oriented so that a x b > 0 in the image (x right, y down), as the board's own
    i, j axes are when its printed side is seen.
    """
    tree = cKDTree(xy)
    p0 = xy[seed]
    seed_steps = _seed_steps(xy, axes, seed, tree, cfg)
    if seed_steps is None:
        return None
    sa, sb = seed_steps
    pts = [p0.copy()]
    placed = np.empty((len(xy) + 16, 2))  # pts as one array, for the crowding test
    placed[0] = p0
    sm1 = smooth_cached(smoothed, grey, 2)
    par = {(0, 0): diag_contrast(sm1, p0, sa, sb, cfg.diag_offset)}
    lab, filled = [(0, 0)], [False]  # each corner's lattice coordinate, and whether a saddle search found it
    step = {(0, 0): (sa, sb)}
    where = {(0, 0): 0}  # the growing lattice's index (see Lattice.where)
    used, queue = {seed}, collections.deque([(0, 0)])  # candidates taken; corners whose neighbours are still to look for
    (H, W), hypot = grey.shape, math.hypot
    ctx = _Growing(xy, axes, tree, grey, sm1, smoothed, rim_dist, used, cfg)
    while queue:
        a, b = queue.popleft()
        k = where[(a, b)]
        sa, sb = step[(a, b)]
        if cfg.remeasure_steps:
            sa, sb = _remeasured(where, pts, a, b, sa, sb, cfg)
        for da, db in STEPS:
            t = (a + da, b + db)
            if t in where:
                continue
            predicted = _predicted(where, pts, a, b, da, db, sa, sb, cfg)
            if predicted is None:
                continue  # the neighbours disagree about where this corner is
            v, pred, len_v = predicted
            side_v = sb if da else sa
            short = min(len_v, hypot(side_v[0], side_v[1]))  # the square's smaller side here
            if not (0 <= pred[0] < W and 0 <= pred[1] < H) or short < cfg.min_step_px:
                continue
            bright = _bright_side(da, db, sa, sb)
            found, was_filled, len_v = _neighbour(ctx, pts[k], pred, v, len_v, short, (da, db), (sa, sb), bright, par[(a, b)])
            if found is None:
                continue
            new_v = found - pts[k]
            len_new = hypot(new_v[0], new_v[1])
            if len_new < cfg.min_step_ratio * len_v or len_new > cfg.max_step_ratio * len_v:
                continue  # the step changed its length too much
            if _crowded(placed[: len(pts)], found, short, len_v, cfg):
                continue
            across = _step_across(where, pts, t, da, db, sa, sb, found, len_new, cfg)
            na, nbv = (new_v * da, across) if da else (across, new_v * db)
            pc = _checker_step(sm1, pts[k], found, na, nbv, bright, min(len_new, hypot(across[0], across[1])), par[(a, b)], cfg)
            if pc is None:
                continue
            par[t] = pc
            where[t] = len(pts)
            if len(pts) == len(placed):
                placed = np.concatenate([placed, np.empty_like(placed)])
            placed[len(pts)] = found
            pts.append(np.asarray(found, np.float64))
            lab.append(t)
            filled.append(was_filled)
            step[t] = (na, nbv)
            queue.append(t)
    return Lattice(np.array(pts), np.array(lab, int), np.array(filled))


# --------------------------------------------------------------------------------------------
# Verification
# --------------------------------------------------------------------------------------------
def largest_component(lat: Lattice) -> np.ndarray:
    """(K,) bool: the largest 4-connected set of the lattice's coordinates."""
    ab, where = lat.ab, lat.where
    comp = -np.ones(len(ab), int)
    n = 0
    for k0 in range(len(ab)):
        if comp[k0] >= 0:
            continue
        comp[k0] = n
        stack = [k0]
        while stack:
            a, b = ab[stack.pop()]
            for da, db in STEPS:
                m = where.get((a + da, b + db))
                if m is not None and comp[m] < 0:
                    comp[m] = n
                    stack.append(m)
        n += 1
    return comp == np.bincount(comp).argmax() if len(ab) else np.zeros(0, bool)


def _local_squares(lat: Lattice, cfg: GridConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per corner of the lattice: (K,) bool whether it is looked at again (its local square at
    least ``cfg.min_step_px`` and on straight lattice lines, :func:`verify_lattice`), (K,) its
    local square's smaller side (px), and (K,) bool whether the square is seen obliquely (sides
    over ``cfg.oblique_ratio``)."""
    where = lat.where
    K = len(lat.ab)
    short, oblique = np.zeros(K), np.zeros(K, bool)
    todo = np.zeros(K, bool)
    pts = lat.xy.tolist()  # scalar arithmetic in the per-corner loop
    for (a, b), k in where.items():
        sides = []
        straight = True
        x, y = pts[k]
        for nbrs in (((a + 1, b), (a - 1, b)), ((a, b + 1), (a, b - 1))):
            d = [math.hypot(pts[where[t]][0] - x, pts[where[t]][1] - y) for t in nbrs if t in where]
            if d:
                sides.append(min(d))
            if len(d) == 2:
                (x1, y1), (x2, y2) = pts[where[nbrs[0]]], pts[where[nbrs[1]]]
                straight &= math.hypot((x1 + x2) / 2 - x, (y1 + y2) / 2 - y) < cfg.max_line_offset * math.hypot(x1 - x2, y1 - y2) / 2
        if sides and min(sides) >= cfg.min_step_px and straight:
            todo[k] = True
            short[k] = min(sides)
            oblique[k] = len(sides) == 2 and max(sides) > cfg.oblique_ratio * min(sides)
    return todo, short, oblique


def _rim_cut_kept(
    lat: Lattice, q: np.ndarray, axes: np.ndarray, keep: np.ndarray, cut: np.ndarray, halves: np.ndarray, circle, cfg: GridConfig
) -> None:
    """:func:`verify_lattice`'s check of the refitted corners ``q`` (K, 2) whose fit window the rim
    cuts (``cut`` (K,) bool): their edge directions ``axes`` (K, 2, 2) must follow the lattice
    lines; ``keep`` (K,) is cleared in place where they do not."""
    where = lat.where
    cos_rim = np.cos(np.radians(cfg.seed_axis_angle))
    for k in np.nonzero(cut)[0]:
        # Cut by the image's border alone (the image circle's rim, and the black frame beyond
        # it, out of the window's reach): no dark rim there to make a half X of its own.
        # (The black frame is kept CIRCLE_INSIDE_PX inside the fitted circle, and 1 px for the fit.)
        rim_room = circle[1] - CIRCLE_INSIDE_PX - 1 - math.hypot(q[k, 0] - circle[0][0], q[k, 1] - circle[0][1]) if circle else 0.0
        border = rim_room > window_reach(halves[k])  # its edges are not held to its neighbours' lines there
        # Cut by the rim, a square's corner against the margin or the rim can pass for half an
        # X-junction: the fitted edges must run along the lattice lines to the neighbours.
        a, b = lat.ab[k]
        seen_axis = [False, False]
        for da, db in STEPS:
            t = (a + da, b + db)
            if t in where:
                u = lat.xy[where[t]] - q[k]
                u = u / max(np.linalg.norm(u), 1e-9)
                keep[k] &= border or bool(np.abs(axes[k] @ u).max() >= cos_rim)
                seen_axis[abs(db)] = True
        for axis in (0, 1):
            if seen_axis[axis] or not keep[k] or not cfg.rim_borrowed_axes:
                continue
            # No neighbour along this lattice axis (a tip, or the rim): the axis as a neighbour
            # across measures it. Where a square's edge meets the rim or the image border, the
            # half-X there has the border as its second edge, across the lattice.
            da, db = (1, 0) if axis == 0 else (0, 1)
            for sa, sb in ((db, da), (-db, -da)):
                m, m2 = where.get((a + sa, b + sb)), None
                if m is not None:
                    m2 = where.get((a + sa + da, b + sb + db))
                    if m2 is None:
                        m2 = where.get((a + sa - da, b + sb - db))
                if m is not None and m2 is not None:
                    u = lat.xy[m2] - lat.xy[m]
                    u = u / max(np.linalg.norm(u), 1e-9)
                    keep[k] &= bool(np.abs(axes[k] @ u).max() >= cos_rim)
                    break


def verify_lattice(
    lat: Lattice,
    grey: np.ndarray,
    cfg: GridConfig,
    smoothed: dict[int, np.ndarray],
    rim_dist: np.ndarray | None = None,
    circle: tuple[np.ndarray, float] | None = None,
) -> Lattice:
    """Second look at every corner with its final neighbours (image grey (H, W), ``rim_dist``
    (H, W)). A corner is dropped when

    - the local square (smaller side) is under ``min_step_px``;
    - a saddle refit in a window sized for the square (with ``rim_dist``, see
      :func:`cotrain.detect.saddle.saddle_fit`: near the image circle's rim from the part of the
      window that is seen) does not land on it again (within ``max_refit_shift`` of the square),
      or, where the window is cut by the rim, its edge directions do not follow the lattice lines
      (within ``seed_axis_angle``; not where the image ``circle`` (centre (2,) and radius, in
      these pixels; None: not known) is out of the window's reach and only the image's border
      cuts it) or, along an axis where it has no neighbour, the direction
      a neighbour across measures along that axis (within that angle too);
    - it breaks a lattice line: the midpoint of its two neighbours along a, or along b, misses it
      by more than ``max_line_offset`` of a step (where a group of corners slipped by a diagonal
      step during the growth, the corners along the seam fail this).
    Of what is left, the largest 4-connected part is kept.
    """
    K = len(lat.ab)
    H, W = grey.shape
    todo, short, oblique = _local_squares(lat, cfg)
    # Refit all corners at once, per window size.
    halves = np.where(todo, window_half(np.maximum(short, 1.0)), 0)
    q, ok, axes = lat.xy.copy(), np.zeros(K, bool), np.zeros((K, 2, 2))
    for h in np.unique(halves[todo]):
        m = todo & (halves == h)
        q[m], ok[m], axes[m] = fit_saddles(grey, smoothed, lat.xy[m], int(h), cfg, rim_dist)
    # Squares seen very obliquely (sides over 2:1) and blurred: at every other corner the two black
    # squares meet along the short diagonal and merge in a large window; a smaller one still sees
    # the X. (Not elsewhere: next to occluders it lets false junctions in.)
    retry = todo & ~ok & oblique & (halves > 2)
    first = halves.copy()
    for h in np.unique(first[retry]):
        m = retry & (first == h)
        halves[m] = max(2, int(h) // 2)
        q[m], ok[m], axes[m] = fit_saddles(grey, smoothed, lat.xy[m], max(2, int(h) // 2), cfg, rim_dist)
    keep = todo & ok & (np.linalg.norm(q - lat.xy, axis=1) < cfg.max_refit_shift * short)
    if rim_dist is not None:
        qi = pixel_index(q, W, H)
        cut = keep & (rim_dist[qi[:, 1], qi[:, 0]] < window_reach(halves))
        _rim_cut_kept(lat, q, axes, keep, cut, halves, circle, cfg)
    xy = np.where(keep[:, None], q, lat.xy)
    lat = Lattice(xy[keep], lat.ab[keep], lat.filled[keep])
    big = largest_component(lat)
    return Lattice(lat.xy[big], lat.ab[big], lat.filled[big])


def skipped_corners(lat: Lattice, response: np.ndarray, cfg: GridConfig | None = None) -> float:
    """Share of lattice steps (along a, along b) or cells whose midpoint is itself an X-junction
    (:func:`cotrain.detect.saddle.saddle_response` (H, W) there over ``cfg.skip_response_ratio``
    of that of the weakest end), the worst of the three.

    On the board, a step's midpoint lies on an edge between two squares and a cell's centre inside
    a square, where the response is near zero. A lattice grown with double steps, or with knight's
    moves (two along, one across: the colours still alternate), has corners at the one or the
    other; in small blurred squares the colour test alone lets them through."""
    cfg = cfg or GridConfig()
    where = lat.where
    groups = []
    for da, db in ((1, 0), (0, 1)):
        groups.append([(k, where[(a + da, b + db)]) for (a, b), k in where.items() if (a + da, b + db) in where])
    cells = [(k, *(where.get(t) for t in ((a + 1, b), (a, b + 1), (a + 1, b + 1)))) for (a, b), k in where.items()]
    groups.append([c for c in cells if None not in c])
    worst = 0.0
    for g in groups:
        if len(g) < 3:
            continue
        idx = np.array(g)
        ends = values_at(response, lat.xy[idx])  # (P, 2 or 4)
        mid = values_at(response, lat.xy[idx].mean(1))
        worst = max(worst, float(np.mean(mid > cfg.skip_response_ratio * ends.min(1))))
    return worst
