"""Tag pass of the detector: Kalibr AprilGrid corners, identified by the tags' own codes.

An AprilGrid's corners are X-junctions: at every tag corner the tag's black border meets the black
square of a gap crossing. Along a row of corners the steps alternate: a tag side (long), a gap
(short, ``tag_spacing`` of a tag). Cells of the corner lattice alternate dark and light like a
checkerboard's: tags and crossing squares are dark, the gap strips between them light. So:

1. candidates (:func:`tag_candidates`): saddle points of the full-resolution image (inside the
   image circle), fitted as the grid pass fits them (:mod:`cotrain.detect.saddle`); their four
   edge rays (:func:`corner_rays`) and the candidates along them (:func:`axis_neighbours`); the
   whole-image work before the fits runs half on a second thread (:func:`_candidates_of`);
2. seeds (:func:`seed_tag`): a candidate whose ray neighbours lead to the three other corners of
   a tag that looks like one (black border ring in white gaps, black and white data cells); seeds
   whose tag decodes alone grow first, the others after them (a quad of junctions across two
   large bent tags can look like a tag, and would otherwise cover their corners);
3. growth (:func:`grow_tag_lattice`): breadth first; each neighbour is predicted one long or one
   short step along a lattice axis (step lengths carried from corner to corner, and the
   parallelograms of neighbours already placed) and matched to a nearby candidate, a saddle found
   at the prediction, or the candidate the corner's own ray leads to (:func:`ray_step`); every
   step must be an edge with the dark cell on the side the lattice's parity says, and must not
   pass over another candidate (:func:`step_taken`);
4. reading (:func:`read_cells`, :func:`look_at_tag`): each tag cell with its four corners is read
   through its own homography (where the frame shows a fisheye's image circle, the homography of
   the corners' rays under an equidistant lens guessed from the circle,
   :mod:`cotrain.detect.image_circle`, so the lens bends the tag's square as it bends the tag),
   bent by the lattice corners around it and by its sides as the
   image shows them (:func:`side_points`; never one homography per board: the fisheye bends a
   tag at the rim, a tag side bowed by a data cell already moves every cell a row), unless the
   sides disagree with the corners (a slid corner); the cells sharpened against blur and the data split
   into black and white by Otsu's threshold; a tag decodes alone within ``max_hamming`` bit errors
   (AprilTag's own default: 2 of tag36h11's 11);
5. placement (:func:`place_board`): each lattice, and each join of lattices grown from several
   seeds that share corners consistently (:func:`join_lattices`), is placed: the turn and offset
   on the board that all its read tags support together (correlation with the codes it puts under
   them); tags that decode alone elsewhere are dropped and counted; :func:`verified_corners`
   keeps the corners of tags that match (small blurred tags: better than a slip by one tag
   would), of unread tags beside a tag that matched surely (and on through unread tags, up to
   ``lend_depth`` tags away), and of unread tags at the lattice's
   fringe a step or two from a firm match (ids through the lattice); :func:`cells_close`,
   :func:`steps_alternate` and :func:`rays_agree` drop corners that slid or sit on a junction
   inside a tag;
6. boards: lattices that place no tag of the target (a second board with other tags; free tags
   have no X-junctions at their corners) give no corners; lattices of one board (a join and its
   parts too) are merged where they agree, and of two that claim the same ids elsewhere, or the
   same place with other ids, the surer placement stays (:func:`consistent_boards`);
7. positions: every corner fitted once more in a small window
   (:func:`cotrain.detect.lattice.final_fits`); one whose fit fails is dropped, except in gaps
   narrower than ``keep_unfitted_px``, where the window reaches across the crossing square and
   its failure says nothing (the corner keeps its lattice position);
8. completion (:mod:`cotrain.detect.tag_completion`): first every corner is checked against the
   print around it (one that a grid neighbour's print matches better is dropped), then the placed
   board's corners the growth did not reach are predicted from the identified ones and checked
   against the print around them;
9. half resolution: where few corners are found, and completion left a corner it predicted in
   view unfound (or none was found), the frame is read again at half resolution and what only
   that finds is added where the print check keeps it (:func:`tag_pass`).

Pure functions over numpy arrays; pixels follow docs/conventions.md (centre of the top-left pixel at (0, 0)).
"""

from __future__ import annotations

import collections
import functools
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import cv2
import numba
import numpy as np
from scipy.spatial import cKDTree

from cotrain.detect.grid_config import GridConfig
from cotrain.detect.half_resolution import corners_at_half_resolution, halve
from cotrain.detect.image_circle import EquidistantLens, guess_lens, parallelogram_corner, ray_homographies
from cotrain.detect.images import MIN_SIDE, local_gain
from cotrain.detect.lattice import (
    STEPS,
    Lattice,
    beside_points,
    corner_rays,
    edge_contrast_kernel,
    edge_sample_points,
    final_fits,
    shortest_steps,
    values_at,
)
from cotrain.detect.saddle import fit_saddles, outside_circle, saddle_response, smooth_cached, smooth_for, window_half
from cotrain.detect.tag_completion import CompletionConfig, complete_board, own_print_corr, print_check, print_moved
from cotrain.targets.aprilgrid import BORDER_BITS, CELLS, DATA_BITS, N_CODES, AprilGrid, printed_bits


@dataclass
class TagConfig:
    # --- candidates ---
    response_sigma: float = 0.9  # px: scale of the saddle response (small: gaps of tiny tags are 2-3 px)
    min_response: float = 0.0015  # saddle response a candidate needs (scale-normalised -det Hessian)
    candidate_min_symmetry: float = 0.5  # a candidate's fit needs this point symmetry (the grid pass's min_symmetry for the rest)
    max_candidates: int = 1500  # strongest response maxima kept (all true corners of the evaluation set rank within 1500)
    # --- growth ---
    seed_axis_angle: float = 12.0  # deg: a seed's neighbours lie within this of its edge rays ...
    retry_seed_angle: float = 16.0  # ... or, in a frame where nothing is found, within this in a second and third look (0: neither)
    ray_search: int = 96  # nearest candidates searched for ray neighbours
    ray_tries: int = 5  # candidates tried along each edge ray, nearest first, for ones reached along an edge
    ray_edge_depth: float = 0.6  # that edge test samples at most this multiple of the nearest-candidate distance aside
    ray_options: int = 3  # candidates reached along an edge kept per ray: a seed's tag sides are tried among them
    ray_radius: float = 0.5  # edge rays are read on a circle of this fraction of the local gap (of a candidate: its nearest candidate)
    fourth_radius: float = 0.6  # a seed tag's fourth corner lies within this fraction of its shorter side of the parallelogram's
    min_long_short: float = 1.7  # at a seed, tag side / gap (Kalibr: 1 / tagSpacing) must exceed this on both axes
    max_seeds: int = 40  # seeds tried (strongest responses first); covered candidates are not tried again
    match_radius: float = 0.35  # a neighbour must lie within this fraction of its predicted step
    match_gap: float = 0.6  # ... and within this fraction of the local gap: under strong perspective the next row lies a gap away
    match_tries: int = 3  # candidates within reach tried at a predicted spot, nearest first, before a saddle is fitted there
    agree_radius: float = 0.3  # predictions from different neighbours must agree within this fraction of the step
    min_step_ratio: float = 0.7  # a new step may be this much shorter than predicted ...
    max_step_ratio: float = 1.4  # ... or this much longer
    ray_step_angle: float = 40.0  # deg: where nothing lies at a prediction, a candidate an edge ray leads to within this of the step
    ray_step_reach: float = 2.0  # ... and within this multiple of the reach of the prediction
    max_step_junction: float = 0.1  # a candidate this close to a step's middle part (fraction of the step) refuses it
    crowd_radius: float = 0.5  # a new corner this close (fraction of the local gap) to a placed one is refused
    min_gap_px: float = 1.6  # no growth across gaps smaller than this
    edge_depth: float = 0.35  # the edge test samples this fraction of the gap to each side of a step
    min_edge_contrast: float = 0.04  # light minus dark side of a step, intensity, mean over the step
    # --- decoding ---
    max_hamming: int = 2  # bit errors a tag read alone may have (tag36h11: codes differ in at least 11 bits)
    min_bit_contrast: float = 0.06  # white gap minus black border a tag needs to be read
    min_data_share: float = 0.15  # a seed's tag has at least this share of white and of black data cells (tag36h11: 0.2 .. 0.8)
    min_data_contrast: float = 0.2  # a seed's white data cells must be lighter than its black ones by this share of the tag's contrast
    min_clean: float = 0.9  # share of its border's inner-ring samples darker, and gap samples lighter, than their midpoint
    max_side_misfit: float = 0.04  # tags are read through a map bent to their sides, where the sides fit it within this (tag widths)
    sharpen: float = 1.5  # weight of the 4-neighbour Laplacian that undoes blur over a tag's cells (rendered tags of 10-30 px)
    min_cell_px: float = 1.0  # tags whose data cells are smaller than this (px) neither seed a lattice nor are read ...
    retry_min_cell_px: float = 0.7  # ... or than this, in a third look (the second's wider cone too) where the first two find nothing
    retry_gain: float = 3.0  # a fourth look where the third finds nothing: contrast raised this much about the local mean (<= 1: never)
    retry_gain_sigma: float = 0.028  # the local mean's Gaussian sigma, as a share of the frame's shorter side (20 px at 720)
    lens_fov: float = 210.0  # deg: where an image circle shows, tags are read through an equidistant lens of this FoV filling it (0: never)
    # --- placement ---
    min_margin: float = 12.0  # the board's placement must beat the runner-up by this (correlation; a clean tag gives 36)
    min_mean_corr: float = (
        0.3  # ... and its tags must correlate with their codes by this much on average (-1 .. 1; blurred 9 px tags: 0.37)
    )
    min_tag_corr: float = 0.5  # a tag that was read keeps its corners when it correlates with its code by this much
    small_tag_px: float = 20.0  # tags narrower than this (px; cells of 2 px) blur: for them ...
    min_tag_corr_local: float = 0.25  # ... this much is enough where it beats the codes a slip by one tag would put there ...
    min_slip_margin: float = 0.15  # ... by this much
    min_lend_corr: float = 0.7  # a read tag lends its ids to an unread tag beside it when it correlates with its code by this much
    min_lend_slip_margin: float = 0.3  # ... or, under small_tag_px, by min_tag_corr_local and beating a slip by one tag by this much
    lend_depth: int = 3  # ... and on through unread tags beside it, up to this many tags away (1: beside it only)
    fringe_steps: int = 2  # an unread tag's corner next to a kept one keeps its id up to this many steps from a min_lend_corr match
    max_cell_misfit: float = 0.25  # a corner must close one of its cells as a parallelogram within this fraction of its side
    max_ray_angle: float = 20.0  # deg: a corner's steps to its lattice neighbours leave along its own edge rays within this ...
    small_gap_px: float = 3.5  # ... or, where its shortest lattice step is under this (tags under 12 px: no data junctions resolve) ...
    max_ray_angle_small: float = 30.0  # ... within this: on a circle of 1.5-1.75 px the rays' angles are coarse
    rim_strict_px: float = 8.0  # corners this close to the rim are reported only in a complete lattice cell
    max_side_gap_ratio: float = 2.0  # a corner's tag side / gap on a lattice line may differ from the target's by this factor
    keep_unfitted_px: float = 6.0  # px: shortest lattice step under which a failed final fit keeps the lattice position
    # --- small frames ---
    min_side_px: int = 720  # frames whose shorter side is under this are read enlarged to it (bilinear; 0: never) ...
    max_enlarge: float = 1.5  # ... by at most this factor; the thresholds above that judge a tag's size in px scale with it
    # --- blurred and large tags ---
    half_below: int = 70  # a frame not read enlarged (min_side_px) where fewer corners are found is read at half resolution too (0: never)
    # --- boards ---
    min_corners: int = 4  # smallest lattice that is reported
    complete: CompletionConfig = field(default_factory=CompletionConfig)  # corners the growth missed, predicted from the placed board
    grid: GridConfig = field(default_factory=GridConfig)  # saddle fit and final positions (the grid pass's)


