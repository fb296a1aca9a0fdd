"""The board's print seen through the lens, as completion (:mod:`cotrain.detect.completion`) and
verification (:mod:`cotrain.detect.verification`) read it: local maps from board points to pixels
fitted to identified corners (:func:`local_map`: a homography of their pixels, or of their rays
through the equidistant lens guessed from the image circle), the printed pattern around a corner
and its correlation with the image there (:func:`print_correlation`), and a corner's edge rays
along the board's axes (:func:`rays_along`). :class:`CompletionConfig` holds the thresholds of
all three modules. Pixels follow docs/conventions.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

from cotrain.detect.image_circle import EquidistantLens, PlaneMaps, local_views
from cotrain.detect.saddle import pixel_index
from cotrain.detect.sampling import corner_rays, values_at
from cotrain.targets import Target


@dataclass
class CompletionConfig:
    # Each number's comment gives its unit and its origin. Sets are named as calib_eval/detection/sets.py names them, at 1280x720 unless a
    # size is given; every AprilGrid seed named here (2027: the AprilGrid evaluation set; 2041, 2043, 2045) and every checkerboard set is a
    # tuning set there. The independent renderer's sets (calib_eval.detection.foreign, seed 5: 6 x 6 and 10 x 8 grids, --photo, --isp) are
    # tuning sets too (sets.FOREIGN_TUNING). Figures are as measured then (CHANGELOG.md, the tuning log's "The AprilGrid: the tag pass",
    # step 10, and the commit named). Not a tuned number: completion runs until a round adds no corner (small gaps' and dim fits' rounds
    # too); each round that goes on adds one at least, so the board's corners bound them. A cap of 8 stopped the front on boards seen
    # whole in small tags (the AprilGrid evaluation set, seed 2027); the cap of 64 that followed (3c18828) was never reached on the kept
    # sets (2026-12-08: the same corners to the bit without it).
    rounds: int | None = None  # rounds of prediction, each a grid step further (None: until one adds no corner; 0: none; n: at most n)
    # count; origin: not recorded (set in 6c06463, "Tag pass: complete a placed AprilGrid from its identified corners ..."); the log's
    # reason: about two tags across, where the fisheye bends little
    neighbours: int = 7  # identified corners nearest on the board that a prediction's homography is fitted to
    # (It had to fit them within half the local gap, max_residual, 0.5, not recorded, 6c06463, until 2026-12-08: without that no row of
    # the kept checkerboard sets changed and the AprilGrid sets gained 3 corners; the print check decides.)
    # origin: not recorded (set in 6c06463, "Tag pass: complete a placed AprilGrid from its identified corners ..."), a copy of the tag
    # growth's 1.6 (set in 24194e2, not recorded either), one number since the thirtieth session
    min_gap_px: float = 1.6  # no prediction where the local gap (crossing square's side) is narrower (px); nor tag growth (TagConfig)
    # (the rim: no prediction nor corner nearer than GridConfig.min_rim_px, the limit of every reported corner)
    # unit: fraction of the local gap; origin: not recorded (set in 6c06463, "Tag pass: complete a placed AprilGrid from its identified
    # corners ...")
    reach: float = 0.3  # a saddle fitted at the prediction counts within this fraction of the local gap ...
    # unit: fraction of the local gap; origin: measured as the tag pass's growth's reach (TagConfig's match_gap until 2026-12-08) on the
    # AprilGrid evaluation set (seed 2027; a tuning set): with the ray step (e9bc70a) recall 0.785 -> 0.791 (64 frames), 0.737 -> 0.741
    # (210), wrong 4 -> 2; 0.8: +0.004 with 2 more wrong corners (CHANGELOG 2026-11-24, later); completion's own (6c06463) not recorded
    search: float = 0.6  # ... else candidates within this fraction of it are tried (and the tag pass's growth matches within it)
    # unit: correlation (-1 .. 1); origin: measured for the tag pass's candidates on seeds 2027, 2031 and 2035 (tuning sets): 0.65 -> 0.5,
    # recall +0.002 / +0.004 / +0.003, wrong corners 16 -> 14 (4df897e); copied here in 6c06463, one number since the thirtieth session
    min_symmetry: float = (
        0.5  # point symmetry of that saddle fit, and of the tag pass's candidates (its grid's min_symmetry for the rest) ...
    )
    # origin: measured on the independent renderer's 10 x 8 grid (its fov220_004: 16 of 17 fits failed 0.5 in 4-6 px gaps), 4 -> 7 px: FoV
    # rows 0.9357 -> 0.9381, 6 x 6 0.9794 -> 0.9800, the evaluation set (seed 2027) 0.9530 -> 0.9542, seed 2041 0.9349 -> 0.9359, no wrong
    # corner added; 10 px gained 0.0003 more (3d25156)
    small_gap_px: float = 7.0  # ... or, where the local gap is narrower than this (px; tags under 23 px), where that fails ...
    # unit: correlation (-1 .. 1); origin: measured on the AprilGrid evaluation set (seed 2027, 1280x720; a tuning set): of the corners
    # missed beside identified ones in 8-12 px tags, 112 of 113 had a response peak within 2 px, 9 fitted at 0.5, 39 at 0.3; recall 0.943 ->
    # 0.946 (636dd27)
    small_min_symmetry: float = 0.3  # ... this much
    # unit: board spacing; origin: not recorded (set in 6c06463, "Tag pass: complete a placed AprilGrid from its identified corners ...")
    patch: float = 0.45  # half-size of the patch compared with the print, in the board's spacing (a tag side, a square)
    # count per side; origin: not recorded (set in 6c06463, "Tag pass: complete a placed AprilGrid from its identified corners ...")
    patch_samples: int = 11  # samples across it
    # unit: correlation (-1 .. 1); origin: not recorded (set in 6c06463, "Tag pass: complete a placed AprilGrid from its identified corners
    # ..."); completion as a whole took the AprilGrid evaluation set (seed 2027, 1280x720; a tuning set) 0.866 -> 0.925 (every second frame)
    # ... and better than with the print around each grid neighbour (by min_corr_margin, 0.1, until 2026-12-08: at 0 one
    # corner more on the independent renderer's photographed prints and nothing else changed over every kept set)
    min_corr: float = 0.5  # correlation of the image with the print around the corner ...
    # unit: fraction of the local gap; origin: not recorded (set in 6c06463, "Tag pass: complete a placed AprilGrid from its identified
    # corners ..."), a copy of the tag pass's ray circle's 0.5 (set in 02e95a5, not recorded either), one number since the thirtieth session
    ray_radius: float = 0.5  # a corner's edge rays are read on a circle of this fraction of the local gap (the tag pass's too) ...
    # origin: not recorded (set in 6c06463, "Tag pass: complete a placed AprilGrid from its identified corners ...")
    max_ray_angle: float = 30.0  # ... and the board's axes must leave along them within this (deg) ...
    # unit: correlation (-1 .. 1); origin: not recorded (set in 6c06463, "Tag pass: complete a placed AprilGrid from its identified corners
    # ..."); the sure match everywhere: a read tag's that lends its ids (TagConfig's min_lend_corr, 0.7, measured on the AprilGrid
    # evaluation set, 5bd7378: recall 0.774 -> 0.779, wrong corners 2 -> 1, 64 frames) and the grid pass's completed corners'
    # (GridConfig.complete_min_corr, 0.7, be2d8e0: at 0.5, 2-4 more wrong corners a set), one number since 2026-12-08
    sure_corr: float = 0.7  # ... unless the print correlation reaches this ...
    # origin: measured on the AprilGrid evaluation set (seed 2027, 1280x720; a tuning set): its fov180_013 (tags of 5-12 px) gave 51 of 144
    # corners with rays asked at every gap, 140 now; FoV rows 0.980 -> 0.982, no wrong corner; 2 px: a circle inside the X's blurred core
    # (3c18828)
    # Where rays are not read, the print's match, better than each grid neighbour's, stands for them (until 2026-12-08 it
    # had to be better by small_corr_margin, 0.3: at 0 the eight AprilGrid sets gained 90 corners, 83 of them on the defocused frames,
    # no wrong one).
    min_ray_px: float = 2.0  # where that circle is smaller (px; tags under 13 px: the X's blurred core) rays are not read (0: always)
    # unit: share of the patch's samples; origin: measured on the AprilGrid evaluation set (seed 2027, 1280x720; a tuning set): its
    # large-squares row's one wrong corner (12 px off, a tag's edge against the dark beyond the rim) found where it is, 0.854 -> 0.855; four
    # AprilGrid and eight checkerboard sets otherwise the same (20a4132)
    sure_inside: float = 0.75  # ... and, among several candidates of the search, over this share of the patch inside the image circle
    check: bool = True  # first, the growth's corners are checked against the print (:func:`print_check`) ...
    # ... and one is dropped where a grid neighbour's print matches it better (at all: a margin of 0, a field of its own, check_margin,
    # until 2026-12-08; measured with check_margin_large below) ...
    # px; origin: not recorded (set in 5ddcdeb, "tag pass: the slip-margin rule applies to tags under 20 px only (their cells blur) ...";
    # recall on the AprilGrid evaluation set unchanged, and in fc01f13, "AprilGrid: every corner the lattice reports is checked against the
    # print ...", as check_large_px, until 2026-12-08 a number of its own, 20 as well); the tag pass's verification reads it too
    small_tag_px: float = 20.0  # ... or, in tags (squares) at least this wide (px, scaled with an enlarged frame), that are not small ...
    # unit: correlation; origin: measured on the AprilGrid evaluation set (seed 2027, 1280x720; a tuning set, sets.py: "the print check's
    # margins"), with the margin of 0 above: its hard rows' wrong corners 9 -> 4 and 14 corners 1.4-2.9 px off dropped, for 3 good ones;
    # seed 2041 at 1920x1080 blurred 1.5 / 2.5 px: 6 -> 2 and 8 -> 2 wrong (fc01f13; CHANGELOG 2026-11-25, third session)
    check_margin_large: float = 0.35  # ... by more than this (a local homography fits a large tag's bend less well) ...
    # unit: correlation (-1 .. 1); origin: measured on the independent renderer's colour-processing set (foreign --isp, seed 5): its two
    # wrong corners dropped; 647 frames of four AprilGrid sets, the photographed prints and 1,712 checkerboard frames unchanged (a6fe1b0)
    check_min_corr_large: float = 0.1  # ... or at all, where its own print correlates under this (nothing of it is there)
    # origin: measured on seed 2045 at 640x480 (a tuning set): its fov220_004 corner slid 12 px down a tag's border, set aside, found 0.04
    # px from its label; 1 px moved 365 corners closer but lost 5-16 right ones on four sets; over 844 AprilGrid frames 7 set aside, only
    # that one changed (a1ac597; CHANGELOG 2026-11-28, twenty-third session)
    moved_px: float = 3.0  # then one this far (px, of the frame) or more from where its neighbours' map puts it (print_moved; 0: never) ...
    # unit: correlation; origin: measured with moved_px (above): that corner's print correlated 0.35 where it lay, 0.79 at its neighbours'
    # spot
    moved_margin: float = 0.2  # ... where the print matches better there by this, is left to completion to place (else put back)
    lens: bool = True  # homographies of the corners' rays under the tag pass's lens guess, where it has one (TagConfig.grid.lens_fov)
    # origin: measured on the AprilGrid evaluation set (seed 2027, 1280x720; a tuning set): 7 -> 10 px, FoV rows 0.9716 -> 0.9745, motion
    # blur 5 -> 3 wrong; seed 2041 0.9493 -> 0.9502; 12 px brought a wrong corner on seed 2041's motion blur, 14 px corners up to 3.7 px off
    # (76c7ce5)
    print_fit_gap_px: float = 10.0  # where the saddle fits fail in a gap under this (px), the print is moved onto the image (print_fit) ...
    # unit: local gaps; origin: not recorded (set in d136463, "Completion moves the print onto the image where a corner's saddle fits fail
    # ...")
    print_fit_radius: float = 1.5  # ... over the pixels within this many local gaps of it ...
    # origin: measured on the evaluation set (seed 2027), seed 2041 and the independent renderer's 6 x 6 and 10 x 8 sets: the same recall,
    # no wrong corner; 13 checkerboard rim corners 0.123 -> 0.095 px from their labels, rim fits 7.4 -> 5.4 ms (7735f80)
    print_fit_max_radius_px: float = 12.0  # ... and this many px at most (the corner's own squares or tag border fill it) ...
    # count of pixels; origin: not recorded (set in d136463, "Completion moves the print onto the image where a corner's saddle fits fail
    # ...")
    print_fit_min_pixels: int = 20  # ... at least this many inside the image circle and the frame ...
    # unit: share of the area; origin: measured for print_fit on seed 2041 (a tuning set): the rim look in gaps of any size brought three
    # wrong corners (3.7-11 px off); with half the disc required one stayed (98b00d9; the tuning log, step 10); off, a test's rim view
    # (test_completion) gets a corner beyond the image circle, 530 px off. The refit below needs as much of its patch in view (its
    # refit_inside, 0.5 too, measured with refit_gap_px, until 2026-12-08).
    min_seen_share: float = 0.5  # ... and this share of the disc (print_fit), or of the patch (the refit below), inside the image circle
    # count per blur; origin: not recorded (set in d136463, "Completion moves the print onto the image where a corner's saddle fits fail
    # ...")
    print_fit_iterations: int = 12  # ... by at most this many Gauss-Newton steps per blur tried ...
    # unit: fraction of the local gap; origin: not recorded (set in d136463, "Completion moves the print onto the image where a corner's
    # saddle fits fail ...")
    print_fit_max_blur: float = 0.5  # ... blurs up to this fraction of the gap (a wider one washes the corner out) ...
    # unit: share of the pixels' variance; origin: noise level (under noise of a tenth of the print's contrast the right place explains
    # 0.7-0.8; a synthetic grey print: every corner within 0.25 px at 0.7, a third refused at 0.8) and measured on seed 2041: glare 0.965 ->
    # 0.981, under-exposed 0.900 -> 0.919; the evaluation set (seed 2027) FoV rows 0.9706 -> 0.9716; 0.65: more corners over 0.5 px
    # (7dfbea1)
    print_fit_min_r2: float = 0.7  # ... and it must explain this share of their variance through the lens ...
    # unit: share of the pixels' variance; origin: measured on CI's test of OpenCV's fisheye rendering of a close rim view, read without the
    # lens: at 0.7 a corner 2.26 px off (3bdfb33); 0.8 was the bar everywhere before 7dfbea1
    print_fit_min_r2_pixels: float = 0.8  # ... or this share through a pixel homography (which misses the bend at the rim)
    # origin: measured on the AprilGrid evaluation set (seed 2027, 1280x720; a tuning set): the rim look at this value took FoV rows 0.9662
    # -> 0.9700 (strong vignetting 0.940 -> 0.953), seed 2041 0.9451 -> 0.9488, no wrong corner added (98b00d9)
    print_fit_rim_px: float = (
        1.5  # a prediction nearer the rim than GridConfig.min_rim_px but this far (px; 0: never) is found by print_fit alone ...
    )
    # origin: measured on seed 2041 (a tuning set): the wrong corner left with half the disc required lay in a gap of 24 px (a tag of 81
    # px); 20 px keeps it out (98b00d9; the tuning log, step 10)
    print_fit_rim_gap_px: float = 20.0  # ... in a gap under this (px), within reach of it
    # origin: measured on the AprilGrid evaluation set (seed 2027, 1280x720; a tuning set), with refit_margin and the share in view: its
    # fov240_037 72 -> 81 corners, FoV rows 0.9698 -> 0.9706; seed 2043 at 1920x1080 +6 corners; the ordinary margin in every gap: 16 wrong
    # corners in gaps under 14 px (fde7189)
    refit_gap_px: float = 16.0  # from this gap on (px; 0: never), an option the moved map refuses is judged under the map through it ...
    # unit: correlation; origin: measured with refit_gap_px (above)
    refit_margin: float = 0.3  # ... where it must match better than each grid neighbour's print by this ...
    # ... over min_seen_share of the patch inside the image circle, and have its edge rays along the board's axes
    # unit: local gaps; origin: measured on the independent renderer's photographed prints (foreign --photo, seed 5): 0.906 -> 0.926 (its
    # fov220_014 80 -> 108 corners), no wrong corner; the evaluation set (seed 2027) FoV rows 0.9824 -> 0.9825 (a5b9ed7; CHANGELOG
    # 2026-11-28, twenty-second session)
    dim_gaps: float = 1.0  # last, failed saddle fits again, their threshold scaled to the print's contrast within this many gaps (0: never)

    @property
    def runs(self) -> bool:
        """Whether completion runs at all (``rounds`` not 0)."""
        return self.rounds is None or self.rounds > 0

    def reads_rays(self, gap_px: float) -> bool:
        """Whether a corner's edge rays are read in a local gap of ``gap_px`` (its circle of
        ``ray_radius`` of the gap at least ``min_ray_px``); else its print's match stands for them."""
        return self.ray_radius * gap_px >= self.min_ray_px


