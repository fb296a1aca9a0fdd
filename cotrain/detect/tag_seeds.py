"""Tag pass, stage 2: seeds (:mod:`cotrain.detect.tag_pass`, step 2).

Takes a candidate with its ray neighbours (:mod:`cotrain.detect.tag_candidates`); gives, where its
ray neighbours lead to the three other corners of a quad that looks like a tag and reads as one
(:func:`looks_like_a_tag`, :func:`cotrain.detect.tag_reading.look_at_tag`), the seed's step
frame, the tag's other corners and whether the tag decodes alone (:func:`seed_tag`), from which
the growth starts. The quads' frames and fourth corners are found compiled (:func:`_seed_quads`),
held to their readable forms (:func:`_seed_frames`, :func:`fourth_corner`) by a test.
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np
from scipy.spatial import cKDTree

from cotrain.detect.image_circle import EquidistantLens, parallelogram_corner
from cotrain.detect.sampling import values_at
from cotrain.detect.tag_candidates import RayNeighbours
from cotrain.detect.tag_config import TagConfig
from cotrain.detect.tag_growth import ray_step
from cotrain.detect.tag_reading import _unit_points, decode_bits, look_at_tag
from cotrain.targets.aprilgrid import CELLS, DATA_BITS


def _seed_frames(nbr: np.ndarray, index: np.ndarray, spacing: float) -> list[tuple[np.ndarray, int, int]]:
    """Step frames (axis, kind (long, short), 2) under which a candidate would be a tag corner with
    the tag in the (+a, +b) quadrant: one per quadrant whose two sides have a neighbour, surest
    first (the nearest neighbours, both sides the longer of their axis), from its neighbours
    ``nbr`` (axis, way, option, 2; see :func:`axis_neighbours`) and their candidate indices
    ``index`` (axis, way, option), each with the candidates its two long steps lead to (along
    axis 0, axis 1). The short steps are the neighbours the other way
    where they are no longer than the side, otherwise the target's gap (``spacing`` of
    the side): a corner on the board's outer edge has no gap beyond it.

    The readable form of the first half of :func:`_seed_quads`, which the seeds run (compiled)
    and which a test holds to it."""
    # Plain floats.
    opts = [
        [[(x, y, math.hypot(x, y), j) for (x, y), j in zip(nbr[a, w].tolist(), index[a, w].tolist()) if x == x] for w in (0, 1)]
        for a in (0, 1)
    ]
    frames = []
    for s1 in (0, 1):
        for s2 in (0, 1):
            for i, (ax, ay, nA, ja) in enumerate(opts[0][s1]):
                for j, (bx, by, nB, jb) in enumerate(opts[1][s2]):
                    cross = ax * by - ay * bx
                    if abs(cross) < 0.3 * nA * nB:
                        continue
                    shorts, rank = [], 0
                    for sx, sy, n_side, others in ((ax, ay, nA, opts[0][1 - s1]), (bx, by, nB, opts[1][1 - s2])):
                        opp = others[0] if others else None
                        if opp is not None and opp[2] <= n_side:
                            shorts.append((-opp[0], -opp[1]))  # the gap behind the corner, pointing +a (+b)
                        else:
                            shorts.append((sx * spacing, sy * spacing))
                            rank += opp is not None and opp[2] > n_side  # the other way is longer: less likely the tag
                    fa, fb = ((ax, ay), shorts[0]), ((bx, by), shorts[1])
                    if cross < 0:
                        frames.append((i + j, rank, len(frames), (fb, fa), jb, ja))
                    else:
                        frames.append((i + j, rank, len(frames), (fa, fb), ja, jb))
    frames.sort(key=lambda x: x[:3])
    return [(np.array(f, np.float64), j0, j1) for *_, f, j0, j1 in frames]


def fourth_corner(
    xy: np.ndarray,
    nbr: RayNeighbours,
    tree: cKDTree,
    corners: tuple[int, int, int],
    cfg: TagConfig,
    lens: EquidistantLens | None = None,
    rays: list[list[float]] | None = None,
) -> int | None:
    """The candidate (index into xy (K, 2)) that closes the quad of candidates ``corners`` (i0,
    ia, ib: p0, p0 + A, ?, p0 + B): the
    one the ray neighbours of p0 + A (toward B) and of p0 + B (toward A) lead to (see
    :func:`ray_step`), where they agree or only one leads anywhere, within ``cfg.fourth_radius`` of
    the shorter side from the parallelogram's fourth corner; where neither does, the candidate
    there if it is the only one. Under perspective a crossing square's far corner may lie nearer the
    parallelogram's corner than the tag's own. With ``lens`` the parallelogram is closed in the
    three corners' own view of their rays (:func:`cotrain.detect.image_circle.parallelogram_corner`;
    ``rays`` (K, 3): the candidates' unit rays, :meth:`EquidistantLens.lift`, lifted here where not
    given). The seeds run it compiled (:func:`_seed_quads`, held to this by a test), and this
    where a ray neighbour has no candidate index."""
    i0, ja, jb = corners
    (x0, y0), (xa, ya), (xb, yb) = xy[i0].tolist(), xy[ja].tolist(), xy[jb].tolist()
    pred = None
    if lens is not None:
        # The parallelogram in the three corners' own view of their rays: the lens's bend removed.
        v0, va, vb = (rays[i0], rays[ja], rays[jb]) if rays is not None else lens.lift(xy[[i0, ja, jb]]).tolist()
        pred = parallelogram_corner(v0, va, vb, lens)
    if pred is None:
        pred = (xa + xb - x0, ya + yb - y0)
    r = cfg.fourth_radius * min(math.hypot(xa - x0, ya - y0), math.hypot(xb - x0, yb - y0))
    A, B = xy[ja] - xy[i0], xy[jb] - xy[i0]
    via = {ray_step(xy[j], nbr.step[j], w, xy, tree, set(), cfg, nbr.index[j]) for j, w in ((ja, B), (jb, A))} - {None}
    if len(via) == 1:
        j = via.pop()
        return j if math.hypot(float(xy[j, 0]) - pred[0], float(xy[j, 1]) - pred[1]) < r else None
    if via:
        return None  # the two sides disagree
    near = tree.query_ball_point(pred, r)
    return int(near[0]) if len(near) == 1 else None


# :func:`_seed_quads`' answers for a quad's fourth corner besides a candidate index:
_NO_FOURTH = -1  # none (the sides disagree, or lead too far from the parallelogram's corner)
_ASK_TREE = -2  # neither side's ray leads anywhere: the candidate near the parallelogram's corner, if it is the only one
_ASK_PYTHON = -3  # a ray neighbour without its candidate index: :func:`fourth_corner` decides


@numba.njit(cache=True, nogil=True)
def _ray_target(step, index, vx, vy, cos_min, lo, hi):
    """:func:`ray_step` of a candidate whose ray neighbours' targets are known and with nothing used
    (as :func:`fourth_corner` asks it), compiled: the target of the nearest neighbour along a ray
    (``step`` (axis, way, option, 2), ``index`` (axis, way, option)) most in the direction (vx,
    vy), within the cone ``cos_min`` and the step-length ratios lo .. hi; -1 where none,
    :data:`_ASK_PYTHON` where that neighbour has no index."""
    nv = math.hypot(vx, vy)
    best, best_cos = -1, -np.inf
    for a in range(2):
        for w in range(2):
            sx, sy = step[a, w, 0, 0], step[a, w, 0, 1]
            if sx != sx:
                continue
            n = math.hypot(sx, sy)
            cos = (sx * vx + sy * vy) / max(n * nv, 1e-9)
            if cos >= cos_min and lo * nv <= n <= hi * nv and cos > best_cos:  # ties: the first, as sorted() keeps them
                best, best_cos = index[a, w, 0], cos
    return _ASK_PYTHON if best_cos > -np.inf and best < 0 else best


@numba.njit(cache=True, nogil=True)
def _seed_options(seed, steps, index):
    """:func:`_seed_quads`' options along each axis and way of candidate ``seed`` (``steps`` (K,
    axis, way, option, 2), ``index`` (K, axis, way, option): :class:`RayNeighbours`): their x, y,
    length and candidate, (axis, way, option) each, NaN rows skipped, and how many each axis and
    way has (axis, way)."""
    n_opt = steps.shape[3]
    ox = np.empty((2, 2, n_opt))
    oy = np.empty((2, 2, n_opt))
    on = np.empty((2, 2, n_opt))
    oj = np.empty((2, 2, n_opt), np.int64)
    cnt = np.zeros((2, 2), np.int64)
    for a in range(2):
        for w in range(2):
            for k in range(n_opt):
                x, y = steps[seed, a, w, k, 0], steps[seed, a, w, k, 1]
                if x == x:
                    c = cnt[a, w]
                    ox[a, w, c], oy[a, w, c], on[a, w, c], oj[a, w, c] = x, y, math.hypot(x, y), index[seed, a, w, k]
                    cnt[a, w] = c + 1
    return ox, oy, on, oj, cnt


@numba.njit(cache=True, nogil=True)
def _short_step(ox, oy, on, cnt, axis, way, sx, sy, n_side, spacing):
    """The short step behind the corner along ``axis`` whose long step (sx, sy), of length
    ``n_side``, is the option taken the way ``way`` (options: :func:`_seed_options`): the nearest
    option the other way where it is no longer than the side, else the target's gap
    (``spacing`` of the side); with 1 where the other way is longer (less likely the tag), else 0."""
    if cnt[axis, 1 - way] > 0 and on[axis, 1 - way, 0] <= n_side:
        return -ox[axis, 1 - way, 0], -oy[axis, 1 - way, 0], 0
    rank = 1 if cnt[axis, 1 - way] > 0 and on[axis, 1 - way, 0] > n_side else 0
    return sx * spacing, sy * spacing, rank


@numba.njit(cache=True, nogil=True)
def _quad_frames(ox, oy, on, oj, cnt, spacing):
    """:func:`_seed_quads`' frames from the options of :func:`_seed_options`: the step frames (F,
    axis, kind, 2) in :func:`_seed_frames`' order and their candidates ja, jb (F,) along a and b."""
    n_opt = ox.shape[2]
    F = 4 * n_opt * n_opt
    frames = np.empty((F, 2, 2, 2))
    ja, jb = np.empty(F, np.int64), np.empty(F, np.int64)
    key = np.empty(F, np.int64)
    nf = 0
    for s1 in range(2):
        for s2 in range(2):
            for i in range(cnt[0, s1]):
                ax, ay, nA, j_a = ox[0, s1, i], oy[0, s1, i], on[0, s1, i], oj[0, s1, i]
                for j in range(cnt[1, s2]):
                    bx, by, nB, j_b = ox[1, s2, j], oy[1, s2, j], on[1, s2, j], oj[1, s2, j]
                    cross = ax * by - ay * bx
                    if abs(cross) < 0.3 * nA * nB:
                        continue
                    gax, gay, rank_a = _short_step(ox, oy, on, cnt, 0, s1, ax, ay, nA, spacing)
                    gbx, gby, rank_b = _short_step(ox, oy, on, cnt, 1, s2, bx, by, nB, spacing)
                    rank = rank_a + rank_b
                    if cross < 0:  # turned: b first, to keep a x b > 0
                        frames[nf, 0, 0, 0], frames[nf, 0, 0, 1], frames[nf, 0, 1, 0], frames[nf, 0, 1, 1] = bx, by, gbx, gby
                        frames[nf, 1, 0, 0], frames[nf, 1, 0, 1], frames[nf, 1, 1, 0], frames[nf, 1, 1, 1] = ax, ay, gax, gay
                        ja[nf], jb[nf] = j_b, j_a
                    else:
                        frames[nf, 0, 0, 0], frames[nf, 0, 0, 1], frames[nf, 0, 1, 0], frames[nf, 0, 1, 1] = ax, ay, gax, gay
                        frames[nf, 1, 0, 0], frames[nf, 1, 0, 1], frames[nf, 1, 1, 0], frames[nf, 1, 1, 1] = bx, by, gbx, gby
                        ja[nf], jb[nf] = j_a, j_b
                    key[nf] = ((i + j) * 8 + rank) * F + nf  # nearest options, then rank, then the order found
                    nf += 1
    order = np.argsort(key[:nf])
    return frames[:nf][order], ja[:nf][order], jb[:nf][order]


