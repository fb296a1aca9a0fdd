"""Tag pass, stage 3: growth (:mod:`cotrain.detect.tag_pass`, step 3).

Takes the candidates and their ray neighbours (:mod:`cotrain.detect.tag_candidates`) and a seed's
step frame (:mod:`cotrain.detect.tag_seeds`); gives the corner lattice grown breadth first from
it (:func:`grow_tag_lattice`: each neighbour predicted one long or short step along a lattice
axis and matched to a candidate, a saddle fitted at the prediction, or the candidate the corner's
ray leads to, :func:`ray_step`; each step an edge with the dark cell where the lattice's parity
says, :func:`step_taken`), and the joins of lattices grown from several seeds of one board
(:func:`lattice_link`, :func:`join_lattices`).
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from cotrain.detect.lattice import STEPS, Lattice
from cotrain.detect.saddle import fit_saddles, smooth_cached, window_half
from cotrain.detect.sampling import edge_contrast_kernel, edge_sample_points, values_at
from cotrain.detect.tag_candidates import RayNeighbours
from cotrain.detect.tag_config import TagConfig
from cotrain.targets.checkerboard import ROTATIONS


def _norm(v: np.ndarray) -> float:
    """Length of one 2-vector (plain arithmetic: the growth asks this for every step)."""
    return math.sqrt(float(v[0]) * float(v[0]) + float(v[1]) * float(v[1]))


def is_long(m: int, dm: int) -> bool:
    """Whether the lattice step from coordinate m to m + dm (dm = +-1) is a tag side (long): cell
    (0, 0) is a tag, so the steps from even coordinates upward are long."""
    return min(m, m + dm) % 2 == 0


def cell_dark(a: int, b: int) -> bool:
    """Whether lattice cell (a, b) (corners a .. a+1, b .. b+1) is dark: a tag (both even) or a gap
    crossing square (both odd)."""
    return (a + b) % 2 == 0


def edge_contrast(img: np.ndarray, p: np.ndarray, q: np.ndarray, normal: np.ndarray, depth: float, rim_dist: np.ndarray) -> float:
    """Mean brightness on the ``+normal`` side of segment p -> q minus the ``-normal`` side, sampled
    at a quarter, half and three quarters of the way, ``depth`` px to each side; NaN where no
    sample pair lies inside the image circle (``rim_dist`` (H, W) > 1). The readable form of
    :func:`cotrain.detect.sampling.edge_contrast_kernel`, which the growth runs (compiled) and which a test holds to it."""
    pts = edge_sample_points(p, q, normal, depth)
    vals = values_at(img, pts)
    rd = values_at(rim_dist, pts)
    ok = (rd[:3] > 1) & (rd[3:] > 1) & np.isfinite(vals[:3]) & np.isfinite(vals[3:])
    if not ok.any():
        return float("nan")
    diff = vals[:3] - vals[3:]
    return float(diff[ok].mean()) if (diff[ok] > 0).all() or (diff[ok] < 0).all() else 0.0


def _junction_on_step(p: np.ndarray, q: np.ndarray, xy: np.ndarray, tree: cKDTree, tol: float, across: float) -> bool:
    """Whether a candidate lies on the segment p -> q (2,) between 15 % and 85 % of the way, within
    ``tol`` of its length and of ``across`` (px, the lattice's long step across the segment): a step
    that jumped over a corner. (A tag's own data junctions lie at least two cells, a fifth of the
    tag, off its sides: a fifth of ``across`` where perspective narrows the tag.)"""
    px, py, dx, dy = float(p[0]), float(p[1]), float(q[0] - p[0]), float(q[1] - p[1])  # scalar arithmetic: it runs per step tried
    n = math.hypot(dx, dy)
    near = tree.query_ball_point(((p[0] + q[0]) / 2, (p[1] + q[1]) / 2), 0.5 * n)
    if not near:
        return False
    m = max(n, 1e-9)
    ux, uy, lim = dx / m, dy / m, tol * min(n, across)
    for x, y in xy[near].tolist():
        ex, ey = x - px, y - py
        if 0.15 < (ex * ux + ey * uy) / m < 0.85 and abs(ex * uy - ey * ux) < lim:
            return True
    return False


def ray_step(
    p: np.ndarray,
    options: np.ndarray,
    v: np.ndarray,
    xy: np.ndarray,
    tree: cKDTree,
    used: set[int],
    cfg: TagConfig,
    targets: np.ndarray | None = None,
) -> int | None:
    """The candidate (index into xy (K, 2)) that the nearest ray neighbour ``options`` of the corner
    at p (2,) along one of its rays (axis, way, option, 2 step vectors; see :func:`axis_neighbours`) reaches in the
    direction of the predicted step v (2,), within ``cfg.ray_step_angle`` and the growth's
    step-length ratios, nearest in direction first; None where there is none that is not a lattice
    corner yet (``used``). ``targets`` (axis, way, option): the candidates the options lead to where
    p is the candidate they were found from (:func:`axis_neighbours`), else looked up."""
    vx, vy = float(v[0]), float(v[1])
    nv = math.hypot(vx, vy)
    cos_min = math.cos(math.radians(cfg.ray_step_angle))
    px, py = float(p[0]), float(p[1])
    reach = []  # (-cos, order, step, target): scalar arithmetic, it runs for every prediction that finds nothing
    known = [-1] * 4 if targets is None else targets[:, :, 0].reshape(-1).tolist()
    for (sx, sy), t in zip(options[:, :, 0].reshape(-1, 2).tolist(), known):  # the nearest along each ray: a farther one may skip a corner
        if sx != sx:  # NaN: no neighbour along this ray
            continue
        n = math.hypot(sx, sy)
        cos = (sx * vx + sy * vy) / max(n * nv, 1e-9)
        if cos >= cos_min and cfg.min_step_ratio * nv <= n <= cfg.max_step_ratio * nv:
            reach.append((-cos, len(reach), sx, sy, t))
    for _, _, sx, sy, t in sorted(reach):
        if t >= 0:  # the candidate the step was found to (p + step is its position)
            if t not in used:
                return t
            continue
        d, j = tree.query((px + sx, py + sy))
        if d < 0.5 and int(j) not in used:
            return int(j)
    return None


class _Step(NamedTuple):
    """A step the growth is about to take from corner ``p``."""

    p: np.ndarray  # (2,) the corner it leaves
    length: float  # px, predicted
    gap: float  # px, the local gap (short step)
    across: float  # px, the long step across it
    normal: np.ndarray  # (2,) unit, toward +b (or +a) across the step
    sign: float  # expected sign of the +normal side minus the -normal side (the lattice's parity)


def step_taken(
    s: _Step, q: np.ndarray, placed: np.ndarray, xy: np.ndarray, tree: cKDTree, sm: np.ndarray, rim_dist: np.ndarray, cfg: TagConfig
) -> bool:
    """Whether the growth takes the step ``s`` to point q (2,): its length within
    ``cfg.min_step_ratio`` .. ``cfg.max_step_ratio`` of the prediction, not crowding a lattice
    corner (``placed`` (n, 2)), passing over no candidate of xy (a tag side and a gap taken as one step), and
    an edge with the dark cell on the side the lattice's parity says (on ``sm``, smoothed)."""
    n_q = math.hypot(q[0] - s.p[0], q[1] - s.p[1])
    if not cfg.min_step_ratio * s.length <= n_q <= cfg.max_step_ratio * s.length:
        return False
    if np.linalg.norm(placed - q, axis=1).min() < cfg.grid.crowd_radius * s.gap:
        return False
    c = edge_contrast_kernel(
        sm, rim_dist, *map(float, (s.p[0], s.p[1], q[0], q[1], s.normal[0], s.normal[1])), float(cfg.edge_depth * s.gap)
    )
    if not (np.isfinite(c) and s.sign * c >= cfg.grid.min_saddle_contrast):
        return False
    return not _junction_on_step(s.p, q, xy, tree, cfg.max_step_junction, s.across)


@dataclass
class _Growth:
    """A lattice as :func:`grow_tag_lattice` grows it."""

    placed: np.ndarray  # (n, 2) pts as one array (its first len(pts) rows), for the crowding test
    pts: list[np.ndarray] = field(default_factory=list)  # (2,) each: the lattice corners in the order placed
    index: list[int] = field(default_factory=list)  # candidate index of each lattice corner, -1 where a saddle was fitted
    lab: list[tuple[int, int]] = field(default_factory=list)  # each corner's lattice coordinates (a, b)
    filled: list[bool] = field(default_factory=list)  # whether each corner is a saddle fitted at its prediction
    frames: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)  # each corner's step frame (axis, kind, 2)
    where: dict[tuple[int, int], int] = field(default_factory=dict)  # lattice coordinates -> index into pts
    used: set[int] = field(default_factory=set)  # candidates that are lattice corners
    queue: collections.deque = field(default_factory=collections.deque)  # corners whose neighbours are still to be looked for

    def add(self, ab: tuple[int, int], p: np.ndarray, j: int, frame: np.ndarray, was_filled: bool) -> None:
        """Place corner ``ab`` at p (2,), candidate j (-1: a saddle fitted), with its step frame."""
        if j >= 0:
            self.used.add(j)  # only lattice corners: a candidate refused from one corner may be taken from another
        self.where[ab] = len(self.pts)
        if len(self.pts) == len(self.placed):
            self.placed = np.concatenate([self.placed, np.empty_like(self.placed)])
        self.placed[len(self.pts)] = p
        self.pts.append(p)
        self.index.append(j)
        self.lab.append(ab)
        self.filled.append(was_filled)
        self.frames[ab] = frame
        self.queue.append(ab)


