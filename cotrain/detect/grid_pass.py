"""Grid pass of the detector: corner identities from the board's topology, not from one pixel.

The network's per-slot heatmaps must recognise *which* of the 54 corners a blob is from global
context alone, and that is what trains slowest on a CPU budget. Its dense maps (board mask,
class-agnostic corner score, column / row classification of every pixel) train much faster.
This pass turns them into identities the way a person would (docs/detector.md has the details):

1. region and candidates (:func:`find_candidates`, :mod:`cotrain.detect.saddle`): X-junctions of
   the full-resolution image inside the network's board region, moved to the saddle of a fitted
   quadratic (which also gives the two edge directions) and kept if the window is point-symmetric;
   next to the image circle's rim or the image border, from the part of the window that is seen;
2. growth (:mod:`cotrain.detect.lattice`): from a seed, neighbours are predicted one square step
   along each grid axis (from the last two steps: perspective's cross-ratio and the fisheye's
   bend) and matched to a candidate, or, when the network missed it, to a saddle found at the
   predicted spot (in large squares, to the one the checker edge leaving the corner leads to);
   checker colours must alternate and a checker edge must run along every step; a verification
   pass drops corners off their lattice lines, and lattices grown with skipped corners; the
   result is a lattice coordinate (a, b) per corner; lattices of different seeds that share
   corners under one turn and offset are joined (:func:`join_lattices`);
3. identity (:mod:`cotrain.detect.identity`): the lattice is placed on the board by one of the
   four in-plane rotations and an integer offset; every placement is scored by the network's
   column / row log-probabilities at the corners, the checker colour of every lattice cell
   (square (i, j) of corners is black when i + j is even) and the board's white margin where the
   lattice stops, and the best one wins if it beats the runner-up by a margin (a board that looks
   the same turned, like 7 x 5 squares, is identified up to that turn: corner 0 goes nearest the
   image's top left); a lattice whose placement fails is placed again cut at each line of its
   margin evidence (:func:`cut_at_margins`: a growth that stepped across the margin onto a
   distractor); other lattices of the same board, placed surely on their own and agreeing
   with the best one where they overlap, add the corners it lacks (:func:`merge_lattices`);
4. positions (:func:`cotrain.detect.refinement.refine_positions`): the reported corners are fitted
   once more in a small window (at most 3 px half-size), close to the junction, where bent edges
   and the blooming of real prints pull least;
5. completion (docs/detector.md, grid pass step 7; :func:`cotrain.detect.completion.complete_board`, as for the AprilGrid): the
   placed board's corners the growth did not reach, predicted from the identified ones (through
   the lens guessed from the image circle, :mod:`cotrain.detect.image_circle`), found where a
   saddle matches the print around them and its edge rays follow the board's axes.

So one identity decision is made per board from all its corners, and a corner only gets an id if
it is connected to the board's lattice. Thresholds: :class:`cotrain.detect.grid_config.GridConfig`.
Pure functions over numpy arrays; pixels follow docs/conventions.md (centre of the top-left pixel at
(0, 0)); input pixels map to the network's maps through the letterbox
(:mod:`cotrain.geometry.letterbox`).
"""

from __future__ import annotations

import math
from concurrent.futures import Executor, Future
from dataclasses import dataclass, replace
from typing import NamedTuple

import cv2
import numpy as np
from scipy.spatial import cKDTree

from cotrain.detect.completion import complete_board
from cotrain.detect.grid_config import GridConfig
from cotrain.detect.half_resolution import corners_at_half_resolution
from cotrain.detect.identity import Placement, assign_ids, canonical_ids, cell_darkness, corner_votes, edge_evidence
from cotrain.detect.image_circle import beyond_circle, lens_of_circle
from cotrain.detect.lattice import STEPS, Lattice, grow_lattice, largest_component, skipped_corners, verify_lattice
from cotrain.detect.print_model import CompletionConfig
from cotrain.detect.refinement import refine_positions
from cotrain.detect.saddle import (
    contrast_scale,
    fit_saddles,
    outside_and_circle,
    pixel_index,
    saddle_candidates,
    saddle_response,
    smooth_ahead,
    smooth_cached,
    window_half,
)
from cotrain.detect.verification import neighbour_check
from cotrain.geometry.letterbox import CELLS, Letterbox
from cotrain.targets import ROTATIONS, Checkerboard


@dataclass
class GridResult:
    ids: np.ndarray  # (K,) corner ids
    xy: np.ndarray  # (K, 2) input-image pixels (saddle points)
    confidence: np.ndarray  # (K,)
    margin: float  # identity margin of the placement (nats); nan when no lattice was found