@numba.njit(cache=True, nogil=True)
def _lens_corner(v0, va, vb, cx, cy, focal):
    """:func:`cotrain.detect.image_circle.parallelogram_corner` of the unit rays v0, va, vb (3,)
    under the lens (centre cx, cy, ``focal``), in the same arithmetic: (px, py, whether there is one)."""
    zx, zy, zz = v0[0] + va[0] + vb[0], v0[1] + va[1] + vb[1], v0[2] + va[2] + vb[2]
    n = math.sqrt(zx * zx + zy * zy + zz * zz)
    if n >= 1e-12:
        zx, zy, zz = zx / n, zy / n, zz / n
        d0 = v0[0] * zx + v0[1] * zy + v0[2] * zz
        d1 = va[0] * zx + va[1] * zy + va[2] * zz
        d2 = vb[0] * zx + vb[1] * zy + vb[2] * zz
        if min(d0, d1, d2) > 0.1:
            x = va[0] / d1 + vb[0] / d2 - v0[0] / d0
            y = va[1] / d1 + vb[1] / d2 - v0[1] / d0
            z = va[2] / d1 + vb[2] / d2 - v0[2] / d0
            rho = math.hypot(x, y)
            k = focal * math.atan2(rho, z) / rho if rho > 1e-12 else 0.0
            return cx + x * k, cy + y * k, True
    return 0.0, 0.0, False