class _Prediction(NamedTuple):
    """Where :func:`grow_tag_lattice` looks for a corner's neighbour (:func:`_predict`)."""

    pred: np.ndarray  # (2,) px: the predicted position
    v: np.ndarray  # (2,) the step from the corner that the corner's frame predicts
    axis: int  # the lattice axis the step is along
    sgn: int  # its way along it (+-1)
    kind: int  # 0: a tag side (long), 1: a gap (short)
    reach: float  # px: how far from the prediction a match may lie
    want: _Step  # the step as step_taken tests it


def _predict(
    g: _Growth, k: int, ab: tuple[int, int], dab: tuple[int, int], fr: np.ndarray, cfg: TagConfig, shape: tuple[int, int]
) -> _Prediction | None:
    """Where the neighbour ``ab + dab`` of lattice corner k (at ``ab``, step frame ``fr``) should lie:
    one long or short step along the axis (the frame's), averaged with the parallelograms of the
    neighbours placed across; None where those disagree, the prediction leaves the image
    ``shape`` (H, W) or the local gap is under ``cfg.complete.min_gap_px``."""
    (a, b), (da, db), (H, W) = ab, dab, shape
    pts, where = g.pts, g.where
    t = (a + da, b + db)
    axis, sgn, m = (0, da, a) if da else (1, db, b)
    kind = 0 if is_long(m, sgn) else 1
    v = sgn * fr[axis, kind]
    preds = [pts[k] + v]
    for side in ((db, da), (-db, -da)):  # neighbours across: their own step along (da, db)
        m0, m1 = where.get((a + side[0], b + side[1])), where.get((t[0] + side[0], t[1] + side[1]))
        if m0 is not None and m1 is not None:
            preds.append(pts[k] + pts[m1] - pts[m0])
    sx, sy = 0.0, 0.0
    for p_ in preds:  # their mean, in scalar arithmetic (in the order np.mean adds them)
        sx, sy = sx + float(p_[0]), sy + float(p_[1])
    pred = np.array([sx / len(preds), sy / len(preds)])
    step = _norm(v)
    if max(_norm(p_ - pred) for p_ in preds) > cfg.grid.agree_radius * step:
        return None
    gap = min(_norm(fr[0, 1]), _norm(fr[1, 1]))  # the local gap (short step)
    if not (0 <= pred[0] < W and 0 <= pred[1] < H) or gap < cfg.complete.min_gap_px:
        return None
    r = min(cfg.match_radius * step, cfg.complete.search * gap)  # never as far as the next row across (a gap away)
    # The step is an edge: the dark cell on the side the lattice's parity says.
    other = fr[1 - axis, 0]
    normal = other / max(_norm(other), 1e-9)  # toward +b (or +a)
    lo = min(m, m + sgn)
    cells = ((lo, b), (lo, b - 1)) if axis == 0 else ((a, lo), (a - 1, lo))  # the +normal side first
    sign = -1.0 if cell_dark(*cells[0]) else 1.0  # expected sign of (+normal side - -normal side)
    return _Prediction(pred, v, axis, sgn, kind, r, _Step(pts[k], step, gap, _norm(other), normal, sign))


