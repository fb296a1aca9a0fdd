"""Saddle points: where the grid pass looks for checker corners, and where it puts them.

- :func:`saddle_candidates`: X-junction candidates, the local maxima of :func:`saddle_response`
  (the negative Hessian determinant) inside the searched region;
- :func:`saddle_fit`: a point moved to the saddle of a quadratic fitted in a small window (Newton
  steps), kept if the saddle has contrast, an X shape and a point-symmetric window; the quadratic's
  zero lines are the two edge directions. Next to the image circle's rim (or the image border) the
  fit uses the part of the window that is seen; :func:`fit_saddles` retries such corners with
  smaller windows;
- :func:`window_half`, :func:`smooth_for`, :func:`smooth_cached`: the window size for a square
  size, and the image blurred for it (once per image and size);
- :func:`outside_circle`: the black frame outside a fisheye's image circle (:func:`black_level`: its level);
- :func:`contrast_scale`, :func:`local_contrast`: how far a region's or a spot's contrast falls
  short of the one the thresholds were set on (a grey print, shade, glare).

Pure functions over numpy arrays; pixels follow docs/conventions.md (centre of the top-left pixel at (0, 0)).
"""

from __future__ import annotations

import functools
import math
from concurrent.futures import Executor, Future

import cv2
import numba
import numpy as np

from cotrain.detect.grid_config import GridConfig
from cotrain.detect.image_circle import fit_image_circle


# --------------------------------------------------------------------------------------------
# The window quadratic
# --------------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=16)
def _basis(half: int) -> tuple[np.ndarray, np.ndarray]:
    """Monomials A (n^2, 6) of the quadratic a x^2 + b xy + c y^2 + d x + e y + f over a
    (2 half + 1)^2 window (row-major, centre at 0) and their Gaussian weights w (n^2,)."""
    g = np.arange(2 * half + 1) - half
    X, Y = np.meshgrid(g, g)
    x, y = X.ravel().astype(np.float64), Y.ravel().astype(np.float64)
    w = np.exp(-(x**2 + y**2) / (2 * (0.6 * half) ** 2))
    return np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], 1), w


@functools.lru_cache(maxsize=16)
def _design(half: int) -> np.ndarray:
    """Weighted least-squares solver (6, n^2) of the window quadratic (see :func:`_basis`):
    coefficients = pinv @ patch.ravel()."""
    A, w = _basis(half)
    return np.linalg.pinv(A * w[:, None]) * w[None, :]


def pixel_index(q: np.ndarray, W: int, H: int) -> np.ndarray:
    """The nearest pixel (K, 2) int of points q (K, 2), clamped into a W x H image (a NaN point:
    pixel 0, as its integer cast clamped gave, without the cast's warning)."""
    r = np.rint(q)
    if not (np.abs(r) < MAX_COORD).all():  # NaN or far out: the cast would warn (checked first: this runs thousands of times a frame)
        r = np.clip(np.nan_to_num(r, nan=0.0), -1.0, np.array([W, H], np.float64))
    qi = r.astype(int)
    return np.minimum(np.maximum(qi, 0), np.array([W - 1, H - 1]))


# origin: code, not a threshold (far beyond any image, far below an integer's range; set in 97b95d8, "Review mends: the saddle kernel
# fails NaN steps and points 1e9 px out")
MAX_COORD = 1e9  # points farther out than this (px) are not fitted: their pixel indices would overflow