@numba.njit(cache=True, nogil=True)
def _quad_fourths(seed, ja, jb, steps, index, xy, rays, use_lens, cx, cy, focal, cos_min, lo, hi, fourth_radius):
    """:func:`_seed_quads`' fourth corners of the quads seed, ja, ?, jb ((F,) each, from
    :func:`_quad_frames`): (F,) a candidate index or :data:`_NO_FOURTH`, :data:`_ASK_TREE`,
    :data:`_ASK_PYTHON`, with the parallelogram's corner (F, 2) and the radius (F,) to look in."""
    nf = len(ja)
    fourth = np.empty(nf, np.int64)
    pred = np.empty((nf, 2))
    radius = np.empty(nf)
    x0, y0 = xy[seed, 0], xy[seed, 1]
    for f in range(nf):
        a, b = ja[f], jb[f]
        xa, ya, xb, yb = xy[a, 0], xy[a, 1], xy[b, 0], xy[b, 1]
        px, py, have = 0.0, 0.0, False
        if use_lens:  # parallelogram_corner, in the same arithmetic
            px, py, have = _lens_corner(rays[seed], rays[a], rays[b], cx, cy, focal)
        if not have:
            px, py = xa + xb - x0, ya + yb - y0
        r = fourth_radius * min(math.hypot(xa - x0, ya - y0), math.hypot(xb - x0, yb - y0))
        pred[f, 0], pred[f, 1], radius[f] = px, py, r
        # The candidates the ray neighbours of p0 + A (toward B) and of p0 + B (toward A) lead to.
        t1 = _ray_target(steps[a], index[a], xb - x0, yb - y0, cos_min, lo, hi)
        t2 = _ray_target(steps[b], index[b], xa - x0, ya - y0, cos_min, lo, hi)
        if t1 == _ASK_PYTHON or t2 == _ASK_PYTHON:
            fourth[f] = _ASK_PYTHON
        elif t1 >= 0 and t2 >= 0 and t1 != t2:
            fourth[f] = _NO_FOURTH  # the two sides disagree
        elif t1 >= 0 or t2 >= 0:
            t = t1 if t1 >= 0 else t2
            fourth[f] = t if math.hypot(xy[t, 0] - px, xy[t, 1] - py) < r else _NO_FOURTH
        else:
            fourth[f] = _ASK_TREE
    return fourth, pred, radius


