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
   ``lend_depth`` tags away; ids through the lattice); :func:`cells_close` drops a corner in
   no complete cell without a neighbour along each axis, and :func:`rays_agree` corners that
   slid or sit on a junction inside a tag;
6. boards: lattices that place no tag of the target (a second board with other tags; free tags
   have no X-junctions at their corners) give no corners; lattices of one board (a join and its
   parts too) are merged where they agree, and of two that claim the same ids elsewhere, or the
   same place with other ids, the surer placement stays (:func:`consistent_boards`);
7. positions: every corner fitted once more in a small window
   (:func:`cotrain.detect.refinement.final_fits`); one whose fit fails is dropped, except in gaps
   narrower than ``keep_unfitted_px``, where the window reaches across the crossing square and
   its failure says nothing (the corner keeps its lattice position);
8. completion (:mod:`cotrain.detect.completion`): first every corner is checked against the
   print around it (one that a grid neighbour's print matches better is dropped), then the placed
   board's corners the growth did not reach are predicted from the identified ones and checked
   against the print around them;
9. half resolution: where few corners are found, and completion left a corner it predicted in
   view unfound (or none was found), the frame is read again at half resolution and what only
   that finds is added where the print check keeps it (:func:`tag_pass`).

The stages are modules, in the order the data flows: :mod:`cotrain.detect.tag_candidates` (1),
:mod:`cotrain.detect.tag_seeds` (2), :mod:`cotrain.detect.tag_growth` (3),
:mod:`cotrain.detect.tag_reading` (4; the seeds read their tag with it too) and
:mod:`cotrain.detect.tag_placement` (5, 6), their parameters and the result in
:mod:`cotrain.detect.tag_config`; this module runs them (the seeds and their growth, the
placement of each lattice, the final positions, completion, the second looks and half
resolution).

Pure functions over numpy arrays; pixels follow docs/conventions.md (centre of the top-left pixel at (0, 0)).
"""

from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple

import cv2
import numpy as np
from scipy.spatial import cKDTree

from cotrain.detect.completion import complete_board
from cotrain.detect.half_resolution import corners_at_half_resolution, halve
from cotrain.detect.image_circle import EquidistantLens, guess_lens
from cotrain.detect.images import MIN_SIDE, local_gain
from cotrain.detect.lattice import Lattice
from cotrain.detect.refinement import final_fits, shortest_steps
from cotrain.detect.retries import Look, aprilgrid_looks, first_found
from cotrain.detect.saddle import outside_circle, smooth_cached
from cotrain.detect.tag_candidates import RayNeighbours, _Candidates, _candidates_of, axis_neighbours
from cotrain.detect.tag_config import TagConfig, TagResult
from cotrain.detect.tag_growth import grow_tag_lattice, join_lattices
from cotrain.detect.tag_placement import (
    _Board,
    cells_close,
    consistent_boards,
    place_board,
    rays_agree,
    tag_under,
    verified_corners,
)
from cotrain.detect.tag_reading import TURNS, read_cells
from cotrain.detect.tag_seeds import seed_tag
from cotrain.detect.verification import own_print_corr, print_check, print_moved
from cotrain.targets.aprilgrid import AprilGrid

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
    ``keep_unfitted_px``) scale with the factor, so the identity rules see
    the tags as they are, as does completion's ``moved_px`` (a distance in the frame's pixels).
    Positions are given in the frame's pixels either way.

    A frame not enlarged where under half the board's corners are found is read again at
    half resolution (blurred tags, large tags), and the corners only that finds are added where the print check keeps them
    (:func:`cotrain.detect.verification.print_check`) and their neighbours put them
    (:func:`cotrain.detect.verification.print_moved`); not where completion found every corner
    it predicted in view (``TagResult.unfound`` 0: a partial view found whole).

    A frame where nothing is found is read again by the next look of the tag pass's retry schedule
    (:func:`cotrain.detect.retries.aprilgrid_looks`: seeds of smaller data cells, then the frame
    with its contrast raised); the corners of the
    first look that finds any are reported, and ``TagResult.look`` names it."""
    cfg = cfg or TagConfig()
    view = _view_of(grey, cfg)

    def read(look: Look) -> TagResult:
        look_cfg = look.config(cfg)
        if look.gained:  # a frame of its own: its crop, lens and candidates read anew
            gained = local_gain(grey, cfg.retry_gain, cfg.grid.retry_gain_sigma * min(grey.shape))
            return _tag_pass_both(gained, board, look_cfg) if look.half_resolution else _tag_pass_circle(gained, board, look_cfg)
        if look.half_resolution:
            return _tag_pass_both(grey, board, look_cfg, view)
        return _tag_pass_circle(grey, board, look_cfg, view)  # the frame as the first look read it

    r, look = first_found(aprilgrid_looks(cfg), read)
    return replace(r, look=look.name)


def _tag_pass_both(grey: np.ndarray, board: AprilGrid, cfg: TagConfig, view: _View | None = None) -> TagResult:
    """One look of :func:`tag_pass` with half resolution: at full resolution (``view``: the frame as read
    for it, :func:`_view_of`, else read here), then at half resolution where few corners were found."""
    view = view or _view_of(grey, cfg)
    r = _tag_pass_circle(grey, board, cfg, view)
    if not cfg.half_resolution or 2 * len(r.ids) >= board.n_corners or r.scale > 1 or min(grey.shape) // 2 < MIN_SIDE:
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
    the image circle's bounding box, its lens guessed (:func:`circle_crop`), its candidates found."""
    f, origin, crop, inside, lens = circle_crop(grey, cfg)
    return _View(f, origin, crop, inside, lens, _candidates_of(crop, inside, cfg))


def circle_crop(grey: np.ndarray, cfg: TagConfig) -> tuple[float, tuple[int, int], np.ndarray, np.ndarray, EquidistantLens | None]:
    """The frame ``grey`` (H, W) enlarged where it is small (:func:`enlargement`) and cropped to the
    image circle's bounding box grown by :data:`CIRCLE_PAD_PX`: the factor, the crop's top-left
    corner (x0, y0) in the enlarged frame, the crop (h, w), which of its pixels lie inside the
    image circle (h, w) bool, and the lens guessed from the circle (in the crop's pixels; None
    where none shows)."""
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
    lens = guess_lens(outside, cfg.grid.lens_fov, (x0, y0))
    return f, (x0, y0), grey[y0:y1, x0:x1], allowed[y0:y1, x0:x1], lens


def _tag_pass_circle(grey: np.ndarray, board: AprilGrid, cfg: TagConfig, view: _View | None = None) -> TagResult:
    """:func:`tag_pass` at one resolution: on the image circle's bounding box, a small frame
    enlarged (``view``: the frame as read already, :func:`_view_of`, else read here)."""
    view = view or _view_of(grey, cfg)
    f = view.scale
    if f > 1:
        cfg = replace(cfg, **{k: getattr(cfg, k) * f for k in ("small_gap_px", "keep_unfitted_px")})
        cfg = replace(cfg, complete=replace(cfg.complete, **{k: getattr(cfg.complete, k) * f for k in ("moved_px", "small_tag_px")}))
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

    found_here = candidates or _candidates_of(grey, allowed, cfg)
    rim_dist, smoothed, xy, tree, rays = found_here
    if tree is None:
        return empty()
    sm = smooth_cached(smoothed, grey, 1)
    nbr = axis_neighbours(xy, rays, tree, sm, cfg)
    spacing = board.cfg.tag_spacing
    grown = _grow_lattices(found_here, nbr, grey, spacing, cfg, lens)
    found, foreign = _placed_boards(grown, grey, spacing, board, cfg, lens, sm)
    if not found:
        return empty(len(foreign))
    kept, lost = consistent_boards(found)
    reported = {c.key for f in kept for c in f.decoded}
    dropped = {c.key for f in lost for c in f.decoded} | {c.key for f in kept for c in f.disagree}
    dropped -= reported
    ids_a, xy_a, conf_a, tags, ham = _final_corners(kept, board, grey, cfg, smoothed, rim_dist)
    ids_a, xy_a, conf_a, unfound = _checked_and_completed(grey, smoothed, sm, rim_dist, xy, board, ids_a, xy_a, conf_a, cfg, lens)
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


def _grow_lattices(
    candidates: _Candidates, nbr: RayNeighbours, grey: np.ndarray, spacing: float, cfg: TagConfig, lens: EquidistantLens | None
) -> list[Lattice]:
    """Steps 2 and 3 of :func:`_tag_pass_in`: the lattices grown from the seeds among the
    ``candidates`` (with their ray neighbours ``nbr``), strongest first, up to ``cfg.grid.max_seeds``;
    a candidate a lattice covers seeds none."""
    rim_dist, smoothed, xy, tree, _ = candidates
    rays_xyz = None if lens is None else lens.lift(xy)  # the candidates' unit rays (K, 3), for the seeds
    covered = np.zeros(len(xy), bool)
    grown: list[Lattice] = []

    def grow(seed: int, frame: np.ndarray, tag_corners: list[int]) -> None:
        nonlocal covered
        grown.append(grow_tag_lattice(xy, nbr, seed, frame, grey, cfg, smoothed, rim_dist, tree, tag_corners))
        covered |= cKDTree(grown[-1].xy).query(xy)[0] < cfg.grid.merge_radius_px
        covered |= inside_cells(grown[-1], xy, grey.shape)  # a grown tag's own data junctions are no seeds

    # Seeds whose tag decodes alone grow first; the others (small or blurred tags, and quads of
    # junctions that only look like a tag: across two large bent tags) once those have covered
    # what they reach, so that such a quad does not cover the corners of the tags it cuts.
    later: list[tuple[int, np.ndarray, list[int]]] = []
    for seed in range(len(xy)):
        if len(grown) >= cfg.grid.max_seeds:
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
        grow(seed, frame, tag_corners)
    for seed, frame, tag_corners in later:
        if len(grown) >= cfg.grid.max_seeds:
            break
        if covered[seed]:
            continue
        grow(seed, frame, tag_corners)
    return grown


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


def _placed_boards(
    grown: list[Lattice],
    grey: np.ndarray,
    spacing: float,
    board: AprilGrid,
    cfg: TagConfig,
    lens: EquidistantLens | None,
    sm: np.ndarray,
) -> tuple[list[_Board], set[tuple[int, int, int]]]:
    """Steps 4 and 5 of :func:`_tag_pass_in`: each lattice ``grown``, and each join of them, read
    and placed on the board, its corners' ids where the placement holds (-1 where a check drops
    them); and the keys (:attr:`TagCell.key`) of the tags read that are not on the target."""
    found: list[_Board] = []
    foreign: set[tuple[int, int, int]] = set()
    joined = [L for L in join_lattices(grown, cfg.grid.merge_radius_px) if not any(L is G for G in grown)]
    for lat in grown + joined:
        if len(lat.ab) < cfg.grid.min_corners:
            continue
        cells = read_cells(lat, grey, spacing, cfg, lens)
        foreign |= {c.key for c in cells if c.clean and c.tag >= board.n_tags and c.hamming <= cfg.max_hamming}
        place = place_board(cells, board)
        if place is None or place.margin < cfg.min_margin_corr or place.score < cfg.min_mean_corr * 36 * place.cells:
            continue
        under = tag_under(np.array([c.cell for c in cells]), place.turn, place.offset, board)
        alone = [(c, t) for c, t in zip(cells, under) if c.clean and c.hamming <= cfg.max_hamming and c.tag < board.n_tags]
        decoded = [c for c, t in alone if c.tag == t and c.turn == place.turn]
        ids = board.id_of(lat.ab @ TURNS[place.turn].T + place.offset)
        ids[~verified_corners(lat, cells, under, place.turn, board, cfg) | ~cells_close(lat) | ~rays_agree(lat, sm, spacing, cfg)] = -1
        found.append(_Board(lat, ids, place, decoded, [c for c, t in alone if not (c.tag == t and c.turn == place.turn)]))
    return found, foreign


def _final_corners(
    kept: list[_Board], board: AprilGrid, grey: np.ndarray, cfg: TagConfig, smoothed: dict[int, np.ndarray], rim_dist: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int], list[int]]:
    """Step 7 of :func:`_tag_pass_in`: the corners of the boards ``kept`` fitted once more, each id
    once (the surer board's): ids (K,), positions (K, 2) and confidences (K,), and the tags that
    decode alone to where their boards put them with their bit errors."""
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
    return np.array(ids, int), np.array(xy_out).reshape(-1, 2), np.array(conf), tags, ham