_PATCHES: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}  # print_patches' results per board and patch
_GRID8 = np.array([(a, b) for b in (-1, 0, 1) for a in (-1, 0, 1) if a or b])  # a corner's eight grid neighbours (column, row steps)


def print_patches(board: Target, cfg: CompletionConfig) -> tuple[np.ndarray, np.ndarray]:
    """Offsets U (M, 2) in metres over a square of half-size ``cfg.patch`` of the board's spacing
    (an AprilGrid's tag side, a checkerboard's square; ``cfg.patch_samples`` across), and the
    board's printed intensity (N, M) around every one of its N corners at them (point samples: 0
    black, 1 white). Kept per board and patch."""
    printed = getattr(board, "printed", None)
    key = (repr(board.cfg), b"" if printed is None else printed.tobytes(), cfg.patch, cfg.patch_samples)
    if key not in _PATCHES:
        g = np.linspace(-cfg.patch, cfg.patch, cfg.patch_samples) * board.spacing
        U = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
        _PATCHES[key] = U, board.intensity(board.board_xy()[:, None] + U[None])[0]
    return _PATCHES[key]


def nearest_value(img: np.ndarray, q: np.ndarray) -> float:
    """img (H, W) at the pixel nearest q (2,), clamped into the image."""
    x, y = pixel_index(q[None], img.shape[1], img.shape[0])[0]
    return float(img[y, x])