# The fit itself is compiled (numba): the grid pass, the growth and the tag pass fit a few hundred
# to a few thousand small windows per frame, one point or a few dozen at a time, and as array
# operations each window cost ten times its arithmetic (measured: 9.7-11.5 ms of a 1280x720
# frame's grid pass, 1.0 ms compiled).
# The kernels release the GIL, so the reading thread of detect_files runs beside them.
@numba.njit(cache=True, nogil=True)
def _sample_window(img, x, y, half, replicate, out):
    """Bilinear (2 half + 1)^2 window of ``img`` (H, W) centred on (x, y), row-major, into
    ``out`` (n^2,) float64. Outside the image: the nearest pixel (``replicate``) or 0."""
    H, W = img.shape
    n = 2 * half + 1
    if not (abs(x) < MAX_COORD and abs(y) < MAX_COORD):  # NaN, or so far out that an int would wrap
        out[:] = np.nan
        return
    fx0, fy0 = math.floor(x), math.floor(y)
    fx, fy = x - fx0, y - fy0
    ix0, iy0 = int(fx0) - half, int(fy0) - half
    w00, w01, w10, w11 = (1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy
    inside = ix0 >= 0 and iy0 >= 0 and ix0 + n < W and iy0 + n < H
    k = 0
    for r in range(n):
        ya = iy0 + r
        for c in range(n):
            xa = ix0 + c
            if inside:
                v00, v01, v10, v11 = img[ya, xa], img[ya, xa + 1], img[ya + 1, xa], img[ya + 1, xa + 1]
            else:
                v00 = _pixel(img, xa, ya, replicate)
                v01 = _pixel(img, xa + 1, ya, replicate)
                v10 = _pixel(img, xa, ya + 1, replicate)
                v11 = _pixel(img, xa + 1, ya + 1, replicate)
            out[k] = w00 * v00 + w01 * v01 + w10 * v10 + w11 * v11
            k += 1


@numba.njit(cache=True, nogil=True)
def bilinear_at(img, x, y):
    """Bilinear value of ``img`` (H, W) at (x, y), compiled: :func:`_sample_window` for one point
    (outside the image the nearest pixel; NaN beyond :data:`MAX_COORD`). For compiled callers."""
    out = np.empty(1)
    _sample_window(img, x, y, 0, True, out)
    return out[0]


@numba.njit(cache=True, nogil=True)
def _pixel(img, x, y, replicate):
    """Pixel (x, y) of ``img`` (H, W) as float64; outside: the nearest one (``replicate``) or 0."""
    H, W = img.shape
    if 0 <= x < W and 0 <= y < H:
        return float(img[y, x])
    if not replicate:
        return 0.0
    return float(img[min(max(y, 0), H - 1), min(max(x, 0), W - 1)])


@numba.njit(cache=True, nogil=True)
def _solve(M, rhs, out):
    """out = M^-1 rhs for a small square M (n, n) (Gaussian elimination, partial pivoting; M and
    rhs are overwritten)."""
    n = M.shape[0]
    for col in range(n):
        piv = col
        for r in range(col + 1, n):
            if abs(M[r, col]) > abs(M[piv, col]):
                piv = r
        if piv != col:
            for c in range(n):
                M[col, c], M[piv, c] = M[piv, c], M[col, c]
            rhs[col], rhs[piv] = rhs[piv], rhs[col]
        for r in range(col + 1, n):
            f = M[r, col] / M[col, col]
            for c in range(col, n):
                M[r, c] -= f * M[col, c]
            rhs[r] -= f * rhs[col]
    for r in range(n - 1, -1, -1):
        s = rhs[r]
        for c in range(r + 1, n):
            s -= M[r, c] * out[c]
        out[r] = s / M[r, r]


@numba.njit(cache=True, nogil=True)
def _fit_window(img, rim, use_rim, x, y, half, pinv, A, w, patch, valid, coef, M, rhs):
    """The window quadratic at (x, y): ``coef`` (6,) fitted to ``patch`` (n^2,), the window of
    ``img``, through ``pinv`` (:func:`_design`: least squares weighted by the Gaussian w squared).
    With ``use_rim``, window pixels the blur has mixed with unusable ones (``rim`` (H, W), the
    distance to them, under 1 + 0.8 half) are left out (``valid`` (n^2,) 0 there, else 1); where
    any are, the quadratic is fitted to the others by least squares weighted by w itself
    (A^T diag(w valid) A). Returns whether the fit is posed: at least half of w valid."""
    _sample_window(img, x, y, half, True, patch)
    n2 = patch.shape[0]
    for p in range(6):
        s = 0.0
        for i in range(n2):
            s += pinv[p, i] * patch[i]
        coef[p] = s
    valid[:] = 1.0
    if not use_rim:
        return True
    H, W = rim.shape
    reach = 1.0 + 0.8 * half
    ix = int(min(max(np.rint(x), 0.0), W - 1.0))
    iy = int(min(max(np.rint(y), 0.0), H - 1.0))
    if not rim[iy, ix] < reach + 1.5 * half + 1:  # the window cannot reach the rim
        return True
    _sample_window(rim, x, y, half, False, valid)
    cut = False
    for i in range(n2):
        if valid[i] > reach:
            valid[i] = 1.0
        else:
            valid[i] = 0.0
            cut = True
    if not cut:
        return True
    M[:, :] = 0.0
    rhs[:] = 0.0
    w_all, w_valid = 0.0, 0.0
    for i in range(n2):
        w_all += w[i]
        wv = valid[i] * w[i]
        if wv == 0.0:
            continue
        w_valid += wv
        for p in range(6):
            ap = wv * A[i, p]
            rhs[p] += ap * patch[i]
            for q in range(6):
                M[p, q] += ap * A[i, q]
    posed = w_valid >= 0.5 * w_all
    if not posed:
        M[:, :] = 0.0
        for p in range(6):
            M[p, p] = 1.0
    for p in range(6):
        M[p, p] += 1e-9  # half a window of a quadratic is well posed; this only guards the solve
    _solve(M, rhs, coef)
    return posed


@numba.njit(cache=True, nogil=True)
def _fit_points(img, rim, use_rim, xy, half, iterations, pinv, A, w, thresholds, out_xy, out_ok, out_axes):
    """:func:`saddle_fit` of every point of ``xy`` (K, 2) into ``out_xy`` (K, 2), ``out_ok`` (K,)
    and ``out_axes`` (K, 2, 2) (zero where the fit fails). ``thresholds``: min_symmetry,
    min_symmetric_share, min_saddle_contrast, min_saddle_ratio, min_rim_px."""
    H, W = img.shape
    n2 = (2 * half + 1) ** 2
    min_symmetry, min_share, min_contrast, min_ratio, min_rim_px = thresholds[0], thresholds[1], thresholds[2], thresholds[3], thresholds[4]
    patch, valid, coef = np.empty(n2), np.empty(n2), np.empty(6)
    M, rhs = np.empty((6, 6)), np.empty(6)
    for k in range(xy.shape[0]):
        x0, y0 = xy[k, 0], xy[k, 1]
        out_xy[k, 0], out_xy[k, 1] = x0, y0
        out_ok[k] = False
        out_axes[k, :, :] = 0.0
        if not (abs(x0) < MAX_COORD and abs(y0) < MAX_COORD):  # NaN, inf, or absurdly far
            continue
        # Newton steps to the saddle of the window quadratic.
        x, y = x0, y0
        alive = True
        for _ in range(iterations):
            posed = _fit_window(img, rim, use_rim, x, y, half, pinv, A, w, patch, valid, coef, M, rhs)
            a, b, c, d, e = coef[0], coef[1], coef[2], coef[3], coef[4]
            det = 4 * a * c - b * b  # of [[2a, b], [b, 2c]]; a saddle has det < 0
            safe = det if det < 0 else -1.0
            sx, sy = -(2 * c * d - b * e) / safe, -(-b * d + 2 * a * e) / safe
            if det >= 0 or not math.hypot(sx, sy) <= half or not posed:  # (a NaN step fails too)
                alive = False
                break
            x, y = x + sx, y + sy
        if not alive:
            continue
        if use_rim:
            inside = 0 <= x <= W - 1 and 0 <= y <= H - 1
            inside = inside and rim[int(np.rint(y)), int(np.rint(x))] >= min_rim_px
        else:
            inside = half <= x < W - 1 - half and half <= y < H - 1 - half
        if not inside or math.hypot(x - x0, y - y0) > half:
            continue
        # The saddle's own window: contrast, X shape, point symmetry.
        posed = _fit_window(img, rim, use_rim, x, y, half, pinv, A, w, patch, valid, coef, M, rhs)
        a, b, c = coef[0], coef[1], coef[2]
        # Point symmetry over the pixel pairs seen on both sides (a 180 deg turn = reversed order).
        seen, total = 0.0, 0.0
        for i in range(n2):
            seen += valid[i]
            total += patch[i] * valid[i]
        mean = total / max(seen, 1.0)
        num, den, pairs = 0.0, 0.0, 0.0
        for i in range(n2):
            pair = valid[i] * valid[n2 - 1 - i]
            zi, zj = patch[i] - mean, patch[n2 - 1 - i] - mean
            num += zi * zj * pair
            den += zi * zi * pair
            pairs += pair
        sym = num >= min_symmetry * max(den, 1e-12) and pairs >= min_share * n2
        # Eigenvalues of the Hessian / 2 [[a, b / 2], [b / 2, c]]: one of each sign at a saddle.
        mid, rad = (a + c) / 2, math.hypot((a - c) / 2, b / 2)
        neg, pos = rad - mid, mid + rad
        big = max(neg, pos, 1e-12)
        if not (posed and sym and neg > 0 and pos > 0 and big * half * half >= min_contrast and min(neg, pos) / big >= min_ratio):
            continue
        th = 0.5 * math.atan2(b, a - c)  # e_pos = (cos th, sin th), e_neg = (-sin th, cos th)
        t = math.atan(math.sqrt(pos / neg))  # zero lines: cos t e_pos +- sin t e_neg
        ct, st, cth, sth = math.cos(t), math.sin(t), math.cos(th), math.sin(th)
        out_axes[k, 0, 0], out_axes[k, 0, 1] = ct * cth - st * sth, ct * sth + st * cth
        out_axes[k, 1, 0], out_axes[k, 1, 1] = ct * cth + st * sth, ct * sth - st * cth
        out_xy[k, 0], out_xy[k, 1] = x, y
        out_ok[k] = True


_NO_RIM = np.zeros((1, 1), np.float32)  # the rim argument of the kernels where there is none


# --------------------------------------------------------------------------------------------
# Saddle fit
# --------------------------------------------------------------------------------------------
def saddle_fit(
    smoothed: np.ndarray,
    xy: np.ndarray,
    half: int,
    iterations: int = 4,
    cfg: GridConfig | None = None,
    rim_dist: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Move points to the saddle of a quadratic fitted in a (2 half + 1)^2 window (Newton steps,
    a fixed number of them; compiled, :func:`_fit_points`).

    Args:
        smoothed: (H, W) float32 grey image, already blurred for this window size.
        xy: (K, 2) start points, pixels.
        rim_dist: optional (H, W) float32 distance in pixels to the nearest unusable pixel (outside
            the image circle or the image). Window pixels the blur has mixed with unusable ones
            (closer than 1 + 0.8 half) are left out of the fit and of the symmetry test, so a corner
            next to the rim is fitted from the part of its X-junction that is seen; at least half
            the window's weight must remain and the saddle must lie ``cfg.min_rim_px`` from the rim.
            Without it, the window must lie inside the image.
    Returns:
        xy: (K, 2) saddle points (start point where the fit failed);
        ok: (K,) bool, a saddle with enough contrast and X shape, converged within half a window;
        axes: (K, 2, 2) unit edge directions (the quadratic's zero lines) per point (zero where
            the fit failed).
    """
    cfg = cfg or GridConfig()
    xy = np.ascontiguousarray(xy, np.float64).reshape(-1, 2)
    # Contiguous float32, as the kernels were compiled for (another layout would compile anew, seconds).
    img = np.ascontiguousarray(smoothed, np.float32)
    rim = _NO_RIM if rim_dist is None else np.ascontiguousarray(rim_dist, np.float32)
    if rim_dist is not None and rim.shape != img.shape:
        raise ValueError(f"rim_dist {rim.shape} and the image {img.shape} differ in size")
    A, w = _basis(int(half))
    thresholds = np.array(
        [cfg.min_symmetry, cfg.min_symmetric_share, cfg.min_saddle_contrast, cfg.min_saddle_ratio, cfg.min_rim_px], np.float64
    )
    K = len(xy)
    out_xy, ok, axes = np.empty((K, 2)), np.zeros(K, bool), np.zeros((K, 2, 2))
    _fit_points(img, rim, rim_dist is not None, xy, int(half), int(iterations), _design(int(half)), A, w, thresholds, out_xy, ok, axes)
    return out_xy, ok, axes


def fit_saddles(
    grey: np.ndarray,
    smoothed: dict[int, np.ndarray],
    xy: np.ndarray,
    half: int,
    cfg: GridConfig,
    rim_dist: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`saddle_fit` of points xy (K, 2) on the image ``grey`` (H, W) blurred for ``half``
    (cached in ``smoothed``, see :func:`smooth_cached`); where that fails within reach of the rim
    (``rim_dist``), again with smaller windows (half // 2, then 2), whose lighter blur reaches less
    far: a corner cut by the image circle keeps enough of its X-junction only in a small window.
    Returns xy (K, 2), ok (K,), axes (K, 2, 2) as :func:`saddle_fit`."""
    q, ok, axes = saddle_fit(smooth_cached(smoothed, grey, half), xy, half, cfg=cfg, rim_dist=rim_dist)
    if rim_dist is None or ok.all():
        return q, ok, axes
    H, W = rim_dist.shape
    xi = pixel_index(xy, W, H)
    near = rim_dist[xi[:, 1], xi[:, 0]] < window_reach(half)
    for h in sorted({max(2, half // 2), 2}, reverse=True):
        retry = np.nonzero(~ok & near)[0]
        if h >= half or not len(retry):
            continue
        q[retry], ok[retry], axes[retry] = saddle_fit(smooth_cached(smoothed, grey, h), xy[retry], h, cfg=cfg, rim_dist=rim_dist)
    return q, ok, axes


# --------------------------------------------------------------------------------------------
# Contrast
# --------------------------------------------------------------------------------------------
# A factor (dimensionless); origin: not recorded (set in 2753813, "contrast_scaled: ... thresholds scaled to a quarter at most;
# figures unchanged")
MIN_CONTRAST_SCALE = 0.25  # the thresholds fall to a quarter at most (a flat region would take them to zero)


def contrast_scale(contrast: float, cfg: GridConfig) -> float:
    """The factor k = ``contrast`` / ``cfg.board_contrast`` (at least :data:`MIN_CONTRAST_SCALE`,
    at most 1) that intensity thresholds set for a board of ``cfg.board_contrast`` are scaled by
    where a print shows only ``contrast`` (5th to 95th percentile); 1 where ``cfg.board_contrast``
    is 0. Saddles and colours scale with the print's contrast."""
    if cfg.board_contrast <= 0:
        return 1.0
    return min(max(float(contrast) / cfg.board_contrast, MIN_CONTRAST_SCALE), 1.0)


def local_contrast(grey: np.ndarray, xy: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """The contrast (5th to 95th percentile) of ``grey`` (H, W) in the square of half-size
    ``radius`` (K,) px around each point xy (K, 2), cut to the image: (K,); 0 where that is empty."""
    H, W = grey.shape
    out = np.zeros(len(xy))
    for k, ((x, y), r) in enumerate(zip(np.asarray(xy, np.float64), np.asarray(radius, np.float64))):
        r = max(int(math.ceil(r)), 1)
        xi, yi = int(round(x)), int(round(y))
        patch = grey[max(yi - r, 0) : min(yi + r + 1, H), max(xi - r, 0) : min(xi + r + 1, W)]
        if patch.size:
            lo, hi = np.percentile(patch, [5, 95])
            out[k] = hi - lo
    return out


# --------------------------------------------------------------------------------------------
# Window size and blur
# --------------------------------------------------------------------------------------------
def window_half(spacing_px: float | np.ndarray, max_half: int = 5) -> int | np.ndarray:
    """Fit window half-size for a local grid spacing (px; scalar or (K,)): about a third of a
    square, 2 .. max_half.

    Larger windows are no better: on real prints the edges bend (the fisheye) and the white
    squares bloom into the black ones, so a wide fit leans off the junction (measured on the
    BoofCV frames: calibration RMS 0.41 px with windows up to 8, 0.26 up to 5)."""
    if np.ndim(spacing_px) == 0 and np.isfinite(spacing_px):  # the growth asks once per corner: plain float arithmetic
        return int(min(max(round(0.3 * float(spacing_px)), 2), max_half))
    return np.clip(np.rint(0.3 * np.asarray(spacing_px)), 2, max_half).astype(int)


def window_reach(half: int | np.ndarray) -> float | np.ndarray:
    """How far (px) from its centre a fit window of half-size ``half`` (scalar or (K,)) and the blur
    for it (:func:`smooth_for`) reach: a point closer than this to the rim has its window cut there."""
    return 1 + 1.8 * half


def smooth_for(grey: np.ndarray, half: int) -> np.ndarray:
    """The (H, W) image blurred for a fit window of half-size ``half`` (sigma = half / 2.5, at
    least 0.7); ``half = -1``: sigma 1 px, for sampling colours. -> (H, W) float32."""
    return cv2.GaussianBlur(np.asarray(grey, np.float32), (0, 0), 1.0 if half < 0 else max(0.7, half / 2.5))


def smooth_cached(smoothed: dict[int, np.ndarray], grey: np.ndarray, half: int) -> np.ndarray:
    """:func:`smooth_for`, computed once per image and window size: ``smoothed`` maps half-sizes
    to blurred copies of ``grey`` (one dict per image, filled on demand, or ahead on another
    thread by :func:`smooth_ahead`)."""
    if half not in smoothed:
        smoothed[half] = smooth_for(grey, half)
    got = smoothed[half]
    if isinstance(got, Future):
        got = smoothed[half] = got.result()
    return got


def smooth_ahead(smoothed: dict[int, np.ndarray], grey: np.ndarray, beside: Executor, max_half: int = 5) -> None:
    """Start :func:`smooth_for` of ``grey`` on ``beside`` (OpenCV's blur releases the GIL) for every
    half-size :func:`window_half` gives (2 .. ``max_half``, its own bounds) and the colours' (-1):
    a grid pass blurs its crop for nearly all of them (each in 44-67 of the grid passes over the
    evaluation set's 55 bench frames, a few read twice). :func:`smooth_cached` takes each when it is asked for, the same array."""
    for half in (*range(2, max_half + 1), -1):
        if half not in smoothed:
            smoothed[half] = beside.submit(smooth_for, grey, half)


# --------------------------------------------------------------------------------------------
# Candidates
# --------------------------------------------------------------------------------------------
def saddle_response(grey: np.ndarray, sigma: float = 1.5) -> np.ndarray:
    """(H, W) scale-normalised negative Hessian determinant -(Ixx Iyy - Ixy^2) sigma^4: large at
    X-junctions, near zero along edges."""
    g = cv2.GaussianBlur(np.asarray(grey, np.float32), (0, 0), sigma)
    ixx = cv2.Sobel(g, cv2.CV_32F, 2, 0, ksize=3)
    iyy = cv2.Sobel(g, cv2.CV_32F, 0, 2, ksize=3)
    ixy = cv2.Sobel(g, cv2.CV_32F, 1, 1, ksize=3)
    np.multiply(ixx, iyy, out=ixx)  # in place: fresh full-size buffers cost page faults (several ms per frame)
    np.multiply(ixy, ixy, out=ixy)
    np.subtract(ixx, ixy, out=ixx)
    np.negative(ixx, out=ixx)  # -(a - b), not b - a: the same signed zeros
    ixx *= np.float32(sigma**4)
    return ixx


def saddle_candidates(
    grey: np.ndarray, roi: np.ndarray, cfg: GridConfig, response: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """X-junction candidates: local maxima (5x5) of :func:`saddle_response` (or the given
    ``response``, (H, W)) inside ``roi`` (H, W bool), over ``cfg.min_response``, at most
    ``cfg.max_candidates``. Returns xy (K, 2) pixels and response (K,), strongest first."""
    D = saddle_response(grey) if response is None else response
    peak = (D >= cv2.dilate(D, np.ones((5, 5), np.uint8))) & (D > cfg.min_response) & roi
    ys, xs = np.nonzero(peak)
    r = D[ys, xs]
    order = np.argsort(-r)[: cfg.max_candidates]
    return np.stack([xs[order], ys[order]], 1).astype(np.float64), r[order].astype(np.float64)


# Intensities in [0, 1] of the half-resolution image (half_blurred), all but MIN_BLACK_SHARE. Set in f5f6e80 ("The black frame found where a
# camera lifts its black level"); the rule, not these values, was measured: the evaluation sets (1280x720; tuning sets) lifted to 16-255,
# AprilGrid seed 2027 FoV recall 0.933 -> 0.962 (wrong 8 -> 1), checkerboard seed 2026 0.906 / 10 wrong -> 0.899 / 3.
# origin: noise level (noise lifts a zero black frame to 0.025 in dark, brightened frames; the frames not recorded). One number for three
# uses of that band since 2026-12-08 (they were BLACK_AS_ZERO, LIFTED_DARK and BLACK_BAND, each 0.03): a black frame up to
# it is black; above it, a camera's lifted black, dark means under its level plus the band (a step: 0.031 -> 0.061); and the black
# frame's pixels lie within the band of its level.
BLACK_NOISE = 0.03  # how far noise spreads the black frame's pixels above its level
# MAX_BLACK_LEVEL, MIN_BLACK_SHARE: origin: not recorded (f5f6e80)
MAX_BLACK_LEVEL = 0.15  # a camera's black level is under this (16/255 = 0.063 is common); above it the border is scene
# Where a black frame shows, pixels within BLACK_NOISE of its level make at least this share of the image border's (its outermost two).
MIN_BLACK_SHARE = 0.2


def half_blurred(grey: np.ndarray) -> np.ndarray:
    """The (H, W) image at half resolution, blurred by 0.7 px: what the black frame is found on."""
    H, W = grey.shape
    return cv2.GaussianBlur(cv2.resize(grey, (max(1, W // 2), max(1, H // 2)), interpolation=cv2.INTER_AREA), (0, 0), 0.7)


def black_level(small: np.ndarray) -> float:
    """The level of the black frame outside a fisheye's image circle where a camera lifts it off
    zero: the 5th percentile of the (H, W) image's outermost two pixels all around, where that
    share of them lies within ``BLACK_NOISE`` of it (a flat black frame, not a dark scene) and it is
    under ``MAX_BLACK_LEVEL``; else 0."""
    ring = np.concatenate([small[:2].ravel(), small[-2:].ravel(), small[2:-2, :2].ravel(), small[2:-2, -2:].ravel()])
    if not len(ring):
        return 0.0
    level = float(np.percentile(ring, 5))
    flat = float(np.mean(ring < level + BLACK_NOISE))
    return level if level <= MAX_BLACK_LEVEL and flat >= MIN_BLACK_SHARE else 0.0


def outside_circle(grey: np.ndarray, dark: float = 0.04, grow_px: int = 1) -> np.ndarray:
    """(H, W) bool: the black frame outside a fisheye's image circle (dark regions connected to
    the image border, found at half resolution), grown by ``grow_px``. Corners there sit on the
    rim, where the checker is cut and a saddle fit is pulled off the corner. Dark means under
    ``dark``; where the image's border shows a flat level over ``BLACK_NOISE``
    (:func:`black_level`: a camera's lifted black, often 16/255), under that level +
    ``BLACK_NOISE`` instead, if what that finds outlines an image circle
    (:func:`cotrain.detect.image_circle.fit_image_circle`; a dim wall at a full frame's border
    does not)."""
    return _black_frame(grey, dark, grow_px, fit_always=False)[0]


def outside_and_circle(grey: np.ndarray, dark: float = 0.04, grow_px: int = 1) -> tuple[np.ndarray, tuple[np.ndarray, float] | None]:
    """:func:`outside_circle` and the image circle fitted to it
    (:func:`cotrain.detect.image_circle.fit_image_circle`; None where none is), fitted once."""
    return _black_frame(grey, dark, grow_px, fit_always=True)


def _black_frame(grey: np.ndarray, dark: float, grow_px: int, fit_always: bool) -> tuple[np.ndarray, tuple[np.ndarray, float] | None]:
    """:func:`outside_circle`'s region and its image circle: the one the lifted-black test fits,
    else (``fit_always``) fitted to the region found under ``dark``, else None."""
    H, W = grey.shape
    small = half_blurred(grey)
    level = black_level(small)
    if level > BLACK_NOISE:
        lifted = _dark_at_border(small, level + BLACK_NOISE, (H, W), grow_px)
        circle = fit_image_circle(lifted)
        if circle is not None:
            return lifted, circle
    out = _dark_at_border(small, dark, (H, W), grow_px)
    return out, (fit_image_circle(out) if fit_always else None)


def _dark_at_border(small: np.ndarray, below: float, shape: tuple[int, int], grow_px: int) -> np.ndarray:
    """(H, W) bool: the regions of the half-resolution ``small`` under ``below`` that touch its
    border, at full resolution ``shape`` and grown by ``grow_px``."""
    H, W = shape
    # Framed by one more dark pixel all round, every region that touches the border joins the frame's.
    dark = cv2.copyMakeBorder((small < below).astype(np.uint8), 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=1)
    cv2.floodFill(dark, None, (0, 0), 2, flags=4)  # the frame's region, 4-connected (a third of labelling every region)
    at_border = (dark[1:-1, 1:-1] == 2).view(np.uint8)
    out = cv2.resize(at_border, (W, H), interpolation=cv2.INTER_NEAREST)
    k = 2 * grow_px + 1
    return cv2.dilate(out, np.ones((k, k), np.uint8)) > 0