@dataclass
class TagResult:
    ids: np.ndarray  # (K,) corner ids (Kalibr's)
    xy: np.ndarray  # (K, 2) input-image pixels
    confidence: np.ndarray  # (K,) 1 for corners of decoded tags, lower through the lattice; completed corners: Completion.corr
    tags: np.ndarray  # (T,) ids of the tags that decode alone to where the board's placement puts them
    hamming: np.ndarray  # (T,) their bit errors
    dropped_tags: int = 0  # tags that decode alone to another place than the board's (not used), and second boards' tags
    foreign_tags: int = 0  # decoded tag36h11 tags that are not on the target (wild tags, other boards)
    scale: float = 1.0  # the factor the frame was read enlarged by (TagConfig.min_side_px); xy are in the frame's pixels
    unfound: int | None = None  # corners completion left unfound in view (the full-resolution pass); None: no completion ran


# --------------------------------------------------------------------------------------------
# Candidates
# --------------------------------------------------------------------------------------------
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
    gcfg = replace(cfg.grid, min_symmetry=cfg.candidate_min_symmetry)
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


# --------------------------------------------------------------------------------------------
# Growth
# --------------------------------------------------------------------------------------------
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
            edge = edges_along(img, xy[has], step, cfg.min_edge_contrast, cfg.ray_edge_depth * d[has, 1])
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


def _seed_frames(nbr: np.ndarray, index: np.ndarray, spacing: float, cfg: TagConfig) -> list[tuple[np.ndarray, int, int]]:
    """Step frames (axis, kind (long, short), 2) under which a candidate would be a tag corner with
    the tag in the (+a, +b) quadrant: one per quadrant whose two sides have a neighbour, surest
    first (the nearest neighbours, both sides the longer of their axis), from its neighbours
    ``nbr`` (axis, way, option, 2; see :func:`axis_neighbours`) and their candidate indices
    ``index`` (axis, way, option), each with the candidates its two long steps lead to (along
    axis 0, axis 1). The short steps are the neighbours the other way
    where they are shorter by ``cfg.min_long_short``, otherwise the target's gap (``spacing`` of
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
                        if opp is not None and opp[2] * cfg.min_long_short <= n_side:
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


def edge_contrast(img: np.ndarray, p: np.ndarray, q: np.ndarray, normal: np.ndarray, depth: float, rim_dist: np.ndarray) -> float:
    """Mean brightness on the ``+normal`` side of segment p -> q minus the ``-normal`` side, sampled
    at a quarter, half and three quarters of the way, ``depth`` px to each side; NaN where no
    sample pair lies inside the image circle (``rim_dist`` (H, W) > 1). The readable form of
    :func:`cotrain.detect.lattice.edge_contrast_kernel`, which the growth runs (compiled) and which a test holds to it."""
    pts = edge_sample_points(p, q, normal, depth)
    vals = values_at(img, pts)
    rd = values_at(rim_dist, pts)
    ok = (rd[:3] > 1) & (rd[3:] > 1) & np.isfinite(vals[:3]) & np.isfinite(vals[3:])
    if not ok.any():
        return float("nan")
    diff = vals[:3] - vals[3:]
    return float(diff[ok].mean()) if (diff[ok] > 0).all() or (diff[ok] < 0).all() else 0.0


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
def _seed_quads(seed, steps, index, xy, rays, use_lens, cx, cy, focal, spacing, min_long_short, cos_min, lo, hi, fourth_radius):
    """:func:`_seed_frames` and each frame's :func:`fourth_corner` for candidate ``seed`` at once,
    compiled (the seeds try about 60 candidates a frame, most of which are no tag corner), in
    their arithmetic but for ``math.hypot``, which numba takes from the C library (a unit in the
    last place off CPython's for about 0.6 % of lengths): the same frames in the same order (F,
    axis, kind, 2), their candidates ja, jb (F,) along a and b, and the fourth corner (F,): a
    candidate index, or :data:`_NO_FOURTH`, :data:`_ASK_TREE` (then the parallelogram's corner
    ``pred`` (F, 2) and radius ``r`` (F,) to look in) or :data:`_ASK_PYTHON`.
    ``steps`` (K, axis, way, option, 2) and ``index`` (K, axis, way,
    option): :class:`RayNeighbours`; ``rays`` (K, 3) the candidates' unit rays under the lens
    (centre cx, cy, ``focal``) where ``use_lens``."""
    n_opt = steps.shape[3]
    # The options along each axis and way: (x, y, length, candidate), NaN rows skipped.
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
                    rank = 0
                    # The short step behind the corner along a (then b): the nearest option the
                    # other way where it is shorter by min_long_short, else the target's gap.
                    if cnt[0, 1 - s1] > 0 and on[0, 1 - s1, 0] * min_long_short <= nA:
                        gax, gay = -ox[0, 1 - s1, 0], -oy[0, 1 - s1, 0]
                    else:
                        gax, gay = ax * spacing, ay * spacing
                        if cnt[0, 1 - s1] > 0 and on[0, 1 - s1, 0] > nA:
                            rank += 1  # the other way is longer: less likely the tag
                    if cnt[1, 1 - s2] > 0 and on[1, 1 - s2, 0] * min_long_short <= nB:
                        gbx, gby = -ox[1, 1 - s2, 0], -oy[1, 1 - s2, 0]
                    else:
                        gbx, gby = bx * spacing, by * spacing
                        if cnt[1, 1 - s2] > 0 and on[1, 1 - s2, 0] > nB:
                            rank += 1
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
    frames, ja, jb = frames[:nf][order], ja[:nf][order], jb[:nf][order]
    fourth = np.empty(nf, np.int64)
    pred = np.empty((nf, 2))
    radius = np.empty(nf)
    x0, y0 = xy[seed, 0], xy[seed, 1]
    for f in range(nf):
        a, b = ja[f], jb[f]
        xa, ya, xb, yb = xy[a, 0], xy[a, 1], xy[b, 0], xy[b, 1]
        px, py, have = 0.0, 0.0, False
        if use_lens:  # parallelogram_corner, in the same arithmetic
            v0, va, vb = rays[seed], rays[a], rays[b]
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
                    px, py, have = cx + x * k, cy + y * k, True
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
        cfg.min_long_short,
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
        if look is None or look.contrast < cfg.min_bit_contrast or look.clean < cfg.min_clean:
            continue
        if min(look.white.mean(), 1 - look.white.mean()) < cfg.min_data_share or look.data_contrast < cfg.min_data_contrast:
            continue  # uniform inside: a crossing square, not a tag
        decodes = decode_bits(look.white)[2] <= cfg.max_hamming
        return frame, [ja, int(j), jb], decodes
    return None


_SEED_NO_RAYS = np.zeros((0, 3))  # :func:`_seed_quads`' rays where no lens is guessed


def shortest_side(corners: np.ndarray) -> float:
    """The shortest side (px) of the quad ``corners`` (4, 2)."""
    return float(np.linalg.norm(corners - np.roll(corners, 1, 0), axis=1).min())


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


def inside_cells(lat: Lattice, xy: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(K,) bool: which points xy (K, 2) lie inside a complete cell of the lattice (image ``shape``)."""
    mask = np.zeros(shape, np.uint8)
    where = lat.where
    for a, b in where:
        ks = [where.get(t) for t in ((a, b), (a + 1, b), (a + 1, b + 1), (a, b + 1))]
        if None not in ks:
            cv2.fillConvexPoly(mask, np.rint(lat.xy[ks]).astype(np.int32), 1)
    H, W = shape
    q = np.clip(np.rint(xy).astype(int), 0, [W - 1, H - 1])
    return mask[q[:, 1], q[:, 0]] > 0


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
    if np.linalg.norm(placed - q, axis=1).min() < cfg.crowd_radius * s.gap:
        return False
    c = edge_contrast_kernel(
        sm, rim_dist, *map(float, (s.p[0], s.p[1], q[0], q[1], s.normal[0], s.normal[1])), float(cfg.edge_depth * s.gap)
    )
    if not (np.isfinite(c) and s.sign * c >= cfg.min_edge_contrast):
        return False
    return not _junction_on_step(s.p, q, xy, tree, cfg.max_step_junction, s.across)


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
    H, W = grey.shape
    pts = [xy[seed].copy()]
    placed = np.empty((len(xy) + 16, 2))  # pts as one array (its first len(pts) rows), for the crowding test
    placed[0] = pts[0]
    index = [seed]  # candidate index of each lattice corner, -1 where a saddle was fitted
    lab = [(0, 0)]
    filled = [False]
    frames = {(0, 0): frame0}
    where = {(0, 0): 0}
    used = {seed}
    queue = collections.deque([(0, 0)])
    for ab, j in zip(((1, 0), (1, 1), (0, 1)), tag_corners or []):
        if j in used:
            continue
        where[ab] = len(pts)
        placed[len(pts)] = xy[j]
        pts.append(xy[j].copy())
        index.append(j)
        lab.append(ab)
        filled.append(False)
        frames[ab] = frame0
        used.add(j)
        queue.append(ab)
    while queue:
        a, b = queue.popleft()
        k = where[(a, b)]
        fr = frames[(a, b)]
        for da, db in STEPS:
            t = (a + da, b + db)
            if t in where:
                continue
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
            if max(_norm(p_ - pred) for p_ in preds) > cfg.agree_radius * step:
                continue
            gap = min(_norm(fr[0, 1]), _norm(fr[1, 1]))  # the local gap (short step)
            if not (0 <= pred[0] < W and 0 <= pred[1] < H) or gap < cfg.min_gap_px:
                continue
            r = min(cfg.match_radius * step, cfg.match_gap * gap)  # never as far as the next row across (a gap away)
            # The step is an edge: the dark cell on the side the lattice's parity says.
            other = fr[1 - axis, 0]
            normal = other / max(_norm(other), 1e-9)  # toward +b (or +a)
            lo = min(m, m + sgn)
            cells = ((lo, b), (lo, b - 1)) if axis == 0 else ((a, lo), (a - 1, lo))  # the +normal side first
            sign = -1.0 if cell_dark(*cells[0]) else 1.0  # expected sign of (+normal side - -normal side)
            want = _Step(pts[k], step, gap, _norm(other), normal, sign)
            # The nearest candidates within reach that are not lattice corners yet (a data junction
            # of a tag may lie nearer than the corner), then a saddle fitted at the prediction.
            near = sorted((math.hypot(*(xy[j] - pred)), j) for j in tree.query_ball_point(pred, r) if j not in used)
            found, j_found = None, -1  # the corner, and its candidate index (-1: a saddle fitted at the prediction)
            for _, j in near[: cfg.match_tries]:
                if step_taken(want, xy[j], placed[: len(pts)], xy, tree, sm, rim_dist, cfg):
                    found, j_found = xy[j], int(j)
                    break
            if found is None:
                q, ok, _ = fit_saddles(grey, smoothed, pred[None], window_half(gap), cfg.grid, rim_dist)
                if ok[0] and math.hypot(*(q[0] - pred)) < r and step_taken(want, q[0], placed[: len(pts)], xy, tree, sm, rim_dist, cfg):
                    found = q[0]
            if found is None and index[k] >= 0:
                # Where the fisheye bends the lattice away from the prediction: the candidates the
                # corner's own edge rays lead to, in the step's direction, near the prediction.
                j = ray_step(pts[k], nbr.step[index[k]], v, xy, tree, used, cfg, nbr.index[index[k]])
                near_enough = j is not None and math.hypot(*(xy[j] - pred)) < cfg.ray_step_reach * r
                if near_enough and step_taken(want, xy[j], placed[: len(pts)], xy, tree, sm, rim_dist, cfg):
                    found, j_found = xy[j], j
            if found is None:
                continue
            was_filled = j_found < 0
            if j_found >= 0:
                used.add(j_found)  # only lattice corners: a candidate refused from one corner may be taken from another
            index.append(j_found)
            new_v = found - pts[k]
            n_new = _norm(new_v)
            # Carry the frame: this axis's steps turn with the new step and scale with it.
            nf = fr.copy()
            unit = sgn * new_v / n_new
            scale = n_new / step
            nf[axis, kind] = sgn * new_v
            nf[axis, 1 - kind] = unit * _norm(fr[axis, 1 - kind]) * scale
            frames[t] = nf
            where[t] = len(pts)
            if len(pts) == len(placed):
                placed = np.concatenate([placed, np.empty_like(placed)])
            placed[len(pts)] = found
            pts.append(np.asarray(found, np.float64))
            lab.append(t)
            filled.append(was_filled)
            queue.append(t)
    return Lattice(np.array(pts), np.array(lab, int), np.array(filled))