@numba.njit(cache=True, nogil=True)
def _seed_quads(seed, steps, index, xy, rays, use_lens, cx, cy, focal, spacing, cos_min, lo, hi, fourth_radius):
    """:func:`_seed_frames` and each frame's :func:`fourth_corner` for candidate ``seed`` at once,
    compiled (the seeds try about 60 candidates a frame, most of which are no tag corner), in
    their arithmetic but for ``math.hypot``, which numba takes from the C library (a unit in the
    last place off CPython's for about 0.6 % of lengths): the same frames in the same order (F,
    axis, kind, 2), their candidates ja, jb (F,) along a and b, and the fourth corner (F,): a
    candidate index, or :data:`_NO_FOURTH`, :data:`_ASK_TREE` (then the parallelogram's corner
    ``pred`` (F, 2) and radius ``r`` (F,) to look in) or :data:`_ASK_PYTHON`.
    ``steps`` (K, axis, way, option, 2) and ``index`` (K, axis, way,
    option): :class:`RayNeighbours`; ``rays`` (K, 3) the candidates' unit rays under the lens
    (centre cx, cy, ``focal``) where ``use_lens``. The options (:func:`_seed_options`), the frames
    (:func:`_quad_frames`), the fourth corners (:func:`_quad_fourths`)."""
    ox, oy, on, oj, cnt = _seed_options(seed, steps, index)
    frames, ja, jb = _quad_frames(ox, oy, on, oj, cnt, spacing)
    fourth, pred, radius = _quad_fourths(seed, ja, jb, steps, index, xy, rays, use_lens, cx, cy, focal, cos_min, lo, hi, fourth_radius)
    return frames, ja, jb, fourth, pred, radius


