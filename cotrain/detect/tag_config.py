"""The tag pass's parameters and its output (:mod:`cotrain.detect.tag_pass`).

Takes nothing; gives :class:`TagConfig`, the one parameter struct every stage of the pass reads
(candidates, growth, decoding, placement, small frames, blurred and large tags, boards), and
:class:`TagResult`, what the pass reports for a frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cotrain.detect.grid_config import GREY_PRINT_GAIN, GridConfig
from cotrain.detect.print_model import CompletionConfig


@dataclass
class TagConfig:
    # Each number's comment gives its unit and its origin. Sets are named as calib_eval/detection/sets.py names them, at 1280x720 unless a
    # size is given; every AprilGrid seed named here is a tuning set there (2027: the AprilGrid evaluation set, 2041: the validation set).
    # "64 / 200 / 210 frames": the evaluation set's table of 16 / 50 per FoV (210 with its empty frames), as the changes of 2026-11-23/24
    # were measured. The independent renderer's sets (calib_eval.detection.foreign, seed 5) are in sets.FOREIGN_TUNING. Figures as measured
    # then (CHANGELOG.md, the tuning log's "The AprilGrid: the tag pass", and the commit named).
    # --- candidates ---
    # origin: measured on the evaluation set (seed 2027; a tuning set): 1.0 -> 0.9 took recall 0.824 -> 0.827 (200 frames) and 0.843 ->
    # 0.855 (64), no new wrong corner (f738ea1); 0.8, on it and seeds 2031, 2035: no gain or more wrong corners (CHANGELOG 2026-11-24, late)
    response_sigma: float = 0.9  # px: scale of the saddle response (small: gaps of tiny tags are 2-3 px)
    # unit: intensity^2 (sigma^4 -(Ixx Iyy - Ixy^2) of the [0, 1] image, OpenCV's Sobel scale); origin: not recorded (set in 24194e2,
    # "AprilGrid tag pass: corners as X-junctions, ..."); lower, on seeds 2027, 2031 and 2035 (tuning sets): no gain or more wrong corners
    # (CHANGELOG 2026-11-24, late)
    min_response: float = 0.0015  # saddle response a candidate needs (scale-normalised -det Hessian)
    # count; origin: measured on the evaluation set (seed 2027; a tuning set): every true corner ranks within 1500 (4000 before; 3de7c2b)
    max_candidates: int = 1500  # strongest response maxima kept (all true corners of the evaluation set rank within 1500)
    # --- growth ---
    # origin: not recorded (set in 24194e2, "AprilGrid tag pass: corners as X-junctions, ..."); kept in the first look on the evaluation set
    # (seed 2027; a tuning set): 16 deg in every frame took FoV 200 0.972 -> 0.964 (07fcdf1)
    seed_axis_angle: float = 12.0  # deg: a seed's neighbours lie within this of its edge rays ...
    # (A frame where nothing was found was read again with a cone of 16 deg, retry_seed_angle, set on the evaluation set's fov180_013 in
    # 07fcdf1, until 2026-12-08: without that look no row of the eight AprilGrid sets changed; fov180_013 is found by the raised contrast,
    # 141 corners instead of 142, and the small cells are found in the first look's cone.)
    # count; origin: not recorded (set in 24194e2, "AprilGrid tag pass: corners as X-junctions, ..."; a field since 107fdeb)
    ray_search: int = 96  # nearest candidates searched for ray neighbours
    # count; origin: not recorded (set in 02e95a5, "tag pass: tags read after sharpening, ...; seeds from each corner's four edge rays")
    ray_tries: int = 5  # candidates tried along each edge ray, nearest first, for ones reached along an edge
    # origin: measured on the evaluation set (seed 2027; a tuning set): recall 0.751 -> 0.762 (210 frames), 0.795 -> 0.806 (64); before,
    # 0.15 of a long side reached into a foreshortened tag's data (107fdeb)
    ray_edge_depth: float = 0.6  # that edge test samples at most this multiple of the nearest-candidate distance aside
    # count; origin: not recorded (set in 02e95a5, "tag pass: tags read after sharpening, ...; seeds from each corner's four edge rays")
    ray_options: int = 3  # candidates reached along an edge kept per ray: a seed's tag sides are tried among them
    # origin: measured on the evaluation set (seed 2027; a tuning set): 0.35 (match_radius) -> 0.6, recall 0.807 -> 0.824 (200 frames; with
    # position clashes dropped, 2c5af52; CHANGELOG 2026-11-24, later)
    fourth_radius: float = 0.6  # a seed tag's fourth corner lies within this fraction of its shorter side of the parallelogram's
    # At a seed, the neighbour behind a corner is its gap where it is no longer than the tag's side, else the gap is the target's (until
    # 2026-12-08 it had to be 1.7 times shorter, min_long_short: at 1 the eight AprilGrid sets gained 46 corners, and lost
    # two wrong ones, on the defocused frames).
    # unit: fraction of the predicted step; origin: not recorded (set in 24194e2, "AprilGrid tag pass: corners as X-junctions, ...")
    match_radius: float = 0.35  # a neighbour must lie within this fraction of its predicted step
    # ... and within CompletionConfig.search (0.6) of the local gap, as completion searches about its predictions: under strong
    # perspective the next row lies a gap away. (A number of its own, match_gap, 0.6 as well, until 2026-12-08.)
    # count; origin: measured on the evaluation set (seed 2027; a tuning set), with candidates offered again and the skipped-corner test
    # scaled (one commit, 8790253): recall 0.633 -> 0.759 (64 frames)
    match_tries: int = 3  # candidates within reach tried at a predicted spot, nearest first, before a saddle is fitted there
    # Predictions from different neighbours agree within grid.agree_radius of the step, and a new corner keeps grid.crowd_radius of the
    # local gap from every placed one (the grid pass's numbers; until 2026-12-07 copies of them here, 0.3 and 0.5, not recorded, 24194e2).
    # unit: ratio to the predicted step; origin: not recorded (set in 24194e2, "AprilGrid tag pass: corners as X-junctions, ...")
    min_step_ratio: float = 0.7  # a new step may be this much shorter than predicted ...
    # unit: ratio to the predicted step; origin: not recorded (set in 24194e2, "AprilGrid tag pass: corners as X-junctions, ...")
    max_step_ratio: float = 1.4  # ... or this much longer
    # origin: measured on seeds 2027, 2031 and 2035 (tuning sets): 25 -> 40 deg, recall +0.004 / +0.006 / +0.004, no more wrong corners
    # (b25fdd6)
    ray_step_angle: float = 40.0  # deg: where nothing lies at a prediction, a candidate an edge ray leads to within this of the step
    # unit: multiple of the prediction's reach; origin: not recorded (set in e9bc70a, "tag pass growth: where nothing lies at a prediction,
    # the candidate a corner's own edge ray leads to ..."; a field since a258657); 3, on seeds 2027, 2031 and 2035 (tuning sets): no gain or
    # more wrong corners (CHANGELOG 2026-11-24, late)
    ray_step_reach: float = 2.0  # ... and within this multiple of the reach of the prediction
    # origin: not recorded (set in 24194e2, "AprilGrid tag pass: corners as X-junctions, ...")
    max_step_junction: float = 0.1  # a candidate this close to a step's middle part (fraction of the step) refuses it
    # origin: not recorded (set in 24194e2, "AprilGrid tag pass: corners as X-junctions, ...")
    edge_depth: float = 0.35  # the edge test samples this fraction of the gap to each side of a step
    # ... and its light side brighter than its dark one by the saddle fit's contrast floor, GridConfig.min_saddle_contrast (0.04 of
    # intensity, mean over the step; the tag pass's min_edge_contrast, 0.04 as well, until 2026-12-08: not recorded, 24194e2; halved with
    # the pass's other contrast thresholds, the evaluation set's low-contrast row went 0.823 -> 0.805, CHANGELOG 2026-11-24, late morning)
    # --- decoding ---
    # count of bits; origin: print geometry (tag36h11's codes differ in at least 11 bits) and AprilTag's own correction of 2 (the tuning
    # log, step 6)
    max_hamming: int = 2  # bit errors a tag read alone may have (tag36h11: codes differ in at least 11 bits)
    # A tag is read where its white gap is lighter than its black border, and a seed's tag where its white data cells are lighter than
    # its black ones by min_data_contrast. (Until 2026-12-08 the gap had to be lighter by min_bit_contrast, 0.06, and a
    # seed's data cells a share of min_data_share, 0.15, white and black: at 0 neither changed a corner of the eight AprilGrid sets.)
    # origin: not recorded (set in 02e95a5, "tag pass: tags read after sharpening, ...; seeds from each corner's four edge rays")
    min_data_contrast: float = 0.2  # a seed's white data cells must be lighter than its black ones by this share of the tag's contrast
    # unit: share of the samples; origin: not recorded (set in 24194e2, "AprilGrid tag pass: corners as X-junctions, ...")
    min_clean: float = 0.9  # share of its border's inner-ring samples darker, and gap samples lighter, than their midpoint
    # origin: measured on seeds 2027 and 2031 (tuning sets): tags read through their sides with this bound, recall 0.832 -> 0.843 and 0.832
    # -> 0.842, wrong 3 -> 3 and 4 -> 3; without it two slid corners were kept (7ad460c; CHANGELOG 2026-11-24, late)
    max_side_misfit: float = 0.04  # tags are read through a map bent to their sides, where the sides fit it within this (tag widths)
    # unit: weight (of the Laplacian against the cell); origin: measured on the evaluation set (seed 2027; a tuning set): the sharpened,
    # standardised, Otsu-split read took recall 0.468 -> 0.581 (64 frames; CHANGELOG 2026-11-24), the weight itself not recorded (set in
    # 02e95a5; a field since a274c13)
    sharpen: float = 1.5  # weight of the 4-neighbour Laplacian that undoes blur over a tag's cells (rendered tags of 10-30 px)
    # origin: not recorded (set in 24194e2, "AprilGrid tag pass: corners as X-junctions, ..."); kept in the first looks on seed 2041: 0.8 px
    # in every look lost its fov240_003 (31 corners; 01e9e3e)
    min_cell_px: float = 1.0  # tags whose data cells are smaller than this (px) neither seed a lattice nor are read ...
    # px; origin: measured on the evaluation set (seed 2027; a tuning set): FoV rows 0.9769 -> 0.9797 (fov200_022 0 -> 46 corners), seed
    # 2041 0.9535 -> 0.9579 (fov220_004 0 -> 40), no wrong corner; 0.8: the same on these sets, but a test's board of 7.8 px tags not found
    # (01e9e3e)
    retry_min_cell_px: float = 0.7  # ... or than this, in a second look where the first finds nothing
    # unit: factor; origin: measured on the independent renderer's photographed prints (foreign --photo, seed 5): 0.845 -> 0.904 (12 per
    # FoV), 0.820 -> 0.896 (24); on the evaluation set (seed 2027; a tuning set) its low-contrast row 0.857 -> 0.916; a gain of 2 placed a
    # board wrongly on the renderer's clean frames (1b3f4f3; the tuning log, step 14) The last look, where the ones before find nothing
    # (cotrain.detect.retries): contrast raised this much about the local mean (<= 1: never); cotrain detect --grey-print's gain for the
    # checkerboard too
    retry_gain: float = GREY_PRINT_GAIN
    # The raised contrast's local mean (sigma GridConfig.retry_gain_sigma) and the lens tags are read through (an equidistant lens of
    # GridConfig.lens_fov filling the image circle; 0: never) are the grid settings' (TagConfig.grid): one number each for both targets
    # (until 2026-12-07 each target had its own copy of 0.028 and 210 deg; lens_fov: on the evaluation set, seed 2027, a tuning set,
    # 190, 210 and 230 deg give the same recall within 0.001; read through it, the large-squares row's tags of 40 px and more read
    # 46 -> 75 of 80 times, 11e1eb1).
    # --- placement ---
    # origin: not recorded (set in 24194e2, "AprilGrid tag pass: corners as X-junctions, ...", as min_margin; renamed in 2ed497b)
    min_margin_corr: float = 12.0  # the board's placement must beat the runner-up by this (summed tag correlation; a clean tag gives 36)
    # origin: measured on seed 2041 (the validation set; a tuning set): 0.4 -> 0.3, its fov200_024 (blurred 9 px tags, placed at 0.37) 0 ->
    # 80 corners, FoV rows 0.9579 -> 0.9647; no wrong corner there nor in 80 random blurred renders (aa63cda)
    min_mean_corr: float = (
        0.3  # ... and its tags must correlate with their codes by this much on average (-1 .. 1; blurred 9 px tags: 0.37)
    )
    # A tag that was read keeps its corners where it correlates with its code by the print's match, CompletionConfig.min_corr (0.5: the
    # image against the board's print, as the print check and completion ask around a corner; min_tag_corr, 0.5 as well, not recorded,
    # 24194e2, until 2026-12-08) ...
    # Tags narrower than CompletionConfig.small_tag_px (20 px; cells of 2 px) blur: for them ...
    # unit: correlation (-1 .. 1); origin: measured on the evaluation set (seed 2027; a tuning set), with a slip margin of 0.15: recall
    # 0.741 -> 0.751 (210 frames), 0.791 -> 0.796 (64), the same wrong corners (bde83f5). That margin (min_slip_margin) went on
    # 2026-12-08: at 0, over the eight AprilGrid sets, the defocused frames went 0.8682 -> 0.8823 (a wrong corner fewer) and the
    # evaluation set's FoV rows lost 2 corners of 16,127.
    min_tag_corr_local: float = 0.25  # ... this much is enough where no code a slip by one tag would put there matches better
    # A read tag lends its ids to an unread tag beside it where it matches its code surely, CompletionConfig.sure_corr (0.7; min_lend_corr,
    # 0.7 as well, until 2026-12-08: measured on the evaluation set, seed 2027, a tuning set, with the rays' halfway level, 5bd7378:
    # recall 0.774 -> 0.779, wrong corners 2 -> 1, 64 frames) ...
    # ... or, under small_tag_px, where it keeps its own corners by min_tag_corr_local (no slip by one tag matching better). (Lending
    # asked the slip to be beaten by 0.3, min_lend_slip_margin, fbbf2d5, until 2026-12-08: at 0 the eight AprilGrid sets gained 6
    # corners, the defocused frames +9, the evaluation set's FoV rows -1, the photographed prints -2, no wrong corner.)
    # count of tags; origin: measured on the evaluation set (seed 2027; a tuning set): recall 0.827 -> 0.832 (200 frames), 0.855 -> 0.860
    # (64), no new wrong corner (f1b11a9)
    lend_depth: int = 3  # ... and on through unread tags beside it, up to this many tags away (1: beside it only)
    # (Until 2026-12-08 an unread tag's corner at a lattice's fringe kept its id within fringe_steps, 2, of a tag matched
    # by min_lend_corr, and corners within rim_strict_px, 8 px, of the rim needed a complete cell: off, neither changed a corner of the
    # eight AprilGrid sets but one, lost, on the evaluation set's motion blur row. Nor, since then, must a corner close its cell as a
    # parallelogram within 0.25 of its side, max_cell_misfit, or keep the side-to-gap ratio along its lattice lines within a factor 2,
    # max_side_gap_ratio: off, the first gained 16 corners over the eight sets, no wrong one, the second changed none. A corner in no
    # complete cell still needs a neighbour along each lattice axis.)
    # A corner's steps to its lattice neighbours leave along its own edge rays within GridConfig.seed_axis_angle (20 deg), as a grid
    # seed's first steps leave along its fitted edges (the tag pass's own max_ray_angle, 20 as well, until 2026-12-08: measured on the
    # evaluation set, seed 2027, a tuning set, the ray check took wrong corners 3 -> 0, 64 frames, 02e95a5; 25-30 deg there: +0.007
    # recall but a corner 4.1 px off, CHANGELOG 2026-11-24, later) ...
    # px; origin: measured on seeds 2027, 2031 and 2035 (tuning sets), with the wider angle below: FoV recall +0.004 each, no new wrong
    # corner; gaps up to 4 px brought wrong ones (d4c9e0e; the tuning log, step 7)
    small_gap_px: float = 3.5  # ... or, where its shortest lattice step is under this (tags under 12 px: no data junctions resolve) ...
    # ... within CompletionConfig.max_ray_angle (30 deg), the angle completion allows every corner it adds: on a circle of 1.5-1.75 px
    # the rays' angles are coarse (measured with small_gap_px, above: 40 or 90 deg brought wrong corners). It was a number of its own,
    # max_ray_angle_small, 30 as well, until 2026-12-08.
    # origin: measured on seeds 2027, 2031 and 2035 (tuning sets): FoV recall +0.004 / +0.004 / +0.001, no new wrong corner; up to 10 px
    # brought two wrong ones (e09fdfa; the tuning log, step 9); sampling: the smallest fit window (5 px) reaches across such a gap
    keep_unfitted_px: float = 6.0  # px: shortest lattice step under which a failed final fit keeps the lattice position
    # --- small frames ---
    # px; origin: measured on seeds 2042 and 2045 at 640x480, 2043 at 512x512, 2044 at 848x800 (tuning sets): enlarged, 0.782 -> 0.865,
    # 0.768 -> 0.795, 0.854 -> 0.876; 848x800 would gain 0.014 at 1.4x, 1280x720 0.023 at 1.5x (bicubic), with four corners given another's
    # id (a10566c; the tuning log, the tag pass's introduction)
    min_side_px: int = 720  # frames whose shorter side is under this are read enlarged to it (bilinear; 0: never) ...
    # unit: factor; origin: measured with min_side_px on the same sets (640x480 needs 1.5 to reach 720); bicubic: 0.869 / 0.802 but four
    # corners given a neighbour's id on seed 2045 (CHANGELOG 2026-11-25, later)
    max_enlarge: float = 1.5  # ... by at most this factor; the thresholds above that judge a tag's size in px scale with it
    # --- blurred and large tags ---
    # A frame not read enlarged (min_side_px) where under half the board's corners are found is read at half resolution too. Measured
    # with 70 of Kalibr's 144 (half_below, until 2026-12-08) on seed 2041 at 1920x1080 blurred 2.5 px (a tuning set): 0.650 under 70,
    # 0.686 run in every frame, which also gives 0.927 on the evaluation set's FoV rows, for 45 ms more on every frame (c9e4ec8; the
    # tuning log, "Limits of the tag pass"); at half the board (72) the eight AprilGrid sets gained 2 corners, nothing else changed.
    half_resolution: bool = True  # (False: never)
    # --- boards ---
    complete: CompletionConfig = field(default_factory=CompletionConfig)  # corners the growth missed, predicted from the placed board
    # The grid pass's settings the tag pass shares: saddle fit, final positions, min_rim_px, merge_radius_px, lens_fov, retry_gain_sigma,
    # agree_radius, crowd_radius, max_seeds, min_corners
    grid: GridConfig = field(default_factory=GridConfig)


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
    look: str = "first"  # the look of the retry schedule that found them (cotrain.detect.retries)