# Lattice-to-lattice turns: two growths of one board share its orientation (a x b > 0 in the
# image), so their coordinates differ by a rotation and an offset.
ROTATIONS = (np.array([[1, 0], [0, 1]]), np.array([[0, -1], [1, 0]]), np.array([[-1, 0], [0, -1]]), np.array([[0, 1], [-1, 0]]))


def lattice_link(A: Lattice, B: Lattice, radius: float) -> tuple[np.ndarray, np.ndarray, int] | None:
    """The map ab_A = M ab_B + offset (M (2, 2), one of :data:`ROTATIONS`; offset (2,) int) that most of the
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


# --------------------------------------------------------------------------------------------
# Decoding
# --------------------------------------------------------------------------------------------
# Lattice-to-board turns: board corner-grid (c, r) = M (a, b) + offset. The lattice is oriented
# a x b > 0 in the image (y down) and Kalibr's page has y up, so M is a reflection (det -1).
TURNS = (
    np.array([[1, 0], [0, -1]]),
    np.array([[-1, 0], [0, 1]]),
    np.array([[0, 1], [1, 0]]),
    np.array([[0, -1], [-1, 0]]),
)


@functools.lru_cache(maxsize=1)
def _codes() -> np.ndarray:
    """(N_CODES, 36) float: every tag36h11 code as printed, +1 white / -1 black, page cell (i, j)
    at j * 6 + i."""
    return printed_bits(N_CODES).reshape(N_CODES, -1).astype(np.float64) * 2 - 1


@functools.lru_cache(maxsize=1)
def _turn_index() -> np.ndarray:
    """(4, 36): for each of :data:`TURNS`, the page data cell of lattice data cell (p, q) (p along a,
    q along b; flat q * 6 + p)."""
    p, q = np.meshgrid(np.arange(DATA_BITS), np.arange(DATA_BITS))
    d = np.stack([p.ravel(), q.ravel()], 0) - (DATA_BITS - 1) / 2
    out = []
    for M in TURNS:
        i, j = np.rint(M @ d + (DATA_BITS - 1) / 2).astype(int)
        out.append(j * DATA_BITS + i)
    return np.array(out)


def page_order(soft: np.ndarray, turn: int) -> np.ndarray:
    """Data cells (..., 36) in lattice order -> page order under turn ``turn`` of :data:`TURNS`."""
    out = np.empty_like(soft)
    out[..., _turn_index()[turn]] = soft
    return out


@functools.lru_cache(maxsize=4)
def _unit_points(spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample points of a tag in its unit square (u along a, v along b; corners at 0 and 1):
    3 x 3 points over the middle half of each data cell (36 * 9, 2; cell by cell in (p, q)
    order), border cell centres (64, 2), and points in the white gaps around the tag (12, 2), half
    a gap out."""
    c = (np.arange(CELLS) + 0.5) / CELLS
    U, V = np.meshgrid(c, c)
    idx = np.arange(CELLS)
    inner = (idx >= BORDER_BITS) & (idx < CELLS - BORDER_BITS)
    data = np.stack([U[np.ix_(inner, inner)].ravel(), V[np.ix_(inner, inner)].ravel()], 1)
    sub = np.stack(np.meshgrid([-0.25, 0, 0.25], [-0.25, 0, 0.25]), -1).reshape(-1, 2) / CELLS
    data = (data[:, None] + sub[None]).reshape(-1, 2)
    border = _border_mask()
    bord = np.stack([U[border], V[border]], 1)
    out = -spacing / 2
    s = np.array([0.3, 0.5, 0.7])
    gaps = np.concatenate(
        [
            np.stack([s, np.full(3, out)], 1),
            np.stack([s, np.full(3, 1 - out)], 1),
            np.stack([np.full(3, out), s], 1),
            np.stack([np.full(3, 1 - out), s], 1),
        ]
    )
    return data, bord, gaps


@dataclass
class TagLook:
    soft: np.ndarray  # (36,) data cells in lattice order (p + 6 q), sharpened, zero mean and unit RMS
    threshold: float  # the split of ``soft`` into black and white cells (two-class Otsu)
    contrast: float  # white gaps minus black border, intensity
    data_contrast: float  # mean white minus mean black data cell (split at ``threshold``), in units of ``contrast``
    clean: float  # share of the border's inner-ring samples darker, and gap samples lighter, than their midpoint

    @property
    def white(self) -> np.ndarray:
        """(36,) bool: the data cells read white."""
        return self.soft > self.threshold


def _quadratic(u: np.ndarray) -> np.ndarray:
    """(..., 2) -> (..., 6) monomials 1, u, v, uv, u^2, v^2."""
    x, y = u[..., 0], u[..., 1]
    return np.stack([np.ones_like(x), x, y, x * y, x * x, y * y], -1)


