"""The tag pass's parameters and its output (:mod:`cotrain.detect.tag_pass`).

Takes nothing; gives :class:`TagConfig`, the one parameter struct every stage of the pass reads
(candidates, growth, decoding, placement, small frames, blurred and large tags, boards), and
:class:`TagResult`, what the pass reports for a frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cotrain.detect.grid_config import GridConfig
from cotrain.detect.print_model import CompletionConfig


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
    min_margin_corr: float = 12.0  # the board's placement must beat the runner-up by this (summed tag correlation; a clean tag gives 36)
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
    look: str = "first"  # the look of the retry schedule that found them (cotrain.detect.retries)
