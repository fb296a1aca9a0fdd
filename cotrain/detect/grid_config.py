"""Every threshold of the detector's grid pass, in one dataclass.

The stages (:mod:`cotrain.detect.saddle`, :mod:`cotrain.detect.lattice`,
:mod:`cotrain.detect.identity`, :mod:`cotrain.detect.grid_pass`) read their numbers from here;
docs/detector.md says what each group decides; the detector's tuning log (CHANGELOG.md) where
each one comes from. Lengths called "steps" are lattice steps in image pixels (the distance to
the neighbouring corner); "squares" are a square's smaller side.
"""

from __future__ import annotations

from dataclasses import dataclass

GREY_PRINT_GAIN = 3.0  # GridConfig.retry_gain of cotrain detect --grey-print (and of the evaluations' '--grey-print' rows)


@dataclass
class GridConfig:
    # --- region and candidates (grid_pass, saddle) ---
    region_threshold: float = 0.3  # corner-score or board-mask probability of a 1/4 cell that puts it in the searched region
    region_grow_cells: int = 2  # the searched region is grown by this many 1/4 cells
    crop_pad_px: int = 12  # the full-resolution work happens on the region's bounding box grown by this
    max_candidates: int = 600  # strongest saddle-response maxima kept as candidates
    min_response: float = 0.002  # saddle response (scale-normalised -det Hessian) a candidate needs
    board_contrast: float = 0.5  # contrast thresholds hold for a region this contrasted (5-95th pct), scale down below (0: off)
    seed_score_floor: float = 0.05  # added to the network's corner score when ranking seeds (response x score)
    merge_radius_px: float = 1.0  # candidates (or a candidate and a lattice corner) this close are one saddle
    # --- saddle fit (saddle) ---
    min_saddle_contrast: float = 0.04  # |eigenvalue| of the fitted quadratic * half^2 (intensity units) a saddle needs
    min_saddle_ratio: float = 0.03  # smaller / larger |eigenvalue|: below this the fit is an edge, not an X
    min_symmetry: float = 0.65  # correlation of the window with itself turned 180 deg (X-junctions are point-symmetric)
    min_symmetric_share: float = 0.3  # share of window pixels seen on both sides of the 180 deg turn the symmetry test needs
    min_rim_px: float = 3.0  # corners closer than this to the image circle's dark rim or the image border are not reported
    # --- lattice growth (lattice.grow_lattice) ---
    seed_axis_angle: float = 20.0  # deg: a seed's first neighbours lie within this of its fitted edge directions (else seed_bend_*)
    seed_bend_angle: float = 35.0  # deg: where none does, the nearest at seed_bend_px or farther within this (0: off)
    seed_bend_px: float = 40.0  # px: ... (the sides of large squares near a fisheye's rim bend by tens of degrees between corners)
    min_seed_axes_sin: float = 0.2  # |sin| of the angle between the seed's two steps (nearly parallel ones are no lattice)
    diag_offset: float = 0.3  # colour test samples the four quadrants this fraction of (step a +- step b) from the corner
    min_seed_contrast: float = 0.05  # |quadrant contrast| (intensity) the seed needs (see sampling.diag_contrast)
    min_alternation: float = 0.25  # a new corner's quadrant contrast must flip sign with at least this share of its parent's
    step_edge_depth: float = 0.15  # a step's edge test samples this fraction of the step (or of the step across, if shorter) to either side
    min_step_edge_contrast: float = 0.15  # ... and needs this share of the parent's quadrant contrast at 1/4, 1/2 and 3/4 of the step
    walk_min_square_px: float = 15.0  # where a prediction finds nothing in squares this large, the edge leaving the corner is followed ...
    walk_min_steps: float = 0.4  # ... to the nearest candidate at least this many predicted steps away ...
    walk_max_steps: float = 1.6  # ... and at most this many ...
    walk_angle: float = 30.0  # ... within this (deg) of the predicted direction ...
    walk_axis_angle: float = 20.0  # ... with one of its own edge directions within this (deg) of the step
    fill_min_alternation: float = 0.15  # a saddle search where no candidate was predicted needs colours alternating this much there
    remeasure_steps: bool = True  # a corner's steps (walk_min_square_px or more) are measured to its neighbours placed by the time it grows
    match_radius: float = 0.45  # a neighbour must lie within this fraction of the grid step of its prediction
    agree_radius: float = 0.3  # predictions of one corner from different neighbours must agree within this fraction of a step
    min_step_ratio: float = 0.5  # a new step may be this much shorter than its prediction ...
    max_step_ratio: float = 2.0  # ... or this much longer
    crowd_radius: float = 0.5  # a new corner this close (fraction of the square's smaller side) to a placed one is refused
    crowd_small_factor: float = 1.5  # in squares under this x min_step_px the crowding is measured against the step instead
    min_step_px: float = 7.0  # no growth into squares smaller than this (saddles of tinier squares are unreliable)
    # --- verification and positions (lattice) ---
    max_line_offset: float = 0.4  # a corner may miss the midpoint of its two neighbours on a line by this fraction of half their distance
    oblique_ratio: float = 2.0  # squares with sides over this ratio are "oblique": a failed refit is retried with a smaller window
    max_refit_shift: float = 0.15  # a verifying refit must land within this fraction of the square on the corner
    max_rim_edge_angle: float = 15.0  # deg: a corner fitted in a window cut by the rim must have its edges along the lattice lines
    max_border_edge_angle: float = 30.0  # deg: ... where only the image's border cuts it (no dark rim in reach to make a half X)
    rim_borrowed_angle: float = 30.0  # deg: ... and along an axis without a neighbour, the axis a neighbour across measures (0: off)
    max_skipped: float = 0.3  # share of lattice steps (cells) with an X-junction at the midpoint (centre) that drops a lattice
    skip_response_ratio: float = 0.5  # a midpoint (centre) is an X-junction when its response exceeds this x that of the weakest end
    final_max_half: int = 3  # px: largest fit window half-size for the reported positions (see refine_positions)
    max_final_shift: float = 0.15  # the final refit may move a corner by at most this fraction of its square
    # --- which lattice is a board (grid_pass) ---
    min_corners: int = 6  # smallest lattice that is reported
    min_cells: int = 2  # complete lattice squares (four corners) a reported lattice needs
    min_board_prob: float = 0.3  # mean board probability (network mask) at a lattice's corners
    max_seeds: int = 16  # seeds tried (best corner scores first); the lattice with the surest identity wins
    # --- identity (identity) ---
    vote_offset: float = 0.25  # network votes are also read this fraction of a step along both lattice axes (the diagonals)
    parity_weight: float = 2.0  # log-likelihood per lattice cell whose checker colour agrees with a placement
    min_margin: float = 25.0  # the best placement must beat the runner-up by this (nats) to be reported ...
    min_margin_backed: float = 9.0  # ... or by this, where the geometry alone (no network votes) puts it ahead ...
    min_geometry_margin: float = 15.0  # ... by this much (colours, margin evidence, extent; see identity.Placement)
    # Where the geometry cannot tell the placement from another, the votes must win by this (inf: nothing is reported there).
    min_margin_votes_alone: float = float("inf")
    min_votes_per_corner: float = 1.2  # ... and by this much per lattice corner (a network biased on a whole view adds up with its size)
    logp_floor: float = -3.0  # network log-probabilities are clamped here (one corner cannot veto a board)
    offboard_penalty: float = 15.0  # per lattice corner a placement puts off the board (verified X-junctions: one is min_geometry_margin)
    edge_weight: float = 8.0  # per lattice corner whose outward neighbour is the board's white margin
    min_edge_contrast: float = 0.1  # intensity difference of the two outward profiles half a step out that margin evidence needs
    edge_end_min: float = 0.7  # steps out: the last squares must end (both profiles turn white) no closer than this ...
    edge_end_max: float = 1.6  # ... and no farther
    goes_on_min_step_px: float = 15.0  # where the step out is this long (px) at least, there is no margin evidence ...
    goes_on_min_steps: float = 0.5  # ... where a candidate X-junction lies this many predicted steps out ...
    goes_on_max_steps: float = 1.8  # ... up to this many ...
    goes_on_angle: float = 25.0  # ... within this (deg) of the step ...
    goes_on_min_contrast: float = 0.4  # ... with a checker edge to it (one side brighter by this share of the squares' contrast) ...
    goes_on_min_alternation: float = 0.7  # ... and its quadrant contrast flipped with this share of the corner's
    edge_predict_min_px: float = 15.0  # margin evidence reads along the predicted next step if this long (else the last step)
    margin_band_start: float = 0.1  # steps beyond the squares' end where the white margin is sampled ...
    margin_band_end: float = 0.25  # ... up to here, at least half-way to white ...
    margin_max_brighter: float = 0.5  # ... and not brighter than the white squares by over this much of their contrast (paper)
    max_violated_edges: float = 2.5  # margin evidence (corners' worth) a placement may contradict before the lattice is rejected
    max_violated_share: float = 0.35  # ... or this share of all the lattice's margin evidence, when that is more
    cut_at_margins: bool = True  # a lattice so rejected, or placed unsurely, is placed again cut at a line of margin evidence ...
    cut_min_evidence: float = 0.5  # ... with this much evidence (corners' worth) along it
    join_lattices: bool = True  # lattices of other seeds that share corners under one turn and offset are joined before the placement
    merge_lattices: bool = True  # join the corners of other surely placed lattices that agree with the best one
    merge_min_shared: int = 2  # lattices join (either way) where they share this many corners (spots, and coordinates or ids)
    merge_crowd_px: float = 3.0  # a joined corner must lie this far from every corner there (join_lattices: else no join at all)
    filled_confidence: float = 0.9  # confidence factor of corners found by a saddle search, not among the candidates
    # --- blurred and large squares (detector) ---
    # A frame where fewer corners are found is read at half resolution too (0: never; 1: where no board
    # is found; at any size: the growth's min_step_px keeps squares too small at half resolution out) ...
    half_below: int = 1
    half_min_board_share: float = (
        0.004  # ... and the network's board map is over 0.5 on this share of its cells (a board too small for it gains nothing) ...
    )
    half_min_shared: int = 4  # ... and taken where both find this many corners at the same places ...
    half_min_margin_alone: float = 25.0  # ... or where only the half-resolution pass finds a board, with this identity margin (min_margin)
    half_min_corr: float = 0.5  # a corner only the half-resolution pass finds must correlate with its print this much ...
    half_rim_px: float = 12.0  # ... and lie this far from the image circle's rim (px)
    # --- grey prints (detector): a frame giving nothing read again (network too) with its contrast raised about its local mean ---
    retry_gain: float = 0.0  # by this factor (<= 1: never; cotrain detect --grey-print: GREY_PRINT_GAIN; ~40 ms a frame giving nothing)
    retry_gain_sigma: float = 0.028  # the local mean's Gaussian sigma, as a share of the frame's shorter side (20 px at 720)
    retry_min_margin: float = float("inf")  # min_margin on the raised frame (inf: placements by the network's votes not reported)
    retry_min_geometry_margin: float = 20.0  # min_geometry_margin on the raised frame: the geometry must put a board this far ahead
    # --- completion of a placed board ---
    max_neighbour_misfit: float = 0.2  # a placed corner this far (of its square) from where its nearest identified ones put it goes ...
    misfit_neighbours: int = 7  # ... those corners (verification.neighbour_check; 0: no check); completion may find it again ...
    max_misfit_share: float = 0.2  # ... unless more of the board's corners miss: then the maps are off (no lens guessed, a bend), not they
    worst_neighbour_misfit: float = 0.15  # then the worst goes where it misses by over this and another too, by half as much without it ...
    worst_misfit_rounds: int = 3  # ... at most this many times (a wrong corner at a row's end bends its neighbour's map: both near 0.2)
    complete_rounds: int = 8  # rounds in which the corners the growth missed are predicted from the identified ones (0: none) ...
    complete_rim_px: float = 3.0  # ... no nearer than this to the image circle's rim or the crop's edge (px; min_rim_px's limit) ...
    complete_min_corr: float = 0.7  # ... matching the print around them this well, their edge rays along the axes ...
    lens_fov: float = 210.0  # ... through an equidistant lens of this FoV filling the image circle, where one shows (0: pixel homographies)