def local_homography(P: np.ndarray, q: np.ndarray) -> np.ndarray | None:
    """Least-squares homography (3, 3) from board points P (K, 2) (metres) to pixels q (K, 2); None
    where the points do not span both board axes."""
    if len(P) < 4 or np.ptp(P[:, 0]) <= 0 or np.ptp(P[:, 1]) <= 0:
        return None
    H, _ = cv2.findHomography(P, q, 0)
    if H is None:
        return None
    return H if (P.mean(0) @ H[2, :2] + H[2, 2]) > 0 else -H  # points in front: positive scale


def smallest_step(board: Target) -> float:
    """The shortest step (metres) between neighbouring corners along the board's x axis: an
    AprilGrid's gap between tags (the crossing square's side), a checkerboard's square."""
    xs = np.unique(np.round(board.board_xy()[:, 0], 9))
    return float(np.diff(xs).min())


def local_map(P: np.ndarray, q: np.ndarray, lens: EquidistantLens | None = None) -> PlaneMaps | None:
    """The map (one of :class:`PlaneMaps`) from board points P (K, 2) (metres) to pixels q (K, 2):
    their :func:`local_homography`, or with ``lens`` the one to the points' own view of their rays
    (:func:`cotrain.detect.image_circle.local_views`: the fisheye's bend across the points is
    then the lens's). None where the points do not span both board axes."""
    if lens is None:
        H = local_homography(P, q)
        return None if H is None else PlaneMaps(H[None])
    g, R, ok = local_views(np.asarray(q, np.float64)[None], lens)
    H = local_homography(P, g[0]) if ok[0] else None
    return None if H is None else PlaneMaps(H[None], R, lens)