def _match(
    g: _Growth,
    k: int,
    p: _Prediction,
    xy: np.ndarray,
    nbr: RayNeighbours,
    tree: cKDTree,
    grey: np.ndarray,
    smoothed: dict[int, np.ndarray],
    sm: np.ndarray,
    rim_dist: np.ndarray,
    cfg: TagConfig,
) -> tuple[np.ndarray | None, int]:
    """The corner that the prediction ``p`` from lattice corner k finds, and its candidate index
    (-1: a saddle fitted at the prediction); (None, -1) where none takes the step."""
    pred, r, want, used = p.pred, p.reach, p.want, g.used
    # The nearest candidates within reach that are not lattice corners yet (a data junction
    # of a tag may lie nearer than the corner), then a saddle fitted at the prediction.
    near = sorted((math.hypot(*(xy[j] - pred)), j) for j in tree.query_ball_point(pred, r) if j not in used)
    for _, j in near[: cfg.match_tries]:
        if step_taken(want, xy[j], g.placed[: len(g.pts)], xy, tree, sm, rim_dist, cfg):
            return xy[j], int(j)
    q, ok, _ = fit_saddles(grey, smoothed, pred[None], window_half(want.gap), cfg.grid, rim_dist)
    if ok[0] and math.hypot(*(q[0] - pred)) < r and step_taken(want, q[0], g.placed[: len(g.pts)], xy, tree, sm, rim_dist, cfg):
        return q[0], -1
    i = g.index[k]
    if i >= 0:
        # Where the fisheye bends the lattice away from the prediction: the candidates the
        # corner's own edge rays lead to, in the step's direction, near the prediction.
        j = ray_step(g.pts[k], nbr.step[i], p.v, xy, tree, used, cfg, nbr.index[i])
        near_enough = j is not None and math.hypot(*(xy[j] - pred)) < cfg.ray_step_reach * r
        if near_enough and step_taken(want, xy[j], g.placed[: len(g.pts)], xy, tree, sm, rim_dist, cfg):
            return xy[j], j
    return None, -1


