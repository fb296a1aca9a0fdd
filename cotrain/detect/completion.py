"""Stage 5, completion of a placed board (both passes): the corners the lattice growth did not
reach. It runs after verification (:mod:`cotrain.detect.verification`: the corners a neighbour's
print matches better are dropped, and completion may find them where they are), through the
print model of :mod:`cotrain.detect.print_model`.

Once a pass (:mod:`cotrain.detect.tag_pass`, :mod:`cotrain.detect.grid_pass`) has identified a board's corners, every other
corner of the board has a known place on the page. Round by round, each corner beside an
identified one (a grid step away) is

1. predicted through a homography fitted to the identified corners nearest to it on the board
   (:func:`local_map`; two tags across or so; where the tag pass has guessed the lens from the
   image circle, the homography of their rays, so the fisheye's bend across them is the lens's,
   else of their pixels, where the fisheye bends little but at the rim; the print check below
   carries the decision, however well the map fits them);
2. found: a saddle fitted at the prediction (within ``reach`` of the local gap); where that fit
   fails or lands farther in a gap under ``print_fit_gap_px``, the print moved onto the image
   there (:func:`print_fit`); else the best of the tag pass's candidates within ``search`` of it
   (the growth stops where the prediction from a lattice's last steps misses by more than its
   reach; here every identified corner around predicts). A prediction closer to the image
   circle's rim than the pass's ``GridConfig.min_rim_px`` (the board's edge against the black frame makes an X of its
   own there) is out of view, but from ``print_fit_rim_px`` on, in a gap under
   ``print_fit_rim_gap_px``, the print fit alone looks for it, within ``reach``. Where the saddle
   fit fails because its contrast is under the threshold set for a whole print (glare, shade, a
   grey print: ``GridConfig.board_contrast``), the corner is fitted again, once the rounds above
   add nothing more, with the threshold scaled to the print's contrast within
   ``dim_gaps`` gaps of the prediction (:func:`dim_fit`), and a confidence lowered as the
   contrast is;
3. verified against the print (:func:`print_correlation`): the image around the corner, sampled
   through the homography moved onto it, must correlate with the board's printed pattern around
   that corner (tag border, crossing square, the tags' data cells) by ``min_corr``, and better
   than with the pattern around each of its eight grid neighbours: a saddle at
   the crossing square's other corner or at a data junction matches another pattern. Under
   ``sure_corr`` its four edge rays must also follow the board's axes (:func:`rays_along`): a
   corner half under an occluder has the occluder's edge for one of them. In gaps too small to
   read rays in (a circle under ``min_ray_px``: tags under about 13 px), the print's match
   stands for them, and such corners are taken only once the
   rounds that read rays add nothing more: their predictions then come from every corner those
   found. Among several
   candidates of the search, one whose rays follow the axes goes before a sure match over a
   patch under ``sure_inside`` inside the image circle: a patch cut by the rim can match the
   print at the board's edge against the dark beyond it better than the corner a few pixels
   away does. In gaps of ``refit_gap_px`` or more, a candidate the moved homography refuses is
   judged again under the homography fitted to the neighbours and to it (:func:`map_through`),
   by ``refit_margin`` and with its rays: across large tags bent by a lens the guess does not
   know, the neighbours' homography misses the print's shape at the corner.

Corners added in a round predict in the next one; a corner that failed is tried again once more
of its neighbours are identified. The corners added are fitted once more in the tag pass's small
final window. Functions over numpy arrays (the print patches are kept per board); pixels follow
docs/conventions.md. The pixel thresholds are not scaled when the tag pass enlarges a small frame.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import cv2
import numba
import numpy as np
from scipy.spatial import cKDTree

from cotrain.detect.grid_config import GridConfig
from cotrain.detect.image_circle import EquidistantLens, PlaneMaps
from cotrain.detect.print_model import (
    CompletionConfig,
    each_local_map,
    map_through,
    nearest_value,
    print_correlation,
    rays_along,
    smallest_step,
)
from cotrain.detect.saddle import MIN_CONTRAST_SCALE, fit_saddles, local_contrast, smooth_cached, window_half
from cotrain.targets import Target

# origin: measured on a flat rendered view (tests/detect/test_completion.py, gaps of 3-5.5 px, blur 1.2 px, predictions 1.5 px
# off): at third-pixel steps 0.034 px from the truth on median (0.08 at most), half-pixel 0.054 (0.13), quarter-pixel 0.033 (0.07)
# for 40 % more time
PRINT_FIT_SUPERSAMPLE = 3  # a count: print_fit renders the print this many times finer than the pixels, per axis
# SIGMAS, MAX_STEP, STOP_STEP: origin: not recorded (set in d136463, "Completion moves the print onto the image where ... fits fail")
PRINT_FIT_SIGMAS = (0.6, 0.9, 1.2, 1.6, 2.1, 2.7)  # the blurs (px) print_fit may try ...
PRINT_FIT_MAX_STEP = 0.5  # ... moving the print by at most this much per Gauss-Newton step (px) ...
PRINT_FIT_STOP_STEP = 0.01  # ... until a step is shorter than this (px)


def _printed_grid(board: Target, to_image: PlaneMaps, lo: np.ndarray, hi: np.ndarray, pad: float, f: int) -> np.ndarray:
    """:func:`print_fit`'s print (nyf, nxf) float32 on a grid ``f`` times finer than the pixels,
    from pixel ``lo - pad`` (2,) to ``hi + pad``. The grid's board points are mapped back at whole
    pixels, linearly between them (the map bends by far less than a hundredth of a pixel over one)."""
    fx0, fy0 = lo[0] - pad, lo[1] - pad
    nxf, nyf = int(np.ceil((hi[0] - lo[0] + 2 * pad) * f)) + 1, int(np.ceil((hi[1] - lo[1] + 2 * pad) * f)) + 1
    ncx, ncy = (nxf - 1) // f + 2, (nyf - 1) // f + 2
    cy, cx = np.mgrid[0:ncy, 0:ncx]
    coarse = to_image.to_plane(np.stack([fx0 + cx, fy0 + cy], -1).reshape(1, -1, 2).astype(np.float64))[0].reshape(ncy, ncx, 2)
    plane, ok = _fine_grid(coarse, f, nxf, nyf)
    return np.where(ok, board.intensity(plane)[0], 0.5).reshape(nyf, nxf).astype(np.float32)


def print_fit(
    img: np.ndarray,
    rim_dist: np.ndarray,
    board: Target,
    to_image: PlaneMaps,
    t: int,
    gap_px: float,
    cfg: CompletionConfig,
    reach: float | None = None,
) -> np.ndarray | None:
    """Corner ``t`` (2,) found by moving the print onto the image ``img`` (H, W), where a saddle
    fit cannot find it: in gaps of a few pixels an AprilGrid's crossing square ends inside the
    smallest fit window, but the print around the corner (the tag's sides and border, the data
    cells next to them) is known. The print is rendered through ``to_image`` (one map, board
    metres -> pixels; it puts the corner at its prediction ``q0``) on a grid
    :data:`PRINT_FIT_SUPERSAMPLE` times finer than the pixels within ``cfg.print_fit_radius``
    local gaps (``gap_px``) of ``q0``, blurred, and moved by Gauss-Newton steps (the print's
    black and white levels fitted linearly at each) to match the image. The blurs of
    :data:`PRINT_FIT_SIGMAS` up to ``cfg.print_fit_max_blur`` of the gap are tried widest first,
    each from the last one's shift, until a narrower one matches worse. Only pixels inside the
    frame and the image circle (``rim_dist`` over 1.5 px) are compared. None where fewer than
    ``cfg.print_fit_min_pixels`` of them, or under ``cfg.min_seen_share`` of the disc, are
    left, the match explains less than ``cfg.print_fit_min_r2`` of their variance (through the
    lens; ``cfg.print_fit_min_r2_pixels`` through a pixel homography), or the shift
    exceeds ``reach`` (default ``cfg.search``) of the gap. Measured on the independent renderer's
    10 x 8 AprilGrid frames (gaps of 3-5 px, grey prints): 0.06 px from the labels on median,
    0.19 px at the 90th percentile, where the prediction was 0.1-2.9 px off."""
    H, W = img.shape
    radius = min(max(cfg.print_fit_radius * gap_px, 3.0), cfg.print_fit_max_radius_px)
    reach = (cfg.search if reach is None else reach) * gap_px
    q0 = to_image(board.board_xy()[t][None, None])[0, 0]
    if not np.isfinite(q0).all():
        return None
    # The pixels compared: integer pixels within the radius, inside the image circle.
    lo = np.maximum(np.floor(q0 - radius).astype(int), 0)  # the frame's edge cuts the patch as the rim does
    hi = np.minimum(np.ceil(q0 + radius).astype(int), [W - 1, H - 1])
    if (hi <= lo).any():
        return None
    ys, xs = np.mgrid[lo[1] : hi[1] + 1, lo[0] : hi[0] + 1]
    disc = np.hypot(xs - q0[0], ys - q0[1]) <= radius
    inside = disc & (rim_dist[ys, xs] > 1.5)
    if inside.sum() < max(cfg.print_fit_min_pixels, cfg.min_seen_share * np.pi * radius**2):
        return None
    px = np.stack([xs[inside], ys[inside]], 1).astype(np.float64)
    obs = img[ys[inside], xs[inside]].astype(np.float64)
    if obs.std() < 1e-6:
        return None
    obs_mean = float(obs.mean())
    obs_c = obs - obs_mean
    obs_ss = float(obs_c @ obs_c)
    sigmas = [x for x in PRINT_FIT_SIGMAS if x <= max(PRINT_FIT_SIGMAS[0], cfg.print_fit_max_blur * gap_px)]
    # The print on a fine grid around them, wide enough for the widest blur and the largest shift.
    f = PRINT_FIT_SUPERSAMPLE
    pad = 3 * sigmas[-1] + reach + 2
    fx0, fy0 = lo[0] - pad, lo[1] - pad
    printed = _printed_grid(board, to_image, lo, hi, pad, f)
    best = None  # (sum of squared residuals, shift)
    origin = np.array([fx0, fy0], np.float64)
    for sigma in sigmas[::-1]:  # widest first: each blur starts from the best shift so far
        model = cv2.GaussianBlur(printed, (0, 0), sigma * f)
        grads = [cv2.Sobel(model, cv2.CV_32F, dx, 1 - dx, ksize=1, scale=0.5 * f) for dx in (1, 0)]  # per pixel
        stack = cv2.merge([model, *grads])
        start = np.zeros(2) if best is None else best[1]
        out = _shift_steps(
            stack, px, obs, origin, float(f), start, reach, cfg.print_fit_iterations, PRINT_FIT_MAX_STEP, PRINT_FIT_STOP_STEP
        )
        if not np.isfinite(out[2]):
            continue  # the model left the grid, or matched with a contrast that is not positive
        if best is not None and out[2] >= best[0]:
            break  # past the image's own blur: narrower ones match worse still
        best = (float(out[2]), out[:2].copy())
    if best is None or 1 - best[0] / obs_ss < (cfg.print_fit_min_r2 if to_image.lens is not None else cfg.print_fit_min_r2_pixels):
        return None
    return q0 + best[1]


@numba.njit(cache=True, nogil=True)
def _fine_grid(coarse, f, nxf, nyf):
    """:func:`print_fit`'s fine grid: the board points ``coarse`` (ncy, ncx, 2) at whole pixels,
    interpolated linearly to ``f`` points per pixel, (nyf * nxf, 2) row by row, along x first;
    and (nyf * nxf,) bool whether a point is finite (the others are given as 0)."""
    plane = np.empty((nyf * nxf, 2))
    ok = np.empty(nyf * nxf, np.bool_)
    for r in range(nyf):
        jy, wy = r // f, (r % f) / f
        for c in range(nxf):
            jx, wx = c // f, (c % f) / f
            i = r * nxf + c
            good = True
            for k in range(2):
                top = coarse[jy, jx, k] * (1 - wx) + coarse[jy, jx + 1, k] * wx
                bottom = coarse[jy + 1, jx, k] * (1 - wx) + coarse[jy + 1, jx + 1, k] * wx
                plane[i, k] = top * (1 - wy) + bottom * wy
                good = good and np.isfinite(plane[i, k])
            ok[i] = good
            if not good:
                plane[i, 0], plane[i, 1] = 0.0, 0.0
    return plane, ok


@numba.njit(cache=True, nogil=True)
def _model_at(stack, px, origin, f, sx, sy, v):
    """:func:`print_fit`'s model moved by (sx, sy) px: its value and gradients (``stack`` (h, w, 3),
    a grid ``f`` times finer than the pixels with its (0, 0) at ``origin`` (2,) px) bilinear at the
    pixels ``px`` (N, 2) into ``v`` (N, 3); False where one of them falls off the grid."""
    h, w = stack.shape[0], stack.shape[1]
    for i in range(px.shape[0]):
        u, t = (px[i, 0] - sx - origin[0]) * f, (px[i, 1] - sy - origin[1]) * f
        if not (0.0 <= u <= w - 1 and 0.0 <= t <= h - 1):
            return False
        x0, y0 = min(int(u), w - 2), min(int(t), h - 2)
        ax, ay = u - x0, t - y0
        for c in range(3):
            top = stack[y0, x0, c] * (1 - ax) + stack[y0, x0 + 1, c] * ax
            bottom = stack[y0 + 1, x0, c] * (1 - ax) + stack[y0 + 1, x0 + 1, c] * ax
            v[i, c] = top * (1 - ay) + bottom * ay
    return True


@numba.njit(cache=True, nogil=True)
def _levels(v, obs):
    """The black level a and contrast b that fit ``a + b v[:, 0]`` to ``obs`` (N,) (least squares)."""
    n = v.shape[0]
    mv, mo = 0.0, 0.0
    for i in range(n):
        mv += v[i, 0]
        mo += obs[i]
    mv, mo = mv / n, mo / n
    var, cov = 0.0, 0.0
    for i in range(n):
        var += (v[i, 0] - mv) ** 2
        cov += (v[i, 0] - mv) * (obs[i] - mo)
    b = cov / var if var > 1e-12 else 0.0
    return mo - b * mv, b


@numba.njit(cache=True, nogil=True)
def _shift_steps(stack, px, obs, origin, f, start, reach, iterations, max_step, stop_step):
    """Gauss-Newton steps of :func:`print_fit`'s shift for one blurred model (see
    :func:`_model_at`), from ``start`` (2,): at each, the print's black level and contrast are
    fitted linearly, the residual's derivative by the shift is the contrast times the model's
    gradient, and its 2 x 2 normal equations are solved in closed form; a step is at most
    ``max_step`` px (the model is linear over a fraction of a pixel), and the steps stop after
    ``iterations``, below ``stop_step``, or beyond ``reach``. Returns (shift x, shift y, sum of
    squared residuals there), the last NaN where the model leaves the grid or its contrast is not
    positive, or the shift ends beyond ``reach``."""
    n = px.shape[0]
    v = np.empty((n, 3))
    sx, sy = start[0], start[1]
    for _ in range(iterations):
        if not _model_at(stack, px, origin, f, sx, sy, v):
            break
        a, b = _levels(v, obs)
        if not b > 0:
            break
        sxx, sxy, syy, rx, ry = 0.0, 0.0, 0.0, 0.0, 0.0
        for i in range(n):
            r = obs[i] - a - b * v[i, 0]
            gx, gy = b * v[i, 1], b * v[i, 2]
            sxx += gx * gx
            sxy += gx * gy
            syy += gy * gy
            rx += gx * r
            ry += gy * r
        det = sxx * syy - sxy * sxy
        if det < 1e-12:
            break
        dx, dy = -(syy * rx - sxy * ry) / det, -(sxx * ry - sxy * rx) / det
        norm = math.hypot(dx, dy)
        scale = min(1.0, max_step / max(norm, 1e-12))
        sx, sy = sx + dx * scale, sy + dy * scale
        if math.hypot(sx, sy) > reach or norm < stop_step:
            break
    out = np.array([sx, sy, np.nan])
    if math.hypot(sx, sy) > reach or not _model_at(stack, px, origin, f, sx, sy, v):
        return out
    a, b = _levels(v, obs)
    if not b > 0:
        return out
    sse = 0.0
    for i in range(n):
        sse += (obs[i] - a - b * v[i, 0]) ** 2
    out[2] = sse
    return out


class Completion(NamedTuple):
    """What :func:`complete_board` gives. With fewer than four corners given nothing is predicted,
    and ``unfound`` is empty: it says nothing then."""

    ids: np.ndarray  # (K',) the corners identified, given and added, sorted
    xy: np.ndarray  # (K', 2) their pixels
    corr: np.ndarray  # (K',) the print correlation of the corners added (times s^2 where dim_fit found them); NaN for the corners given
    unfound: np.ndarray  # (U,) corners beside identified ones, not predicted off the view, not found (or not tried: rounds ran out)


def best_option(
    sm: np.ndarray,
    rim_dist: np.ndarray,
    board: Target,
    to_image: PlaneMaps,
    q0: np.ndarray,
    t: int,
    p: np.ndarray,
    gap: float,
    options: list[np.ndarray],
    searched: bool,
    gap_px: float,
    known_q: np.ndarray,
    rim_px: float,
    crowd: float,
    cfg: CompletionConfig,
    refit: Callable[[np.ndarray], PlaneMaps | None] | None = None,
) -> tuple[np.ndarray | None, float]:
    """The position among ``options`` (each (2,) px) that corner ``t``, predicted at q0 (2,)
    through ``to_image`` (one map) from its board point p (2,) with a local gap of ``gap_px``
    (the board's ``gap`` metres, :func:`smallest_step`), is found at (step 3 of the module's
    docstring), and its print correlation; (None, -inf) where none holds. An option nearer than ``crowd`` of the gap to
    a known corner (``known_q`` (K, 2)) or nearer than ``rim_px`` to the rim (``rim_dist`` (H, W))
    is refused; the others must match the print around t by ``cfg.min_corr``, better than a grid
    neighbour's, and have their edge rays along the
    board's axes unless their match is sure (``cfg.sure_corr``); where the rays' circle would be
    under ``cfg.min_ray_px``, the print's match, better than every grid neighbour's, stands for
    the rays. The best match wins; but among
    several ``searched`` candidates (the tag pass's, not a fit at the prediction), those whose
    rays follow the axes go before a sure match over a patch under ``cfg.sure_inside`` inside the
    image circle. With ``refit`` (an option -> the map through it, :func:`map_through`, or None),
    an option the moved map refuses is judged again under the map through it, by
    ``cfg.refit_margin`` over each grid neighbour's print, over ``cfg.min_seen_share`` of the patch
    inside the image circle, and with its edge rays along that map's axes."""
    best, best_key = None, (False, -np.inf)
    for q in options:
        if np.linalg.norm(known_q - q, axis=1).min() < crowd * gap_px or nearest_value(rim_dist, q) < rim_px:
            continue
        m = print_correlation(sm, rim_dist, board, to_image, q - q0, t, cfg)
        refitted = False
        if not (m.corr >= cfg.min_corr and m.corr >= m.other):
            # Across large tags bent by a lens the guess does not know, the map extrapolated from
            # the neighbours misses the print's shape there: judged again under the map through q,
            # more strictly (that map was fitted to q).
            through = None if refit is None else refit(q)
            if through is None:
                continue
            m = print_correlation(sm, rim_dist, board, through, np.zeros(2), t, cfg)
            if not (m.corr >= cfg.min_corr and m.corr - m.other >= cfg.refit_margin and m.inside >= cfg.min_seen_share):
                continue
            if not rays_along(sm, q, through, p, gap, gap_px, cfg):
                continue
            refitted = True
        sure = m.corr >= cfg.sure_corr
        # A patch cut by the rim can match the print at the board's edge against the dark beyond
        # it better than the corner a few pixels away does: among several candidates, one whose
        # rays follow the board's axes goes before a sure match over such a patch.
        cut = searched and len(options) > 1 and m.inside < cfg.sure_inside
        if refitted or (sure and not cut):
            rays = True
        elif not cfg.reads_rays(gap_px):  # too small to read: the print's match, better than its neighbours', stands for them
            rays = True
        else:
            rays = rays_along(sm, q, to_image, p, gap, gap_px, cfg)
        if not (sure or rays):
            continue
        if (rays, m.corr) >= best_key:
            best, best_key = q, (rays, m.corr)
    return best, best_key[1]


def dim_contrast(grey: np.ndarray, q0: np.ndarray, gap_px: float, grid: GridConfig, cfg: CompletionConfig) -> float:
    """The print's contrast within ``cfg.dim_gaps`` local gaps (``gap_px``) of q0 (2,) as a share
    of ``grid.board_contrast``, the contrast ``grid``'s thresholds hold for (at most 1; 1 where
    ``cfg.dim_gaps`` or ``grid.board_contrast`` is 0)."""
    if cfg.dim_gaps <= 0 or grid.board_contrast <= 0:
        return 1.0
    c = float(local_contrast(grey, q0[None], np.array([cfg.dim_gaps * gap_px]))[0])
    return min(c / grid.board_contrast, 1.0)


def dim_fit(
    grey: np.ndarray,
    smoothed: dict[int, np.ndarray],
    q0: np.ndarray,
    gap_px: float,
    half: int,
    grid: GridConfig,
    rim_dist: np.ndarray,
    cfg: CompletionConfig,
) -> tuple[np.ndarray, float] | None:
    """The saddle fitted at the prediction q0 (2,) in a window of half-size ``half``, with
    ``grid``'s saddle contrast threshold scaled by the print's share of contrast there, s =
    :func:`dim_contrast` (at least :data:`cotrain.detect.saddle.MIN_CONTRAST_SCALE`), and s; None
    where s is 1 (the fit with the full threshold has had its go), where the fit fails, or where
    it lands ``cfg.reach`` gaps or more away."""
    share = dim_contrast(grey, q0, gap_px, grid, cfg)
    if share >= 1:
        return None
    k = max(share, MIN_CONTRAST_SCALE)  # share < 1 here, and board_contrast > 0 (dim_contrast)
    q, ok, _ = fit_saddles(grey, smoothed, q0[None], half, replace(grid, min_saddle_contrast=grid.min_saddle_contrast * k), rim_dist)
    if not ok[0] or np.linalg.norm(q[0] - q0) >= cfg.reach * gap_px:
        return None
    return q[0], share


class _Scene(NamedTuple):
    """What the completion rounds (:func:`complete_board`) look in: the image and the board."""

    grey: np.ndarray  # (H, W) float32 image
    smoothed: dict[int, np.ndarray]  # its blur cache (smooth_cached)
    sm: np.ndarray  # (H, W) the image blurred by 1 px, for the print correlations
    rim_dist: np.ndarray  # (H, W) distance to the image circle's rim, px
    candidates: np.ndarray  # (C, 2) the tag pass's fitted saddles
    tree: cKDTree | None  # over candidates (None: none)
    board: Target
    P: np.ndarray  # (N, 2) every corner's board point
    gap: float  # the board's smallest step (smallest_step), metres
    cfg: CompletionConfig
    grid: GridConfig  # the saddle fit's thresholds ...
    fit_cfg: GridConfig  # ... with cfg.min_symmetry ...
    small_cfg: GridConfig  # ... and with cfg.small_min_symmetry (gaps under cfg.small_gap_px)
    lens: EquidistantLens | None


@dataclass
class _Rounds:
    """The state of :func:`complete_board`'s rounds."""

    known: dict[int, np.ndarray]  # corner -> its pixel, given and added
    score: dict[int, float]  # corner -> its print correlation (NaN for the given ones)
    gaps: dict[int, float] = field(default_factory=dict)  # added corner -> its local gap (px)
    failed: dict[int, int] = field(default_factory=dict)  # corner -> identified neighbours when it failed: tried again when it has more
    unfound: set[int] = field(default_factory=set)  # corners predicted inside the image where nothing matched
    # The corners of gaps too small to read edge rays in (cfg.min_ray_px) are taken on their print's
    # margin alone only once the rounds that read rays add nothing more: their predictions then come
    # from every corner those found, and a corner they would also find keeps the position it has there.
    # Each small-gap corner those rounds refused (for any reason) is tried once more then, with
    # the maps of every corner found so far.
    small_rays: bool = False
    # Last, where no corner is added otherwise, the corners whose saddle fit failed are fitted
    # again with the contrast threshold scaled to the print's contrast around them (dim_fit): the
    # corners taken before keep their positions (a print fit or a candidate sits better there).
    # These last rounds take small gaps' corners on their print's margin too, as the rounds
    # before them do.
    dim_rounds: bool = False
    # Corners whose saddle fit failed in a dim spot (dim_contrast under 1) while those wait.
    dim_failed: set[int] = field(default_factory=set)
    small_failed: set[int] = field(default_factory=set)  # corners refused in gaps too small for rays while those wait


def _to_try(st: _Rounds, board: Target) -> list[tuple[int, int]]:
    """(corner, identified grid neighbours) of the corners beside identified ones, not found and
    not failed with as many neighbours."""
    nx = board.nx
    have = {(i % nx, i // nx) for i in st.known}
    out = []
    for t in range(board.n_corners):
        if t in st.known:
            continue
        c, r = t % nx, t // nx
        beside = sum((c + a, r + b) in have for a, b in ((1, 0), (-1, 0), (0, 1), (0, -1)))
        if beside and st.failed.get(t, 0) < beside:
            out.append((t, beside))
    return out


def _predictions(s: _Scene, st: _Rounds, kP: np.ndarray, kq: np.ndarray) -> list[tuple]:
    """Step 1 of a round: each corner to try, predicted through its identified neighbours' map,
    as (t, prediction (2,), local gap px, map, identified neighbours, at the rim, neighbours'
    indices into kP); those that cannot be looked for are marked failed (and unfound where they
    may be in view)."""
    cfg, P = s.cfg, s.P
    Hh, Ww = s.grey.shape
    todo = []
    tries = _to_try(st, s.board)
    nears = np.array([np.argsort(np.linalg.norm(kP - P[t], axis=1))[: cfg.neighbours] for t, _ in tries], int)
    # Every corner's map from its identified neighbours, and through it its prediction, its
    # gap's ends and the neighbours again, all at once (each as local_map gives it alone).
    maps, posed = each_local_map(kP[nears], kq[nears], s.lens) if len(tries) else (None, np.zeros(0, bool))
    if len(tries):
        ahead = maps(P[[t for t, _ in tries]][:, None] + np.array([[0.0, 0.0], [s.gap, 0], [0, s.gap]]))  # (N, 3, 2)
        again = np.linalg.norm(maps(kP[nears]) - kq[nears], axis=2).max(1)  # (N,)
    for n, (t, beside) in enumerate(tries):
        near = nears[n]
        if not posed[n]:
            st.failed[t] = beside
            st.unfound.add(t)  # no prediction: it may be in view
            continue
        to_image = maps.take(n)
        q0, *ends = ahead[n]
        g_px = min(np.linalg.norm(ends[0] - q0), np.linalg.norm(ends[1] - q0))
        res = again[n]
        in_frame = bool(0 <= q0[0] <= Ww - 1 and 0 <= q0[1] <= Hh - 1)
        rim_q0 = nearest_value(s.rim_dist, q0)
        at_rim = in_frame and g_px < cfg.print_fit_rim_gap_px and 0 < cfg.print_fit_rim_px <= rim_q0 < s.grid.min_rim_px
        if not in_frame or (rim_q0 < s.grid.min_rim_px and not at_rim):
            st.failed[t] = beside  # out of view (NaN: behind the horizon)
            st.unfound.discard(t)
            continue
        if not np.isfinite(g_px) or g_px < cfg.min_gap_px or np.isnan(res):
            st.failed[t] = beside
            st.unfound.add(t)  # too small to fit, or a poor prediction: it may be in view
            continue
        todo.append((t, q0, g_px, to_image, beside, at_rim, near))
    return todo


def _saddles_at(s: _Scene, todo: list[tuple], sel: np.ndarray, h: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 2's saddle fits at the predictions ``todo[sel]`` in windows of half-size ``h``:
    fitted (S, 2), ok (S,), and fit (S,), whether a saddle was fitted (none at the rim, where the
    print fit alone looks)."""
    fit = ~np.array([todo[k][5] for k in sel], bool)
    fitted, ok = np.array([todo[k][1] for k in sel], np.float64), np.zeros(len(sel), bool)
    if fit.any():
        fitted[fit], ok[fit], _ = fit_saddles(s.grey, s.smoothed, fitted[fit], int(h), s.fit_cfg, s.rim_dist)
    # In gaps of a few pixels the crossing square ends inside the smallest window and its far
    # corner breaks the point symmetry (tags of 8-12 px): such a fit is tried again, looser.
    small = np.nonzero(fit & ~ok & (np.array([todo[k][2] for k in sel]) < s.cfg.small_gap_px))[0]
    if len(small):
        pts = np.array([todo[sel[k]][1] for k in small])
        fitted[small], ok[small], _ = fit_saddles(s.grey, s.smoothed, pts, int(h), s.small_cfg, s.rim_dist)
    return fitted, ok, fit


def _options(s: _Scene, item: tuple, q_fit: np.ndarray, ok_k: bool) -> tuple[list[np.ndarray], bool]:
    """Step 2's positions to judge for one prediction: the saddle fitted there (within ``reach``
    of the gap), else the print fit (in small gaps, or at the rim), else the tag pass's
    candidates around it; and whether they are those candidates (searched)."""
    cfg = s.cfg
    t, q0, g_px, to_image, _, at_rim, _ = item
    options = [q_fit] if ok_k and np.linalg.norm(q_fit - q0) < cfg.reach * g_px else []
    if not options and (g_px < cfg.print_fit_gap_px or at_rim):
        q_print = print_fit(s.grey, s.rim_dist, s.board, to_image, t, g_px, cfg, cfg.reach if at_rim else cfg.search)
        options = [] if q_print is None else [q_print]
    searched = s.tree is not None and not options and not at_rim
    if searched:
        options = [s.candidates[j] for j in s.tree.query_ball_point(q0, cfg.search * g_px)]
    return options, searched


def _found(s: _Scene, st: _Rounds, item: tuple, q_fit, ok_k: bool, fit_k: bool, h: int, round_cfg: CompletionConfig, kP, kq) -> bool:
    """Steps 2 and 3 for one prediction ``item`` (:func:`_predictions`): the corner taken where
    an option holds (recorded in ``st``), else marked failed; whether it was taken."""
    cfg = s.cfg
    t, q0, g_px, to_image, beside, at_rim, near = item
    options, searched = _options(s, item, q_fit, ok_k)
    rim_px = cfg.print_fit_rim_px if at_rim else s.grid.min_rim_px
    allq = np.array(list(st.known.values()))
    # The map through an option, for a second look (best_option); in gaps of refit_gap_px on.
    refit = None
    if 0 < cfg.refit_gap_px <= g_px:
        refit = functools.partial(map_through, kP[near], kq[near], s.P[t], lens=s.lens)
    look = functools.partial(best_option, s.sm, s.rim_dist, s.board, to_image, q0, t, s.P[t], s.gap)
    best, best_corr = look(options, searched, g_px, allq, rim_px, s.grid.crowd_radius, round_cfg, refit)
    if best is None and fit_k and not ok_k and not st.dim_rounds:
        if dim_contrast(s.grey, q0, g_px, s.grid, cfg) < 1:
            st.dim_failed.add(t)
    elif best is None and fit_k and not ok_k:
        # Under glare, in shade or on a grey print a saddle's contrast falls under the
        # threshold set for a whole print, while the neighbours, found where the print is
        # clear, predict it within a fraction of a pixel: where nothing else is taken, a
        # fit with the threshold scaled by the contrast around the prediction is offered
        # to the same checks. Only then: a print fit or a candidate taken sits better.
        # Its score (the detection's confidence, the calibrator's weight: an inverse
        # variance) is the print correlation times s^2, s the print's share of contrast
        # there: the same noise moves a saddle of s times the contrast 1/s times as far.
        dim = dim_fit(s.grey, s.smoothed, q0, g_px, int(h), s.small_cfg if g_px < cfg.small_gap_px else s.fit_cfg, s.rim_dist, cfg)
        if dim is not None:
            best, best_corr = look([dim[0]], False, g_px, allq, rim_px, s.grid.crowd_radius, round_cfg, refit)
            best_corr *= dim[1] ** 2
    if best is None:
        st.failed[t] = beside
        if not st.small_rays and options and not cfg.reads_rays(g_px):
            st.small_failed.add(t)
        if at_rim:
            st.unfound.discard(t)  # as out of view: the view may end there
        else:
            st.unfound.add(t)
        return False
    st.known[t], st.score[t], st.gaps[t] = np.asarray(best, np.float64), best_corr, g_px
    return True


def _round(s: _Scene, st: _Rounds, rays_cfg: CompletionConfig) -> int:
    """One round: every corner beside an identified one predicted, found and verified; the
    number added."""
    round_cfg = s.cfg if st.small_rays else rays_cfg
    kid = np.array(sorted(st.known))
    kP, kq = s.P[kid], np.array([st.known[i] for i in kid])
    todo = _predictions(s, st, kP, kq)
    added = 0
    halves = np.array([window_half(x[2]) for x in todo])
    for h in np.unique(halves):
        sel = np.nonzero(halves == h)[0]
        fitted, ok, fit = _saddles_at(s, todo, sel, h)
        for k, q_fit, ok_k, fit_k in zip(sel, fitted, ok, fit):
            added += _found(s, st, todo[k], q_fit, ok_k, fit_k, h, round_cfg, kP, kq)
    return added


def _next_rounds(st: _Rounds) -> bool:
    """After a round that added nothing: whether rounds go on, with the corners of small gaps
    (once the rounds that read rays are done), then with the corners whose saddle was too faint
    (dim_fit); the corners found since are no longer waiting."""
    st.small_failed -= st.known.keys()  # found since, with more neighbours
    st.dim_failed -= st.known.keys()
    if not st.small_rays and st.small_failed:
        st.small_rays = True  # the rounds that read rays are done: the corners of small gaps again
        for t in st.small_failed:
            st.failed.pop(t, None)
    elif not st.dim_rounds and st.dim_failed:
        st.dim_rounds = st.small_rays = True  # then the corners whose saddle was too faint, with dim_fit
        for t in st.dim_failed:
            st.failed.pop(t, None)
    else:
        return False
    return True


def _final_positions(s: _Scene, st: _Rounds) -> None:
    """Final positions as the tag pass's (refinement.final_fits): the corners added fitted once more
    in a small window; where that fails the corner keeps the position it was found at."""
    grid = s.grid
    add = np.array(sorted(st.gaps))
    g = np.array([st.gaps[t] for t in add])
    halves = window_half(g, grid.final_max_half)
    for h in np.unique(halves):
        sel = np.nonzero(halves == h)[0]
        q_old = np.array([st.known[t] for t in add[sel]])
        q, ok, _ = fit_saddles(s.grey, s.smoothed, q_old, int(h), grid, s.rim_dist)
        good = ok & (np.linalg.norm(q - q_old, axis=1) < grid.max_refit_shift * g[sel])
        for k, t in enumerate(add[sel]):
            if good[k]:
                st.known[t] = q[k]


def complete_board(
    grey: np.ndarray,
    smoothed: dict[int, np.ndarray],
    rim_dist: np.ndarray,
    candidates: np.ndarray,
    board: Target,
    ids: np.ndarray,
    xy: np.ndarray,
    cfg: CompletionConfig,
    grid: GridConfig,
    lens: EquidistantLens | None = None,
) -> Completion:
    """Add the board's corners that its identified corners predict (see the module's docstring;
    with ``lens``, through the homographies of the rays, :func:`local_map`).

    Args:
        grey: (H, W) float32 image; smoothed: its blur cache (:func:`smooth_cached`); rim_dist: (H, W)
            distance to the image circle's rim; candidates: (C, 2) the tag pass's fitted saddles.
        ids: (K,) identified corner ids with positions xy (K, 2).
    Returns:
        The :class:`Completion`: the corners, sorted by id, and those that may be in view and were
        not found (occluded, blurred, the prediction off, or left untried when the rounds ran out).
    """
    s = _Scene(
        grey,
        smoothed,
        smooth_cached(smoothed, grey, 1),
        rim_dist,
        candidates,
        cKDTree(candidates) if len(candidates) else None,
        board,
        board.board_xy(),
        smallest_step(board),
        cfg,
        grid,
        replace(grid, min_symmetry=cfg.min_symmetry),
        replace(grid, min_symmetry=cfg.small_min_symmetry),
        lens,
    )
    st = _Rounds({int(i): np.asarray(p, np.float64) for i, p in zip(ids, xy)}, {int(i): np.nan for i in ids})
    rays_cfg = replace(cfg, min_ray_px=0.0)  # the rounds that read rays at every gap
    # Until a round adds nothing: every round that goes on adds a corner, or starts the small gaps' or
    # the dim fits' rounds (once each), so the board's corners bound them.
    limit = len(s.P) + 3 if cfg.rounds is None else cfg.rounds
    for _ in range(limit if len(st.known) >= 4 else 0):
        if not _round(s, st, rays_cfg) and not _next_rounds(st):
            break
    else:
        if cfg.runs and len(st.known) >= 4:
            st.unfound |= {t for t, _ in _to_try(st, board)}  # the rounds ran out with these still to try
    if st.gaps:
        _final_positions(s, st)
    out = np.array(sorted(st.known), int)
    return Completion(
        out,
        np.array([st.known[i] for i in out]).reshape(-1, 2),
        np.array([st.score[i] for i in out]),
        np.array(sorted(st.unfound - set(st.known)), int),
    )