def each_local_map(P: np.ndarray, q: np.ndarray, lens: EquidistantLens | None = None) -> tuple[PlaneMaps, np.ndarray]:
    """:func:`local_map` of N point sets (P, q (N, K, 2)) each, the same maps as one at a time
    (the views of the rays found at once, ``cv2.findHomography`` per set): the N maps (the
    identity where a set gives none) and whether each exists (N,)."""
    N = len(P)
    H = np.tile(np.eye(3), (N, 1, 1))
    posed = np.zeros(N, bool)
    g, R, ok = (q, None, np.ones(N, bool)) if lens is None else local_views(np.asarray(q, np.float64), lens)
    for n in range(N):
        h = local_homography(P[n], g[n]) if ok[n] else None
        if h is not None:
            H[n], posed[n] = h, True
    return PlaneMaps(H, R, lens), posed


def map_through(
    P: np.ndarray, q: np.ndarray, p: np.ndarray, q_p: np.ndarray, lens: EquidistantLens | None, max_px: float | None = None
) -> PlaneMaps | None:
    """:func:`local_map` of board points P (K, 2) at pixels q (K, 2) and of one more, p (2,) at
    q_p (2,): the map through a corner's candidate position. None where there is none, or where
    it does not fit all K + 1 points within ``max_px`` (None: any fit)."""
    P1, q1 = np.vstack([P, p]), np.vstack([q, q_p])
    m = local_map(P1, q1, lens)
    worst = np.nan if m is None else np.linalg.norm(m(P1[None])[0] - q1, axis=1).max()
    if np.isnan(worst) or (max_px is not None and not worst <= max_px):
        return None
    return m