def _carried(fr: np.ndarray, p: _Prediction, new_v: np.ndarray) -> np.ndarray:
    """The step frame of the corner the step ``new_v`` (2,) of prediction ``p`` reached from a corner
    with frame ``fr``: this axis's steps turn with the new step and scale with it."""
    n_new = _norm(new_v)
    nf = fr.copy()
    unit = p.sgn * new_v / n_new
    scale = n_new / p.want.length
    nf[p.axis, p.kind] = p.sgn * new_v
    nf[p.axis, 1 - p.kind] = unit * _norm(fr[p.axis, 1 - p.kind]) * scale
    return nf


def grow_tag_lattice(
    xy: np.ndarray,
    nbr: RayNeighbours,
    seed: int,
    frame0: np.ndarray,
    grey: np.ndarray,
    cfg: TagConfig,
    smoothed: dict[int, np.ndarray],
    rim_dist: np.ndarray,
    tree: cKDTree | None = None,
    tag_corners: list[int] | None = None,
) -> Lattice:
    """Breadth-first growth of an AprilGrid corner lattice from candidate ``seed`` among candidates
    xy (K, 2) with their neighbours along edge rays ``nbr`` (see :func:`axis_neighbours`), on the
    image grey (H, W), starting with the seed's step frame ``frame0`` (axis, kind (long, short), 2;
    see :func:`seed_tag`) and, where given, the seed tag's other corners ``tag_corners``
    (candidates at lattice (1, 0), (1, 1), (0, 1): the seed's look vouched for them, at the rim
    the growth's edge test may not). Lattice cell (0, 0) is a tag; axes are oriented so that a x b > 0 in the image (x right, y down)."""
    tree = tree or cKDTree(xy)
    sm = smooth_cached(smoothed, grey, 2)
    g = _Growth(np.empty((len(xy) + 16, 2)))
    g.add((0, 0), xy[seed].copy(), seed, frame0, False)
    for ab, j in zip(((1, 0), (1, 1), (0, 1)), tag_corners or []):
        if j not in g.used:
            g.add(ab, xy[j].copy(), j, frame0, False)
    while g.queue:
        a, b = g.queue.popleft()
        k = g.where[(a, b)]
        fr = g.frames[(a, b)]
        for da, db in STEPS:
            t = (a + da, b + db)
            if t in g.where:
                continue
            p = _predict(g, k, (a, b), (da, db), fr, cfg, grey.shape)
            if p is None:
                continue
            found, j_found = _match(g, k, p, xy, nbr, tree, grey, smoothed, sm, rim_dist, cfg)
            if found is None:
                continue
            g.add(t, np.asarray(found, np.float64), j_found, _carried(fr, p, found - g.pts[k]), j_found < 0)
    return Lattice(np.array(g.pts), np.array(g.lab, int), np.array(g.filled))