def _shortest_side_of(p0: np.ndarray, frame: np.ndarray, p2: np.ndarray) -> float:
    """:func:`shortest_side` of the quad p0, p0 + frame[0, 0], p2, p0 + frame[1, 0], in scalar
    arithmetic (the same sums as numpy's norm: it runs for each quad a seed tries)."""
    x0, y0 = float(p0[0]), float(p0[1])
    pts = (
        (x0, y0),
        (x0 + float(frame[0, 0, 0]), y0 + float(frame[0, 0, 1])),
        (float(p2[0]), float(p2[1])),
        (x0 + float(frame[1, 0, 0]), y0 + float(frame[1, 0, 1])),
    )
    sides = []
    for i in range(4):
        dx, dy = pts[i][0] - pts[i - 1][0], pts[i][1] - pts[i - 1][1]
        sides.append(math.sqrt(dx * dx + dy * dy))  # products, not powers: numpy's norm sums x * x
    return min(sides)


def seed_tag(
    xy: np.ndarray,
    nbr: RayNeighbours,
    seed: int,
    img: np.ndarray,
    spacing: float,
    cfg: TagConfig,
    tree: cKDTree,
    lens: EquidistantLens | None = None,
    rays: np.ndarray | None = None,
) -> tuple[np.ndarray, list[int], bool] | None:
    """A seed for the growth: candidate ``seed`` (of xy (K, 2), neighbours along its edges ``nbr``,
    see :func:`axis_neighbours`) is a tag corner whose tag, lattice cell
    (0, 0), has its three other corners among the candidates and looks like a tag in ``img``
    (H, W): a black border ring inside white gaps, black and white data cells (see
    :func:`look_at_tag`). Returns the seed's step frame (axis, kind (long, short), 2), the
    candidates at the tag's other corners, lattice (1, 0), (1, 1), (0, 1), and whether the tag
    decodes alone (a tag36h11 code within ``cfg.max_hamming``); None otherwise. This
    keeps the growth off the X-junctions between a tag's own data cells, and off the black squares
    at the gap crossings. With ``lens``, ``rays`` (K, 3) are the candidates' unit rays under it
    (:func:`fourth_corner`)."""
    p0 = xy[seed]
    if lens is not None and rays is None:
        rays = lens.lift(xy)
    # The frames and their fourth corners (_seed_frames and fourth_corner, compiled).
    frames, jas, jbs, fourth, pred, radius = _seed_quads(
        seed,
        nbr.step,
        nbr.index,
        xy,
        _SEED_NO_RAYS if rays is None else rays,
        lens is not None,
        *((lens.centre[0], lens.centre[1], lens.focal) if lens is not None else (0.0, 0.0, 1.0)),
        float(spacing),
        math.cos(math.radians(cfg.ray_step_angle)),
        cfg.min_step_ratio,
        cfg.max_step_ratio,
        cfg.fourth_radius,
    )
    for frame, ja, jb, j, q, r in zip(frames, jas.tolist(), jbs.tolist(), fourth.tolist(), pred, radius.tolist()):
        if j == _ASK_TREE:
            near = tree.query_ball_point(q, r)
            j = int(near[0]) if len(near) == 1 else _NO_FOURTH
        elif j == _ASK_PYTHON:
            j = fourth_corner(xy, nbr, tree, (seed, ja, jb), cfg, lens, None if rays is None else rays.tolist())
            j = _NO_FOURTH if j is None else j
        if j == _NO_FOURTH:
            continue
        if _shortest_side_of(p0, frame, xy[j]) / CELLS < cfg.min_cell_px:
            continue
        c = np.array([p0, p0 + frame[0, 0], xy[j], p0 + frame[1, 0]])
        if not looks_like_a_tag(img, c, spacing):
            continue  # a quick look first: most quads of candidates are no tag
        look = look_at_tag(img, c, spacing, sharpen=cfg.sharpen, max_side_misfit=cfg.max_side_misfit, lens=lens)
        if look is None or look.contrast < 0 or look.clean < cfg.min_clean:
            continue
        if look.data_contrast < cfg.min_data_contrast:
            continue  # uniform inside: a crossing square, not a tag
        decodes = decode_bits(look.white)[2] <= cfg.max_hamming
        return frame, [ja, int(j), jb], decodes
    return None