def local_maps(P: np.ndarray, q: np.ndarray, lens: EquidistantLens | None = None) -> tuple[PlaneMaps, np.ndarray]:
    """:func:`local_map` of N point sets at once (P, q (N, K, 2); through :func:`local_homographies`):
    the maps and whether each is posed (N,)."""
    if lens is None:
        H, posed = local_homographies(P, q)
        return PlaneMaps(H), posed
    g, R, ok = local_views(np.asarray(q, np.float64), lens)
    H, posed = local_homographies(P, g)
    return PlaneMaps(H, R, lens), posed & ok


# unit: share of the patch's samples; origin: not recorded (set in 6c06463 as a fifth of the patch, "Tag pass: complete a placed AprilGrid
# ..."; named in 20a4132)
MIN_INSIDE = 0.2  # print matches need this share of the patch's samples inside the image circle


class PrintMatch(NamedTuple):
    """How the image around a corner matches the print (:func:`print_correlation`)."""

    corr: float  # correlation with the print around the corner
    other: float  # the best correlation with the print around any of its eight grid neighbours
    inside: float  # the share of the patch's samples inside the image circle that the correlations are over


def print_correlation(
    sm: np.ndarray, rim_dist: np.ndarray, board: Target, to_image: PlaneMaps, shift: np.ndarray, t: int, cfg: CompletionConfig
) -> PrintMatch:
    """The image ``sm`` (H, W) around corner ``t`` against the print there, sampled through
    ``to_image`` (one map, board metres -> pixels) moved by ``shift`` (2,) px over the patch of
    :func:`print_patches` (see :class:`PrintMatch`). (-1, 1) where under :data:`MIN_INSIDE` of the
    samples lie inside the image circle (``rim_dist`` (H, W) over 1.5 px)."""
    corr, other_ok, inside = print_correlations(sm, rim_dist, board, to_image, np.asarray(shift, np.float64)[None], np.array([t]), cfg)
    if not inside[0] >= MIN_INSIDE:
        return PrintMatch(-1.0, 1.0, float(inside[0]))
    others = corr[0, 1:][other_ok[0]]
    return PrintMatch(float(corr[0, 0]), float(others.max()) if len(others) else -1.0, float(inside[0]))


