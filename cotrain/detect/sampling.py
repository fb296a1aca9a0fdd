"""Image sampling shared by the stages of both passes: bilinear values at points, the checker
colour test of a corner's four quadrants (:func:`diag_contrast`), the edge tests along a step
(:func:`edge_contrasts`, :func:`step_has_edge`, the tag pass's :func:`edge_contrast_kernel`) and
a candidate's four edge rays (:func:`corner_rays`). Compiled where they run per point; pixels
follow docs/conventions.md (centre of the top-left pixel at (0, 0)).
"""

from __future__ import annotations

import math

import cv2
import numba
import numpy as np

from cotrain.detect.grid_config import GridConfig
from cotrain.detect.saddle import bilinear_at


def value_at(img: np.ndarray, q: np.ndarray) -> float:
    """Bilinear value of ``img`` (H, W) at one point q (2,) (exact sub-pixel position, border replicated)."""
    return float(cv2.getRectSubPix(img, (1, 1), (float(q[0]), float(q[1])))[0, 0])


_REMAP_COLS = 1024  # points per row of the maps of :func:`values_at` for long lists


def values_at(img: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear values (...) of ``img`` (H, W) at points (..., 2); NaN outside the image. With
    channels (``img`` (H, W, C), up to 4): (..., C).

    As OpenCV 5's ``cv2.remap`` gives them (float32 coordinates; NaN wherever the 2 x 2 pixels a
    point falls between leave the image): compiled for float32 images (:func:`remap_values`;
    most calls read a few points, where remap's own set-up dominates), through remap otherwise."""
    if img.dtype == np.float32:
        flat = np.ascontiguousarray(pts, np.float64).reshape(-1, 2)
        if img.ndim == 2:
            return remap_values(img, flat).reshape(pts.shape[:-1])
        chans = [remap_values(np.ascontiguousarray(img[..., c]), flat) for c in range(img.shape[2])]
        return np.stack(chans, -1).reshape(*pts.shape[:-1], img.shape[2])
    chans = img.shape[2:]
    flat = pts.reshape(-1, 2).astype(np.float32)
    n = len(flat)
    if n == 0:
        return np.zeros((*pts.shape[:-1], *chans), np.float32)
    if n > _REMAP_COLS:  # cv2.remap maps must stay under 32767 rows: lay long lists out in rows
        flat = np.concatenate([flat, np.zeros((-n % _REMAP_COLS, 2), np.float32)]).reshape(-1, _REMAP_COLS, 2)
    else:
        flat = flat[:, None]
    v = cv2.remap(img, flat[..., 0], flat[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(np.nan,) * 4)
    return v.reshape(-1, *chans)[:n].reshape(*pts.shape[:-1], *chans)


@numba.njit(cache=True, nogil=True)
def _lerp32(t, a, b):
    """a + t (b - a) in float32 as a fused multiply-add gives it: the product of two float32 is
    exact in float64, the sum rounds to float64 and then to float32 (a double rounding that can
    differ from the fused one in about 2^-29 of cases; none in the tests against remap)."""
    return np.float32(np.float64(t) * np.float64(np.float32(b - a)) + np.float64(a))


@numba.njit(cache=True, nogil=True)
def remap_values(img, pts):
    """:func:`values_at` of a float32 image ``img`` (H, W) at points ``pts`` (N, 2), for compiled
    callers too, in ``cv2.remap``'s arithmetic (OpenCV 5, INTER_LINEAR, a constant NaN border): the coordinates in
    float32, a fused multiply-add along x, then along y; NaN where one of the four pixels lies
    outside. -> (N,) float32."""
    H, W = img.shape
    out = np.empty(pts.shape[0], np.float32)
    for i in range(pts.shape[0]):
        x, y = np.float32(pts[i, 0]), np.float32(pts[i, 1])
        if not (0 <= x < W - 1 and 0 <= y < H - 1):  # floor(x) + 1 < W; false for NaN too
            out[i] = np.nan
            continue
        ix, iy = int(math.floor(x)), int(math.floor(y))
        ax, ay = np.float32(x - np.float32(ix)), np.float32(y - np.float32(iy))
        top = _lerp32(ax, img[iy, ix], img[iy, ix + 1])
        bottom = _lerp32(ax, img[iy + 1, ix], img[iy + 1, ix + 1])
        out[i] = _lerp32(ay, top, bottom)
    return out


@numba.njit(cache=True, nogil=True)
def edge_contrast_kernel(img, rim_dist, px, py, qx, qy, nx, ny, depth):
    """The tag pass's edge test (:func:`cotrain.detect.tag_growth.edge_contrast`) of segment (px, py)
    -> (qx, qy) with normal (nx, ny), compiled, in its arithmetic (float32 samples and their
    mean); ``img`` and ``rim_dist`` float32. Here beside :func:`remap_values`, which it calls:
    numba's cache of a function is renewed when its own file changes, not its callees'."""
    dx, dy = qx - px, qy - py
    sx, sy = depth * nx, depth * ny
    pts = np.empty((6, 2))
    for k in range(3):
        t = 0.25 * (k + 1)
        pts[k, 0], pts[k, 1] = px + t * dx + sx, py + t * dy + sy
        pts[k + 3, 0], pts[k + 3, 1] = px + t * dx - sx, py + t * dy - sy
    vals = remap_values(img, pts)
    rd = remap_values(rim_dist, pts)
    total, n, pos, neg = np.float32(0.0), 0, True, True
    for k in range(3):
        if rd[k] > 1 and rd[k + 3] > 1 and np.isfinite(vals[k]) and np.isfinite(vals[k + 3]):
            d = vals[k] - vals[k + 3]
            total = d if n == 0 else np.float32(total + d)
            n += 1
            pos = pos and d > 0
            neg = neg and d < 0
    if n == 0:
        return np.nan
    return float(np.float32(total / np.float32(n))) if pos or neg else 0.0


# origin: not recorded (set in 02e95a5, "tag pass: ... seeds from each corner's four edge rays"); 7.5 deg apart: 0.2 px on a 1.5 px
# circle, 1.05 px on an 8 px one
RAY_SAMPLES = 48  # a count: samples on the circle around a candidate that finds its four edge rays


# origin: not recorded (set in 02e95a5 as above, named in a274c13, "tag pass tidy-up after review")
RAY_RADIUS_PX = (1.5, 8.0)  # the circle's radius is kept within these (px): enough samples per edge, inside the X


def corner_rays(img: np.ndarray, xy: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """The four edge rays of X-junctions xy (K, 2) in ``img`` (H, W, lightly smoothed): where the
    intensity on a circle of ``radius`` (K,) px (kept within :data:`RAY_RADIUS_PX`) around each crosses the level halfway between its
    dark and light samples (10th and 90th percentiles), in order of angle (x right, y down). The
    rays need not be opposite pairs: perspective and the fisheye shear a tag corner. Returns
    (K, 4, 2) unit vectors, NaN where the circle does not cross that level exactly four times (not
    an X-junction at this scale)."""
    K = len(xy)
    ang = np.arange(RAY_SAMPLES) * (2 * np.pi / RAY_SAMPLES)
    ring = np.stack([np.cos(ang), np.sin(ang)], 1)  # (n, 2)
    radius = np.clip(radius, *RAY_RADIUS_PX)
    vals = values_at(img, xy[:, None] + radius[:, None, None] * ring[None])  # (K, n)
    lo, hi = np.percentile(np.where(np.isfinite(vals), vals, 0.0), [10, 90], axis=1)  # rows with NaN are dropped below
    d = vals - ((lo + hi) / 2)[:, None]  # the level halfway between dark and light (not the mean: sectors differ in width)
    nxt = np.roll(d, -1, 1)
    cross = (d > 0) != (nxt > 0)
    out = np.full((K, 4, 2), np.nan)
    good = np.nonzero((cross.sum(1) == 4) & np.isfinite(vals).all(1))[0]
    i = np.nonzero(cross[good])[1].reshape(-1, 4)  # each good row's four crossings, in order of angle
    dk, nk = np.take_along_axis(d[good], i, 1), np.take_along_axis(nxt[good], i, 1)
    a = (i + dk / (dk - nk)) * (2 * np.pi / RAY_SAMPLES)  # linear zero crossing between samples i and i + 1
    out[good] = np.stack([np.cos(a), np.sin(a)], -1)
    return out


@numba.njit(cache=True, nogil=True)
def _bilinear(img, x, y):
    """:func:`value_at` compiled, for points within a pixel of ``img`` (H, W) (border replicated
    as there: :func:`cotrain.detect.saddle.bilinear_at`); NaN farther out."""
    H, W = img.shape
    if not (-1.0 <= x <= W and -1.0 <= y <= H):
        return np.nan
    return bilinear_at(img, x, y)


@numba.njit(cache=True, nogil=True)
def _diag_kernel(img, px, py, ax, ay, bx, by, offset):
    """:func:`diag_contrast` in scalars, compiled; NaN where a sample lies over a pixel outside ``img``."""
    d1x, d1y, d2x, d2y = offset * (ax + bx), offset * (ay + by), offset * (ax - bx), offset * (ay - by)
    return (
        _bilinear(img, px + d2x, py + d2y)
        + _bilinear(img, px - d2x, py - d2y)
        - _bilinear(img, px + d1x, py + d1y)
        - _bilinear(img, px - d1x, py - d1y)
    )


def diag_contrast(img: np.ndarray, p: np.ndarray, ea: np.ndarray, eb: np.ndarray, offset: float) -> float:
    """Brightness of the (+a, -b) / (-a, +b) quadrants minus the (+a, +b) / (-a, -b) ones around
    corner ``p`` (2,) (steps ``ea``, ``eb`` (2,), sampled ``offset`` of the way along the
    diagonals): its sign alternates between lattice neighbours on a checker. (Compiled: the
    growth asks it for every step it tries, 60 times a frame; ``img`` float32.)"""
    if img.dtype == np.float32 and img.flags.c_contiguous:
        c = _diag_kernel(img, float(p[0]), float(p[1]), float(ea[0]), float(ea[1]), float(eb[0]), float(eb[1]), float(offset))
        if c == c:
            return float(c)
    d1, d2 = offset * (ea + eb), offset * (ea - eb)
    return value_at(img, p + d2) + value_at(img, p - d2) - value_at(img, p + d1) - value_at(img, p - d1)


def beside_points(p: np.ndarray, step: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """(K, 3, 2): the points a quarter, half and three quarters of the way along segments
    p -> p + step (K, 2), moved by offset (K, 2) to one side (the samples of the edge tests)."""
    t = np.array([0.25, 0.5, 0.75])[None, :, None]
    return p[:, None] + t * step[:, None] + offset[:, None]


def edge_sample_points(p: np.ndarray, q: np.ndarray, o: np.ndarray, depth: float) -> np.ndarray:
    """(6, 2): the points ``depth`` px to the ``+o`` side of segment p -> q (2,) at a quarter, half
    and three quarters of the way, then the same to the ``-o`` side (:func:`beside_points`' points
    for one segment, in scalar arithmetic: it runs per step tried)."""
    px, py, dx, dy = float(p[0]), float(p[1]), float(q[0] - p[0]), float(q[1] - p[1])
    sx, sy = float(depth * o[0]), float(depth * o[1])
    return np.array(
        [[px + t * dx + sx, py + t * dy + sy] for t in (0.25, 0.5, 0.75)]
        + [[px + t * dx - sx, py + t * dy - sy] for t in (0.25, 0.5, 0.75)]
    )


def edge_contrasts(img: np.ndarray, p: np.ndarray, q: np.ndarray, o: np.ndarray, depth: float) -> np.ndarray:
    """Brightness ``depth`` px to the ``+o`` side of segment p -> q (2,) minus the ``-o`` side, at a
    quarter, half and three quarters of the way: (3,) (``o`` (2,) a unit vector; NaN outside the image)."""
    vals = values_at(img, edge_sample_points(p, q, o, depth))
    return vals[:3] - vals[3:]


def step_has_edge(img: np.ndarray, p: np.ndarray, q: np.ndarray, o: np.ndarray, depth: float, parent: float, cfg: GridConfig) -> bool:
    """Whether the step p -> q (2,) runs along a checker edge: at a quarter, half and three quarters
    of the way the side ``o`` (2,) (a unit vector), ``depth`` px out, is brighter than the other side
    where the parent corner's quadrant contrast ``parent`` is positive (darker where negative), by
    ``cfg.min_step_edge_contrast`` of that contrast. Between two lattice neighbours lies the edge of
    a black and a white square; a step across the board's white margin to another pattern, or a
    knight's move, has no such edge all along."""
    if img.dtype == np.float32 and img.flags.c_contiguous:  # compiled: the growth asks for every step it takes
        px, py, qx, qy, ox, oy = float(p[0]), float(p[1]), float(q[0]), float(q[1]), float(o[0]), float(o[1])
        return _edge_kernel(img, px, py, qx, qy, ox, oy, float(depth), math.copysign(1.0, parent), cfg.min_step_edge_contrast * abs(parent))
    c = edge_contrasts(img, p, q, o, depth) * math.copysign(1.0, parent)
    return bool(np.all(c >= cfg.min_step_edge_contrast * abs(parent)))


@numba.njit(cache=True, nogil=True)
def _edge_kernel(img, px, py, qx, qy, ox, oy, depth, sign, least):
    """:func:`step_has_edge` in scalars, compiled: whether ``sign`` times the contrasts of
    :func:`edge_contrasts` all reach ``least`` (False where a sample lies outside ``img``, as
    :func:`values_at` gives NaN there)."""
    H, W = img.shape
    dx, dy, sx, sy = qx - px, qy - py, depth * ox, depth * oy
    for t in (0.25, 0.5, 0.75):
        ax, ay, bx, by = px + t * dx + sx, py + t * dy + sy, px + t * dx - sx, py + t * dy - sy
        if not (0.0 <= ax <= W - 1 and 0.0 <= ay <= H - 1 and 0.0 <= bx <= W - 1 and 0.0 <= by <= H - 1):
            return False
        if not sign * (_bilinear(img, ax, ay) - _bilinear(img, bx, by)) >= least:
            return False
    return True