def search_region(prob: np.ndarray, box: Letterbox, cfg: GridConfig) -> np.ndarray:
    """Full-resolution (H, W) bool region of the input image from a (h, w) 1/4-processing-resolution
    probability map: cells above ``cfg.region_threshold``, grown by ``cfg.region_grow_cells``,
    mapped back through the letterbox."""
    k = 2 * cfg.region_grow_cells + 1
    m = cv2.dilate((prob > cfg.region_threshold).astype(np.uint8), np.ones((k, k), np.uint8))
    return box.cell_mask_to_input(m)


def find_candidates(
    grey: np.ndarray,
    roi: np.ndarray,
    offset: np.ndarray,
    box: Letterbox,
    corner_prob: np.ndarray,
    cfg: GridConfig,
    smoothed: dict[int, np.ndarray],
    rim_dist: np.ndarray | None = None,
    response: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Saddle points inside ``roi`` (the network's corner / board region), best seeds first.

    ``grey`` (H, W), ``roi`` (H, W), ``rim_dist`` (H, W) and ``response`` (H, W) are a crop of the
    input whose top-left pixel is input pixel ``offset`` (2,); ``corner_prob`` (h, w) is the
    network's corner score. Returns xy (K, 2) crop pixels and axes (K, 2, 2) (see
    :func:`cotrain.detect.saddle.saddle_fit`)."""
    xy0, resp = saddle_candidates(grey, roi, cfg, response=response)
    if len(xy0) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2, 2))
    # Window per candidate from the spacing to its nearest other candidate.
    d, _ = cKDTree(xy0).query(xy0, k=2)
    halves = window_half(d[:, 1])
    xy = np.zeros_like(xy0)
    ok = np.zeros(len(xy0), bool)
    axes = np.zeros((len(xy0), 2, 2))
    for h in np.unique(halves):
        m = halves == h
        xy[m], ok[m], axes[m] = fit_saddles(grey, smoothed, xy0[m], int(h), cfg, rim_dist)
    # Seeds in order of saddle response times the network's corner score there.
    score = resp * (CELLS.sample(corner_prob[None], box.to_processing(xy + offset))[:, 0])
    keep = np.nonzero(ok)[0]
    keep = keep[np.argsort(-score[keep])]
    # Merge candidates that converged onto the same saddle: the better-scored one stays.
    drop = np.zeros(len(keep), bool)
    for i, j in sorted(cKDTree(xy[keep]).query_pairs(cfg.merge_radius_px)):
        if not drop[i]:
            drop[j] = True
    keep = keep[~drop]
    return xy[keep], axes[keep]


def contrast_scaled(cfg: GridConfig, grey: np.ndarray, roi: np.ndarray) -> GridConfig:
    """``cfg`` with its contrast thresholds (saddle contrast, margin contrast)
    scaled by k = the contrast of ``grey`` (H, W) in ``roi`` (H, W bool; 5th to 95th percentile) /
    ``cfg.board_contrast`` where k < 1 (:func:`cotrain.detect.saddle.contrast_scale`), and
    ``board_contrast`` with them (the contrast they hold for); unchanged otherwise and where
    ``cfg.board_contrast`` is 0. A grey print, a board in the shade or
    behind glare has a fraction of the contrast these were set on, and its saddles and colours
    scale with it. The tests that compare shares of a corner's own contrast need no change, and
    the saddle response stays as it is: lowered, it lets in noise maxima that take the seeds'
    turns (measured: a board lost for every two gained)."""
    if cfg.board_contrast <= 0:
        return cfg
    seen = grey[::4, ::4][roi[::4, ::4]]  # every 4th pixel each way: the percentiles of a region cost 0.5 ms
    if not seen.size:
        return cfg
    lo, hi = np.percentile(seen, [5, 95])
    k = contrast_scale(float(hi - lo), cfg)
    if k >= 1:
        return cfg
    return replace(
        cfg,
        board_contrast=cfg.board_contrast * k,  # what the scaled thresholds hold for (a spot dimmer still scales them again)
        min_saddle_contrast=cfg.min_saddle_contrast * k,
        min_edge_contrast=cfg.min_edge_contrast * k,
    )


def extent_weight(lat: Lattice, rim_dist: np.ndarray, rim_px: float) -> np.ndarray:
    """The weight (K,) of each lattice corner as evidence of the board's extent (its off-board
    penalty in :func:`cotrain.detect.identity.assign_ids`): 0 for a corner nearer than ``rim_px``
    to the image circle's rim (``rim_dist`` (H, W), px), which the pass would not report, else 1."""
    x, y = pixel_index(lat.xy, rim_dist.shape[1], rim_dist.shape[0]).T
    return np.where(rim_dist[y, x] < rim_px, 0.0, 1.0)