def _project(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Homographies H (T, 3, 3) applied to points p (T, n, 2) -> (T, n, 2), as
    ``cv2.perspectiveTransform`` does (a point at infinity goes to 0)."""
    x, y = p[..., 0], p[..., 1]
    h = H[:, None]
    w = h[..., 2, 0] * x + h[..., 2, 1] * y + h[..., 2, 2]
    inv = np.where(np.abs(w) > np.finfo(np.float64).eps, 1.0 / np.where(w == 0, 1.0, w), 0.0)
    px = (h[..., 0, 0] * x + h[..., 0, 1] * y + h[..., 0, 2]) * inv
    py = (h[..., 1, 0] * x + h[..., 1, 1] * y + h[..., 1, 2]) * inv
    return np.stack([px, py], -1)


@dataclass
class TagMap:
    """T tags' unit squares (u along a, v along b; corners at 0 and 1) -> image pixels (:func:`tag_maps`)."""

    H: np.ndarray  # (T, 3, 3) the homographies of the tags' four corners (to pixels; with a lens, to rays)
    coef: np.ndarray  # (T, 6, 2) the quadratics that bend the unit squares first (:func:`_quadratic`); zero: not bent
    misfit: np.ndarray  # (T,) the largest distance (tag widths) of a point found on a side from the fitted side; 0 without side points
    lens: EquidistantLens | None = None  # the lens guessed from the image circle; None: H maps to pixels

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """(k, 2) unit coordinates (the same for every tag) or (T, k, 2) -> (T, k, 2) pixels."""
        u = np.broadcast_to(np.asarray(u, np.float64), (len(self.H), *np.shape(u)[-2:]))
        return _to_image(self.H, u + _quadratic(u) @ self.coef, self.lens)

    def take(self, idx: np.ndarray) -> TagMap:
        """The maps of tags ``idx`` (an index or bool mask over T)."""
        return TagMap(self.H[idx], self.coef[idx], self.misfit[idx], self.lens)


def _to_image(H: np.ndarray, u: np.ndarray, lens: EquidistantLens | None) -> np.ndarray:
    """Unit points u (T, n, 2) through homographies H (T, 3, 3) to pixels (T, n, 2): directly, or
    as rays through ``lens``."""
    if lens is None:
        return _project(H, u)
    x, y = u[..., 0], u[..., 1]
    h = H[:, None]
    return lens.project_xyz(*(h[..., i, 0] * x + h[..., i, 1] * y + h[..., i, 2] for i in range(3)))


def _to_unit(Hi: np.ndarray, p: np.ndarray, lens: EquidistantLens | None) -> np.ndarray:
    """Pixels p (T, n, 2) through the inverse homographies Hi (T, 3, 3) to unit points (T, n, 2):
    directly, or lifted to rays by ``lens`` first (a point at infinity goes to 0)."""
    if lens is None:
        return _project(Hi, p)
    v = lens.lift(p)
    w = (Hi[:, None] @ v[..., None])[..., 0]
    z = w[..., 2:]
    return np.where(np.abs(z) > np.finfo(np.float64).eps, w[..., :2] / np.where(z == 0, 1.0, z), 0.0)


def tag_maps(
    corners: np.ndarray,
    unit_more: list[np.ndarray] | None = None,
    more: list[np.ndarray] | None = None,
    side_px: np.ndarray | None = None,
    side_of: np.ndarray | None = None,
    side_ok: np.ndarray | None = None,
    lens: EquidistantLens | None = None,
    homographies: np.ndarray | None = None,
) -> TagMap:
    """The maps from T tags' unit squares to the image: the homography of each tag's four corners
    (``corners`` (T, 4, 2); with ``lens``, of their rays, so that the lens bends the square as it
    bends the tag), bent by a quadratic where more is known of how the fisheye bends the
    tag: lattice corners around it (``more[t]`` (n_t, 2) pixels at unit coordinates
    ``unit_more[t]`` (n_t, 2)), and points found on its sides (``side_px`` (T, m, 2) pixels on the
    sides ``side_of`` (T, m) of :data:`SIDES`, where ``side_ok`` (T, m) says they were found; see
    :func:`sides_seen`; such a point fixes only the coordinate across its side). Each coordinate's
    quadratic is fitted where it has at least 6 constraints besides the corners, by weighted least
    squares (the corners stay where they are, weight 10) with a little ridge: on two opposite
    sides alone, u and u^2 (or v and v^2) are one column. ``homographies`` (T, 3, 3): the corners'
    homographies where a map of these corners has them already (:attr:`TagMap.H`)."""
    corners = np.asarray(corners, np.float64)
    T = len(corners)
    unit = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    if homographies is not None:
        H, good = np.array(homographies, np.float64), np.ones(T, bool)  # NaN where the corners gave none
    elif lens is None:
        H = np.stack([cv2.getPerspectiveTransform(unit, c.astype(np.float32)) for c in corners]) if T else np.zeros((0, 3, 3))
        good = np.ones(T, bool)
    else:
        H, good = ray_homographies(lens.lift(corners))
        H[~good] = np.nan  # four rays no square of a plane gives: the tag's samples are NaN, it is not read
    finite = np.isfinite(H).all((1, 2))
    det = np.linalg.det(np.where(finite[:, None, None], H, np.eye(3)))
    good &= finite & (np.abs(det) >= 1e-12)  # elsewhere a degenerate quad: nothing to bend
    Hi = np.zeros_like(H)
    Hi[good] = np.linalg.inv(H[good])
    n_more = [0 if more is None or more[t] is None else len(more[t]) for t in range(T)]
    m = 0 if side_px is None else side_px.shape[1]
    rows = 4 + max(n_more, default=0) + m
    U = np.zeros((2, T, rows, 2))  # per coordinate k: unit points, offsets, weights
    R = np.zeros((2, T, rows))
    Wt = np.zeros((2, T, rows))
    U[:, :, :4] = unit
    Wt[:, :, :4] = 10.0
    if rows > 4 + m:
        nm = rows - 4 - m
        um, pm = np.zeros((T, nm, 2)), np.zeros((T, nm, 2))
        for t, n in enumerate(n_more):
            if n:
                um[t, :n], pm[t, :n] = unit_more[t], more[t]
        there = np.arange(nm)[None] < np.array(n_more)[:, None]  # (T, nm)
        seen = _to_unit(Hi, pm, lens)
        U[:, :, 4 : 4 + nm] = um
        R[:, :, 4 : 4 + nm] = np.where(there, (seen - um).transpose(2, 0, 1), 0.0)
        Wt[:, :, 4 : 4 + nm] = there
    if m:
        seen = _to_unit(Hi, side_px, lens)
        ok = np.ones(side_px.shape[:2], bool) if side_ok is None else side_ok
        s0 = 4 + max(n_more, default=0)
        for k in range(2):
            on = (SIDES[side_of, 0] == k) & ok  # the sides on which coordinate k is fixed
            u = seen.copy()
            u[..., k] = SIDES[side_of, 1]
            U[k, :, s0:] = np.where(on[..., None], u, 0.0)  # rows not used: zero (a point not found may be NaN)
            R[k, :, s0:] = np.where(on, seen[..., k] - u[..., k], 0.0)
            Wt[k, :, s0:] = on
    A = _quadratic(U)  # (2, T, rows, 6)
    Aw = A * Wt[..., None]
    M = Aw.swapaxes(-1, -2) @ Aw + 1e-6 * np.eye(6)
    coef = np.linalg.solve(M, (Aw.swapaxes(-1, -2) @ (R * Wt)[..., None]))[..., 0]  # (2, T, 6)
    fit = ((Wt[:, :, 4:] > 0).sum(-1) >= 6) & good  # (2, T)
    coef = np.where(fit[..., None], coef, 0.0)
    misfit = np.zeros(T)
    if m:
        res = np.abs((A[:, :, s0:] @ coef[..., None])[..., 0] - R[:, :, s0:])  # (2, T, m)
        res = np.where((Wt[:, :, s0:] > 0) & fit[..., None], res, 0.0)
        misfit = res.max(axis=(0, 2))
    return TagMap(H, coef.transpose(1, 2, 0), misfit, lens)


def tag_map(
    corners: np.ndarray,
    unit_more: np.ndarray | None = None,
    more: np.ndarray | None = None,
    side_px: np.ndarray | None = None,
    side_of: np.ndarray | None = None,
) -> TagMap:
    """:func:`tag_maps` of one tag (``corners`` (4, 2); ``side_px`` (m, 2) on sides ``side_of`` (m,))."""
    sides = {} if side_px is None or not len(side_px) else {"side_px": np.asarray(side_px)[None], "side_of": np.asarray(side_of)[None]}
    return tag_maps(np.asarray(corners)[None], None if more is None else [unit_more], None if more is None else [more], **sides)


# A tag's sides in its unit square: (the coordinate fixed on it, its value), in the order
# v = 0 (a), u = 1, v = 1, u = 0; the unit normal into the tag follows.
SIDES = np.array([[1, 0.0], [0, 1.0], [1, 1.0], [0, 0.0]])
_SIDE_INWARD = np.array([[0.0, 1.0], [-1.0, 0.0], [0.0, -1.0], [1.0, 0.0]])


@functools.lru_cache(maxsize=4)
def _side_samples(spacing: float, n: int) -> np.ndarray:
    """(4, n, 15, 2) unit-square samples of :func:`sides_seen`: on each side of :data:`SIDES`, at
    ``n`` points between its corners, from the gap's middle outside to 1.8 border cells in."""
    t = (np.arange(n) + 1) / (n + 1)
    s = np.linspace(-spacing / 2, 1.8 / CELLS, 15)
    base = np.empty((4, n, 2))
    for k, (fixed, value) in enumerate(SIDES):
        base[k, :, int(fixed)] = value
        base[k, :, 1 - int(fixed)] = t
    return base[:, :, None, :] + s[None, None, :, None] * _SIDE_INWARD[:, None, None, :]


def sides_seen(
    img: np.ndarray, to_image: TagMap, spacing: float, dark: np.ndarray, light: np.ndarray, n: int = 5
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where T tags' sides are: on each side, at ``n`` points between its corners, the crossing of
    ``(dark + light) / 2`` ((T,) each) from the white gap into the black border, searched along the
    side's normal from the gap's middle to 1.8 border cells in (``to_image``: the tags' current
    maps, :func:`tag_maps`). Returns pixels (T, 4 n, 2), their sides (4 n,) (of :data:`SIDES`) and
    whether each was found (T, 4 n): sides cut by an occluder or blur give fewer points."""
    unit = _side_samples(float(spacing), n)  # (4, n, S, 2)
    S = unit.shape[2]
    T = len(to_image.H)
    px = to_image(unit.reshape(-1, 2)).reshape(T, 4 * n, S, 2)
    vals = values_at(img, px)
    mid = ((np.asarray(dark, np.float64) + np.asarray(light, np.float64)) / 2).astype(vals.dtype)[:, None, None]
    below = vals < mid
    # One crossing only, white gap outside, black border inside (sides cut by an occluder or blur fail).
    ok = np.isfinite(vals).all(-1) & ~below[..., 0] & below[..., -3:].all(-1) & ((below[..., 1:] != below[..., :-1]).sum(-1) == 1)
    j = np.maximum(below.argmax(-1), 1)[..., None]  # the first sample below the midpoint
    v0, v1 = np.take_along_axis(vals, j - 1, -1)[..., 0], np.take_along_axis(vals, j, -1)[..., 0]
    f = ((v0 - mid[..., 0]) / np.maximum(v0 - v1, vals.dtype.type(1e-9)))[..., None]
    p0, p1 = np.take_along_axis(px, j[..., None] - 1, -2)[..., 0, :], np.take_along_axis(px, j[..., None], -2)[..., 0, :]
    return p0 + f * (p1 - p0), np.arange(4 * n) // n, ok


def side_points(img: np.ndarray, to_image: TagMap, spacing: float, dark: float, light: float, n: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sides_seen` of one tag: the points found (m, 2) and their sides (m,)."""
    px, side, ok = sides_seen(img, to_image, spacing, np.array([dark]), np.array([light]), n)
    return px[0][ok[0]], side[ok[0]]


def look_at_tags(
    img: np.ndarray,
    corners: np.ndarray,
    spacing: float,
    unit_more: list[np.ndarray] | None = None,
    more: list[np.ndarray] | None = None,
    *,
    sharpen: float,
    max_side_misfit: float | None = None,
    lens: EquidistantLens | None = None,
) -> list[TagLook | None]:
    """Read the T tags whose corners, lattice (0, 0), (1, 0), (1, 1), (0, 1), are ``corners``
    (T, 4, 2) from ``img`` (H, W; unblurred: cells of small tags are 1-2 px) through each tag's own
    geometry (:func:`tag_maps`, with the lattice corners around it where given; never one
    homography per board: the fisheye bends the board); with ``max_side_misfit``, a tag's map is
    bent further to its sides found in the image (:func:`sides_seen`) where they fit it within
    that many tag widths (else a corner slid and the sides would hide it); None for a tag whose
    samples fall outside the image. The 10 x 10 cells are sharpened (a 4-neighbour Laplacian of
    weight ``sharpen``: blur darkens a white cell among black ones), the data cells standardised
    and split by Otsu's threshold, so a grey print, a dim corner or a blurred small tag reads as
    well as a clean one. All tags are read at once (the arithmetic is batched)."""
    corners = np.asarray(corners, np.float64)
    T = len(corners)
    if T == 0:
        return []
    data, bord, gaps = _unit_points(float(spacing))
    u = np.concatenate([data, bord, gaps])
    n = len(data)
    to_image = tag_maps(corners, unit_more, more, lens=lens)
    vals = values_at(img, to_image(u))  # (T, 400)
    seen = np.isfinite(vals).all(1)
    if max_side_misfit is not None:
        bl, wh = _row_medians(vals[:, n : n + 64]), _row_medians(vals[:, n + 64 :])
        try_ = seen & (wh - bl > 0)
        if try_.any():
            # The sides as the image shows them bend the map further (a fisheye bends a tag's sides).
            idx = np.nonzero(try_)[0]
            sub = to_image.take(idx)
            side_px, side_of, side_ok = sides_seen(img, sub, spacing, bl[idx], wh[idx])
            bent = tag_maps(
                corners[idx],
                None if unit_more is None else [unit_more[t] for t in idx],
                None if more is None else [more[t] for t in idx],
                side_px,
                np.broadcast_to(side_of, side_ok.shape),
                side_ok,
                lens,
                sub.H,
            )
            use = bent.misfit <= max_side_misfit  # else the corners and the sides disagree: a corner slid
            if use.any():
                again = values_at(img, bent.take(use)(u))
                vals[idx[use]] = again
                seen[idx[use]] = np.isfinite(again).all(1)
    out: list[TagLook | None] = [None] * T
    ok = np.nonzero(seen)[0]
    if not len(ok):
        return out
    v = vals[ok]  # the samples' own type (float32): means, medians and the level compared in it
    d, bv, gv = v[:, :n].reshape(len(ok), 36, -1).mean(-1), v[:, n : n + 64], v[:, n + 64 :]
    bl, wh = _row_medians(bv).astype(np.float64), _row_medians(gv).astype(np.float64)
    mid = ((bl + wh) / 2).astype(v.dtype)[:, None]
    # Clean: the inner ring of the border (a cell and a half in from the sides) and the gaps; the
    # outer ring lies within half a cell of the sides, which the fisheye bends at the rim.
    clean = np.concatenate([bv[:, _inner_ring()] < mid, gv > mid], 1).mean(1)
    # Undo some of the blur: a white data cell among black ones reads darker than one among white
    # ones (cells of small tags are 1-2 px). Sharpen the 10 x 10 cells (border cells from their
    # centres) with a 4-neighbour Laplacian.
    grid = np.empty((len(ok), CELLS, CELLS))
    inner = slice(BORDER_BITS, CELLS - BORDER_BITS)
    grid[:, _border_mask()] = bv
    grid[:, inner, inner] = d.reshape(-1, DATA_BITS, DATA_BITS)  # [q, p]
    lap = grid[:, :-2, 1:-1] + grid[:, 2:, 1:-1] + grid[:, 1:-1, :-2] + grid[:, 1:-1, 2:] - 4 * grid[:, 1:-1, 1:-1]
    sharp = (grid[:, 1:-1, 1:-1] - sharpen * lap / 4)[:, 1:-1, 1:-1].reshape(len(ok), -1)
    centred = sharp - sharp.mean(1, keepdims=True)
    rms = np.maximum(np.sqrt((centred**2).mean(1, keepdims=True)), 1e-9)
    soft = centred / rms
    thr = otsu_splits(soft)
    white = soft > thr[:, None]
    n_white = white.sum(1)
    mean_w = (sharp * white).sum(1) / np.maximum(n_white, 1)
    mean_b = (sharp * ~white).sum(1) / np.maximum(36 - n_white, 1)
    spread = np.where((n_white > 0) & (n_white < 36), mean_w - mean_b, 0.0)
    for r, t in enumerate(ok.tolist()):
        c = float(wh[r] - bl[r])
        out[t] = TagLook(soft[r], float(thr[r]), c, float(spread[r]) / max(c, 1e-6), float(clean[r]))
    return out


def _row_medians(x: np.ndarray) -> np.ndarray:
    """The median of each row of x (T, n), in x's type, as ``np.median(x, 1)`` gives it for rows
    without NaN (the mean of the two middle values where n is even) at a fraction of its cost: it
    runs for every tag looked at, often one at a time. A row with NaN gets a number, not NaN."""
    s = np.sort(x, 1)
    n = s.shape[1]
    return s[:, n // 2] if n % 2 else (s[:, n // 2 - 1] + s[:, n // 2]) / x.dtype.type(2)


def look_at_tag(
    img: np.ndarray,
    corners: np.ndarray,
    spacing: float,
    unit_more: np.ndarray | None = None,
    more: np.ndarray | None = None,
    *,
    sharpen: float,
    max_side_misfit: float | None = None,
    lens: EquidistantLens | None = None,
) -> TagLook | None:
    """:func:`look_at_tags` of one tag (``corners`` (4, 2), ``unit_more`` and ``more`` (n, 2))."""
    ring = {} if more is None else {"unit_more": [unit_more], "more": [more]}
    return look_at_tags(img, np.asarray(corners)[None], spacing, **ring, sharpen=sharpen, max_side_misfit=max_side_misfit, lens=lens)[0]


@functools.lru_cache(maxsize=1)
def _border_mask() -> np.ndarray:
    """(10, 10) bool: the border cells, in the order of :func:`_unit_points`'s border samples."""
    idx = np.arange(CELLS)
    inner = (idx >= BORDER_BITS) & (idx < CELLS - BORDER_BITS)
    return ~(inner[:, None] & inner[None, :])


@functools.lru_cache(maxsize=1)
def _inner_ring() -> np.ndarray:
    """(64,) bool over the border samples of :func:`_unit_points`: those of the border's inner ring."""
    idx = np.arange(CELLS)
    ring = (idx >= 1) & (idx < CELLS - 1)
    inner_ring = ring[:, None] & ring[None, :] & _border_mask()
    return inner_ring[_border_mask()]


def otsu_splits(x: np.ndarray) -> np.ndarray:
    """The threshold that splits each row of values x (T, n) into two classes of least summed
    variance (Otsu): the midpoint between the two values it falls between. -> (T,)"""
    s = np.sort(x, 1)
    n = s.shape[1]
    k = np.arange(1, n)
    c1 = np.cumsum(s, 1)[:, :-1]
    c2 = np.cumsum(s**2, 1)[:, :-1]
    t1, t2 = s.sum(1, keepdims=True), (s**2).sum(1, keepdims=True)
    within = (c2 - c1**2 / k) + ((t2 - c2) - (t1 - c1) ** 2 / (n - k))
    i = np.argmin(within, 1)[:, None]
    return ((np.take_along_axis(s, i, 1) + np.take_along_axis(s, i + 1, 1)) / 2)[:, 0]


def otsu_split(x: np.ndarray) -> float:
    """:func:`otsu_splits` of one set of values x (n,)."""
    return float(otsu_splits(np.asarray(x)[None])[0])


def decode_many(white: np.ndarray) -> list[tuple[int, int, int]]:
    """The tag36h11 code nearest to each row of lattice-order data cells (T, 36) bool (True:
    white) over the four turns: [(id, turn index, Hamming distance)] (the first turn, then the
    lowest id, where several are as near)."""
    if not len(white):
        return []
    # Each turn's page-order bits packed into one integer: Hamming distance = popcount(xor),
    # (T, turns, codes) in integer arithmetic (a +-1 matrix product took BLAS threads: 1-60 ms
    # for a frame's few dozen tags, as busy as the machine was).
    turns = np.stack([page_order(np.asarray(white, bool), m) for m in range(len(TURNS))], 1)  # (T, turns, 36)
    dist = np.bitwise_count(_packed(turns)[:, :, None] ^ _packed(_codes() > 0)[None, None, :])
    flat = dist.reshape(len(turns), -1).argmin(1)  # turn-major: the first turn's nearest code first
    turn, tag = np.divmod(flat, dist.shape[2])
    return [(int(t), int(m), int(dist[r, m, t])) for r, (m, t) in enumerate(zip(turn.tolist(), tag.tolist()))]


def _packed(bits: np.ndarray) -> np.ndarray:
    """36 data cells (..., 36) bool (True: white) as one integer (...) uint64, cell k at bit k."""
    return (bits.astype(np.uint64) << np.arange(36, dtype=np.uint64)).sum(-1, dtype=np.uint64)


def decode_bits(white: np.ndarray) -> tuple[int, int, int]:
    """The tag36h11 code nearest to lattice-order data cells (36,) bool (True: white) over the
    four turns: (id, turn index, Hamming distance)."""
    return decode_many(np.asarray(white)[None])[0]


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
class TagCell:
    cell: tuple[int, int]  # lattice cell (a, b) of the tag (both even)
    look: TagLook
    tag: int  # nearest tag36h11 id
    turn: int  # its turn (index into TURNS)
    hamming: int  # bits that differ from it
    clean: bool  # a black border inside white gaps: only such cells place and verify the board
    side: float  # px, the tag's shortest side
    centre: tuple[float, float] = (0.0, 0.0)  # px, the mean of its four corners (one tag read in several lattices is one tag)

    @property
    def key(self) -> tuple[int, int, int]:
        """The tag as read and where (its id, its centre to the pixel): counted once however many lattices read it."""
        return (self.tag, round(self.centre[0]), round(self.centre[1]))


def read_cells(lat: Lattice, img: np.ndarray, spacing: float, cfg: TagConfig, lens: EquidistantLens | None = None) -> list[TagCell]:
    """Every tag cell of the lattice (a, b both even) with its four corners, data cells of at least
    ``cfg.min_cell_px`` and all samples in the image, read; ``clean`` says whether it looks like a
    tag (``cfg.min_bit_contrast``, ``cfg.min_clean``)."""
    where = lat.where
    pos = {-1: -spacing, 0: 0.0, 1: 1.0, 2: 1.0 + spacing}
    found: list[tuple[tuple[int, int], np.ndarray, float]] = []  # (cell, corners, shortest side)
    unit_more, more = [], []
    for a, b in where:
        if a % 2 or b % 2:
            continue
        ks = [where.get(t) for t in ((a, b), (a + 1, b), (a + 1, b + 1), (a, b + 1))]
        if None in ks:
            continue
        c = lat.xy[ks]
        side = shortest_side(c)
        if side / CELLS < cfg.min_cell_px:
            continue
        # The lattice corners around the tag (a 4 x 4 patch of the lattice without the tag's own).
        ring = [(i, j) for i in (-1, 0, 1, 2) for j in (-1, 0, 1, 2) if not (0 <= i <= 1 and 0 <= j <= 1) and (a + i, b + j) in where]
        found.append(((a, b), c, side))
        unit_more.append(np.array([(pos[i], pos[j]) for i, j in ring]).reshape(-1, 2))
        more.append(lat.xy[[where[(a + i, b + j)] for i, j in ring]].reshape(-1, 2))
    if not found:
        return []
    corners = np.stack([c for _, c, _ in found])
    looks = look_at_tags(img, corners, spacing, unit_more, more, sharpen=cfg.sharpen, max_side_misfit=cfg.max_side_misfit, lens=lens)
    read = [k for k, look in enumerate(looks) if look is not None]
    codes = decode_many(np.array([looks[k].white for k in read]).reshape(-1, 36))
    out = []
    for k, (tag, turn, ham) in zip(read, codes):
        cell, c, side = found[k]
        look = looks[k]
        ok = look.contrast >= cfg.min_bit_contrast and look.clean >= cfg.min_clean
        out.append(TagCell(cell, look, tag, turn, ham, ok, side, tuple(c.mean(0).tolist())))
    return out


# --------------------------------------------------------------------------------------------
# Placement
# --------------------------------------------------------------------------------------------
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


def steps_alternate(lat: Lattice, spacing: float, tol: float) -> np.ndarray:
    """(K,) bool: corners whose two steps along each lattice line, a tag side and a gap, have the
    target's ratio (1 / ``spacing``) within a factor ``tol`` (perspective changes it little over
    one tag). A corner slid along a tag's side breaks it. (Scalar arithmetic: it runs per corner.)"""
    where = lat.where
    pts = lat.xy.tolist()
    ok = np.ones(len(lat.ab), bool)
    for (a, b), k in where.items():
        x, y = pts[k]
        for da, db in ((1, 0), (0, 1)):
            m1, m2 = where.get((a + da, b + db)), where.get((a - da, b - db))
            if m1 is None or m2 is None:
                continue
            d1 = math.hypot(pts[m1][0] - x, pts[m1][1] - y)
            d2 = math.hypot(pts[m2][0] - x, pts[m2][1] - y)
            long_side, gap = (d1, d2) if is_long(a if da else b, 1) else (d2, d1)
            r = long_side * spacing / max(gap, 1e-9)
            if not 1 / tol <= r <= tol:
                ok[k] = False
    return ok


def near_rim(lat: Lattice, rim_dist: np.ndarray, px: float) -> np.ndarray:
    """(K,) bool: lattice corners within ``px`` of the image circle's rim or the image border."""
    H, W = rim_dist.shape
    q = np.clip(np.rint(lat.xy).astype(int), 0, [W - 1, H - 1])
    return rim_dist[q[:, 1], q[:, 0]] < px


def cells_close(lat: Lattice, tol: float, strict: np.ndarray | None = None) -> np.ndarray:
    """(K,) bool: corners that close at least one lattice cell they belong to as a parallelogram
    of its other three corners would, within ``tol`` of the cell's longer side (over one cell the
    fisheye's bend is small); a corner in no complete cell needs a neighbour along each lattice
    axis, or, where ``strict`` (K,) says so (next to the image circle's rim, where the cut print
    makes false junctions), is dropped. A corner slid along a side fails. (Scalar arithmetic: it
    runs per corner and cell.)"""
    where = lat.where
    pts = lat.xy.tolist()
    ok = np.ones(len(lat.ab), bool)
    for (a, b), k in where.items():
        x, y = pts[k]
        best = math.inf
        for da in (-1, 1):
            ka = where.get((a + da, b))
            if ka is None:
                continue
            xa, ya = pts[ka]
            for db in (-1, 1):
                kb, kab = where.get((a, b + db)), where.get((a + da, b + db))
                if kb is None or kab is None:
                    continue
                (xb, yb), (xc, yc) = pts[kb], pts[kab]
                side = max(math.hypot(xa - x, ya - y), math.hypot(xb - x, yb - y))
                best = min(best, math.hypot(xa + xb - xc - x, ya + yb - yc - y) / max(side, 1e-9))
        if best < math.inf:
            ok[k] = best <= tol
        elif strict is not None and strict[k]:
            ok[k] = False
        else:  # in no complete cell: it needs a neighbour along each axis
            ok[k] = any((a + d, b) in where for d in (-1, 1)) and any((a, b + d) in where for d in (-1, 1))
    return ok


def rays_agree(lat: Lattice, img: np.ndarray, spacing: float, cfg: TagConfig) -> np.ndarray:
    """(K,) bool: lattice corners whose steps to their lattice neighbours each leave along one of
    the corner's own edge rays (:func:`corner_rays` on ``img`` (H, W)), within
    ``cfg.max_ray_angle``. The rays are read at ``cfg.ray_radius`` of the local gap: the shortest of
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
    rays = corner_rays(img, lat.xy, cfg.ray_radius * np.where(np.isfinite(gap), gap, 0.0))
    cos = np.einsum("knd,krd->knr", steps / np.where(np.isnan(dist), 1.0, dist)[..., None], rays)
    best = np.where(np.isnan(cos), -2.0, cos).max(axis=2)  # (K, 4): the nearest ray of each step
    # In the gaps of small tags the circle is at its smallest (1.5 px) and its rays' angles are
    # coarse, while data cells under 1.2 px make no junctions to mistake for corners: a looser angle
    # there (on three sets, FoV recall +0.004 each, no new wrong corner; 40 and 90 deg, or gaps up
    # to 4 px, brought wrong ones).
    shortest = np.where(np.isnan(dist), np.inf, dist).min(axis=1)  # the corner's own shortest step: its gap where it has one
    angle = np.where(shortest < cfg.small_gap_px, cfg.max_ray_angle_small, cfg.max_ray_angle)
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
    placement puts under it (correlation ``cfg.min_tag_corr``; for tags under ``cfg.small_tag_px``,
    whose cells blur, ``cfg.min_tag_corr_local`` where it beats the codes a slip by one tag would
    put there by ``cfg.min_slip_margin``); its corners are dropped otherwise (a lattice that
    slipped by a row there). A tag that could not be read (too small, cut by the rim) keeps its
    corners if a tag beside it (sharing a side, not a corner) matched surely
    (``cfg.min_lend_corr``; under ``cfg.small_tag_px`` also by ``cfg.min_tag_corr_local`` where it
    beats a slip by ``cfg.min_lend_slip_margin``), or an unread tag beside one that has, up to
    ``cfg.lend_depth`` tags from the one read (a region of tags too small to read, never across a
    tag that was read and did not match): its ids come through the lattice. So does an
    unread tag's corner next to a corner kept so, within ``cfg.fringe_steps`` lattice steps of a
    corner of a tag matched by ``cfg.min_lend_corr`` (the fringe of a lattice at the rim, where
    no tag beside it is complete)."""
    good, sure, firm, read = set(), set(), set(), set()
    for c, t in zip(cells, under):
        corr = float(tag_corr(c.look.soft, turn, np.array([t]))[0]) if t >= 0 else -1.0
        blurred = c.side < cfg.small_tag_px  # cells of 2 px or less: blur, not a misprint, lowers the correlation
        slip_margin = corr - slipped_corr(c, t, turn, board) if t >= 0 else -2.0
        local = blurred and corr >= cfg.min_tag_corr_local and slip_margin >= cfg.min_slip_margin
        if c.clean and (corr >= cfg.min_tag_corr or local):
            good.add(c.cell)
        read.add(c.cell)
        lends_small = blurred and corr >= cfg.min_tag_corr_local and slip_margin >= cfg.min_lend_slip_margin
        if c.clean and (corr >= cfg.min_lend_corr or lends_small):
            sure.add(c.cell)
        if c.clean and corr >= cfg.min_lend_corr:
            firm.add(c.cell)
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
    if cfg.fringe_steps > 0:
        where = lat.where
        first = keep.copy()
        for k, (a, b) in enumerate(lat.ab.tolist()):
            if first[k] or cell_of[k] in read:
                continue
            if not any(first[where[(a + i, b + j)]] for i, j in STEPS if (a + i, b + j) in where):
                continue
            keep[k] = any(
                ((a + i) - (a + i) % 2, (b + j) - (b + j) % 2) in firm
                for i in range(-cfg.fringe_steps, cfg.fringe_steps + 1)
                for j in range(-cfg.fringe_steps, cfg.fringe_steps + 1)
                if abs(i) + abs(j) <= cfg.fringe_steps and (a + i, b + j) in where
            )
    return keep


# --------------------------------------------------------------------------------------------
# The pass
# --------------------------------------------------------------------------------------------
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


# The lowest confidence a corner put back after print_moved gets (its own print's correlation,
# clipped: a confidence of 0 reads as unknown, weight 1, in a sequence's detections).
MIN_PUT_BACK_CONFIDENCE = 0.05

# The tag pass works on the image circle's bounding box grown by this (px): samples up to this far beyond the
# rim read the black frame as on the whole image (farther ones read NaN; the rays, tag reads and fits reach less far).
CIRCLE_PAD_PX = 48


def tag_pass(grey: np.ndarray, board: AprilGrid, cfg: TagConfig | None = None) -> TagResult:
    """AprilGrid corners with Kalibr's ids in the (H, W) float32 image ``grey`` in [0, 1].

    The work happens on the bounding box of the fisheye's image circle, grown by
    :data:`CIRCLE_PAD_PX` of the black frame beyond it (a circle 720 px across in a 1280 px wide
    frame: 64 % of the pixels to filter); a frame without a black border is read whole.

    A frame whose shorter side is under ``cfg.min_side_px`` is read enlarged to it (bilinear, by at
    most ``cfg.max_enlarge``): the pass's smallest fit windows, sampling circles and crossing
    tests are fixed in pixels, and tags of 8-12 px in a 640x480 frame resolve only enlarged; the
    thresholds that judge a tag's size in pixels (``small_tag_px``, ``small_gap_px``,
    ``keep_unfitted_px``, ``rim_strict_px``) scale with the factor, so the identity rules see
    the tags as they are, as does completion's ``moved_px`` (a distance in the frame's pixels).
    Positions are given in the frame's pixels either way.

    A frame not enlarged where fewer than ``cfg.half_below`` corners are found is read again at
    half resolution (blurred tags, large tags), and the corners only that finds are added where the print check keeps them
    (:func:`cotrain.detect.tag_completion.print_check`) and their neighbours put them
    (:func:`cotrain.detect.tag_completion.print_moved`); not where completion found every corner
    it predicted in view (``TagResult.unfound`` 0: a partial view found whole).

    A frame where nothing is found is read once more at full resolution with seeds whose
    neighbours lie within ``cfg.retry_seed_angle`` of their edge rays, and where that finds
    nothing, once more with seeds of tags whose data cells are ``cfg.retry_min_cell_px`` wide
    (instead of ``cfg.min_cell_px``); where that finds nothing too, the frame with its contrast
    raised ``cfg.retry_gain`` times about its local mean (:func:`cotrain.detect.images.local_gain`;
    a grey print, a board in the shade) is read as the first look reads a frame, at half
    resolution too. The corners of the first look that finds any are reported."""
    cfg = cfg or TagConfig()
    view = _view_of(grey, cfg)
    r = _tag_pass_both(grey, board, cfg, view)
    if len(r.ids) or cfg.retry_seed_angle <= 0:
        return r
    # Nothing found: once more with a wider cone for the ray neighbours. Where tags are small the
    # edge rays are read on circles of a few pixels, their angles coarse, and the neighbours fall
    # outside the cone: the lattices stop after a tag or two and no placement holds. Widened in
    # every frame, the cone changes which seeds grow first elsewhere and lost whole frames
    # (docs/detector.md, tag pass step 12). Full resolution only: the tags it is for are small,
    # and the half-resolution reading has had its look. The frame as the first look read it (the
    # crop, the lens, the candidates and their rays) is the same.
    wider = replace(cfg, seed_axis_angle=cfg.retry_seed_angle)
    looks = [wider]
    if cfg.retry_min_cell_px < cfg.min_cell_px:
        # Then with seeds, and tags read, whose data cells are smaller than a pixel (a board of
        # 8-10 px tags seen whole offers no other seed), in the wider cone still. Only here: where larger tags show, a quad of a large
        # tag's data junctions that small can seed first and cover the board's corners.
        looks.append(replace(wider, min_cell_px=cfg.retry_min_cell_px))
    for look in looks:
        again = _tag_pass_circle(grey, board, look, view)
        if len(again.ids):
            return again
    if cfg.retry_gain > 1:
        # A print whose white is grey, in the shade or dim light: its saddles' responses and
        # contrasts fall under the pass's thresholds (set in intensity), and no seed holds. Its
        # contrast raised about the local mean, the frame is read anew. Only here: raised in every
        # frame, the clean independent renderer's frames lost corners (0.994 -> 0.991), and a
        # gain of 2 placed one wrongly.
        gained = local_gain(grey, cfg.retry_gain, cfg.retry_gain_sigma * min(grey.shape))
        again = _tag_pass_both(gained, board, cfg)  # at half resolution too: there most of these boards are found
        if len(again.ids):
            return again
    return r


def _tag_pass_both(grey: np.ndarray, board: AprilGrid, cfg: TagConfig, view: _View | None = None) -> TagResult:
    """:func:`tag_pass` without its second look: at full resolution (``view``: the frame as read
    for it, :func:`_view_of`, else read here), then at half resolution where few corners were found."""
    view = view or _view_of(grey, cfg)
    r = _tag_pass_circle(grey, board, cfg, view)
    if len(r.ids) >= cfg.half_below or r.scale > 1 or min(grey.shape) // 2 < MIN_SIDE:
        return r
    if r.unfound == 0:
        return r  # every corner the board predicts inside the image circle is found: nothing to look for
    # Blurred and large tags (cotrain.detect.half_resolution): corners found only at half
    # resolution, fitted again and checked against the print; their tags are added to the
    # decoded ones where a corner of theirs is kept.
    r2 = _tag_pass_circle(halve(grey), board, replace(cfg, min_side_px=0))
    lens = view.frame_lens() if cfg.complete.lens else None
    found = corners_at_half_resolution(grey, r.ids, r.xy, r2.ids, r2.xy, board, cfg.grid, cfg.complete, lens=lens)
    if found is None or not len(found[0]):
        return r
    sel, q = found
    ids = np.concatenate([r.ids, r2.ids[sel]])
    order = np.argsort(ids)
    more = ~np.isin(r2.tags, r.tags) & np.array([np.isin(board.tag_corners(t), r2.ids[sel]).any() for t in r2.tags.tolist()], bool)
    return replace(
        r,
        ids=ids[order],
        xy=np.concatenate([r.xy, q])[order],
        confidence=np.concatenate([r.confidence, r2.confidence[sel]])[order],
        tags=np.concatenate([r.tags, r2.tags[more]]),
        hamming=np.concatenate([r.hamming, r2.hamming[more]]),
        # Counts of tags the two passes mostly both saw: the larger of the two.
        dropped_tags=max(r.dropped_tags, r2.dropped_tags),
        foreign_tags=max(r.foreign_tags, r2.foreign_tags),
    )


class _Candidates(NamedTuple):
    """What a pass reads off its image before the seeds (:func:`_candidates_of`)."""

    rim_dist: np.ndarray  # (H, W) px to the image circle's rim
    smoothed: dict[int, np.ndarray]  # the image's blurs (saddle.smooth_cached)
    xy: np.ndarray  # (K, 2) fitted saddle points, strongest first (tag_candidates)
    tree: cKDTree | None  # of xy; None where there are fewer than cfg.min_corners
    rays: np.ndarray | None  # (K, 4, 2) their edge rays (lattice.corner_rays)


class _View(NamedTuple):
    """A frame as one pass reads it (:func:`_view_of`)."""

    scale: float  # the factor the frame was enlarged by (enlargement)
    origin: tuple[int, int]  # (x0, y0): the crop's top-left corner in the (enlarged) frame
    grey: np.ndarray  # (H, W) the crop: the image circle's bounding box grown by CIRCLE_PAD_PX
    allowed: np.ndarray  # (H, W) bool: inside the image circle
    lens: EquidistantLens | None  # the lens guessed from the image circle (in the crop's pixels)
    candidates: _Candidates

    def frame_lens(self) -> EquidistantLens | None:
        """:attr:`lens` in the frame's own pixels (before the enlargement and the crop)."""
        if self.lens is None:
            return None
        f, (x0, y0) = self.scale, self.origin
        c = ((self.lens.centre[0] + x0 + 0.5) / f - 0.5, (self.lens.centre[1] + y0 + 0.5) / f - 0.5)
        return EquidistantLens(c, self.lens.focal / f)


def _view_of(grey: np.ndarray, cfg: TagConfig) -> _View:
    """The frame ``grey`` as :func:`_tag_pass_circle` reads it: a small frame enlarged, cropped to
    the image circle's bounding box, its lens guessed, its candidates found."""
    f = enlargement(grey.shape, cfg)
    if f > 1:
        grey = cv2.resize(grey, None, fx=f, fy=f, interpolation=cv2.INTER_LINEAR)
    outside = outside_circle(grey)
    allowed = ~outside
    allowed[[0, -1], :] = False
    allowed[:, [0, -1]] = False
    ys, xs = np.nonzero(allowed.any(1))[0], np.nonzero(allowed.any(0))[0]
    H, W = grey.shape
    y0, y1 = (max(0, ys[0] - CIRCLE_PAD_PX), min(H, ys[-1] + 1 + CIRCLE_PAD_PX)) if len(ys) else (0, H)
    x0, x1 = (max(0, xs[0] - CIRCLE_PAD_PX), min(W, xs[-1] + 1 + CIRCLE_PAD_PX)) if len(xs) else (0, W)
    lens = guess_lens(outside, cfg.lens_fov, (x0, y0))
    crop, inside = grey[y0:y1, x0:x1], allowed[y0:y1, x0:x1]
    return _View(f, (x0, y0), crop, inside, lens, _candidates_of(crop, inside, cfg))


def _tag_pass_circle(grey: np.ndarray, board: AprilGrid, cfg: TagConfig, view: _View | None = None) -> TagResult:
    """:func:`tag_pass` at one resolution: on the image circle's bounding box, a small frame
    enlarged (``view``: the frame as read already, :func:`_view_of`, else read here)."""
    view = view or _view_of(grey, cfg)
    f = view.scale
    if f > 1:
        cfg = replace(cfg, **{k: getattr(cfg, k) * f for k in ("small_tag_px", "small_gap_px", "keep_unfitted_px", "rim_strict_px")})
        cfg = replace(cfg, complete=replace(cfg.complete, moved_px=cfg.complete.moved_px * f))
    r = _tag_pass_in(view.grey, view.allowed, board, cfg, view.lens, view.candidates)
    xy = r.xy + np.array(view.origin, np.float64)
    if f > 1:
        xy = (xy + 0.5) / f - 0.5  # pixel centres: x' = (x + 0.5) f - 0.5
    return replace(r, xy=xy, scale=f)


def enlargement(shape: tuple[int, int], cfg: TagConfig) -> float:
    """The factor :func:`tag_pass` enlarges a frame of ``shape`` (H, W) by: 1 where its shorter side
    reaches ``cfg.min_side_px`` (or that is 0), else up to it, at most ``cfg.max_enlarge``."""
    short = min(shape)
    if cfg.min_side_px <= 0 or short >= cfg.min_side_px:
        return 1.0
    return min(cfg.min_side_px / short, cfg.max_enlarge)


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
    if len(xy) < cfg.min_corners:
        return _Candidates(rim_dist, smoothed, xy, None, None)
    tree = cKDTree(xy)
    near = tree.query(xy, k=2)[0][:, 1]
    rays = corner_rays(smooth_cached(smoothed, grey, 1), xy, cfg.ray_radius * near)
    return _Candidates(rim_dist, smoothed, xy, tree, rays)


def _tag_pass_in(
    grey: np.ndarray,
    allowed: np.ndarray,
    board: AprilGrid,
    cfg: TagConfig,
    lens: EquidistantLens | None,
    candidates: _Candidates | None = None,
) -> TagResult:
    """:func:`tag_pass` on ``grey`` (H, W) where ``allowed`` (H, W) bool is the image circle;
    tags are read through ``lens`` where one is guessed (:mod:`cotrain.detect.image_circle`);
    ``candidates``: found already (:func:`_candidates_of`), else found here."""

    def empty(foreign: int = 0) -> TagResult:
        return TagResult(np.zeros(0, int), np.zeros((0, 2)), np.zeros(0), np.zeros(0, int), np.zeros(0, int), 0, foreign)

    rim_dist, smoothed, xy, tree, rays = candidates or _candidates_of(grey, allowed, cfg)
    if tree is None:
        return empty()
    sm = smooth_cached(smoothed, grey, 1)
    nbr = axis_neighbours(xy, rays, tree, sm, cfg)
    spacing = board.cfg.tag_spacing
    rays_xyz = None if lens is None else lens.lift(xy)  # the candidates' unit rays (K, 3), for the seeds
    covered = np.zeros(len(xy), bool)
    grown: list[Lattice] = []
    # Seeds whose tag decodes alone grow first; the others (small or blurred tags, and quads of
    # junctions that only look like a tag: across two large bent tags) once those have covered
    # what they reach, so that such a quad does not cover the corners of the tags it cuts.
    later: list[tuple[int, np.ndarray, list[int]]] = []
    for seed in range(len(xy)):
        if len(grown) >= cfg.max_seeds:
            break
        if covered[seed]:
            continue
        found_seed = seed_tag(xy, nbr, seed, grey, spacing, cfg, tree, lens, rays_xyz)
        if found_seed is None:
            continue
        frame, tag_corners, decodes = found_seed
        if not decodes:
            later.append((seed, frame, tag_corners))
            continue
        grown.append(grow_tag_lattice(xy, nbr, seed, frame, grey, cfg, smoothed, rim_dist, tree, tag_corners))
        covered |= cKDTree(grown[-1].xy).query(xy)[0] < cfg.grid.merge_radius_px
        covered |= inside_cells(grown[-1], xy, grey.shape)  # a grown tag's own data junctions are no seeds
    for seed, frame, tag_corners in later:
        if len(grown) >= cfg.max_seeds:
            break
        if covered[seed]:
            continue
        grown.append(grow_tag_lattice(xy, nbr, seed, frame, grey, cfg, smoothed, rim_dist, tree, tag_corners))
        covered |= cKDTree(grown[-1].xy).query(xy)[0] < cfg.grid.merge_radius_px
        covered |= inside_cells(grown[-1], xy, grey.shape)
    found: list[_Board] = []
    foreign: set[tuple[int, int, int]] = set()
    joined = [L for L in join_lattices(grown, cfg.grid.merge_radius_px) if not any(L is G for G in grown)]
    for lat in grown + joined:
        if len(lat.ab) < cfg.min_corners:
            continue
        cells = read_cells(lat, grey, spacing, cfg, lens)
        foreign |= {c.key for c in cells if c.clean and c.tag >= board.n_tags and c.hamming <= cfg.max_hamming}
        place = place_board(cells, board)
        if place is None or place.margin < cfg.min_margin or place.score < cfg.min_mean_corr * 36 * place.cells:
            continue
        under = tag_under(np.array([c.cell for c in cells]), place.turn, place.offset, board)
        alone = [(c, t) for c, t in zip(cells, under) if c.clean and c.hamming <= cfg.max_hamming and c.tag < board.n_tags]
        decoded = [c for c, t in alone if c.tag == t and c.turn == place.turn]
        ids = board.id_of(lat.ab @ TURNS[place.turn].T + place.offset)
        ids[
            ~verified_corners(lat, cells, under, place.turn, board, cfg)
            | ~steps_alternate(lat, spacing, cfg.max_side_gap_ratio)
            | ~cells_close(lat, cfg.max_cell_misfit, near_rim(lat, rim_dist, cfg.rim_strict_px))
            | ~rays_agree(lat, sm, spacing, cfg)
        ] = -1
        found.append(_Board(lat, ids, place, decoded, [c for c, t in alone if not (c.tag == t and c.turn == place.turn)]))
    if not found:
        return empty(len(foreign))
    kept, lost = consistent_boards(found)
    reported = {c.key for f in kept for c in f.decoded}
    dropped = {c.key for f in lost for c in f.decoded} | {c.key for f in kept for c in f.disagree}
    dropped -= reported
    ids, xy_out, conf, tags, ham = [], [], [], [], []
    seen: set[int] = set()
    for f in kept:
        on = f.ids >= 0
        # Final positions; a corner whose small-window fit fails is not an X-junction (a tag's data
        # cell against its border makes a T) and is dropped.
        sub = Lattice(f.lat.xy[on], f.lat.ab[on], f.lat.filled[on])
        xy_fit, fitted = final_fits(sub, grey, cfg.grid, smoothed, rim_dist)
        # Except in the gaps of small tags: the smallest window (5 px) reaches across a crossing
        # square under 6 px into the gaps beyond, and its failure says nothing there (evaluation
        # set: FoV rows' recall +0.004 this way, and no wrong corner; up to 8 px the same, 10 px
        # brought two wrong ones).
        fitted |= shortest_steps(sub) < cfg.keep_unfitted_px
        on = np.nonzero(on)[0][fitted]
        lat = Lattice(xy_fit[fitted], f.lat.ab[on], f.lat.filled[on])
        read = set()
        for c in f.decoded:
            read |= set(board.tag_corners(c.tag).tolist())
        for i, p in zip(f.ids[on].tolist(), lat.xy):
            if i in seen:
                continue
            seen.add(i)
            ids.append(i)
            xy_out.append(p)
            conf.append(1.0 if i in read else float(1 - np.exp(-f.place.margin / 36)))
        for c in f.decoded:
            if c.tag not in tags:
                tags.append(c.tag)
                ham.append(c.hamming)
    ids_a, xy_a, conf_a = np.array(ids, int), np.array(xy_out).reshape(-1, 2), np.array(conf)
    print_lens = lens if cfg.complete.lens else None  # the print check's and completion's maps go through it
    if cfg.complete.check:
        # A corner the print around it contradicts (a neighbour's pattern matches better) is dropped;
        # completion may find it where it is.
        ok = print_check(sm, rim_dist, board, ids_a, xy_a, cfg.complete, lens=print_lens)
        ids_a, xy_a, conf_a = ids_a[ok], xy_a[ok], conf_a[ok]
    aside = np.zeros(len(ids_a), bool)
    if cfg.complete.check and cfg.complete.rounds:
        # A corner some pixels from where its neighbours put it, where the print matches better
        # there, is set aside for completion to place; where completion does not, it is put back.
        aside = print_moved(sm, rim_dist, board, ids_a, xy_a, cfg.complete, print_lens)
    aside_ids, aside_xy, aside_conf = ids_a[aside], xy_a[aside], conf_a[aside]
    ids_a, xy_a, conf_a = ids_a[~aside], xy_a[~aside], conf_a[~aside]
    unfound = None
    if cfg.complete.rounds and len(ids_a) >= 4:
        # Corners the growth missed, predicted from the identified ones and checked against the
        # print; their confidence is that check's correlation.
        given = dict(zip(ids_a.tolist(), conf_a.tolist()))
        ids_a, xy_a, corr, missing = complete_board(grey, smoothed, rim_dist, xy, board, ids_a, xy_a, cfg.complete, cfg.grid, print_lens)
        conf_a = np.array([given.get(i, c) for i, c in zip(ids_a.tolist(), corr.tolist())])
        unfound = len(set(missing.tolist()) - set(aside_ids.tolist()))
    # (Where setting corners aside left under 4, completion did not run: unfound stays None, as
    # for any board completion does not run on, and the frame may be read at half resolution.)
    back = ~np.isin(aside_ids, ids_a)
    ids_a = np.concatenate([ids_a, aside_ids[back]])
    xy_a = np.concatenate([xy_a, aside_xy[back]])
    if back.any():
        # A corner put back is one the print placed elsewhere: its confidence (the calibrator's
        # weight) is its own print's correlation where it lies, among all the corners now found.
        put = np.arange(len(ids_a) - int(back.sum()), len(ids_a))
        corr = own_print_corr(sm, rim_dist, board, ids_a, xy_a, put, cfg.complete, print_lens)
        aside_conf = aside_conf.copy()
        aside_conf[back] = np.minimum(aside_conf[back], np.clip(np.nan_to_num(corr, nan=1.0), MIN_PUT_BACK_CONFIDENCE, 1.0))
    conf_a = np.concatenate([conf_a, aside_conf[back]])
    order = np.argsort(ids_a)
    return TagResult(
        ids_a[order],
        xy_a[order],
        conf_a[order],
        np.array(tags, int),
        np.array(ham, int),
        len(dropped),
        len(foreign),
        unfound=unfound,
    )
