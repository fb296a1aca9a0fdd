"""Every threshold of the detector's grid pass, in one dataclass.

The stages (:mod:`cotrain.detect.saddle`, :mod:`cotrain.detect.lattice`,
:mod:`cotrain.detect.identity`, :mod:`cotrain.detect.grid_pass`) read their numbers from here;
docs/detector.md says what each group decides; the detector's tuning log (CHANGELOG.md) where
each one comes from. Lengths called "steps" are lattice steps in image pixels (the distance to
the neighbouring corner); "squares" are a square's smaller side.
"""

from __future__ import annotations

from dataclasses import dataclass

# unit: factor (contrast about the local mean); origin: measured at 3 only, on the independent renderer's photographed prints (foreign
# --photo, seed 5; a tuning set, sets.FOREIGN_TUNING): 0.749 -> 0.898, and on the eight sets: 14 frames more, no wrong corner (1b3f4f3; the
# tuning log, "Known limits"); TagConfig.retry_gain's value
GREY_PRINT_GAIN = 3.0  # GridConfig.retry_gain of cotrain detect --grey-print (and of the evaluations' '--grey-print' rows)


@dataclass
class GridConfig:
    # Above each number: its unit (where the line does not say it) and its origin. Sets as calib_eval/detection/sets.py names them, all
    # tuning sets: "the evaluation set" is seed 2026 at 1280x720; "the six sets" it, seeds 7 and 11 (1280x720) and seed 2026's frames at
    # 640x480, 1024x1024 and 1920x1080 (drawn before 2026-12-07); "the seven sets" seeds 2026, 7, 11, 41, 53 (1280x720), 31 (1024x768) and
    # 67 (1920x1080); "the eight sets" those and seed 71 at 640x480; "the eleven sets" the tuning log's 2,041 frames (the evaluation set,
    # seeds 7, 11, 31, 97, 99 at five sizes, and the independent renderer's three, sets.FOREIGN_TUNING). "The tuning log":
    # CHANGELOG.md's section of that name. "Not recorded": no figure found for the value.
    # --- region and candidates (grid_pass, saddle) ---
    # origin: not recorded (set in 5c3691a, "Detector grid pass: ..."; named so in 0e9879c)
    region_threshold: float = 0.3  # corner-score or board-mask probability of a 1/4 cell that puts it in the searched region
    # unit: count of 1/4-resolution map cells; origin: not recorded (set in 5c3691a, "Detector grid pass: ...", as a 5 x 5 dilation)
    region_grow_cells: int = 2  # the searched region is grown by this many 1/4 cells
    # px; origin: not recorded (set in 4429f82, "Grid pass: vectorised saddle fit, ROI via warpAffine, work on the crop around the board")
    crop_pad_px: int = 12  # the full-resolution work happens on the region's bounding box grown by this
    # unit: count; origin: not recorded (set in 5c3691a, "Detector grid pass: ...")
    max_candidates: int = 600  # strongest saddle-response maxima kept as candidates
    # unit: -det Hessian x sigma^4 of the [0, 1] image (sigma 1.5 px); origin: not recorded (set in 5c3691a, "Detector grid pass: ...");
    # scaled with the region's contrast it lost a board for every two gained on grey prints (307613b)
    min_response: float = 0.002  # saddle response (scale-normalised -det Hessian) a candidate needs
    # unit: intensity in [0, 1]; origin: measured on the evaluation set, seeds 7 and 11, at this value only (307613b): low-contrast rows
    # 0.759 -> 0.794 / 0.903 -> 0.905 / 0.863 -> 0.917, no wrong id added
    board_contrast: float = 0.5  # contrast thresholds hold for a region this contrasted (5-95th pct), scale down below (0: off)
    # (Seeds rank by saddle response x the network's corner score. A floor of 0.05 was added to the score, seed_score_floor, not
    # recorded, 5c3691a, until 2026-12-08: without it no row of the kept checkerboard sets changed.)
    # origin: not recorded (set in 5c3691a, "Detector grid pass: ...")
    merge_radius_px: float = 1.0  # candidates (or a candidate and a lattice corner) this close are one saddle
    # --- saddle fit (saddle) ---
    # origin: not recorded (set in 5c3691a, "Detector grid pass: ..."); 0.015 in completion was tried (CHANGELOG, twentieth session): 232
    # more photographed AprilGrid corners, 0.46 px from their labels on median
    min_saddle_contrast: float = 0.04  # |eigenvalue| of the fitted quadratic * half^2 (intensity units) a saddle needs
    # unit: ratio of the |eigenvalues|; origin: not recorded (set in 5c3691a, "Detector grid pass: ...")
    min_saddle_ratio: float = 0.03  # smaller / larger |eigenvalue|: below this the fit is an edge, not an X
    # unit: correlation (-1 .. 1); origin: not recorded (set in 1169bd2, "Grid pass: stricter X-junction symmetry (0.65) drops
    # half-occluded corners"); 0.3 for the tag pass's final fits was tried (CHANGELOG 2026-11-24): tiny tags' corners slid a gap over
    # (3.1-3.3 px) kept their ids
    min_symmetry: float = 0.65  # correlation of the window with itself turned 180 deg (X-junctions are point-symmetric)
    # origin: not recorded (set in a94aa89, "Grid pass: corners next to the image circle's rim and the image border are fitted from the
    # part of the window that is seen ...")
    min_symmetric_share: float = 0.3  # share of window pixels seen on both sides of the 180 deg turn the symmetry test needs
    # px; origin: not recorded (set in a94aa89, "Grid pass: corners next to the image circle's rim and the image border are fitted from
    # the part of the window that is seen ...")
    min_rim_px: float = 3.0  # corners closer than this to the image circle's dark rim or the image border are not reported
    # --- lattice growth (lattice.grow_lattice) ---
    # origin: not recorded (set in 5c3691a, "Detector grid pass: ...")
    seed_axis_angle: float = 20.0  # deg: a seed's first neighbours lie within this of its fitted edge directions (else seed_bend_*)
    # origin: measured on the six sets (8866c5c): +108 corners, no new wrong one (seed 11 large squares 0.680 -> 0.717, seed 7 strong
    # vignetting 0.790 -> 0.833); this angle taken first lost 0.003-0.009 of the FoV rows
    seed_bend_angle: float = 35.0  # deg: where none does, the nearest at seed_bend_px or farther within this (0: off)
    # origin: measured on the six sets with seed_bend_angle (8866c5c): the wider angle at every distance lost 0.003-0.009 of the FoV rows
    seed_bend_px: float = 40.0  # px: ... (the sides of large squares near a fisheye's rim bend by tens of degrees between corners)
    # (A seed's two steps had to be 11.5 deg apart, min_seed_axes_sin 0.2, until 2026-12-08: at 0 no row of the kept
    # checkerboard sets changed. Exactly parallel ones, both edge directions finding the same neighbour, still go; so judged too.)
    # unit: fraction of (step a +- step b); origin: not recorded (set in 5c3691a, "Detector grid pass: ...")
    diag_offset: float = 0.3  # colour test samples the four quadrants this fraction of (step a +- step b) from the corner
    # (A seed needed a quadrant contrast of 0.05, min_seed_contrast, until 2026-12-08: at 0 four rows of the kept
    # checkerboard sets gained a corner each, no wrong one; its colours must still alternate as the growth goes.)
    # unit: share of the parent's quadrant contrast; origin: not recorded (set in 5c3691a, "Detector grid pass: ...")
    min_alternation: float = 0.25  # a new corner's quadrant contrast must flip sign with at least this share of its parent's
    # unit: fraction of the step; origin: not recorded (set with the edge test in 4e02862, "Grid pass: lattice growth follows squares that
    # grow or shrink fast ...")
    step_edge_depth: float = 0.15  # a step's edge test samples this fraction of the step (or of the step across, if shorter) to either side
    # unit: share of the parent's quadrant contrast; origin: measured on the evaluation set, at this value only (4e02862): the edge test
    # took the motion-blur row's 8 wrong corners to 0
    min_step_edge_contrast: float = 0.15  # ... and needs this share of the parent's quadrant contrast at 1/4, 1/2 and 3/4 of the step
    # Squares from this size on are large: the lens bends their sides between corners, and their X-junctions survive motion blur. Read
    # by the edge walk and the steps measured anew (remeasure_steps, below), the board going on (board_goes_on) and margin evidence
    # along the predicted step (edge_predict); the walk, the board going on and the predicted step had each its own 15 until the
    # thirtieth session.
    # px (a square's smaller side, or the step out); origin: measured three times at this value only: the walk on the evaluation set,
    # seeds 7 and 11 (4e02862, with the edge test and the scaled step across): large squares at the rim 0.632 -> 0.749 / 0.549 -> 0.636 /
    # 0.635 -> 0.671; the board going on on seed 31 at 640x480 (0829808): without the floor a motion-blurred board was placed wrongly (12
    # px squares smeared into junctions in the margin); the predicted step on seed 2026's frames at 640x480 (drawn before 2026-12-07;
    # 0a4d9a1): with motion blur a prediction from blurred corners under 15 px placed a board wrongly, and the rule took the evaluation
    # set's large squares 0.811 -> 0.840
    large_square_px: float = 15.0  # where a prediction finds nothing in squares this large, the edge leaving the corner is followed ...
    # unit: predicted steps; origin: not recorded (set with the walk in 4e02862, "Grid pass: lattice growth follows squares that grow or
    # shrink fast ..."; one range 0.4-1.6 until c6caa6a)
    walk_min_steps: float = 0.4  # ... to the nearest candidate at least this many predicted steps away ...
    # unit: predicted steps; origin: not recorded (set with the walk in 4e02862, "Grid pass: lattice growth follows squares that grow or
    # shrink fast ...")
    walk_max_steps: float = 1.6  # ... and at most this many ...
    # origin: not recorded (set with the walk in 4e02862, "Grid pass: lattice growth follows squares that grow or shrink fast ...");
    # the window binds: the board going on's 0.5-1.8 steps within 25 deg for the walk too lost up to 0.054 of a row (the evaluation
    # set's large squares at the rim 0.9126 -> 0.8582) and added a wrong corner (2026-12-08); the board going on looks in it too
    walk_angle: float = 30.0  # ... within this (deg) of the predicted direction ...
    # ... with one of its own edge directions within seed_axis_angle of the step (the seed's test; a number of its own, 20 deg too,
    # until 2026-12-07: walk_axis_angle, not recorded, set with the walk in 4e02862)
    # A saddle search where no candidate was predicted needs the colours there alternating by min_alternation (above) already: set in
    # 4627ba0 at 0.15 of its own, fill_min_alternation, until 2026-12-08 (the evaluation set and the real BoofCV frames: the same corners;
    # the searches it skips, most of the growth's time, found none); at min_alternation's 0.25 no row of the kept checkerboard sets
    # changed.
    remeasure_steps: bool = True  # a corner's steps (large_square_px or more) are measured to its neighbours placed by the time it grows
    # unit: fraction of the step; origin: not recorded (set in 5c3691a, "Detector grid pass: ...")
    match_radius: float = 0.45  # a neighbour must lie within this fraction of the grid step of its prediction
    # unit: fraction of the step; origin: not recorded (set in 5c3691a, "Detector grid pass: ...")
    agree_radius: float = 0.3  # predictions of one corner from different neighbours must agree within this fraction of a step
    # unit: ratio to the predicted step; origin: not recorded (set in 5c3691a, "Detector grid pass: ...")
    min_step_ratio: float = 0.5  # a new step may be this much shorter than its prediction ...
    # unit: ratio to the predicted step; origin: not recorded (set in 5c3691a, "Detector grid pass: ...")
    max_step_ratio: float = 2.0  # ... or this much longer
    # origin: not recorded (set in 33db735, "Grid pass: a new corner is refused as a duplicate only within half the square's smaller side
    # ...")
    crowd_radius: float = 0.5  # a new corner this close (fraction of the square's smaller side) to a placed one is refused
    # unit: multiple of min_step_px (10.5 px); origin: not recorded (set in 134e25b, "Grid pass: a new corner is refused as a duplicate
    # ...; small squares keep the step-length rule")
    crowd_small_factor: float = 1.5  # in squares under this x min_step_px the crowding is measured against the step instead
    # px; origin: not recorded (set in 802bb1b, "Grid pass: ...; squares under 7 px not grown into; ...", was 4.5); the evaluation counts
    # squares of 10 px and more as detectable (docs/training.md)
    min_step_px: float = 7.0  # no growth into squares smaller than this (saddles of tinier squares are unreliable)
    # --- verification and positions (lattice) ---
    # unit: fraction of half the neighbours' distance; origin: not recorded (set in 802bb1b, "Grid pass: rim distance, lattice-line check
    # and largest component in the verification; ...")
    max_line_offset: float = 0.4  # a corner may miss the midpoint of its two neighbours on a line by this fraction of half their distance
    # unit: ratio of a square's sides; origin: not recorded (set in c7e064b, "Grid pass: verification refits corners of very oblique
    # squares (sides over 2:1) with a smaller window ...")
    oblique_ratio: float = 2.0  # squares with sides over this ratio are "oblique": a failed refit is retried with a smaller window
    # unit: fraction of the square's smaller side; origin: not recorded (set in 5c3691a, "Detector grid pass: ...")
    # (the final refit of the reported positions too: it had its own max_final_shift, 0.15 as well, until 2026-12-07; not recorded,
    # set in 67077f0, "Detector: other checkerboards ...; ... the reported positions refitted within 3 px ...")
    max_refit_shift: float = 0.15  # a verifying or final refit must land within this fraction of the square on the corner
    # A corner fitted in a window cut by the rim must have its edges along the lattice lines within seed_axis_angle (20 deg), as a
    # seed's first steps must. (It had 15 deg of its own, max_rim_edge_angle, set in a94aa89 without a figure, until 2026-12-08: at 20
    # the kept checkerboard sets gained 88 corners over 36 rows, no row lost one, no wrong corner; 30 deg took +186 corners with 23
    # wrong on the seven sets of e17c0e8, a whole board among them) ...
    # ... but not where only the image's border cuts it (no dark rim in reach to make a half X): true corners 5-10 px from the frame's
    # top or bottom edge fit their edges 15-25 deg off (e17c0e8). It was held to 30 deg there (max_border_edge_angle) until 2026-12-08:
    # without that, four rows of the kept checkerboard sets gained a corner or two, no wrong one.
    # ... and along an axis without a neighbour, the axis a neighbour across measures, within the same angle (set in 8a49be6, "Grid
    # pass: join parts of one lattice before the placement; rim-cut tips need both edge directions", with 30 deg of its own,
    # rim_borrowed_angle, not recorded, until 2026-12-08: at the rim's 15 then the kept checkerboard sets lost 18 corners of 14 rows,
    # none by over 0.004, and 24 wrong ones, a whole board on seed 7's 1920x1080 strong vignetting)
    rim_borrowed_axes: bool = True  # (False: the rule off)
    # unit: share of the lattice's steps (cells); origin: not recorded (set in caa7962, "Grid pass: drop lattices grown with skipped
    # corners ...")
    max_skipped: float = 0.3  # share of lattice steps (cells) with an X-junction at the midpoint (centre) that drops a lattice
    # unit: ratio of saddle responses; origin: not recorded (set in caa7962, "Grid pass: drop lattices grown with skipped corners ...")
    skip_response_ratio: float = 0.5  # a midpoint (centre) is an X-junction when its response exceeds this x that of the weakest end
    # origin: measured on the real BoofCV frames (../shared/real, 26 frames; not rendered): calibration RMS 0.47 px with windows up to 8,
    # 0.35 up to 5, 0.31 with this final fit (ucm; OpenCV's corners 0.31); on half the evaluation set the median error 0.061 -> 0.043 px
    # (67077f0)
    final_max_half: int = 3  # px: largest fit window half-size for the reported positions (see refine_positions)
    # --- which lattice is a board (grid_pass) ---
    # unit: count; origin: not recorded (set in 5c3691a, "Detector grid pass: ..."); the tag pass's own was 4 (one tag) until the
    # thirtieth session: at 6 no row of the eight AprilGrid sets changed
    min_corners: int = 6  # smallest lattice that is reported (both passes)
    # A reported lattice needs a complete square (four corners; lines of corners along a diagonal are not lattices). It needed two,
    # min_cells, set in 54ef7eb, until 2026-12-08: at 0 (so at 1 too) no row of the kept checkerboard sets changed.
    # (A lattice needed a mean board probability of 0.3 at its corners, min_board_prob, until 2026-12-08: at 0 the
    # independent renderer's photographed prints went 0.7501 -> 0.7858, no wrong corner, and no other kept row changed.)
    # unit: count; origin: measured on the six sets (614b101): 12 -> 16 took the evaluation set's under-exposed row 0.853 -> 0.891 and
    # seed 11's FoV rows 0.8957 -> 0.8975 for about 0.5 ms; 24 placed 3 wrong corners in a motion-blurred frame. The tag pass's own was
    # 40 until the thirtieth session: at 16 no row of the eight AprilGrid sets changed (it counts the lattices it grows, the grid pass
    # the seeds it tries)
    max_seeds: int = 16  # the growths a frame gets, best seeds first (the tag pass: strongest responses, covered candidates not tried)
    # --- identity (identity) ---
    # origin: not recorded (set in 6b100e9, "Grid pass: column/row votes averaged over the corner and its four quarter-square points")
    vote_offset: float = 0.25  # network votes are also read this fraction of a step along both lattice axes (the diagonals)
    # unit: nats per cell; origin: not recorded (set in 5c3691a, "Detector grid pass: ...")
    parity_weight: float = 2.0  # log-likelihood per lattice cell whose checker colour agrees with a placement
    # origin: measured on seed 7 (1280x720): tuned to 18 (its wrong placements up to 16.1 nats, seed 11's 19.2); raised to 25 when the
    # evaluation set showed one at 22.2 (2f0a606): 25 keeps 0.02 % wrong on the three, 22 0.47 % on the evaluation set (the tuning log,
    # "How the thresholds were chosen")
    min_margin: float = 25.0  # the best placement must beat the runner-up by this (nats) to be reported ...
    # unit: nats; origin: measured on the eight sets (2ea4b05): 15 -> 9, +179 corners, none wrong or lost (evaluation FoV 240 0.8888 ->
    # 0.9004); the votes lean against by up to 6 (over_exposed_020: 9.7, geometry 15.0); seeds 7, 11, 2026 degraded (JPEG, blur): the same
    # wrong corners as at 15
    min_margin_backed: float = 9.0  # ... or by this, where the geometry alone (no network votes) puts it ahead ...
    # unit: nats; origin: measured on the evaluation set (ca12683, read off its placements): its wrong ones at 12-25 nats had a geometry
    # margin of 0, one at 7.2 nats had 15; seeds 7 / 11: +70 / 0 corners, none wrong; 15.5 lost 64 right corners over the eleven sets
    # (CHANGELOG, twenty-fourth session)
    min_geometry_margin: float = 15.0  # ... by this much (colours, margin evidence, extent; see identity.Placement)
    # Where the geometry cannot tell the placement from another, nothing is reported (False), however sure the network's votes: on
    # seeds 11 and 53 (1280x720) and seed 2026 at 640x480 the votes alone placed boards wrongly at 27.7, 32.4 and 35.2 nats, right
    # ones at 35.6 and 36.0, so no threshold separates them (30, 35, then off: 39f6d1a, 87ccd6d, f548109; the threshold and its
    # per-corner companion went in the thirtieth session, CHANGELOG). True: the votes alone place a board by min_margin, as
    # calib_eval.detection.tuning scores every placement.
    votes_alone: bool = False
    # unit: nats; origin: not recorded (set in 0cd3a4e, "Grid pass: the board's white margin as identity evidence, off-board penalty,
    # conservative margin ..."; was -7)
    logp_floor: float = -3.0  # network log-probabilities are clamped here (one corner cannot veto a board)
    # unit: nats per corner; origin: measured on the seven sets with the votes alone off (f548109): 10 -> 15, +304 / -88 corners, 19 wrong
    # corners fewer and 1 more; 15 so that one corner backs a placement as min_geometry_margin asks
    offboard_penalty: float = 15.0  # per lattice corner a placement puts off the board (verified X-junctions: one is min_geometry_margin)
    # unit: nats per corner; origin: not recorded (set in 1ca7ed5, "Grid pass: margin probe at 1.15 steps ..., margin evidence weight 8";
    # was 5)
    edge_weight: float = 8.0  # per lattice corner whose outward neighbour is the board's white margin
    # origin: not recorded (set in 0cd3a4e, "Grid pass: the board's white margin as identity evidence, off-board penalty, conservative
    # margin ...")
    min_edge_contrast: float = 0.1  # intensity difference of the two outward profiles half a step out that margin evidence needs
    # origin: not recorded (set in d242238, "Grid pass: margin evidence from two outward profiles (the square row's end ... 0.7-1.6 steps
    # out; ...)")
    edge_end_min: float = 0.7  # steps out: the last squares must end (both profiles turn white) no closer than this ...
    # unit: steps; origin: not recorded (set in d242238, "Grid pass: margin evidence from two outward profiles (the square row's end ...
    # 0.7-1.6 steps out; ...)"); 2.0-2.5 tried: no change (CHANGELOG 2026-11-24, late morning)
    edge_end_max: float = 1.6  # ... and no farther
    # Where the step out is large_square_px long at least, there is no margin evidence where a candidate X-junction lies where the
    # walk looks for the next corner (walk_min_steps to walk_max_steps predicted steps out, within walk_angle of the step) ... (The
    # rule was set in 0829808, "Margin evidence is void where the board visibly goes on ...", for seed 31's frame 9 at 1920x1080: a
    # board half a turn wrong, 21 wrong ids; its window had numbers of its own until 2026-12-08, 0.5-1.8 steps within 25 deg, not
    # recorded as values: with the walk's no row of the kept checkerboard sets changed.)
    # origin: not recorded as a value (set in 0829808, with the rule)
    goes_on_min_contrast: float = 0.4  # ... with a checker edge to it (one side brighter by this share of the squares' contrast) ...
    # unit: share of the corner's quadrant contrast; origin: measured on seed 31 at 1920x1080 (frame 9; 0829808): 0.25 fixed a glare frame
    # too but voided true evidence where a square's side meets the margin (its colours flip by half; a test)
    goes_on_min_alternation: float = 0.7  # ... and its quadrant contrast flipped with this share of the corner's
    # Margin evidence reads along the predicted next step where that is large_square_px long (else along the last step).
    # unit: steps; origin: measured on the evaluation set (CHANGELOG 2026-11-24, late morning): a band at 0.05-0.15 took large squares
    # 0.778 -> 0.807 but the FoV rows 0.895 -> 0.890; set in d242238 without a figure
    margin_band_start: float = 0.1  # steps beyond the squares' end where the white margin is sampled ...
    # unit: steps; origin: measured on the evaluation set, with margin_band_start (above)
    margin_band_end: float = 0.25  # ... up to here, at least half-way to white ...
    # unit: share of the squares' contrast; origin: measured on seed 97 (1280x720; 47d8a33): a light occluder read as margin placed a
    # 36-corner board half a turn and a row off at 58 nats; at 0.5 it goes (35 wrong corners fewer, 1 right lost), the eight sets
    # unchanged
    margin_max_brighter: float = 0.5  # ... and not brighter than the white squares by over this much of their contrast (paper)
    # origin: not recorded (set in 44965a3, "Grid pass rejects a lattice whose board edges contradict the target's size; ...")
    max_violated_edges: float = 2.5  # margin evidence (corners' worth) a placement may contradict before the lattice is rejected
    # unit: share of the lattice's margin evidence; origin: not recorded (set in 44965a3, "Grid pass rejects a lattice whose board edges
    # contradict the target's size; ...")
    max_violated_share: float = 0.35  # ... or this share of all the lattice's margin evidence, when that is more
    cut_at_margins: bool = True  # a lattice so rejected, or placed unsurely, is placed again cut at a line of margin evidence ...
    # origin: measured on the seven sets, at this value only (6053f32): the cut took +80 corners in 4 frames, none lost, no new wrong one
    # (evaluation glare 0.874 -> 0.924)
    cut_min_evidence: float = 0.5  # ... with this much evidence (corners' worth) along it
    # ... and a part is taken only where its placement adds evidence to the whole lattice's (grid_pass.cut_adds_evidence; no number):
    # measured on the eight tuning sets of docs/results/cut_parts.md, 17 wrong ids -> 0 and no other change
    cut_needs_evidence: bool = True
    join_lattices: bool = True  # lattices of other seeds that share corners under one turn and offset are joined before the placement
    merge_lattices: bool = True  # join the corners of other surely placed lattices that agree with the best one
    # unit: count; origin: geometry (two shared corners are the fewest that fix the turn and offset of one lattice onto the other; at 1
    # no row of the kept checkerboard sets changed on 2026-12-08, but a join would take an arbitrary turn) and measured at this value:
    # merges took the evaluation set's FoV rows 0.8949 -> 0.8956, large squares 0.778 -> 0.797 (acbea97); joins seed 7's 0.8940 -> 0.8993,
    # seed 11's 0.8947 -> 0.8957 (8a49be6); no new wrong corner
    merge_min_shared: int = 2  # lattices join (either way) where they share this many corners (spots, and coordinates or ids)
    # (A joined corner had to lie 3 px from every corner there, merge_crowd_px, until 2026-12-08: at 0 no row of the kept
    # checkerboard sets changed; a corner not at a shared spot lies merge_radius_px away at least.)
    # unit: factor on the confidence; origin: not recorded (set in 5c3691a, "Detector grid pass: ...")
    filled_confidence: float = 0.9  # confidence factor of corners found by a saddle search, not among the candidates
    # --- blurred and large squares (detector) ---
    # A frame where no board is found is read at half resolution too (False: never; at any size: the growth's min_step_px keeps squares
    # too small at half resolution out) ... Measured on the evaluation set (771ed0f; the tuning log, step 8): about 4 ms a frame (58.8
    # against 54.6 ms), seeds 7 / 11 motion blur 0.481 -> 0.614 / 0.426 -> 0.795; read under 60 corners found, not only none: motion
    # blur 0.62 -> 0.70, glare 0.81 -> 0.85, for 18 ms a frame (the count was GridConfig.half_below, 1, until the thirtieth session, with
    # half_min_shared 4 for the case of corners found at both resolutions, inert at 1)
    half_resolution: bool = True
    # unit: share of the map's cells; origin: measured on the five kept sets of 2026-11-25 (seeds 2026, 7, 11 at 1280x720, the 1920x1080
    # and 1024x1024 ones; 2a4ec01): the 15 boards this pass gave had 105 cells or more (2 %); frames under 20 (0.4 %), 40-57 % of those
    # read again, skipped for 0.8-2.5 ms a frame with the same corners
    half_min_board_share: float = (
        0.004  # ... and the network's board map is over 0.5 on this share of its cells (a board too small for it gains nothing) ...
    )
    # unit: nats; origin: measured on the seven sets (038a44a): 60 -> 25, the 16 boards only this pass found (28-189 nats) had every id
    # right, 8 frames gained (evaluation FoV 220 0.885 -> 0.894); min_margin's value
    half_min_margin_alone: float = 25.0  # ... and its board taken at this identity margin (min_margin's value)
    # A corner only the half-resolution pass finds matches its print by the print check's CompletionConfig.min_corr (0.5; it was
    # half_min_corr, a copy of that value, until 2026-12-08) ...
    # origin: not recorded (set in 771ed0f, "Checkerboard: a frame where the grid pass finds no board is read again at half resolution
    # ...")
    half_rim_px: float = 12.0  # ... and lies this far from the image circle's rim (px)
    # --- grey prints (detector): a frame giving nothing read again (network too) with its contrast raised about its local mean ---
    # unit: factor; origin: code/table, not a threshold (0: off by default; at GREY_PRINT_GAIN the evaluation set's bench frames took 23.5
    # -> 50.8 ms over files, 1b3f4f3)
    retry_gain: float = 0.0  # by this factor (<= 1: never; cotrain detect --grey-print: GREY_PRINT_GAIN; ~40 ms a frame giving nothing)
    # unit: share of the shorter side; origin: not recorded (set in 1b3f4f3, "Photographed prints: ...; cotrain detect --grey-print does
    # the same for the checkerboard ..."); the tag pass's raised contrast uses it too (TagConfig.grid.retry_gain_sigma)
    retry_gain_sigma: float = 0.028  # the local mean's Gaussian sigma, as a share of the frame's shorter side (20 px at 720)
    # unit: nats; origin: measured on the evaluation set (1b3f4f3; the tuning log, "Known limits"): with the votes deciding too, a board
    # cut by two occluders was placed half a turn wrong
    retry_min_margin: float = float("inf")  # min_margin on the raised frame (inf: placements by the network's votes not reported)
    # unit: nats; origin: not recorded (set in 1b3f4f3, "Photographed prints: ...; cotrain detect --grey-print does the same for the
    # checkerboard ..."); at 20 the eight sets found 14 frames more, no wrong corner
    retry_min_geometry_margin: float = 20.0  # min_geometry_margin on the raised frame: the geometry must put a board this far ahead
    # --- completion of a placed board ---
    # unit: fraction of the square's smaller side; origin: measured on the seven sets and a 640x480 one, at this value only (e56a15a,
    # 157f341): wrong corners 16 -> 5 (seed 41's 8 all gone), 9 right ones of 46,000 lost and 2 gained
    # (0: no check.) Its nearest identified ones are the CompletionConfig.neighbours (7) nearest on the board, as completion's (a copy,
    # misfit_neighbours, set in e56a15a, until 2026-12-08); verification.neighbour_check; completion may find it again.
    max_neighbour_misfit: float = 0.2  # a placed corner this far (of its square) from where its nearest identified ones put it goes ...
    # unit: share of the board's corners; origin: measured on the seven sets and a 640x480 one (157f341): frames missing over a sixth read
    # 0.18 (5 of 6 misses wrong), then 0.23-0.96 (all right); at 0.15 (e56a15a) seed 41's frame of 5 wrong corners (18 % missing) went
    # unchecked
    max_misfit_share: float = 0.2  # ... unless more of the board's corners miss: then the maps are off (no lens guessed, a bend), not they
    # ... then the worst goes where it misses by over max_refit_shift (0.15 of its square: as far as a refit may move a corner) and
    # another too, by half as much without it (worst_neighbour_misfit, 0.15 as well, until 2026-12-08: measured on the eight sets,
    # 1ed5ebf: it took out the two corners 3 px or more off, evaluation under-exposed and motion blur, nothing else; without the
    # half-as-much condition also 12 right ones) ...
    # unit: count; origin: not recorded (set in 1ed5ebf, "Neighbour check: the worst corner goes where it bends another's map ...")
    worst_misfit_rounds: int = 3  # ... at most this many times (a wrong corner at a row's end bends its neighbour's map: both near 0.2)
    # Completed corners lie min_rim_px from the image circle's rim or the crop's edge at least (its own number until 2026-12-07,
    # 3 px: measured on the seven sets, 05a8f70: 8 -> 3, +116 corners, none lost, median error 0.09 px; the growth's own 3-5 px from
    # the rim: 0.12).
    # The corners the growth missed are predicted from the identified ones (stage 5, completion), round by round until one adds no
    # corner (CompletionConfig.rounds), as in the tag pass (the grid pass had its own cap of 8 until the thirtieth session; without it,
    # on every kept set: seed 2026 at 640x480 glare 0.8920 -> 0.8944, no other row changed) ...
    completion: bool = True
    # ... matching the print around them surely (CompletionConfig.sure_corr, 0.7; complete_min_corr, 0.7 too, until 2026-12-08: measured
    # on seven rendered sets of 2026-11-25, the evaluation set among them, be2d8e0: at 0.5, without the edge rays and 3 px from the rim,
    # 2-4 more wrong corners a set, at occluders' edges, 1.4-2.7 px off), their edge rays along the axes ...
    # unit: deg; origin: measured on the AprilGrid evaluation set (seed 2027, 1280x720; a tuning set): 190, 210 and 230 deg give the same
    # recall within 0.001 (11e1eb1); the tag pass reads its tags through the same lens (TagConfig.grid.lens_fov)
    lens_fov: float = 210.0  # ... through an equidistant lens of this FoV filling the image circle, where one shows (0: pixel homographies)