def _checked_and_completed(
    grey: np.ndarray,
    smoothed: dict[int, np.ndarray],
    sm: np.ndarray,
    rim_dist: np.ndarray,
    xy: np.ndarray,
    board: AprilGrid,
    ids_a: np.ndarray,
    xy_a: np.ndarray,
    conf_a: np.ndarray,
    cfg: TagConfig,
    lens: EquidistantLens | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int | None]:
    """Step 8 of :func:`_tag_pass_in`: the corners ``ids_a`` (K,) at ``xy_a`` (K, 2) with
    confidences ``conf_a`` (K,) checked against the print around them and completed (the
    candidates ``xy`` (M, 2) among the points completion may take): ids, positions and confidences,
    and the corners completion left unfound in view (None: completion did not run)."""
    print_lens = lens if cfg.complete.lens else None  # the print check's and completion's maps go through it
    if cfg.complete.check:
        # A corner the print around it contradicts (a neighbour's pattern matches better) is dropped;
        # completion may find it where it is.
        ok = print_check(sm, rim_dist, board, ids_a, xy_a, cfg.complete, lens=print_lens)
        ids_a, xy_a, conf_a = ids_a[ok], xy_a[ok], conf_a[ok]
    aside = np.zeros(len(ids_a), bool)
    if cfg.complete.check and cfg.complete.runs:
        # A corner some pixels from where its neighbours put it, where the print matches better
        # there, is set aside for completion to place; where completion does not, it is put back.
        aside = print_moved(sm, rim_dist, board, ids_a, xy_a, cfg.complete, print_lens)
    aside_ids, aside_xy, aside_conf = ids_a[aside], xy_a[aside], conf_a[aside]
    ids_a, xy_a, conf_a = ids_a[~aside], xy_a[~aside], conf_a[~aside]
    unfound = None
    if cfg.complete.runs and len(ids_a) >= 4:
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
    return ids_a, xy_a, conf_a, unfound
