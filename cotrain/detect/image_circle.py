"""The fisheye a frame was taken with, guessed from its image circle, for reading tags.

A board is a plane, so the map from a tag's square to the camera's rays is a homography
(``v ~ H (u, v, 1)``) whatever the lens. In the image the same square is bent by the lens:
near the rim of a 200-degree image a large tag's sides are arcs, and a homography of its four
corners in pixels misplaces its inner cells by a cell or more. Here the lens is guessed from
the image circle alone, an equidistant fisheye (``r = f theta``) whose circle of radius ``R``
is ``fov`` degrees across (``f = R / (fov / 2)``): tags read through the homography of their
corners' rays under that guess are bent as the lens bends them, within a small part of a cell
for any FoV from 180 to 240 degrees and any of the usual models (Kannala-Brandt, UCM, EUCM,
Double Sphere), since it is only used for the inside of one tag from its four corners.

- :func:`fit_image_circle`: the circle (centre, radius) of the black frame's inner edge, or
  None where no such circle shows (a frame without a black frame: pixels are read through
  homographies then; :func:`frame_edge`: the pixels it is fitted to); :func:`guess_lens`: the
  lens from it.
- :class:`EquidistantLens`: ``lift`` pixels to unit rays and ``project`` rays to pixels.
- :func:`ray_homographies`: per tag, the homography from its unit square to its corners' rays.
- :func:`local_views` and :class:`PlaneMaps`: a set of corners' own pinhole view of their rays,
  and the maps from board points to pixels through such views (or straight homographies);
  :func:`parallelogram_corner`: a parallelogram closed in such a view, in scalar arithmetic.

Functions and small value classes over numpy arrays; pixels follow docs/conventions.md (centre of
the top-left pixel at (0, 0)), in whatever image the caller works on (the passes work on a crop
of the frame, and move the circle's centre into it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

# MIN_ARC_PX, MIN_INLIERS: origin: not recorded (set in 11e1eb1, "AprilGrid tags read through an equidistant lens guessed from the
# image circle")
MIN_ARC_PX = 200  # a count: edge pixels of the black frame a circle needs (about 30 degrees of a 720 px circle)
# origin: not recorded (set in ee8df3a, "Review mends: the image circle's fit narrows its inlier band ... and ignores noise specks")
MIN_CONTOUR_PX = 40  # a count of contour pixels: contours of the black frame shorter than this are specks of noise, not its edge
# origin: sampling (a pixel of the half-resolution image the frame's edge is found on is 2 px here; set in 11e1eb1)
INLIER_PX = 2.0  # px: edge pixels this close to the circle are on it (the frame's edge is found at half resolution)
MIN_INLIERS = 0.6  # share of the black frame's edge on the narrowing fit's circle (else a dark scene joins it: the consensus fit)
# CONSENSUS_TRIES, CONSENSUS_POINTS, MIN_RING_OUTSIDE: origin: not recorded (set in 71b40b3, "Image circle: where the narrowing fit leaves
# too little of the edge on its circle ...")
CONSENSUS_TRIES = 128  # a count: circles through three edge pixels that the consensus fit tries ...
# origin: measured on the AprilGrid evaluation set (seed 2027, 1280x720; a tuning set): a circle in 315 of its 322 frames, 300 with the
# first 128 draws alone (fov200_017 had none); no other count recorded (set in 166e6a2)
CONSENSUS_RETRY_TRIES = 1024  # a count: ... and where its circle fails, in a second, larger draw (a dark scene joined to most of the edge)
# origin: measured on checkerboard seed 31 at 1024x768 (the bench's set; a tuning set): the fit 2.65 -> 1.48 ms a frame (24 of its 52
# frames have a black frame but no circle), the same detections on every set; no other count recorded (set in 4bbc145)
CONSENSUS_RESCORED = 32  # a count: ... whose circles are scored on a quarter of the points, and these best on all of them
CONSENSUS_POINTS = 600  # a count: ... each scored on about this many of the edge pixels (every n-th)
# origin: measured (CHANGELOG, fifth session, "Tried and not kept"): the ring sampled at 6, 10 or 15 px found circles in 17 of the 26
# real BoofCV frames instead of 11, but admitted a motion-blurred frame's wrong circle and 3 corners 3.2-3.9 px off (its set not named)
RING_PX = 6.0  # the black frame must lie this far outside the circle (px; its edge, found at half resolution, is 2-4 px soft) ...
# (a real lens's halo leaves 80-95 % of the ring black: 15 of the 26 real BoofCV frames are read without the lens)
MIN_RING_OUTSIDE = 0.95  # ... on this share of the ring's samples there inside the image


@dataclass(frozen=True)
class EquidistantLens:
    """An equidistant fisheye: a ray at ``theta`` from the axis lands ``focal * theta`` px from ``centre``."""

    centre: tuple[float, float]  # px, where the axis meets the image (in the pixels of the image the caller works on)
    focal: float  # px per radian

    @classmethod
    def from_circle(cls, centre: np.ndarray, radius: float, fov_deg: float) -> EquidistantLens:
        """The lens whose image circle of ``radius`` px about ``centre`` (2,) spans ``fov_deg`` degrees."""
        return cls((float(centre[0]), float(centre[1])), float(radius) / np.radians(fov_deg / 2))

    def lift(self, q: np.ndarray) -> np.ndarray:
        """Pixels q (..., 2) -> unit rays v (..., 3) (z along the axis)."""
        q = np.asarray(q, np.float64)
        dx, dy = q[..., 0] - self.centre[0], q[..., 1] - self.centre[1]
        r = np.hypot(dx, dy)
        theta = r / self.focal
        # sin(theta) / r, which tends to 1 / focal at the centre.
        s = np.where(r > 1e-9, np.sin(theta) / np.maximum(r, 1e-9), 1.0 / self.focal)
        return np.stack([dx * s, dy * s, np.cos(theta)], -1)

    def project(self, v: np.ndarray) -> np.ndarray:
        """Rays v (..., 3), of any length (not 0) -> pixels (..., 2); rays behind the lens too (theta over 90 deg)."""
        v = np.asarray(v, np.float64)
        return self.project_xyz(v[..., 0], v[..., 1], v[..., 2])

    def project_xyz(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """:meth:`project` of rays given by their components (each (...,)) -> pixels (..., 2)."""
        rho = np.hypot(x, y)
        k = np.where(rho > 1e-12, self.focal * np.arctan2(rho, z) / np.maximum(rho, 1e-12), 0.0)  # on the axis: the centre
        return np.stack([self.centre[0] + x * k, self.centre[1] + y * k], -1)


def parallelogram_corner(v0: list[float], v1: list[float], v2: list[float], lens: EquidistantLens) -> tuple[float, float] | None:
    """The pixel of a parallelogram's fourth corner, opposite v0, from the unit rays (3 floats
    each) of its corners v0, v1, v2 on a plane: the parallelogram closed in the three rays' own
    pinhole view (:func:`local_views`), where each ray meets the plane ``z . p = 1`` perpendicular
    to their mean z, and projected through ``lens``. None where a ray is over 84 deg from the
    mean, as :func:`local_views` refuses. Scalar arithmetic: it runs for each quad a seed tries."""
    zx, zy, zz = v0[0] + v1[0] + v2[0], v0[1] + v1[1] + v2[1], v0[2] + v1[2] + v2[2]
    n = math.sqrt(zx * zx + zy * zy + zz * zz)
    if n < 1e-12:
        return None
    zx, zy, zz = zx / n, zy / n, zz / n
    d = [v[0] * zx + v[1] * zy + v[2] * zz for v in (v0, v1, v2)]
    if min(d) <= 0.1:
        return None
    x, y, z = (v1[k] / d[1] + v2[k] / d[2] - v0[k] / d[0] for k in range(3))
    rho = math.hypot(x, y)  # lens.project_xyz, in scalars
    k = lens.focal * math.atan2(rho, z) / rho if rho > 1e-12 else 0.0
    return float(lens.centre[0] + x * k), float(lens.centre[1] + y * k)


def fit_image_circle(outside: np.ndarray) -> tuple[np.ndarray, float] | None:
    """The image circle of a fisheye frame whose black frame is ``outside`` (H, W) bool (see
    :func:`cotrain.detect.saddle.outside_circle`): its centre (2,) px and radius px, fitted to the
    frame's inner edge: the contours of the black frame off the image border (not the specks noise
    leaves in it, under :data:`MIN_CONTOUR_PX`), an algebraic circle fit, and fits again to the edge pixels
    within a band around the last fit that narrows from a fifth of the radius to
    :data:`INLIER_PX` (so a dark part of the scene joined to the frame pulls only the first fit).
    A circle is kept where its centre lies in the image and the black frame lies all around
    outside it (:func:`_black_all_around`). Where that fit fails this, or leaves under
    :data:`MIN_INLIERS` of the edge on its circle (a dark scene joined to much of the frame: the
    black borders of tags at the rim, a dark room), the circle with the most edge pixels on it
    among circles through three of them (:func:`_consensus_circle`), if it passes. None where the
    edge is too short or no circle passes (no black frame, or a dark scene's round edge)."""
    H, W = outside.shape
    p = frame_edge(outside)
    if len(p) < MIN_ARC_PX:
        return None

    def passes(fit: tuple[np.ndarray, float] | None) -> bool:  # its centre in the image, the black frame all around it
        return fit is not None and 0 <= fit[0][0] < W and 0 <= fit[0][1] < H and _black_all_around(outside, *fit)

    fit = _narrowing_circle(p)
    if fit is not None:
        keep = _near_circle(p, *fit, INLIER_PX)
        if keep.sum() < MIN_ARC_PX or keep.mean() < MIN_INLIERS:
            fit = None
    if not passes(fit):
        fit = _consensus_circle(p, outside.shape)
    if not passes(fit):
        # Where a dark scene joins most of the frame's edge (a circle cut by the image's sides leaves
        # four short arcs in its corners), 128 draws may miss three points on the circle itself.
        fit = _consensus_circle(p, outside.shape, seed=1, tries=CONSENSUS_RETRY_TRIES)
        if not passes(fit):
            return None
    centre, radius = fit
    # The contour runs along the black frame's own pixels, half a pixel outside the boundary (the
    # frame, found at half resolution and grown by a pixel, still comes out about a pixel wide).
    return centre, radius - 0.5


def guess_lens(outside: np.ndarray, fov_deg: float, offset: tuple[float, float] = (0.0, 0.0)) -> EquidistantLens | None:
    """The equidistant lens whose circle spans ``fov_deg`` degrees, guessed from the image circle
    of the black frame ``outside`` (H, W) bool (:func:`fit_image_circle`), in the pixels of a
    crop whose top-left corner is at ``offset`` (x, y) in the frame; None where ``fov_deg`` is 0
    (pixel homographies wanted) or no circle shows."""
    return lens_of_circle(fit_image_circle(outside) if fov_deg > 0 else None, fov_deg, offset)


def lens_of_circle(
    circle: tuple[np.ndarray, float] | None, fov_deg: float, offset: tuple[float, float] = (0.0, 0.0)
) -> EquidistantLens | None:
    """:func:`guess_lens` from an image circle already fitted (centre (2,) and radius, frame
    pixels; None: no circle)."""
    if circle is None or fov_deg <= 0:
        return None
    return EquidistantLens.from_circle(circle[0] - np.asarray(offset, np.float64), circle[1], fov_deg)


# origin: the fit's inlier band (INLIER_PX), not measured (set in 9a264a5, "Grid pass: the black frame ends at the fitted image circle")
CIRCLE_INSIDE_PX = INLIER_PX  # px: beyond_circle: the black frame's region is kept this far inside the fitted circle (the fit's tolerance)


def beyond_circle(outside: np.ndarray, circle: tuple[np.ndarray, float] | None) -> np.ndarray:
    """(H, W) bool: the black frame ``outside`` (H, W) bool (:func:`cotrain.detect.saddle.outside_circle`)
    where it lies beyond its image ``circle`` (:func:`fit_image_circle`) less
    :data:`CIRCLE_INSIDE_PX`; all of it where there is no circle. Under vignetting the black
    squares of a board at the rim join the frame's dark region and reach far into the circle;
    counted as frame, their corners look cut by the rim and no saddle fit holds there."""
    if circle is None:
        return outside
    (cx, cy), r = circle
    inside = np.zeros(outside.shape, np.uint8)
    shift = 4  # the circle drawn to 1/16 px
    cv2.circle(inside, (round(cx * 16), round(cy * 16)), max(round((r - CIRCLE_INSIDE_PX) * 16), 0), 1, -1, cv2.LINE_8, shift)
    return outside & (inside == 0)


def frame_edge(outside: np.ndarray) -> np.ndarray:
    """The black frame ``outside`` (H, W) bool's pixels along its edge (N, 2), px: its contours
    without the specks noise leaves in it (under :data:`MIN_CONTOUR_PX`) and without the image's
    border, which is no edge of the circle."""
    H, W = outside.shape
    contours, _ = cv2.findContours(outside.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    contours = [c for c in contours if len(c) >= MIN_CONTOUR_PX]
    if not contours:
        return np.zeros((0, 2))
    p = np.concatenate([c.reshape(-1, 2) for c in contours]).astype(np.float64)
    return p[(p[:, 0] >= 3) & (p[:, 0] < W - 3) & (p[:, 1] >= 3) & (p[:, 1] < H - 3)]


def _narrowing_circle(p: np.ndarray) -> tuple[np.ndarray, float] | None:
    """The circle fitted to edge pixels p (N, 2) again and again, each time to those within a band
    around the last fit, narrowing from a fifth of the radius to :data:`INLIER_PX`."""
    fit = _algebraic_circle(p)
    for band in (0.2, 0.1, 0.05, 0.0):
        if fit is None:
            return None
        centre, radius = fit
        keep = _near_circle(p, centre, radius, max(band * radius, INLIER_PX))
        if keep.sum() < MIN_ARC_PX:
            return None
        fit = _algebraic_circle(p[keep])
    return fit


def _consensus_circle(
    p: np.ndarray, shape: tuple[int, int], seed: int = 0, tries: int = CONSENSUS_TRIES
) -> tuple[np.ndarray, float] | None:
    """The circle through most of the edge pixels p (N, 2) of an image of ``shape`` (H, W): of
    ``tries`` circles through three of them (a fixed random draw from ``seed``) with a radius
    of a fifth of the image's shorter side to twice its longer, the one with the most within
    :data:`INLIER_PX`, fitted again to those; None where under :data:`MIN_ARC_PX` lie on it. A
    draw larger than :data:`CONSENSUS_TRIES` is scored on a quarter of the points first and its
    :data:`CONSENSUS_RESCORED` best circles on all of them."""
    H, W = shape
    sub = p[:: max(1, len(p) // CONSENSUS_POINTS)]
    tri = sub[np.random.default_rng(seed).integers(0, len(sub), (tries, 3))]  # (T, 3, 2)
    # The centre c through three points: 2 (p_k - p_0) . c = |p_k|^2 - |p_0|^2, k = 1, 2.
    A = 2 * (tri[:, 1:] - tri[:, :1])  # (T, 2, 2)
    b = (tri[:, 1:] ** 2).sum(2) - (tri[:, :1] ** 2).sum(2)  # (T, 2)
    ok = np.abs(np.linalg.det(A)) > 1e-6
    c = np.linalg.solve(np.where(ok[:, None, None], A, np.eye(2)), np.where(ok[:, None], b, 0.0)[..., None])[..., 0]
    r = np.hypot(tri[:, 0, 0] - c[:, 0], tri[:, 0, 1] - c[:, 1])
    ok &= (r > 0.2 * min(H, W)) & (r < 2 * max(H, W))

    def inliers(c: np.ndarray, r: np.ndarray, pts: np.ndarray) -> np.ndarray:
        # Within INLIER_PX of a circle: squared distances between (r - INLIER_PX)^2 and (r + INLIER_PX)^2 (no roots).
        d2 = (pts[None, :, 0] - c[:, None, 0]) ** 2 + (pts[None, :, 1] - c[:, None, 1]) ** 2  # (T, n)
        lo = np.maximum(r - INLIER_PX, 0.0) ** 2
        return ((d2 > lo[:, None]) & (d2 < ((r + INLIER_PX) ** 2)[:, None])).sum(1)

    if tries > CONSENSUS_TRIES:
        # A large draw: every circle scored on a quarter of the points, the best few on all of them.
        pre = np.where(ok, inliers(c, r, sub[::4]), -1)
        top = np.argsort(-pre, kind="stable")[:CONSENSUS_RESCORED]
        score = np.full(tries, -1)
        score[top] = np.where(ok[top], inliers(c[top], r[top], sub), -1)
    else:
        score = np.where(ok, inliers(c, r, sub), -1)
    k = int(np.argmax(score))
    if score[k] < 3:
        return None
    centre, radius = c[k], r[k]
    for _ in range(3):
        keep = _near_circle(p, centre, radius, INLIER_PX)
        if keep.sum() < MIN_ARC_PX:
            return None
        fit = _algebraic_circle(p[keep])
        if fit is None:
            return None
        centre, radius = fit
    return centre, radius


def _black_all_around(outside: np.ndarray, centre: np.ndarray, radius: float) -> bool:
    """Whether the black frame ``outside`` (H, W) bool lies all around the circle: on
    :data:`MIN_RING_OUTSIDE` of 720 samples of a ring :data:`RING_PX` outside it that fall inside
    the image (at least 36 of them). A dark scene's edge that happens to be round is not."""
    H, W = outside.shape
    a = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    x, y = centre[0] + (radius + RING_PX) * np.cos(a), centre[1] + (radius + RING_PX) * np.sin(a)
    seen = (x >= 3) & (x < W - 3) & (y >= 3) & (y < H - 3)
    xi, yi = np.rint(x[seen]).astype(int), np.rint(y[seen]).astype(int)
    return bool(seen.sum() >= 36 and outside[yi, xi].mean() >= MIN_RING_OUTSIDE)


def _near_circle(p: np.ndarray, centre: np.ndarray, radius: float, band: float) -> np.ndarray:
    """(N,) bool: the points p (N, 2) within ``band`` of the circle (``centre`` (2,), ``radius``)."""
    return np.abs(np.hypot(p[:, 0] - centre[0], p[:, 1] - centre[1]) - radius) < band


def _algebraic_circle(p: np.ndarray) -> tuple[np.ndarray, float] | None:
    """The least-squares circle ``|p|^2 = 2 c . p + (r^2 - |c|^2)`` through points p (N, 2): its
    centre (2,) and radius; None where the points fit no circle (fewer than three, or on a line).

    Solved about the points' mean, where the normal equations split into a 2 x 2 system for the
    centre and the mean for the constant (the same least-squares circle: moving the points moves
    it with them), in sums rather than a factorisation of the (N, 3) system (about 10x faster on the
    few thousand edge pixels of a frame)."""
    if len(p) < 3:
        return None
    m = p.mean(0)
    u, v = p[:, 0] - m[0], p[:, 1] - m[1]
    z = u * u + v * v
    suu, suv, svv = float(u @ u), float(u @ v), float(v @ v)
    det = suu * svv - suv * suv
    if not det > 1e-12 * max(suu * svv, 1e-300):
        return None
    suz, svz = float(u @ z), float(v @ z)
    a, b = (svv * suz - suv * svz) / det, (suu * svz - suv * suz) / det  # 2 c, about the mean
    cx, cy = a / 2, b / 2
    r2 = float(z.mean()) + cx * cx + cy * cy
    return (np.array([m[0] + cx, m[1] + cy]), float(np.sqrt(r2))) if np.isfinite(r2) and r2 > 0 else None


# The unit square's projective basis: [u0 u1 u3] mu = u2 gives mu = (-1, 1, 1), and its map is
# B = [u0 u1 u3] diag(mu) (corners as homogeneous columns); :func:`ray_homographies` uses B^-1.
_UNIT_SQUARE_BASIS_INV = np.linalg.inv(np.array([[0.0, 1, 0], [0, 0, 1], [1, 1, 1]]) * np.array([-1.0, 1, 1]))


def ray_homographies(v_corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per tag, the homography H (T, 3, 3) with ``v ~ H (u, v, 1)`` that takes the unit square's
    corners (0, 0), (1, 0), (1, 1), (0, 1) to the rays ``v_corners`` (T, 4, 3), scaled so that it
    gives every corner a positive multiple of its ray (a tag's points then lie in front of the
    lens, however far off-axis); and (T,) bool whether it does (else three of the rays lie in one
    plane through the lens, or the four cross the line at infinity: no view of a plane's square).

    Through the projective basis: ``P = [p0 p1 p3] diag(lam)`` with ``[p0 p1 p3] lam = p2`` takes
    e1, e2, e3 and (1, 1, 1) to the four corners, and H is that of the rays after the inverse of
    the unit square's own."""
    v = np.asarray(v_corners, np.float64)
    A = v[:, [0, 1, 3]].transpose(0, 2, 1)  # (T, 3, 3): the rays of corners 0, 1, 3 as columns
    det = np.linalg.det(A)
    ok = np.isfinite(det) & (np.abs(det) > 1e-9)
    A = np.where(ok[:, None, None], A, np.eye(3))
    lam = np.linalg.solve(A, np.where(ok[:, None], v[:, 2], 1.0)[..., None])[..., 0]  # (T, 3)
    # H = A diag(lam) B^-1 (B^-1: _UNIT_SQUARE_BASIS_INV); corner i goes to lam_i / mu_i times its ray (corner 2: to p2 itself).
    H = (A * lam[:, None, :]) @ _UNIT_SQUARE_BASIS_INV
    # Corner 2 goes to its ray itself; the others' multiples must be positive too.
    ok &= ((lam * np.array([-1.0, 1, 1])) > 0).all(1) & np.isfinite(H).all((1, 2))
    return H, ok


def local_views(q: np.ndarray, lens: EquidistantLens) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """N sets of pixels q (N, K, 2) as each set's own pinhole view of their rays under ``lens``:
    the rays turned so that their mean lies on the axis (``R`` (N, 3, 3), ``R v``) and divided by
    their depth, (N, K, 2). A plane's points map to these views by a homography, as they map to
    the rays. Also (N,) bool: every ray of the set within 84 deg of its mean (else the set spans
    too much of the sphere for one view; a set of nearby corners never does)."""
    v = lens.lift(q)
    z = v.mean(1)
    z /= np.maximum(np.linalg.norm(z, axis=-1, keepdims=True), 1e-12)
    helper = np.where(np.abs(z[:, :1]) < 0.9, np.array([1.0, 0, 0]), np.array([0.0, 1, 0]))
    x = np.cross(helper, z)
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    R = np.stack([x, np.cross(z, x), z], 1)  # rows: the view's axes
    w = np.einsum("nij,nkj->nki", R, v)
    ok = (w[..., 2] > 0.1).all(1)
    return w[..., :2] / np.where(w[..., 2:] > 0.1, w[..., 2:], 1.0), R, ok


def _in_front(h: np.ndarray, w: np.ndarray) -> np.ndarray:
    """h / w for homogeneous points (h (..., 2), w (..., 1)); NaN where w is not positive (behind)."""
    return np.where(w > 1e-12, h / np.where(w > 1e-12, w, 1.0), np.nan)


def _through(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Homographies H (K, 3, 3) applied to points p (K, M, 2) -> (K, M, 2); NaN behind (see
    :func:`_in_front`: the maps are oriented so that the points in front have a positive scale)."""
    return _in_front(p @ H[:, :2, :2].transpose(0, 2, 1) + H[:, None, :2, 2], p @ H[:, 2, :2, None] + H[:, None, 2, 2:])


@dataclass
class PlaneMaps:
    """K maps from points of a plane (the board, metres) to pixels: homographies ``H`` (K, 3, 3)
    straight to the image, or, with ``lens``, to each map's own view of the rays (``R`` (K, 3, 3),
    :func:`local_views`) and on through the lens."""

    H: np.ndarray  # (K, 3, 3) board points -> pixels, or -> the local views
    R: np.ndarray | None = None  # (K, 3, 3) the local views' axes (rows), with a lens
    lens: EquidistantLens | None = None  # the lens the views' rays go through; None: H maps to pixels

    def __call__(self, p: np.ndarray) -> np.ndarray:
        """Board points p (K, M, 2) -> pixels (K, M, 2); NaN behind a map's horizon."""
        g = _through(self.H, np.asarray(p, np.float64))
        if self.lens is None:
            return g
        v = np.concatenate([g, np.ones_like(g[..., :1])], -1) @ self.R  # R^T (g, 1): back to the camera's rays
        return self.lens.project(v)

    def to_plane(self, q: np.ndarray) -> np.ndarray:
        """Pixels q (K, M, 2) -> the plane's points (K, M, 2) under each map (the inverse of
        calling it); NaN where a pixel's ray misses the plane in front."""
        g = np.asarray(q, np.float64)
        if self.lens is not None:
            w = self.lens.lift(g) @ self.R.transpose(0, 2, 1)  # R v: the rays in each map's view
            g = _in_front(w[..., :2], w[..., 2:])
        return _through(np.linalg.inv(self.H), g)

    def take(self, idx: np.ndarray | int) -> PlaneMaps:
        """The maps ``idx`` (an index array, a mask, or one index kept as a batch of one)."""
        idx = np.atleast_1d(idx)
        return PlaneMaps(self.H[idx], None if self.R is None else self.R[idx], self.lens)