def placement_is_sure(margin: float, geometry_margin: float, cfg: GridConfig) -> bool:
    """Whether a placement that beats the runner-up by ``margin`` nats, ``geometry_margin`` of them
    from the geometry alone (:class:`cotrain.detect.identity.Placement`), is reported: by
    ``cfg.min_margin``, or ``cfg.min_margin_backed`` where the geometry puts it
    ``cfg.min_geometry_margin`` ahead; where the geometry cannot tell it from another placement at
    all, only the network's votes could decide, and nothing is reported unless ``cfg.votes_alone``
    (then by ``cfg.min_margin``)."""
    if margin >= cfg.min_margin_backed and geometry_margin >= cfg.min_geometry_margin:
        return True
    if geometry_margin > 0:
        return margin >= cfg.min_margin
    return cfg.votes_alone and margin >= cfg.min_margin


def _joined(big: Lattice, small: Lattice, cfg: GridConfig) -> Lattice | None:
    """``big`` joined by ``small``'s corners where the two share at least ``cfg.merge_min_shared``
    corners at the same spots (within ``cfg.merge_radius_px``) and one turn and offset of small's
    lattice coordinates onto big's maps every shared corner onto its own; None where they do not,
    or where a corner of small would land on a coordinate big has at another spot."""
    d, nn = cKDTree(big.xy).query(small.xy)
    shared = np.nonzero(d < cfg.merge_radius_px)[0]
    if len(shared) < cfg.merge_min_shared:
        return None
    for R in ROTATIONS:
        o = big.ab[nn[shared[0]]] - small.ab[shared[0]] @ R.T
        if np.array_equal(small.ab[shared] @ R.T + o, big.ab[nn[shared]]):
            break
    else:
        return None
    new = np.ones(len(small.ab), bool)
    new[shared] = False
    ab_new = small.ab @ R.T + o
    if any(tuple(t) in big.where for t in ab_new[new].tolist()):
        return None
    union = {tuple(t): q for t, q in zip(big.ab.tolist(), big.xy)}
    new_idx = np.nonzero(new)[0]
    joined = new_idx[_join_outwards(union, [(tuple(ab_new[k].tolist()), small.xy[k]) for k in new_idx], cfg)]
    if not len(joined):
        return big
    xy = np.concatenate([big.xy, small.xy[joined]])
    return Lattice(xy, np.concatenate([big.ab, ab_new[joined]]), np.concatenate([big.filled, small.filled[joined]]))


def join_lattices(lattices: list[Lattice], cfg: GridConfig) -> list[Lattice]:
    """Lattices grown from different seeds that are parts of one lattice (:func:`_joined`: shared
    corners at the same spots under one turn and offset, no coordinate claimed twice) joined into
    one, largest first; the others as they are. A seed's growth stops at a missed candidate, a
    bend or blur, and another seed's growth goes on from there: joined, both halves are placed
    together, where each alone may leave the placement unsure."""
    out: list[Lattice] = []
    for lat in sorted(lattices, key=lambda x: -len(x.ab)):
        for n, big in enumerate(out):
            j = _joined(big, lat, cfg)
            if j is not None:
                out[n] = j
                break
        else:
            out.append(lat)
    return out


def _fits_the_union(ij: tuple[int, int], q: np.ndarray, union: dict[tuple[int, int], np.ndarray], cfg: GridConfig) -> bool | None:
    """Whether point q (2,) fits at coordinates ij among the corners ``union`` has placed (board
    (i, j), or lattice (a, b), -> pixels (2,)): every prediction of ij, by the line of two corners
    behind it or by the parallelogram of a cell it completes, within ``cfg.match_radius`` of the
    distance from that prediction to the nearest corner placed. That is at most a step (the
    corner behind lies a step away); where the board is seen obliquely, a cell is a thin rhombus
    and the corner one row across lies nearer. None where nothing predicts it yet."""
    i, j = ij
    ok = None
    placed = np.array(list(union.values())).reshape(-1, 2)
    for di, dj in STEPS:
        p1, p2 = union.get((i - di, j - dj)), union.get((i - 2 * di, j - 2 * dj))
        preds = []
        if p1 is not None and p2 is not None:
            preds.append(2 * p1 - p2)
        for ei, ej in ((dj, di), (-dj, -di)):  # the cell that (i - di, j - dj), ij and their neighbours across close
            p3, p4 = union.get((i + ei, j + ej)), union.get((i - di + ei, j - dj + ej))
            if p1 is not None and p3 is not None and p4 is not None:
                preds.append(p1 + p3 - p4)
        for pred in preds:
            if np.hypot(*(q - pred)) > cfg.match_radius * np.hypot(*(placed - pred).T).min():
                return False
            ok = True
    return ok


def _join_outwards(union: dict[tuple[int, int], np.ndarray], items: list[tuple[tuple[int, int], np.ndarray]], cfg: GridConfig) -> list[int]:
    """Which of ``items`` ((coordinates, pixels (2,)) each) join ``union`` (coordinates -> pixels,
    updated in place): outwards from the corners already there, each where those there by then
    predict it (:func:`_fits_the_union`); none at coordinates ``union`` already has. Returns the
    joined items' indices."""
    todo, joined = [n for n, (ij, _) in enumerate(items) if ij not in union], []
    while todo:
        later = []
        for n in todo:
            ij, q = items[n]
            fits = None if ij in union else _fits_the_union(ij, q, union, cfg)
            if fits is None and ij not in union:
                later.append(n)
            elif fits:
                union[ij] = q
                joined.append(n)
        if len(later) == len(todo):
            break
        todo = later
    return joined


