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
- :func:`outside_circle`: the black frame outside a fisheye's image circle (:func:`black_level`: its level).

Pure functions over numpy arrays; pixels follow docs/conventions.md (centre of the top-left pixel at (0, 0)).
"""

from __future__ import annotations

import functools
import math

import cv2
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


def _masked_coefficients(patch: np.ndarray, valid: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray]:
    """Quadratic coefficients (K, 6) fitted to the valid pixels of each window (K, n^2) only
    (``valid`` (K, n^2) in [0, 1]), and whether the fit is posed (K,): at least half the Gaussian
    weight valid."""
    A, w = _basis(half)
    wv = valid * w[None]  # (K, n^2)
    M = np.einsum("ki,ip,iq->kpq", wv, A, A)  # A^T W A per window (K, 6, 6)
    rhs = np.einsum("ki,ip,ki->kp", wv, A, patch)
    posed = wv.sum(1) >= 0.5 * w.sum()
    M[~posed] = np.eye(6)
    M += 1e-9 * np.eye(6)  # half a window of a quadratic is well posed; this only guards the solve
    return np.linalg.solve(M, rhs[..., None])[..., 0], posed


def _patches(img: np.ndarray, p: np.ndarray, half: int, border: int = cv2.BORDER_REPLICATE) -> np.ndarray:
    """Bilinear (2 half + 1)^2 windows of ``img`` (H, W) centred on points p (K, 2) -> (K, n * n)."""
    n = 2 * half + 1
    g = np.arange(n, dtype=np.float32) - half
    mx = (p[:, 0, None, None] + g[None, None, :]).astype(np.float32) + np.zeros((1, n, 1), np.float32)
    my = (p[:, 1, None, None] + g[None, :, None]).astype(np.float32) + np.zeros((1, 1, n), np.float32)
    out = cv2.remap(img, mx.reshape(-1, n), my.reshape(-1, n), cv2.INTER_LINEAR, borderMode=border, borderValue=0)
    return out.reshape(len(p), n * n).astype(np.float64)


def pixel_index(q: np.ndarray, W: int, H: int) -> np.ndarray:
    """The nearest pixel (K, 2) int of points q (K, 2), clamped into a W x H image."""
    qi = np.rint(q).astype(int)
    return np.minimum(np.maximum(qi, 0), np.array([W - 1, H - 1]))


def _window(img: np.ndarray, x: float, y: float, half: int, border: int = cv2.BORDER_REPLICATE) -> np.ndarray:
    """One bilinear window (n^2,) float64 of ``img`` (H, W) centred on (x, y), as :func:`_patches`
    cuts it (one C call when the window lies inside the image)."""
    n = 2 * half + 1
    H, W = img.shape
    if half + 1 < x < W - half - 2 and half + 1 < y < H - half - 2:
        return cv2.getRectSubPix(img, (n, n), (x, y)).ravel().astype(np.float64)
    return _patches(img, np.array([[x, y]]), half, border)[0]


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
    a fixed number of them, all points at once).

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
        axes: (K, 2, 2) unit edge directions (the quadratic's zero lines) per point.
    """
    cfg = cfg or GridConfig()
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    K = len(xy)
    if K == 1:  # the lattice growth's single spots: the same fit in scalar arithmetic
        return _saddle_fit_one(smoothed, xy[0], half, iterations, cfg, rim_dist)
    pinv = _design(half)
    H, W = smoothed.shape
    reach = 1.0 + 0.8 * half

    def fit(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Coefficients (k, 6), patches (k, n^2), valid weights (k, n^2), posed (k,) at points q (k, 2)."""
        patch = _patches(smoothed, q, half)
        if rim_dist is None:
            return patch @ pinv.T, patch, np.ones_like(patch), np.ones(len(q), bool)
        coef, valid, posed = patch @ pinv.T, np.ones_like(patch), np.ones(len(q), bool)
        qi = pixel_index(q, W, H)
        near = rim_dist[qi[:, 1], qi[:, 0]] < reach + 1.5 * half + 1  # the window may reach the rim
        if near.any():
            valid[near] = (_patches(rim_dist, q[near], half, cv2.BORDER_CONSTANT) > reach).astype(np.float64)
            cut = near & (valid.min(1) < 1)  # only windows that reach the rim need the masked solve
            if cut.any():
                coef[cut], posed[cut] = _masked_coefficients(patch[cut], valid[cut], half)
        return coef, patch, valid, posed

    p = xy.copy()
    alive = np.ones(K, bool)
    for _ in range(iterations):
        idx = np.nonzero(alive)[0]
        if not len(idx):
            break
        coef, _, _, posed = fit(p[idx])
        a, b, c, d, e, _ = coef.T
        det = 4 * a * c - b * b  # of [[2a, b], [b, 2c]]; a saddle has det < 0
        safe = np.where(det < 0, det, -1.0)
        step = -np.stack([2 * c * d - b * e, -b * d + 2 * a * e], 1) / safe[:, None]
        bad = (det >= 0) | (np.linalg.norm(step, axis=1) > half) | ~posed
        p[idx[~bad]] += step[~bad]
        alive[idx[bad]] = False
    if rim_dist is None:
        inside = (p[:, 0] >= half) & (p[:, 0] < W - 1 - half) & (p[:, 1] >= half) & (p[:, 1] < H - 1 - half)
    else:
        pi = pixel_index(p, W, H)
        inside = (p[:, 0] >= 0) & (p[:, 0] <= W - 1) & (p[:, 1] >= 0) & (p[:, 1] <= H - 1)
        inside &= rim_dist[pi[:, 1], pi[:, 0]] >= cfg.min_rim_px
    ok = alive & inside & (np.linalg.norm(p - xy, axis=1) <= half)
    axes = np.zeros((K, 2, 2))
    idx = np.nonzero(ok)[0]
    if len(idx):
        coef, patch, valid, posed = fit(p[idx])
        a, b, c = coef.T[:3]
        # Point symmetry over the pixel pairs seen on both sides (a 180 deg turn = reversed ravel).
        pair = valid * valid[:, ::-1]
        mean = (patch * valid).sum(1, keepdims=True) / np.maximum(valid.sum(1, keepdims=True), 1)
        z = patch - mean
        sym = (z * z[:, ::-1] * pair).sum(1) >= cfg.min_symmetry * np.maximum((z * z * pair).sum(1), 1e-12)
        sym &= pair.sum(1) >= cfg.min_symmetric_share * pair.shape[1]
        lam, vec = np.linalg.eigh(np.stack([np.stack([a, b / 2], -1), np.stack([b / 2, c], -1)], -2))  # lam[:, 0] <= lam[:, 1]
        neg, pos = -lam[:, 0], lam[:, 1]
        big = np.maximum(np.maximum(neg, pos), 1e-12)
        good = posed & sym & (neg > 0) & (pos > 0) & (big * half * half >= cfg.min_saddle_contrast)
        good &= np.minimum(neg, pos) / big >= cfg.min_saddle_ratio
        t = np.arctan(np.sqrt(np.maximum(pos, 0) / np.maximum(neg, 1e-12)))  # zero lines: cos t e_pos +- sin t e_neg
        e_pos, e_neg = vec[:, :, 1], vec[:, :, 0]
        axes[idx, 0] = np.cos(t)[:, None] * e_pos + np.sin(t)[:, None] * e_neg
        axes[idx, 1] = np.cos(t)[:, None] * e_pos - np.sin(t)[:, None] * e_neg
        ok[idx] = good
    return np.where(ok[:, None], p, xy), ok, axes


def _saddle_fit_one(
    smoothed: np.ndarray, xy: np.ndarray, half: int, iterations: int, cfg: GridConfig, rim_dist: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`saddle_fit` of one point xy (2,), in scalar arithmetic: the lattice growth fits one
    predicted spot at a time, and the batched path's array operations on one point cost ten
    times the arithmetic. Same steps, thresholds and outputs ((1, 2), (1,), (1, 2, 2)); the
    tests hold the two paths to the same results."""
    pinv = _design(half)
    H, W = smoothed.shape
    reach = 1.0 + 0.8 * half
    n2 = (2 * half + 1) ** 2

    def fit(x: float, y: float) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, bool]:
        """Coefficients (6,), patch (n^2,), valid weights (n^2,) or None (all valid), posed."""
        patch = _window(smoothed, x, y, half)
        coef = pinv @ patch
        if rim_dist is None:
            return coef, patch, None, True
        ix, iy = min(max(round(x), 0), W - 1), min(max(round(y), 0), H - 1)
        if not rim_dist[iy, ix] < reach + 1.5 * half + 1:
            return coef, patch, None, True
        valid = (_window(rim_dist, x, y, half, cv2.BORDER_CONSTANT) > reach).astype(np.float64)
        if valid.min() < 1:
            c, posed = _masked_coefficients(patch[None], valid[None], half)
            return c[0], patch, valid, bool(posed[0])
        return coef, patch, valid, True

    x0, y0 = float(xy[0]), float(xy[1])
    x, y = x0, y0
    alive = True
    for _ in range(iterations):
        coef, _, _, posed = fit(x, y)
        a, b, c, d, e, _ = coef.tolist()
        det = 4 * a * c - b * b  # of [[2a, b], [b, 2c]]; a saddle has det < 0
        safe = det if det < 0 else -1.0
        sx, sy = -(2 * c * d - b * e) / safe, -(-b * d + 2 * a * e) / safe
        if det >= 0 or math.hypot(sx, sy) > half or not posed:
            alive = False
            break
        x, y = x + sx, y + sy
    if rim_dist is None:
        inside = half <= x < W - 1 - half and half <= y < H - 1 - half
    else:
        ix, iy = min(max(round(x), 0), W - 1), min(max(round(y), 0), H - 1)
        inside = 0 <= x <= W - 1 and 0 <= y <= H - 1 and rim_dist[iy, ix] >= cfg.min_rim_px
    axes = np.zeros((1, 2, 2))
    if not (alive and inside and math.hypot(x - x0, y - y0) <= half):
        return xy[None].copy(), np.zeros(1, bool), axes
    coef, patch, valid, posed = fit(x, y)
    a, b, c = coef[:3].tolist()
    # Point symmetry over the pixel pairs seen on both sides (a 180 deg turn = reversed order).
    if valid is None:
        z = patch - patch.mean()
        sym = float(z @ z[::-1]) >= cfg.min_symmetry * max(float(z @ z), 1e-12) and cfg.min_symmetric_share <= 1
    else:
        pair = valid * valid[::-1]
        z = patch - (patch * valid).sum() / max(valid.sum(), 1)
        sym = float((z * z[::-1] * pair).sum()) >= cfg.min_symmetry * max(float((z * z * pair).sum()), 1e-12)
        sym = sym and pair.sum() >= cfg.min_symmetric_share * n2
    lam, vec = np.linalg.eigh(np.array([[a, b / 2], [b / 2, c]]))  # lam[0] <= lam[1]
    neg, pos = -float(lam[0]), float(lam[1])
    big = max(neg, pos, 1e-12)
    good = posed and sym and neg > 0 and pos > 0 and big * half * half >= cfg.min_saddle_contrast
    good = good and min(neg, pos) / big >= cfg.min_saddle_ratio
    if not good:
        return xy[None].copy(), np.zeros(1, bool), axes
    t = math.atan(math.sqrt(pos / neg))  # zero lines: cos t e_pos +- sin t e_neg
    e_pos, e_neg = vec[:, 1], vec[:, 0]
    axes[0, 0] = math.cos(t) * e_pos + math.sin(t) * e_neg
    axes[0, 1] = math.cos(t) * e_pos - math.sin(t) * e_neg
    return np.array([[x, y]]), np.ones(1, bool), axes


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
    if rim_dist is None:
        return q, ok, axes
    H, W = rim_dist.shape
    xi = pixel_index(xy, W, H)
    near = rim_dist[xi[:, 1], xi[:, 0]] < 1 + 1.8 * half  # the window (and its blur) reaches the rim
    for h in sorted({max(2, half // 2), 2}, reverse=True):
        retry = np.nonzero(~ok & near)[0]
        if h >= half or not len(retry):
            continue
        q[retry], ok[retry], axes[retry] = saddle_fit(smooth_cached(smoothed, grey, h), xy[retry], h, cfg=cfg, rim_dist=rim_dist)
    return q, ok, axes


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


def smooth_for(grey: np.ndarray, half: int) -> np.ndarray:
    """The (H, W) image blurred for a fit window of half-size ``half`` (sigma = half / 2.5, at
    least 0.7); ``half = -1``: sigma 1 px, for sampling colours. -> (H, W) float32."""
    return cv2.GaussianBlur(np.asarray(grey, np.float32), (0, 0), 1.0 if half < 0 else max(0.7, half / 2.5))


def smooth_cached(smoothed: dict[int, np.ndarray], grey: np.ndarray, half: int) -> np.ndarray:
    """:func:`smooth_for`, computed once per image and window size: ``smoothed`` maps half-sizes
    to blurred copies of ``grey`` (one dict per image, filled on demand)."""
    if half not in smoothed:
        smoothed[half] = smooth_for(grey, half)
    return smoothed[half]


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


BLACK_AS_ZERO = 0.03  # a black frame up to this level is black (noise lifts it to 0.025 in dark, brightened frames) ...
LIFTED_DARK = 0.03  # ... above it, a camera's lifted black: dark means under its level + this (a step: 0.031 -> 0.061)
MAX_BLACK_LEVEL = 0.15  # a camera's black level is under this (16/255 = 0.063 is common); above it the border is scene
BLACK_BAND = 0.03  # the black frame's pixels lie within this of its level ...
MIN_BLACK_SHARE = 0.2  # ... over at least this share of the image border, where a black frame shows


def half_blurred(grey: np.ndarray) -> np.ndarray:
    """The (H, W) image at half resolution, blurred by 0.7 px: what the black frame is found on."""
    H, W = grey.shape
    return cv2.GaussianBlur(cv2.resize(grey, (max(1, W // 2), max(1, H // 2)), interpolation=cv2.INTER_AREA), (0, 0), 0.7)


def black_level(small: np.ndarray) -> float:
    """The level of the black frame outside a fisheye's image circle where a camera lifts it off
    zero: the 5th percentile of the (H, W) image's outermost two pixels all around, where that
    share of them lies within ``BLACK_BAND`` of it (a flat black frame, not a dark scene) and it is
    under ``MAX_BLACK_LEVEL``; else 0."""
    ring = np.concatenate([small[:2].ravel(), small[-2:].ravel(), small[2:-2, :2].ravel(), small[2:-2, -2:].ravel()])
    if not len(ring):
        return 0.0
    level = float(np.percentile(ring, 5))
    flat = float(np.mean(ring < level + BLACK_BAND))
    return level if level <= MAX_BLACK_LEVEL and flat >= MIN_BLACK_SHARE else 0.0


def outside_circle(grey: np.ndarray, dark: float = 0.04, grow_px: int = 1) -> np.ndarray:
    """(H, W) bool: the black frame outside a fisheye's image circle (dark regions connected to
    the image border, found at half resolution), grown by ``grow_px``. Corners there sit on the
    rim, where the checker is cut and a saddle fit is pulled off the corner. Dark means under
    ``dark``; where the image's border shows a flat level over ``BLACK_AS_ZERO``
    (:func:`black_level`: a camera's lifted black, often 16/255), under that level +
    ``LIFTED_DARK`` instead, if what that finds outlines an image circle
    (:func:`cotrain.detect.image_circle.fit_image_circle`; a dim wall at a full frame's border
    does not)."""
    H, W = grey.shape
    small = half_blurred(grey)
    level = black_level(small)
    if level > BLACK_AS_ZERO:
        lifted = _dark_at_border(small, level + LIFTED_DARK, (H, W), grow_px)
        if fit_image_circle(lifted) is not None:
            return lifted
    return _dark_at_border(small, dark, (H, W), grow_px)


def _dark_at_border(small: np.ndarray, below: float, shape: tuple[int, int], grow_px: int) -> np.ndarray:
    """(H, W) bool: the regions of the half-resolution ``small`` under ``below`` that touch its
    border, at full resolution ``shape`` and grown by ``grow_px``."""
    H, W = shape
    # Framed by one more dark pixel all round, every region that touches the border joins the frame's.
    dark = cv2.copyMakeBorder((small < below).astype(np.uint8), 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=1)
    _, lab = cv2.connectedComponents(dark, connectivity=4)
    at_border = (lab[1:-1, 1:-1] == lab[0, 0]).view(np.uint8)
    out = cv2.resize(at_border, (W, H), interpolation=cv2.INTER_NEAREST)
    k = 2 * grow_px + 1
    return cv2.dilate(out, np.ones((k, k), np.uint8)) > 0