_SEED_NO_RAYS = np.zeros((0, 3))  # :func:`_seed_quads`' rays where no lens is guessed


# origin: measured on 839 AprilGrid frames (rendered, photographed and processed; the sets not named in CHANGELOG): no tag read spans
# under 0.17, and their detections are the same with the test (set in 6280c63)
QUICK_DATA_SPAN = 0.08  # looks_like_a_tag: a tag's data cells span at least this share of its border-to-gap contrast


def looks_like_a_tag(img: np.ndarray, corners: np.ndarray, spacing: float) -> bool:
    """A quick test that the quad ``corners`` (4, 2) (lattice (0, 0), (1, 0), (1, 1), (0, 1)) could
    be a tag, before it is read: at a third and two thirds of each side, the black border (its
    inner ring, a cell and a half in) is darker than (at 7 of the 8 points) the white gap beyond
    the side (half a gap out); and the centres of its 6 x 6 data cells are not all alike (they
    span :data:`QUICK_DATA_SPAN` of the gap's median minus the ring's at least: a checker square
    or a dark patch framed by light is uniform inside; of the quads read as tags on rendered,
    photographed and processed frames none spans under 0.17). A ring or gap point beyond the
    frame's edge counts as failed (one may); where a data cell lies beyond it, the data test is
    left to the full read. Bilinear in the quad: 52 samples."""
    vals = values_at(img, _quick_weights(float(spacing)) @ corners)
    ring, gaps, data = vals[:8], vals[8:16], vals[16:]
    if (ring < gaps).sum() < 7:  # a point beyond the frame's edge (NaN) counts as failed
        return False
    if not np.isfinite(data).all():  # data cells beyond the frame's edge say nothing: the full read decides
        return True
    return bool(data.max() - data.min() >= QUICK_DATA_SPAN * (np.nanmedian(gaps) - np.nanmedian(ring)))


@functools.lru_cache(maxsize=4)
def _quick_weights(spacing: float) -> np.ndarray:
    """(52, 4) bilinear weights of :func:`looks_like_a_tag`'s samples on a quad's four corners: two
    points on each side, a cell and a half in (8), then half a gap out (8), then the centres of the
    6 x 6 data cells (36)."""
    t = np.array([1 / 3, 2 / 3])

    def on_sides(d: float) -> np.ndarray:  # (8, 2): two points on each side, ``d`` in from it (unit square)
        lo, hi = np.full(2, d), np.full(2, 1 - d)
        return np.concatenate([np.stack(p, 1) for p in ((t, lo), (t, hi), (lo, t), (hi, t))])

    data = _unit_points(spacing)[0].reshape(DATA_BITS * DATA_BITS, 9, 2)[:, 4]  # each data cell's centre: the middle of its 3 x 3 points
    uv = np.concatenate([on_sides(1.5 / CELLS), on_sides(-spacing / 2), data])
    u, v = uv[:, 0], uv[:, 1]
    w = np.stack([(1 - u) * (1 - v), u * (1 - v), u * v, (1 - u) * v], 1)
    w.setflags(write=False)  # cached: shared by every call
    return w