def merge_lattices(
    lat: Lattice, ids: np.ndarray, others: list[tuple[float, Lattice, np.ndarray, float]], board: Checkerboard, cfg: GridConfig
) -> tuple[Lattice, np.ndarray]:
    """The best placed lattice ``lat`` with ids (K,) joined by the corners of other lattices of the
    same board. Another lattice (margin, lattice, ids, geometry margin) joins where it is placed
    surely on its own (:func:`placement_is_sure`) and shares at least ``cfg.merge_min_shared``
    corners with the same ids at the same spots (within ``cfg.merge_radius_px``; up to a turn of
    a symmetric board) and none with other ids; each of its other corners joins where its id is
    new and the corners already there
    predict it (:func:`_fits_the_union`; a lattice's wrong corner at a spot the best one refused
    does not fit). Returns the joined lattice, whose coordinates are the board's (i, j), and its
    ids (K',). Seeds stopped by an occluder, a bend or blur grow parts of one board."""
    on = ids >= 0
    xy, out_ids, filled = lat.xy[on], ids[on], lat.filled[on]
    union = {(int(v % board.nx), int(v // board.nx)): p for v, p in zip(out_ids, xy)}
    joined: list[tuple[int, np.ndarray, bool]] = []
    for margin, other, oids, geo in sorted(others, key=lambda x: -x[0]):
        if not placement_is_sure(margin, geo, cfg):
            continue
        o_on = oids >= 0
        oxy, oid0, ofilled = other.xy[o_on], oids[o_on], other.filled[o_on]
        if joined:  # the corners joined from earlier lattices count as there
            xy = np.concatenate([lat.xy[on], np.array([p for _, p, _ in joined])])
            out_ids = np.concatenate([ids[on], [k for k, _, _ in joined]]).astype(int)
        d, nn = cKDTree(xy).query(oxy)
        same_spot = d < cfg.merge_radius_px
        if same_spot.sum() < cfg.merge_min_shared:
            continue
        for perm in (None, *board.symmetries()):
            oid = oid0 if perm is None else perm[oid0]
            if np.all(out_ids[nn[same_spot]] == oid[same_spot]):
                break
        else:
            continue  # placed otherwise: not joined
        cand = np.nonzero(~same_spot)[0]
        items = [((int(oid[k] % board.nx), int(oid[k] // board.nx)), oxy[k]) for k in cand]
        joined += [(int(oid[k]), oxy[k], bool(ofilled[k])) for k in cand[_join_outwards(union, items, cfg)]]
    if not joined:
        return lat, ids
    out_ids = np.concatenate([ids[on], [k for k, _, _ in joined]]).astype(int)
    xy = np.concatenate([lat.xy[on], np.array([p for _, p, _ in joined])])
    filled = np.concatenate([filled, [f for _, _, f in joined]]).astype(bool)
    ab = np.stack([out_ids % board.nx, out_ids // board.nx], 1)
    return Lattice(xy, ab, filled), out_ids


def cut_at_margins(lat: Lattice, edges: list[tuple[int, int, int, float]], cfg: GridConfig) -> list[Lattice]:
    """The parts of ``lat`` on the board's side of each line of margin evidence ``edges`` ((k, da,
    db, e) each, :func:`cotrain.detect.identity.edge_evidence`): where corner k's outward neighbour
    is missing and the white margin follows, the board has no corner further along (da, db), so
    lattice coordinates beyond k's line (a da + b db > a_k da + b_k db) belong to something else,
    like a distractor the growth stepped onto across the margin. One part per line with
    ``cfg.cut_min_evidence`` of evidence; each the largest 4-connected piece left, with
    ``cfg.min_corners`` at least and fewer corners than ``lat``."""
    lines: dict[tuple[int, int, int], float] = {}
    for k, da, db, e in edges:
        key = (da, db, int(lat.ab[k] @ (da, db)))
        lines[key] = lines.get(key, 0.0) + e
    parts, seen = [], set()
    for (da, db, c), e in sorted(lines.items(), key=lambda x: -x[1]):
        m = lat.ab @ np.array([da, db]) <= c
        if e < cfg.cut_min_evidence or m.all():
            continue
        part = Lattice(lat.xy[m], lat.ab[m], lat.filled[m])
        keep = largest_component(part)
        key = frozenset(map(tuple, part.ab[keep].tolist()))
        if keep.sum() >= cfg.min_corners and key not in seen:
            seen.add(key)
            parts.append(Lattice(part.xy[keep], part.ab[keep], part.filled[keep]))
    return parts


def cut_adds_evidence(whole: Placement, whole_stands: bool, lat: Lattice, part: Lattice, placed: Placement) -> bool:
    """Whether ``part``, cut from ``lat`` at a line of margin evidence (:func:`cut_at_margins`) and
    placed on its own as ``placed``, says something the whole lattice's placement ``whole`` did
    not: its corners get other ids, or the same ids with the geometry behind them by more (a larger
    geometry margin), or the whole contradicted its margin evidence (``whole_stands`` False).
    Otherwise the cut took corners away from an unsure placement and nothing else changed, and a
    margin that then crosses ``min_margin`` is no evidence. Measured on seed 31 at 640x480 (a
    tuning set), fov200_022: a small board at the rim placed 24.9 nats ahead (under 25; geometry
    14.3), cut by one corner to 25.2 (geometry 14.3 again): 17 wrong ids at confidence 1, the only
    change over eight tuning sets. No threshold: two placements compared. The geometry margins are
    compared exactly (sums over other corner sets: a rounding difference counts as more), and ids
    as given (a part placed under a turn of a symmetric board counts as other ids): both err
    toward taking the part, as the cut did before the check."""
    if not whole_stands or placed.geometry_margin > whole.geometry_margin:
        return True
    rows = [lat.where[t] for t in map(tuple, part.ab.tolist())]
    return not np.array_equal(whole.ids[rows], placed.ids)


class BlackFrame(NamedTuple):
    """The frame's black border beyond the fisheye's image circle (:func:`black_frame`): read from
    the image alone, so it can be read while the network runs on the same image."""

    outside: np.ndarray  # (H, W) bool: beyond the image circle (the black frame, not the board's black squares that join it)
    circle: tuple[np.ndarray, float] | None  # the image circle (centre (2,), radius) in input pixels; None where none is


def black_frame(grey: np.ndarray) -> BlackFrame:
    """The black frame of the (H, W) float32 image ``grey`` and its image circle
    (:func:`cotrain.detect.saddle.outside_and_circle`, cut at the circle by
    :func:`cotrain.detect.image_circle.beyond_circle`)."""
    outside, circle = outside_and_circle(grey)
    return BlackFrame(beyond_circle(outside, circle), circle)


class _Crop(NamedTuple):
    """The part of the input image the grid pass works on (crop pixels + offset = input pixels)."""

    grey: np.ndarray  # (h, w) float32 crop of the input image
    roi: np.ndarray  # (h, w) bool: the network's corner / board region, inside the image circle
    allowed: np.ndarray  # (h, w) bool: inside the image circle and off the image's border
    offset: np.ndarray  # (2,) input pixel of the crop's top-left pixel
    bounds: tuple[int, int, int, int]  # x0, x1, y0, y1 of the crop in the input image
    shape: tuple[int, int]  # (H, W) of the input image
    rim_dist: np.ndarray | None  # (h, w) float32 distance to the nearest pixel not allowed, px (rim_distance; grid_pass fills it in)
    circle: tuple[np.ndarray, float] | None  # the image circle (centre, radius) in input pixels
    cfg: GridConfig  # the settings, contrast thresholds scaled to the crop (contrast_scaled)


def _crop(
    grey: np.ndarray, box: Letterbox, corner_prob: np.ndarray, mask_prob: np.ndarray, cfg: GridConfig, frame: BlackFrame | None
) -> _Crop | None:
    """Stage 1, the region: the crop around the network's corner / board region (all
    full-resolution filtering scales with its area), inside the image circle (``frame``, read
    here where None); None where the region is empty."""
    roi = search_region(np.maximum(corner_prob, mask_prob), box, cfg)
    outside, circle = frame or black_frame(grey)
    allowed = ~outside
    allowed[[0, -1], :] = False  # the image's own border is a rim too
    allowed[:, [0, -1]] = False
    roi &= allowed
    ys, xs = np.nonzero(roi.any(1))[0], np.nonzero(roi.any(0))[0]
    if not len(ys):
        return None
    pad = cfg.crop_pad_px
    y0, y1 = max(0, ys[0] - pad), min(grey.shape[0], ys[-1] + 1 + pad)
    x0, x1 = max(0, xs[0] - pad), min(grey.shape[1], xs[-1] + 1 + pad)
    grey_c, roi, allowed = grey[y0:y1, x0:x1], roi[y0:y1, x0:x1], allowed[y0:y1, x0:x1]
    offset = np.array([x0, y0], np.float64)
    cfg = contrast_scaled(cfg, grey_c, roi)
    return _Crop(grey_c, roi, allowed, offset, (x0, x1, y0, y1), outside.shape, None, circle, cfg)


def rim_distance(allowed: np.ndarray) -> np.ndarray:
    """(h, w) float32 distance (px) of each pixel of ``allowed`` (h, w) bool to the nearest one that
    is not (the image circle's rim, the image's border; OpenCV's 3 x 3 L2 distance transform)."""
    return cv2.distanceTransform(allowed.astype(np.uint8), cv2.DIST_L2, 3)


def _grow(c: _Crop, xy: np.ndarray, axes: np.ndarray, smoothed: dict, response: np.ndarray) -> list[Lattice]:
    """Stage 3, the lattices: grown from several seeds (distractors can hold the strongest
    saddles) among the candidates of the network's board region, verified; joined where ``cfg.join_lattices``
    (joined lattices are placed beside their parts, a part alone can be surer, and verified again
    with their corners' final neighbours)."""
    cfg, grey, offset, rim_dist = c.cfg, c.grey, c.offset, c.rim_dist
    crop_circle = None if c.circle is None else (c.circle[0] - offset, c.circle[1])  # the image circle in crop pixels
    covered = np.zeros(len(xy), bool)
    tried = 0
    grown: list[Lattice] = []
    for seed in range(len(xy)):
        if tried >= cfg.max_seeds:
            break
        if covered[seed]:
            continue
        tried += 1
        lat = grow_lattice(xy, axes, seed, grey, cfg, smoothed, rim_dist)
        if lat is None:
            continue
        covered |= cKDTree(lat.xy).query(xy)[0] < cfg.merge_radius_px
        if len(lat.ab) < cfg.min_corners:
            continue  # (the verification only drops corners)
        lat = verify_lattice(lat, grey, cfg, smoothed, rim_dist, crop_circle)
        if len(lat.ab) < cfg.min_corners or skipped_corners(lat, response, cfg) > cfg.max_skipped:
            continue
        grown.append(lat)
    if cfg.join_lattices:
        parts = {id(x) for x in grown}
        joined = [verify_lattice(x, grey, cfg, smoothed, rim_dist, crop_circle) for x in join_lattices(grown, cfg) if id(x) not in parts]
        grown += [x for x in joined if len(x.ab) >= cfg.min_corners and skipped_corners(x, response, cfg) <= cfg.max_skipped]
    return grown


class _Votes(NamedTuple):
    """What stage 4 places a lattice with: the network's maps and the image around the lattice."""

    logp_col: np.ndarray  # (nx + 2, h, w) column log-probabilities
    logp_row: np.ndarray  # (ny + 2, h, w) row log-probabilities
    box: Letterbox  # the input's letterbox into the processing size
    xy: np.ndarray  # (K, 2) every candidate, crop pixels
    extent_rim_px: float  # lattice corners this near the rim are no evidence of the board's extent


def _place(c: _Crop, lat: Lattice, v: _Votes, board: Checkerboard, smoothed: dict) -> tuple[Placement, list, bool] | None:
    """The lattice's placement, its margin evidence, and whether the placement stands (does not
    contradict that evidence beyond ``cfg.max_violated_edges`` or ``cfg.max_violated_share`` of
    it: the board would end where the target goes on, another target or a distractor); None for
    a line of corners."""
    cfg = c.cfg
    blur1 = smooth_cached(smoothed, c.grey, -1)
    dark = cell_darkness(blur1, lat)
    if not dark:
        return None  # a line of corners (or a diagonal), without one complete square, is not a checker lattice
    lc, lr = corner_votes(lat, v.logp_col, c.offset, v.box, cfg), corner_votes(lat, v.logp_row, c.offset, v.box, cfg)
    edges = edge_evidence(blur1, lat, cfg, v.xy)
    placed = assign_ids(lat.ab, lc, lr, dark, board, cfg, edges, extent_weight(lat, c.rim_dist, v.extent_rim_px))
    return placed, edges, placed.violated <= max(cfg.max_violated_edges, cfg.max_violated_share * sum(e[3] for e in edges))


def _identify(
    c: _Crop, grown: list[Lattice], v: _Votes, board: Checkerboard, smoothed: dict
) -> list[tuple[float, Lattice, np.ndarray, float]]:
    """Stage 4, identity: each lattice placed on the board, (margin, lattice, ids, geometry
    margin) for those whose placement stands. A lattice whose placement contradicts its margin
    evidence or is unsure may have stepped over the board's margin onto a distractor: its parts on
    this side of each line of margin evidence are placed on their own, and the surest that stands,
    is sure and adds evidence (:func:`cut_adds_evidence`) replaces it."""
    cfg = c.cfg
    scored = []
    for lat in grown:
        res = _place(c, lat, v, board, smoothed)
        if res is None:
            continue
        placed, edges, stands = res
        if cfg.cut_at_margins and edges and not (stands and placement_is_sure(placed.margin, placed.geometry_margin, cfg)):
            cuts = []
            for part in cut_at_margins(lat, edges, cfg):
                r = _place(c, part, v, board, smoothed)
                if r is None or not r[2] or not placement_is_sure(r[0].margin, r[0].geometry_margin, cfg):
                    continue
                if cfg.cut_needs_evidence and not cut_adds_evidence(placed, stands, lat, part, r[0]):
                    continue
                cuts.append((r[0], part))
            if cuts:
                (placed, lat), stands = max(cuts, key=lambda x: x[0].margin), True
        if stands:
            scored.append((placed.margin, lat, placed.ids, placed.geometry_margin))
    return scored


def grid_completion(cfg: GridConfig) -> CompletionConfig:
    """The completion settings of the grid pass's stage 5, whose ``neighbours`` its neighbour
    check (stage 6) fits its maps to as well.

    A checker's print tells only the two parities apart: a saddle at an occluder's edge, or the
    rim's, can match it, so every corner added must also have its four edge rays along the
    board's axes and a sure correlation (``CompletionConfig.sure_corr``). Nor is a corner judged again
    under the map through it (``CompletionConfig.refit_gap_px``): with a map fitted to it, a
    checker's print matched a saddle 15 px off at the rim (a new wrong corner, no new right one
    over the eight checkerboard sets)."""
    shared = CompletionConfig()
    return replace(
        shared,
        min_corr=shared.sure_corr,  # the sure match is the least one (no rays stand in for it) ...
        check=False,
        sure_corr=math.inf,  # ... and the rays are always asked
        min_ray_px=0.0,  # rays at every gap: a checker's print tells only the parities apart
        refit_gap_px=0.0,
    )


def _completed(c: _Crop, xy: np.ndarray, ids: np.ndarray, q: np.ndarray, conf: np.ndarray, margin: float, board, smoothed, lens):
    """Stage 5, completion: corners the growth did not reach (bent rows at the rim, a blurred
    stretch), predicted from the identified ones and checked against the print
    (:mod:`cotrain.detect.completion`); their confidence is the placement's times that
    check's correlation. Returns ids, q (crop pixels) and confidence."""
    cfg = c.cfg
    x0, x1, y0, y1 = c.bounds
    # The crop's own edges (where they are not the frame's) cut fit windows as the rim does.
    inside = c.allowed.copy()
    inside[:, : int(x0 > 0)] = inside[:, inside.shape[1] - int(x1 < c.shape[1]) :] = False
    inside[: int(y0 > 0)] = inside[inside.shape[0] - int(y1 < c.shape[0]) :] = False
    rim_c = cv2.distanceTransform(inside.astype(np.uint8), cv2.DIST_L2, 3)
    given = dict(zip(ids.tolist(), conf.tolist()))
    ids, q, corr, _ = complete_board(c.grey, smoothed, rim_c, xy, board, ids, q, grid_completion(cfg), cfg, lens)
    conf = np.array([given.get(i, (1.0 - np.exp(-margin)) * k) for i, k in zip(ids.tolist(), corr.tolist())])
    return ids, q, conf


def _neighbours_agree(ids: np.ndarray, q: np.ndarray, board: Checkerboard, cfg: GridConfig, lens) -> np.ndarray:
    """Stage 6's check: (K,) bool, the corners where their identified neighbours put them. A corner
    off there (the growth took a T-junction at an occluder's edge, or slid a row's end) is dropped;
    completion may find it where it is. Where many miss, the maps are at fault (no image circle to
    guess the lens from, and a bend no homography follows: a 640x480 board lost 22 of its 23
    placed corners so), and none is dropped."""
    return neighbour_check(
        board,
        ids,
        q,
        grid_completion(cfg).neighbours,
        cfg.max_neighbour_misfit,
        lens,
        max_share=cfg.max_misfit_share,
        worst_misfit=cfg.max_refit_shift,
        worst_rounds=cfg.worst_misfit_rounds,
    )


def grid_pass(
    grey: np.ndarray,
    box: Letterbox,
    corner_prob: np.ndarray,
    mask_prob: np.ndarray,
    logp_col: np.ndarray,
    logp_row: np.ndarray,
    board: Checkerboard,
    cfg: GridConfig,
    extent_rim_px: float = 0.0,
    frame: BlackFrame | None = None,
    beside: Executor | None = None,
) -> GridResult:
    """Corners with ids from the network's dense outputs and the full-resolution image.

    Args:
        grey: (H, W) float32 input image in [0, 1]; box: its letterbox into the processing size.
        corner_prob: (h, w) class-agnostic corner probability and mask_prob: (h, w) board
        probability at 1/4 processing resolution; logp_col: (nx + 2, h, w), logp_row: (ny + 2, h, w)
        for ``board`` (nx x ny inner corners)
        column / row log-probabilities.
        extent_rim_px: lattice corners nearer the image circle's rim than this (px of ``grey``)
        are no evidence of the board's extent (:func:`extent_weight`): the half-resolution
        reading does not report them (``cfg.half_rim_px``), since the board's edge against the
        dark rim makes X-junctions of its own there.
        frame: ``grey``'s black frame (:func:`black_frame`) where already read; else read here.
        beside: a thread idle meanwhile: the crop's distance to the rim (:func:`rim_distance`) and
        its blurs for the fits (:func:`cotrain.detect.saddle.smooth_ahead`) are made there while
        this thread finds the saddle response, the same arrays (OpenCV releases the GIL).
    """
    empty = GridResult(np.zeros(0, int), np.zeros((0, 2)), np.zeros(0), float("nan"))
    c = _crop(grey, box, corner_prob, mask_prob, cfg, frame)
    if c is None:
        return empty
    cfg = c.cfg
    smoothed: dict[int, np.ndarray] = {}
    rim = beside.submit(rim_distance, c.allowed) if beside is not None else None
    if beside is not None:
        smooth_ahead(smoothed, c.grey, beside)
    response = saddle_response(c.grey)
    c = c._replace(rim_dist=rim_distance(c.allowed) if rim is None else rim.result())
    xy, axes = find_candidates(c.grey, c.roi, c.offset, box, corner_prob, cfg, smoothed, c.rim_dist, response)  # stage 2
    if len(xy) < cfg.min_corners:
        return _unasked_dropped(smoothed, empty)
    grown = _grow(c, xy, axes, smoothed, response)
    scored = _identify(c, grown, _Votes(logp_col, logp_row, box, xy, extent_rim_px), board, smoothed)
    if not scored:
        return _unasked_dropped(smoothed, empty)
    # The lattice whose identity is surest wins (the first of equal margins).
    margin, lat, ids, geometry_margin = max(scored, key=lambda s: s[0])
    if not placement_is_sure(margin, geometry_margin, cfg):
        return _unasked_dropped(smoothed, GridResult(np.zeros(0, int), np.zeros((0, 2)), np.zeros(0), float(margin)))
    if cfg.merge_lattices:
        lat, ids = merge_lattices(lat, ids, [x for x in scored if x[1] is not lat], board, cfg)
    lat = refine_positions(lat, c.grey, cfg, smoothed, c.rim_dist)  # stage 6, refinement
    ids = canonical_ids(ids, lat.xy, board)
    on = ids >= 0
    conf = np.full(len(ids), 1.0 - np.exp(-margin)) * np.where(lat.filled, cfg.filled_confidence, 1.0)
    ids, q, conf = ids[on], lat.xy[on], conf[on]
    lens = lens_of_circle(c.circle, cfg.lens_fov, c.offset)
    if cfg.max_neighbour_misfit > 0:
        ok = _neighbours_agree(ids, q, board, cfg, lens)
        ids, q, conf = ids[ok], q[ok], conf[ok]
    if cfg.completion and 4 <= len(ids) < board.n_corners:
        ids, q, conf = _completed(c, xy, ids, q, conf, margin, board, smoothed, lens)
    order = np.argsort(ids)
    return GridResult(ids[order], q[order] + c.offset, conf[order], float(margin))


def _unasked_dropped(smoothed: dict, result: GridResult) -> GridResult:
    """``result``, the blurs made ahead (:func:`cotrain.detect.saddle.smooth_ahead`) that no fit
    asked for cancelled where not begun: the thread is the next look's."""
    for job in smoothed.values():
        if isinstance(job, Future):
            job.cancel()
    return result


def merge_half_resolution(grey: np.ndarray, full: GridResult, half: GridResult, board: Checkerboard, cfg: GridConfig) -> GridResult:
    """The grid pass's result on the (H, W) image ``grey`` (``full``) completed with its result on
    the image at half resolution (``half``, :func:`cotrain.detect.half_resolution.halve`'s pixels),
    where ``full`` found nothing (:meth:`cotrain.detect.detector.Detector._grid` reads it only
    then). It is taken where its identity margin reaches ``cfg.half_min_margin_alone``; its
    corners are kept as
    :func:`cotrain.detect.half_resolution.corners_at_half_resolution` keeps them (a correlation
    of the print check's ``min_corr`` with their print and no better one with an axis neighbour's, the
    other checker parity; ``cfg.half_rim_px`` from the rim, where a board's edge against the dark
    rim makes an X of its own and the full-resolution pass's rim rules were not applied)."""
    if len(full.ids) or not len(half.ids) or not half.margin >= cfg.half_min_margin_alone:
        return full
    # Not held to print_moved (CompletionConfig.moved_px 0): the grid pass guesses no lens, so its
    # maps would be pixel homographies, which bend from the board at the rim (on the checkerboard
    # sets it changed nothing: 676 frames).
    check = CompletionConfig(moved_px=0.0)
    found = corners_at_half_resolution(
        grey, full.ids, full.xy, half.ids, half.xy, board, cfg, check, min_corr=check.min_corr, rim_px=cfg.half_rim_px
    )
    if found is None or not len(found[0]):
        return full
    sel, q = found
    order = np.argsort(half.ids[sel])
    return GridResult(half.ids[sel][order], q[order], half.confidence[sel][order], half.margin)