def print_correlations(
    sm: np.ndarray, rim_dist: np.ndarray, board: Target, to_image: PlaneMaps, shift: np.ndarray, ids: np.ndarray, cfg: CompletionConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The image ``sm`` (H, W) around corners ``ids`` (K,), sampled over the patch of
    :func:`print_patches` through K maps ``to_image`` (board metres -> pixels) moved by
    ``shift`` (K, 2) px, correlated with the print around each corner and around its eight grid
    neighbours. Returns the correlations (K, 9) (the corner's own first; -1 without contrast),
    which neighbours count (K, 8): on the board and printed otherwise than the corner (a
    checkerboard's diagonal neighbours are printed alike), and the share of the samples inside
    the image circle (``rim_dist`` over 1.5 px) (K,)."""
    U, printed = print_patches(board, cfg)
    p = board.board_xy()[ids]
    q = to_image(p[:, None] + U[None]) + shift[:, None]
    q = np.where(np.isfinite(q), q, -1e6)  # behind the horizon: outside the image
    vals = values_at(sm, q)  # (K, M), NaN outside the image
    inside = np.isfinite(vals) & (values_at(rim_dist, q) > 1.5)
    c0, r0 = ids % board.nx, ids // board.nx
    cn, rn = c0[:, None] + _GRID8[:, 0], r0[:, None] + _GRID8[:, 1]
    on = (cn >= 0) & (cn < board.nx) & (rn >= 0) & (rn < board.ny)
    nb = np.where(on, rn * board.nx + cn, 0)
    pat = printed[np.concatenate([ids[:, None], nb], 1)]  # (K, 9, M)
    m = inside.astype(np.float64)[:, None]  # (K, 1, M)
    cnt = np.maximum(m.sum(2, keepdims=True), 1)
    seen = np.where(inside, vals, 0.0)[:, None]
    seen = (seen - (seen * m).sum(2, keepdims=True) / cnt) * m
    pat = (pat - (pat * m).sum(2, keepdims=True) / cnt) * m
    den = np.sqrt((pat * pat).sum(2) * (seen * seen).sum(2))
    corr = np.where(den > 1e-12, (pat * seen).sum(2) / np.maximum(den, 1e-12), -1.0)
    same = np.abs(printed[nb] - printed[ids][:, None]).max(2) < 1e-6
    return corr, on & ~same, inside.mean(1)


def local_homographies(P: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`local_homography` of N point sets at once: board points P (N, K, 2) (metres) to
    pixels q (N, K, 2), by the normalised direct linear transform (each set centred and scaled to
    mean distance sqrt(2), the smallest singular vector; the least-squares algebraic fit, which
    ``cv2.findHomography(P, q, 0)`` refines further). Returns H (N, 3, 3), oriented with the points
    in front, and whether each is posed (N,): both board axes spanned, and not degenerate."""
    P, q = np.asarray(P, np.float64), np.asarray(q, np.float64)
    N, K = P.shape[:2]
    if K < 4:
        return np.zeros((N, 3, 3)), np.zeros(N, bool)
    finite = np.isfinite(P).all((1, 2)) & np.isfinite(q).all((1, 2))
    P, q = np.where(finite[:, None, None], P, 0.0), np.where(finite[:, None, None], q, 0.0)

    def normaliser(x: np.ndarray) -> np.ndarray:  # (N, 3, 3): centre at 0, mean distance sqrt(2)
        m = x.mean(1)
        d = np.linalg.norm(x - m[:, None], axis=2).mean(1)
        f = np.sqrt(2) / np.maximum(d, 1e-12)
        T = np.zeros((N, 3, 3))
        T[:, 0, 0] = T[:, 1, 1] = f
        T[:, :2, 2] = -f[:, None] * m
        T[:, 2, 2] = 1
        return T

    Tp, Tq = normaliser(P), normaliser(q)
    a = P * Tp[:, None, 0, 0, None] + Tp[:, None, :2, 2]
    b = q * Tq[:, None, 0, 0, None] + Tq[:, None, :2, 2]
    one, zero = np.ones((N, K, 1)), np.zeros((N, K, 3))
    ah = np.concatenate([a, one], 2)  # (N, K, 3)
    rows_x = np.concatenate([ah, zero, -b[..., :1] * ah], 2)
    rows_y = np.concatenate([zero, ah, -b[..., 1:] * ah], 2)
    A = np.concatenate([rows_x, rows_y], 1)  # (N, 2K, 9)
    _, sv, vt = np.linalg.svd(A)
    Hn = vt[:, -1].reshape(N, 3, 3)
    H = np.linalg.solve(Tq, Hn @ Tp)  # Tq^-1 Hn Tp
    span = (np.ptp(P[..., 0], 1) > 0) & (np.ptp(P[..., 1], 1) > 0) & (K >= 4)
    # Rank 8 (the 8th singular value of the 2K x 9 system clear of 0): three of four points on a line are not.
    posed = finite & span & np.isfinite(H).all((1, 2)) & (sv[:, 7] > 1e-9 * sv[:, 0])
    w = np.einsum("nk,nk->n", P.mean(1), H[:, 2, :2]) + H[:, 2, 2]
    return H * np.where(w < 0, -1.0, 1.0)[:, None, None], posed


# origin: measured on the seven rendered checkerboard sets (2026, 7, 11, 41, 53; 67 at 1920x1080, 31 at 1024x768; tuning sets) and two
# AprilGrid sets (not named there): +9 and +3 corners, none wrong; a corner 7.8 px below a 240-degree frame's top edge had no rays before
# (03e0e54)
MIN_BORDER_RAY_PX = 3.0  # rays_along: the smallest circle read next to the image's border (px; the blurred core of an X is 1-2 px)


def rays_along(sm: np.ndarray, q: np.ndarray, to_image: PlaneMaps, p: np.ndarray, gap: float, gap_px: float, cfg: CompletionConfig) -> bool:
    """Whether the X-junction at q (2,) in ``sm`` has four edge rays (read on a circle of
    ``cfg.ray_radius`` of the local gap ``gap_px``) and each of the board's four axis directions
    at board point p (2,) (through ``to_image``, one map; ``gap`` metres long) leaves along one of them
    within ``cfg.max_ray_angle``: a corner half under an occluder or cut by a glare spot has an
    edge of that instead. Next to the image's border the circle shrinks to stay inside it (to
    :data:`MIN_BORDER_RAY_PX` at least): a corner a few pixels from the frame's edge has its
    rays as well."""
    H, W = sm.shape
    inside = min(q[0], q[1], W - 1 - q[0], H - 1 - q[1]) - 1.0  # the largest circle inside the image
    radius = min(cfg.ray_radius * gap_px, inside)
    if radius < min(MIN_BORDER_RAY_PX, cfg.ray_radius * gap_px):
        return False
    rays = corner_rays(sm, q[None], np.array([radius]))[0]  # (4, 2)
    if np.isnan(rays).any():
        return False
    ends = to_image((p + np.array([[0.0, 0], [gap, 0], [0, gap], [-gap, 0], [0, -gap]]))[None])[0]
    d = ends[1:] - ends[0]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return bool((d @ rays.T).max(1).min() >= np.cos(np.radians(cfg.max_ray_angle)))