def lattice_link(A: Lattice, B: Lattice, radius: float) -> tuple[np.ndarray, np.ndarray, int] | None:
    """The map ab_A = M ab_B + offset (M (2, 2), one of the quarter turns
    :data:`cotrain.targets.checkerboard.ROTATIONS`: two growths of one board share its orientation,
    a x b > 0 in the image, so their coordinates differ by a rotation and an offset; offset (2,) int) that most of the
    corners B shares with A (within ``radius`` px) agree on, with B's tags on A's tag cells, and
    the number of corners in conflict under it: a shared corner at another coordinate, or a corner
    of B on a coordinate where A holds another corner (a seed tag's wrong corner, a slip at the
    end of a growth). None where fewer than 2 shared corners agree, or where conflicts are not
    outvoted: 3 votes at least and more than twice the conflicts (B is another board, or slipped)."""
    d, k = cKDTree(A.xy).query(B.xy, distance_upper_bound=radius)
    shared = np.isfinite(d)
    if shared.sum() < 2:
        return None
    best = None
    for M in ROTATIONS:
        offs, votes = np.unique(A.ab[k[shared]] - B.ab[shared] @ M.T, axis=0, return_counts=True)
        if best is None or votes.max() > best[2]:
            best = (M, offs[votes.argmax()], int(votes.max()))
    M, off, votes = best
    if votes < 2:
        return None
    lo = np.minimum(M @ (0, 0), M @ (1, 1)) + off  # B's tag cell (0, 0) in A: its lower corner
    if (lo % 2).any():
        return None
    where = A.where
    moved = B.ab[~shared] @ M.T + off
    conflicts = int(shared.sum()) - votes + sum(tuple(t) in where for t in moved.tolist())
    if conflicts and (votes < 3 or votes <= 2 * conflicts):
        return None
    return M, off, conflicts


def join_lattices(lats: list[Lattice], radius: float) -> list[Lattice]:
    """Growths of one board from several seeds (an occluder, a bend or a blur stops each) joined
    into one lattice where they link (:func:`lattice_link`), in the first one's coordinates:
    together their tags place the board where each alone reads too few. Corners in conflict are
    dropped from the join (which of the two is right is not known); the parts are placed alone as
    well, and where a part and its join disagree the surer placement wins
    (:func:`consistent_boards`)."""
    out: list[Lattice] = []
    for L in lats:
        joined = True
        while joined:
            joined = False
            for i, C in enumerate(out):
                link = lattice_link(C, L, radius)
                if link is None:
                    continue
                M, off, _ = link
                ab = L.ab @ M.T + off
                d, k = cKDTree(C.xy).query(L.xy, distance_upper_bound=radius)
                shared = np.isfinite(d)
                where = C.where
                drop_c = np.zeros(len(C.ab), bool)
                add = np.zeros(len(L.ab), bool)
                for q, t in enumerate(map(tuple, ab.tolist())):
                    if shared[q] and tuple(C.ab[k[q]]) == t:
                        continue  # the same corner
                    if shared[q]:
                        drop_c[k[q]] = True
                    if t in where:
                        drop_c[where[t]] = True
                    add[q] = not shared[q] and t not in where
                keep = ~drop_c
                xy = np.concatenate([C.xy[keep], L.xy[add]])
                L = Lattice(xy, np.concatenate([C.ab[keep], ab[add]]), np.concatenate([C.filled[keep], L.filled[add]]))
                out.pop(i)
                joined = True
                break
        out.append(L)
    return out
