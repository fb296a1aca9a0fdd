"""Frames from a second, independent renderer: ``python -m calib_eval.detection.foreign [--target KIND | --board YAML]
[--photo] [--isp] [--defocus SIGMA]``.

Our detectors are judged on frames other renderers draw, and everything they were tuned on came
from one renderer (:mod:`cotrain.render`, kornia). This module draws frames another way, sharing
none of that code: numpy and OpenCV only, the lens as a closed-form radial law, the board as a
texture sampled by ray casting with a box filter, and the sensor in linear light encoded as sRGB.
Then it runs our detector and the detectors a user would otherwise pick on the same frames
(checkerboard: ``findChessboardCornersSB``; AprilGrid: the peers of ``python -m
calib_eval.detection.tags``) and scores them (:func:`calib_eval.detection.evaluation.score`, so
the figures read like ``calib-eval detection``'s). A set rendered before with the same settings
is reused.

- Lens: the image radius of a ray ``theta`` off the axis follows one of three classic fisheye
  laws (:data:`LENSES`: equidistant ``f theta``, equisolid ``2 f sin(theta / 2)``, stereographic
  ``2 f tan(theta / 2)``), each with its closed-form inverse; the image circle (the FoV's edge)
  has a radius of 0.5-0.75 of the frame's height, so the frame's top and bottom may cut it.
  Beyond it the frame is black.
- Board: the default target of its kind (10 x 7 squares of 40 mm with half a square of white
  margin, drawn from its numbers; or Kalibr's 6 x 6 AprilGrid of 55 mm tags, its page drawn again
  from OpenCV's marker images, :func:`aprilgrid_texture`), or the board of a target file
  (``--board``: Kalibr's target yaml or ours; on a board that looks the same under a half turn,
  a frame's ids count under either of the equivalent sets), its centre 0.15-0.6 m away, 0-(FoV / 2
  - 5) deg off the axis, turned 0-60 deg from facing the camera and any angle in its plane. Print:
  black 0.03-0.15, white 0.7-0.95.
- Scene: a background of smooth shading and random grey shapes; in a third of the frames a grey
  occluder in front of the board.
- Optics and sensor: ``supersample`` x ``supersample`` rays per pixel (box filter), a Gaussian
  lens blur of 0.3-1.0 px, vignetting down to 0.5-0.9 at the rim (quadratic in theta), an
  exposure of 0.6-1.3, shot and read noise, sRGB encoding to 8 bits, and in half the frames JPEG
  at quality 70-95.
- ``--photo`` (:attr:`ForeignConfig.photo`): what a camera sees of a print in a room. Print: black
  0.12-0.3, white 0.35-0.65 (grey paper, dim light); light across the board falling by 20-60 %
  along a random direction, and in half the frames a shadow's soft edge (3-15 px) darkening one
  side to 0.35-0.7; in half the frames a glare blob on the print (amplitude 0.4-1.5 of white
  light, 3-10 % of the frame's height wide; corners within a quarter of their size, 3 px at
  least, of a saturated pixel are not detectable); read noise 3-5x higher (its sigma); JPEG at
  quality 50-85 in every frame. A frame's lens, pose and background are its clean twin's (the
  same seed draws them first); its occluder, blur, vignetting, exposure, noise and JPEG are drawn
  anew.
- ``--isp`` (:attr:`ForeignConfig.isp`): a colour camera's image processing before the JPEG. The
  8-bit frame is taken as the sensor's Bayer mosaic (one of the four layouts) under white-balance
  gains (red 1.5-2.2, blue 1.3-1.9, green 1). It is demosaiced by OpenCV (bilinear or
  edge-aware), the gains are applied and the result turned grey. It is then sharpened by an
  unsharp mask (amount 0.6-1.5, sigma 0.8-1.6 px), with the dark and bright halos along edges
  that phone, action and many USB cameras leave. The labels are the clean frame's. Combines with
  ``--photo``.
- ``--defocus SIGMA`` (:attr:`ForeignConfig.defocus`): a soft lens (many fisheye lenses at their
  rim, or focused for another distance): the lens blur is widened to the root sum of squares of
  the drawn one and SIGMA px. The frames are otherwise their sharp twins (the same draws); a
  Gaussian blur leaves an X-junction where it is, so the labels stay, and so does what is
  detectable (but under ``--photo``, where the glare's saturated pixels are found after the blur).

Labels: every corner's projection through the same closed-form law (an independent check of our
geometry is in the tests: the equidistant law against ``cv2.fisheye.projectPoints``). A corner is
visible when it lies on the board's printed side, inside the image circle and the frame, and not
under the occluder; detectable when also 3 px inside the circle, 2 px inside the frame, clear of
the occluder by 3 px and a quarter of its size, and that size in the image is 10 px at least for
a checkerboard (the shortest step to a neighbour, as in ``calib-eval detection``) or 8 px for an
AprilGrid (the shorter side of its tag, as in ``python -m calib_eval.detection.tags``). A corner
reported at a visible corner's label (within 3 px) with its id counts as right; at a hidden
one's, apart ("labelled hidden"); farther, or with another id, as wrong.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from calib_eval.detection.evaluation import score
from calib_eval.detection.opencv_baseline import find_chessboard
from cotrain.progress import progress_bar
from cotrain.targets import AprilGrid, Checkerboard, TargetConfig, load_target

# The radial laws: image radius rho(theta) / f and its inverse theta(rho / f).
LENSES = {
    "equidistant": (lambda t: t, lambda r: r),
    "equisolid": (lambda t: 2 * np.sin(t / 2), lambda r: 2 * np.arcsin(np.clip(r / 2, -1, 1))),
    "stereographic": (lambda t: 2 * np.tan(t / 2), lambda r: 2 * np.arctan(r / 2)),
}


@dataclass
class ForeignConfig:
    fovs: tuple[int, ...] = (180, 200, 220, 240)  # full field of view of each row, degrees
    per_fov: int = 24  # frames per FoV (each with a board)
    width: int = 1280  # frame size, pixels
    height: int = 720
    seed: int = 5  # everything random derives from it
    supersample: int = 3  # rays per pixel side (box filter over the pixel)
    target: str = "checkerboard"  # the board drawn: "checkerboard" (10 x 7 squares) or "aprilgrid" (Kalibr's 6 x 6 tags) ...
    board: str = ""  # ... or the board of this target file (Kalibr's target yaml or ours; its kind then sets target)
    min_square_px: float = 10.0  # detectable: a checkerboard corner's square at least this many pixels ...
    min_tag_px: float = 8.0  # ... an AprilGrid corner's tag at least this many (as python -m calib_eval.detection.tags)
    min_visible: int = 6  # frames are drawn again until this many corners are detectable
    photo: bool = False  # photographed prints: grey paper, uneven light and shadow, glare, more noise, JPEG in every frame
    isp: bool = False  # a colour camera's processing before the JPEG: Bayer mosaic, white balance, demosaicing, sharpening
    defocus: float = 0.0  # a soft lens: this Gaussian blur (px, sigma) on top of the drawn lens blur, in quadrature


@dataclass
class Frame:
    image: np.ndarray  # (H, W) uint8, sRGB-encoded
    corners: np.ndarray  # (N, 2) pixel positions of every corner id (docs/conventions.md)
    visible: np.ndarray  # (N,) bool
    detectable: np.ndarray  # (N,) bool
    lens: str
    jpeg: int  # JPEG quality applied, 0 for none
    centre: np.ndarray  # (2,) the image circle's centre, pixels
    radius: float  # the image circle's radius, pixels
    size: np.ndarray  # (N,) each corner's square (checkerboard) or tag side (AprilGrid) in the image, pixels


def rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` (rad) about unit ``axis`` (Rodrigues)."""
    return cv2.Rodrigues((np.asarray(axis, float) / np.linalg.norm(axis) * angle).reshape(3, 1))[0]


def project(p: np.ndarray, lens: str, f: float, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (..., 2) of camera-frame points p (..., 3) through radial law ``lens`` with focal
    length f (px) and image centre (2,), and each point's angle off the axis (...,) in rad."""
    theta = np.arctan2(np.hypot(p[..., 0], p[..., 1]), p[..., 2])
    phi = np.arctan2(p[..., 1], p[..., 0])
    rho = f * LENSES[lens][0](theta)
    return centre + np.stack([rho * np.cos(phi), rho * np.sin(phi)], -1), theta


def rays(xy: np.ndarray, lens: str, f: float, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit rays (..., 3) of pixels xy (..., 2) and their angle off the axis (...,) (the inverse of
    :func:`project`)."""
    d = xy - centre
    theta = LENSES[lens][1](np.hypot(d[..., 0], d[..., 1]) / f)
    phi = np.arctan2(d[..., 1], d[..., 0])
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], -1), theta


@functools.lru_cache(maxsize=2)
def checkerboard_texture(board: Checkerboard):
    """The checkerboard's print: (u, v) board-frame metres (..., ) -> (reflectance in [0, 1], bool
    on the sheet). Squares from 0 to squares_x s, square (0, 0) black, ``board.cfg.margin``
    squares of white margin; drawn from the target's numbers alone."""
    s, cfg = board.s, board.cfg
    m = cfg.margin * s

    def texture(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cu, cv = np.floor(u / s), np.floor(v / s)
        in_squares = (cu >= 0) & (cu < cfg.squares_x) & (cv >= 0) & (cv < cfg.squares_y)
        dark = in_squares & ((cu + cv) % 2 == 0)
        cover = (u >= -m) & (u <= cfg.squares_x * s + m) & (v >= -m) & (v <= cfg.squares_y * s + m)
        return np.where(dark, 0.0, 1.0), cover

    return texture


@functools.lru_cache(maxsize=2)  # one page per board, not per frame
def aprilgrid_texture(board: AprilGrid, px_per_cell: int = 8):
    """The AprilGrid's print as Kalibr's ``createTargetPDF.py`` lays it out, drawn here again from
    OpenCV's marker images (not from :class:`cotrain.targets.AprilGrid`'s texture): the page frame
    has x to the right and y up, tag t sits at column t % tag_cols and row t // tag_cols from the
    bottom left, each tag is its marker with a 2-cell black border turned by a half turn, and a
    black square fills every gap crossing. Returns (u, v) metres -> (reflectance, bool on the
    sheet), sampled from a raster of ``px_per_cell`` pixels per tag cell (nearest pixel)."""
    S, gap, tc, tr = board.S, board.gap, board.tc, board.tr
    cell = S / 10
    x0, y0, x1, y1 = board.extent()
    px = cell / px_per_cell  # metres per raster pixel
    W, H = int(np.ceil((x1 - x0) / px)), int(np.ceil((y1 - y0) / px))
    page = np.ones((H, W), np.float32)
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)

    def fill(xa: float, ya: float, xb: float, yb: float, img) -> None:  # page metres (y up) -> raster rows
        c0, c1 = int(round((xa - x0) / px)), int(round((xb - x0) / px))
        r0, r1 = int(round((y1 - yb) / px)), int(round((y1 - ya) / px))
        page[r0:r1, c0:c1] = img if np.isscalar(img) else cv2.resize(img, (c1 - c0, r1 - r0), interpolation=cv2.INTER_NEAREST)

    for t in range(tc * tr):
        marker = cv2.aruco.generateImageMarker(d, t, 10, borderBits=2).astype(np.float32) / 255  # one pixel per cell
        xa, ya = (t % tc) * (S + gap), (t // tc) * (S + gap)
        fill(xa, ya, xa + S, ya + S, np.rot90(marker, 2))
    for i in range(-1, tc):
        for j in range(-1, tr):
            xa, ya = i * (S + gap) + S, j * (S + gap) + S
            fill(xa, ya, xa + gap, ya + gap, 0.0)

    def texture(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = np.floor((u - x0) / px).astype(np.int64)
        r = np.floor((y1 - v) / px).astype(np.int64)
        cover = (c >= 0) & (c < W) & (r >= 0) & (r < H)
        return page[np.clip(r, 0, H - 1), np.clip(c, 0, W - 1)], cover

    return texture


def background(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """(h, w) linear-light reflectance: smooth shading, random grey shapes, fine texture."""
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    img = rng.uniform(0.15, 0.6) + rng.uniform(-0.2, 0.2) * xx + rng.uniform(-0.2, 0.2) * yy
    img = img.astype(np.float32)
    for _ in range(rng.integers(3, 9)):
        c = (int(rng.uniform(0, w)), int(rng.uniform(0, h)))
        col = float(rng.uniform(0.05, 0.9))
        if rng.random() < 0.5:
            axes = (int(rng.uniform(20, w / 3)), int(rng.uniform(20, h / 3)))
            cv2.ellipse(img, c, axes, float(rng.uniform(0, 180)), 0, 360, col, -1)
        else:
            pts = rng.uniform([0, 0], [w, h], (4, 2)).astype(np.int32)
            cv2.fillConvexPoly(img, cv2.convexHull(pts), col)
    small = rng.normal(0, 0.05, (h // 16 + 1, w // 16 + 1)).astype(np.float32)
    img += cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
    return np.clip(img, 0.02, 0.95)


def board_pixels(xy: np.ndarray, R: np.ndarray, t: np.ndarray, lens: str, f: float, centre: np.ndarray) -> np.ndarray:
    """Pixels (..., 2) of board-frame points xy (..., 2) (metres, z = 0) for the board pose R (3, 3),
    t (3,) in the camera frame (:func:`project`)."""
    return project(xy @ R[:, :2].T + t, lens, f, centre)[0]


def corner_steps(board: Checkerboard | AprilGrid, p_at) -> tuple[np.ndarray, np.ndarray]:
    """Each corner id's pixel (N, 2) and its size in the image (N,): for a checkerboard the
    shortest step to a neighbouring corner (the neighbours beyond the board's last corners
    included), for an AprilGrid the shorter side of its tag. ``p_at(xy)`` maps board-frame
    metres (..., 2) to pixels (..., 2) (:func:`board_pixels`)."""
    n = board.n_corners
    ij = board.ij_of(np.arange(n))
    if isinstance(board, AprilGrid):
        q = p_at(board.board_xy())
        partner_x = board.id_of(np.stack([ij[:, 0] ^ 1, ij[:, 1]], 1))  # the tag's other corner along x
        partner_y = board.id_of(np.stack([ij[:, 0], ij[:, 1] ^ 1], 1))
        return q, np.minimum(np.linalg.norm(q - q[partner_x], axis=1), np.linalg.norm(q - q[partner_y], axis=1))
    q = p_at((ij + 1) * board.s)
    size = np.full(n, np.inf)
    for step in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        size = np.minimum(size, np.linalg.norm(p_at((ij + 1 + step) * board.s) - q, axis=1))
    return q, size


def render_frame(fov: float, cfg: ForeignConfig, rng: np.random.Generator, board: Checkerboard | AprilGrid | None = None) -> Frame:
    """One frame with ``board`` (default the checkerboard) at least partly in view (drawn again
    until ``cfg.min_visible`` corners are detectable)."""
    board = board or Checkerboard()
    texture = aprilgrid_texture(board) if isinstance(board, AprilGrid) else checkerboard_texture(board)
    h, w = cfg.height, cfg.width
    x0, y0, x1, y1 = board.extent()
    while True:
        lens = str(rng.choice(list(LENSES)))
        theta_max = np.radians(fov / 2)
        radius = rng.uniform(0.5, 0.75) * h  # the image circle, px
        f = radius / LENSES[lens][0](theta_max)
        centre = np.array([w / 2 - 0.5, h / 2 - 0.5]) + rng.normal(0, 8, 2)
        # The board: its centre off the axis, facing the camera within 60 deg, turned in its plane;
        # its z axis points away from the viewer (checkerboard) or toward it (AprilGrid: Kalibr's
        # page frame), ``board.front``.
        off = np.radians(rng.uniform(0, fov / 2 - 5))
        az = rng.uniform(0, 2 * np.pi)
        d = np.array([np.sin(off) * np.cos(az), np.sin(off) * np.sin(az), np.cos(off)])
        dist = rng.uniform(0.15, 0.6)
        z_axis = -board.front * d
        tilt_axis = np.cross(z_axis, rng.normal(size=3))
        R = rotation(tilt_axis, np.radians(rng.uniform(0, 60))) @ _frame_with_z(z_axis)
        R = R @ rotation(np.array([0.0, 0.0, 1.0]), rng.uniform(0, 2 * np.pi))
        t = dist * d - R[:, :2] @ np.array([(x0 + x1) / 2, (y0 + y1) / 2])  # the board frame's origin

        q, size = corner_steps(board, functools.partial(board_pixels, R=R, t=t, lens=lens, f=f, centre=centre))
        pc = board.board_xy() @ R[:, :2].T + t
        _, th = project(pc, lens, f, centre)
        facing = -board.front * (pc @ R[:, 2]) > 0  # the viewer sees the printed side
        rim = np.hypot(*(q - centre).T)
        visible = facing & (th < theta_max) & (rim <= radius)
        visible &= (q[:, 0] >= -0.5) & (q[:, 0] <= w - 0.5) & (q[:, 1] >= -0.5) & (q[:, 1] <= h - 0.5)
        clear = (rim <= radius - 3) & (q[:, 0] >= 2) & (q[:, 0] <= w - 3) & (q[:, 1] >= 2) & (q[:, 1] <= h - 3)
        min_size = cfg.min_tag_px if isinstance(board, AprilGrid) else cfg.min_square_px
        if (visible & clear & (size >= min_size)).sum() >= cfg.min_visible:
            break
    # Ray casting, supersampled: every sample's board point, reflectance and coverage.
    s = cfg.supersample
    off_s = (np.arange(s) + 0.5) / s - 0.5
    acc = np.zeros((h, w), np.float64)
    bg = background(h, w, rng).astype(np.float64)
    black, white = (rng.uniform(0.12, 0.3), rng.uniform(0.35, 0.65)) if cfg.photo else (rng.uniform(0.03, 0.15), rng.uniform(0.7, 0.95))
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    light = room_light(xs, ys, q[visible].mean(0), rng) if cfg.photo else 1.0  # on the print only
    on_print = np.zeros((h, w))
    for oy in off_s:
        for ox in off_s:
            v, theta = rays(np.stack([xs + ox, ys + oy], -1), lens, f, centre)
            denom = v @ R[:, 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                lam = (t @ R[:, 2]) / denom
            hit = (lam > 0) & (-board.front * denom > 0)  # the printed side, in front
            pb = (lam[..., None] * v - t) @ R[:, :2]  # board-frame (u, v) of the hit
            refl, cover = texture(pb[..., 0], pb[..., 1])
            sample = np.where(hit & cover, light * (black + (white - black) * refl), bg)
            sample = np.where(theta <= theta_max, sample, 0.0)
            acc += sample
            on_print += hit & cover & (theta <= theta_max)
    img = acc / (s * s)
    if cfg.photo and rng.random() < 0.5:  # glare: a specular blob on the print (adds light where the print is)
        k = int(rng.choice(np.nonzero(visible)[0]))
        c = q[k] + rng.normal(0, 2 * np.median(size[np.isfinite(size)]), 2)
        sigma = rng.uniform(0.03, 0.1) * h
        img = img + rng.uniform(0.4, 1.5) * np.exp(-((xs - c[0]) ** 2 + (ys - c[1]) ** 2) / (2 * sigma**2)) * on_print / (s * s)
    # An occluder in a third of the frames, in front of everything: corners under it are hidden,
    # corners within 3 px of it (or a quarter of their square) are not detectable.
    if rng.random() < 1 / 3:
        mask = np.zeros((h, w), np.uint8)
        k = int(rng.integers(board.n_corners))
        c = q[k] + rng.normal(0, 3 * np.median(size[np.isfinite(size)]), 2)
        axes = (int(rng.uniform(30, w / 5)), int(rng.uniform(30, h / 4)))
        cv2.ellipse(mask, (int(c[0]), int(c[1])), axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
        img = np.where(mask > 0, rng.uniform(0.1, 0.8), img)
        dist = cv2.distanceTransform((mask == 0).astype(np.uint8), cv2.DIST_L2, 5)
        qi = np.clip(np.round(q).astype(int), 0, [w - 1, h - 1])
        d_occ = dist[qi[:, 1], qi[:, 0]]
        visible &= d_occ > 0
        clear &= d_occ > np.maximum(3.0, 0.25 * size)
    # Optics and sensor, in linear light; then sRGB.
    img = cv2.GaussianBlur(img, (0, 0), math.hypot(rng.uniform(0.3, 1.0), cfg.defocus))
    _, theta_px = rays(np.stack([xs, ys], -1), lens, f, centre)
    img = img * (1 - rng.uniform(0.1, 0.5) * (np.minimum(theta_px, theta_max) / theta_max) ** 2) * rng.uniform(0.6, 1.3)
    if cfg.photo:  # a corner next to a saturated pixel cannot be found where it is: not detectable
        d_sat = cv2.distanceTransform((img < 0.98).astype(np.uint8), cv2.DIST_L2, 5)
        qi = np.clip(np.round(q).astype(int), 0, [w - 1, h - 1])
        clear &= d_sat[qi[:, 1], qi[:, 0]] > np.maximum(3.0, 0.25 * np.nan_to_num(size))
    z, shot = rng.normal(0, 1, img.shape), rng.uniform(1e-4, 6e-4)  # noise, shot and read
    read = rng.uniform(3e-5, 4e-4) if cfg.photo else rng.uniform(1e-6, 4e-5)
    img = img + z * np.sqrt(np.maximum(img, 0) * shot + read)
    img = np.clip(img, 0, 1)
    srgb = np.where(img <= 0.0031308, 12.92 * img, 1.055 * img ** (1 / 2.4) - 0.055)
    u8 = np.round(srgb * 255).astype(np.uint8)
    jpeg = int(rng.integers(50, 86)) if cfg.photo else int(rng.integers(70, 96)) if rng.random() < 0.5 else 0
    if cfg.isp:  # drawn after everything else: the frame is its clean twin processed
        u8 = camera_isp(u8, rng)
    if jpeg:
        u8 = cv2.imdecode(cv2.imencode(".jpg", u8, [cv2.IMWRITE_JPEG_QUALITY, jpeg])[1], cv2.IMREAD_GRAYSCALE)
    return Frame(u8, q, visible, visible & clear & (size >= min_size), lens, jpeg, centre, float(radius), size)


# OpenCV's demosaicing codes per Bayer layout (bilinear, edge-aware) and where its red and blue sites are.
BAYER = {
    "BG": (cv2.COLOR_BayerBG2BGR, cv2.COLOR_BayerBG2BGR_EA, (0, 0), (1, 1)),
    "GB": (cv2.COLOR_BayerGB2BGR, cv2.COLOR_BayerGB2BGR_EA, (0, 1), (1, 0)),
    "RG": (cv2.COLOR_BayerRG2BGR, cv2.COLOR_BayerRG2BGR_EA, (1, 1), (0, 0)),
    "GR": (cv2.COLOR_BayerGR2BGR, cv2.COLOR_BayerGR2BGR_EA, (1, 0), (0, 1)),
}


def camera_isp(u8: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A colour camera's processing of the (H, W) uint8 grey frame ``u8``: its Bayer mosaic under
    white-balance gains, demosaiced by OpenCV, the gains applied, turned grey, then sharpened by an
    unsharp mask. Returns (H, W) uint8. The mosaic of a grey scene is grey / gain at each site, so
    the colour interpolation meets at edges and leaves a zipper there, as a real sensor's does."""
    layout = list(BAYER)[int(rng.integers(len(BAYER)))]
    bilinear, edge_aware, (ry, rx), (by, bx) = BAYER[layout]
    gain_r, gain_b = rng.uniform(1.5, 2.2), rng.uniform(1.3, 1.9)
    code = edge_aware if rng.random() < 0.5 else bilinear
    amount, sigma = rng.uniform(0.6, 1.5), rng.uniform(0.8, 1.6)
    raw = u8.astype(np.float32)
    raw[ry::2, rx::2] /= gain_r
    raw[by::2, bx::2] /= gain_b
    bgr = cv2.cvtColor(np.round(raw).astype(np.uint8), code).astype(np.float32) * np.float32([gain_b, 1.0, gain_r])
    grey = cv2.cvtColor(np.clip(bgr, 0, 255), cv2.COLOR_BGR2GRAY)
    sharp = grey + amount * (grey - cv2.GaussianBlur(grey, (0, 0), sigma))
    return np.clip(np.round(sharp), 0, 255).astype(np.uint8)


def room_light(xs: np.ndarray, ys: np.ndarray, at: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(h, w) light falling on a print in a room (``xs``, ``ys``: pixel grids; ``at`` (2,): where the
    board is seen): down by 20-60 % along a random direction across the frame, and in half the
    frames a shadow's soft edge (3-15 px) through a point near ``at`` darkening one side to
    0.35-0.7."""
    h, w = xs.shape
    a = rng.uniform(0, 2 * np.pi)
    along = ((xs - w / 2) * np.cos(a) + (ys - h / 2) * np.sin(a)) / np.hypot(w, h) + 0.5  # 0..1 across the frame
    light = 1 - rng.uniform(0.2, 0.6) * np.clip(along, 0, 1)
    if rng.random() < 0.5:
        b = rng.uniform(0, 2 * np.pi)
        c = at + rng.normal(0, 0.05 * h, 2)
        signed = (xs - c[0]) * np.cos(b) + (ys - c[1]) * np.sin(b)  # px from the shadow's edge
        shade = rng.uniform(0.35, 0.7)
        with np.errstate(over="ignore"):  # far on the shaded side exp overflows to inf: the logistic is 0 there (light x shade)
            light = light * (shade + (1 - shade) / (1 + np.exp(-signed / (rng.uniform(3, 15) / 4))))
    return light


def _frame_with_z(z: np.ndarray) -> np.ndarray:
    """(3, 3) rotation whose third column is unit z (its first two any orthonormal pair)."""
    z = z / np.linalg.norm(z)
    a = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(a, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], 1)


def make_board(cfg: ForeignConfig) -> Checkerboard | AprilGrid:
    """The board of the target file ``cfg.board``, else the default target of ``cfg.target``'s kind
    (configs/). Raises ValueError (one line) for a file that describes no board, or one of another
    kind than ``cfg.target``."""
    if cfg.board:
        board = load_target(cfg.board)
        if board.kind != cfg.target:
            raise ValueError(f"{cfg.board}: describes a {board.kind} board, and --target says {cfg.target}")
        return board
    if cfg.target == "checkerboard":
        return Checkerboard()
    if cfg.target == "aprilgrid":
        return AprilGrid(TargetConfig(kind="aprilgrid"))
    raise ValueError(f"target must be checkerboard or aprilgrid, not {cfg.target!r}")


def render_set(out: Path, cfg: ForeignConfig, progress: bool = True) -> list[dict]:
    """Frames and labels (``out/images/*.png``, ``out/labels.json``, the layout of ``calib-eval
    detection``'s sets); returns the labels."""
    board = make_board(cfg)
    (out / "images").mkdir(parents=True, exist_ok=True)
    labels = []
    jobs = [(fov, i) for fov in cfg.fovs for i in range(cfg.per_fov)]
    for fov, i in progress_bar(jobs, desc=f"render {cfg.target} (independent renderer)", unit="img", enabled=progress):
        fr = render_frame(fov, cfg, np.random.default_rng([cfg.seed, fov, i]), board)
        name = f"fov{fov}_{i:03d}.png"
        cv2.imwrite(str(out / "images" / name), fr.image)
        labels.append(
            {
                "image": name,
                "fov": fov,
                "condition": None,
                "model": fr.lens,
                "jpeg": fr.jpeg,
                "has_target": True,
                "corners": fr.corners.tolist(),
                "visible": fr.visible.tolist(),
                "detectable": fr.detectable.tolist(),
                "centre": fr.centre.tolist(),
                "radius": fr.radius,
                "size_px": fr.size.tolist(),
            }
        )
    (out / "labels.json").write_text(json.dumps({"config": asdict(cfg), "target": board.to_json(), "labels": labels}))
    return labels


def detect_set(out: Path, labels: list[dict], board: Checkerboard | AprilGrid, progress: bool = True) -> dict[str, dict]:
    """Our detector and the peers a user would otherwise pick on the set's frames: predictions
    (``calib_eval.detection.evaluation.score``'s input) by detector name. Checkerboard: ours as
    ``cotrain detect`` runs by default and with ``--grey-print``, and ``findChessboardCornersSB``
    (corners without trusted ids, matched by position). AprilGrid: the
    tag detectors of ``python -m calib_eval.detection.tags`` that are installed (cv2.aruco always),
    each in a process of its own, each tag's corners taking its Kalibr ids. Times are per frame, decoding left out."""
    from calib_eval.detection.tags import run_peers, tags_to_corners
    from cotrain.detect.buffers import keep_image_buffers
    from cotrain.detect.detector import make_detector
    from cotrain.detect.grid_config import GREY_PRINT_GAIN, GridConfig

    keep_image_buffers()  # as cotrain detect runs (cotrain.detect.buffers); the peers are timed under it too
    runs: dict = {"ours": make_detector(board).detect}
    if isinstance(board, Checkerboard):
        # Frames giving nothing read again with their contrast raised, as cotrain detect --grey-print does.
        runs["ours --grey-print"] = make_detector(board, grid=GridConfig(retry_gain=GREY_PRINT_GAIN)).detect
        runs["opencv_sb"] = None
    preds: dict[str, dict] = {}
    for name, run in runs.items():  # one detector over every frame, then the next (as calib_eval.detection.tags)
        preds[name] = {}
        for lab in progress_bar(labels, desc=name, unit="img", enabled=progress):
            grey = cv2.imread(str(out / "images" / lab["image"]), cv2.IMREAD_GRAYSCALE)
            t0 = time.perf_counter()
            if name.startswith("ours"):
                d = run(grey)
                corners = [[int(i), float(x), float(y)] for i, (x, y) in zip(d.ids, d.xy)]
            else:
                c = find_chessboard(grey, (board.nx, board.ny), "sb")
                corners = [[-1, float(x), float(y)] for x, y in c] if c is not None else []
            preds[name][lab["image"]] = {"corners": corners, "ms": 1000 * (time.perf_counter() - t0), "has_id": name.startswith("ours")}
    if isinstance(board, AprilGrid):
        # Each peer in a process of its own (tags.run_peers: a crash in its library ends its row only).
        for name, found in run_peers([out / "images" / lab["image"] for lab in labels], progress=progress).items():
            preds[name] = {}
            for lab, (tags, ms) in zip(labels, found):
                ids, xy = tags_to_corners(tags, board, np.array(lab["corners"]))
                corners = [[int(i), float(q[0]), float(q[1])] for i, q in zip(ids, xy)]
                preds[name][lab["image"]] = {"corners": corners, "ms": ms, "has_id": True}
    return preds


def table(results: dict[str, dict], fovs: tuple[int, ...]) -> str:
    """Markdown: recall per FoV and over all, wrong corners, mean error of the recalled corners
    and median ms per image, per detector."""
    head = (
        "| detector | " + " | ".join(f"FoV {f}" for f in fovs) + " | all | wrong corners | labelled hidden | mean err (px) | ms / image |"
    )
    rows = [head, "|" + " --- |" * (len(fovs) + 6)]
    for name, r in results.items():
        per = r["per_fov"]
        det = sum(per[str(f)]["n_detectable"] for f in fovs)
        hit = sum(per[str(f)]["recall"] * per[str(f)]["n_detectable"] for f in fovs)
        wrong = sum(round(per[str(f)]["outlier_rate"] * per[str(f)]["n_reported"]) for f in fovs)
        hidden = sum(per[str(f)]["n_hidden"] for f in fovs)
        errors = [e for f in fovs for e in r["errors"].get(str(f), [])]
        mean = float(np.mean(errors)) if errors else float("nan")
        cells = " | ".join(f"{per[str(f)]['recall']:.3f}" for f in fovs)
        rows.append(f"| {name} | {cells} | {hit / max(det, 1):.3f} | {wrong} | {hidden} | {mean:.3f} | {r['ms_per_image']:.1f} |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    usage = " ".join(__doc__.split("\n\n")[0].split())  # the docstring's first paragraph, on one line
    ap = argparse.ArgumentParser(description=usage, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--target", choices=("checkerboard", "aprilgrid"), default=None, help="the board drawn: its kind's default")
    ap.add_argument("--board", type=Path, default=None, help="a target file (Kalibr's target yaml or ours): its board is drawn")
    ap.add_argument("--per-fov", type=int, default=ForeignConfig.per_fov, help="frames per FoV")
    ap.add_argument("--seed", type=int, default=ForeignConfig.seed)
    ap.add_argument("--photo", action="store_true", help="photographed prints: grey paper, uneven light, shadow, glare, noise, JPEG")
    ap.add_argument("--isp", action="store_true", help="a colour camera's processing: Bayer mosaic, white balance, demosaicing, sharpening")
    ap.add_argument("--defocus", type=float, default=ForeignConfig.defocus, metavar="SIGMA", help="a soft lens: SIGMA px more blur")
    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output folder (default report/foreign_<target or board>[_photo][_isp][_defocusS])",
    )
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    if a.per_fov < 1:
        print("error: --per-fov must be at least 1", file=sys.stderr)
        return 2
    if not 0 <= a.defocus <= 20:
        print("error: --defocus must be between 0 and 20 px", file=sys.stderr)
        return 2
    try:
        kind = load_target(a.board).kind if a.board else a.target or "checkerboard"
        cfg = ForeignConfig(
            per_fov=a.per_fov, seed=a.seed, target=a.target or kind, board=str(a.board or ""), photo=a.photo, isp=a.isp, defocus=a.defocus
        )
        make_board(cfg)  # a file of another kind than --target: said before anything is drawn
        out = a.out or Path(
            f"report/foreign_{a.board.stem if a.board else cfg.target}{'_photo' if a.photo else ''}{'_isp' if a.isp else ''}"
            + (f"_defocus{a.defocus:g}" if a.defocus else "")
        )
        print(evaluate(cfg, out, progress=not a.no_progress))
    except (OSError, ValueError) as e:  # an output folder that cannot be written, a broken labels.json
        print(f"error: {e}", file=sys.stderr)
        return 1
    return 0


def evaluate(cfg: ForeignConfig, out: Path, progress: bool = True) -> str:
    """Render (or reuse) the set under ``out``, run the detectors, score them; writes
    predictions.json (before scoring), results.json and results.md there and returns the latter."""
    old = out / "labels.json"
    board = make_board(cfg)
    same = {"config": json.loads(json.dumps(asdict(cfg))), "target": board.to_json()}
    if old.exists() and {k: json.loads(old.read_text()).get(k) for k in same} == same:
        labels = json.loads(old.read_text())["labels"]  # this set, rendered before with the same settings
        print(f"{out}: reusing the {len(labels)} frames rendered there with these settings", file=sys.stderr)
    else:
        labels = render_set(out, cfg, progress=progress)
    preds = detect_set(out, labels, board, progress=progress)
    (out / "predictions.json").write_text(json.dumps(preds))  # kept before scoring
    results = {name: score(p, labels, board.symmetries()) for name, p in preds.items()}
    size = f"tag {cfg.min_tag_px:g}" if cfg.target == "aprilgrid" else f"square {cfg.min_square_px:g}"
    which = f"--board {cfg.board}" if cfg.board else f"--target {cfg.target}"
    flags = (" --photo" if cfg.photo else "") + (" --isp" if cfg.isp else "") + (f" --defocus {cfg.defocus:g}" if cfg.defocus else "")
    md = (
        f"Independent renderer, {board} (`python -m calib_eval.detection.foreign {which}{flags}`, seed {cfg.seed}, "
        f"{cfg.per_fov} frames per FoV at {cfg.width}x{cfg.height}): recall of detectable corners ({size} px across at least) "
        "within 3 px, with the right id"
        + (" (findChessboardCornersSB: matched by position)" if cfg.target == "checkerboard" else " (peers: a tag's corners take its ids)")
        + ".\n\n"
        + table(results, cfg.fovs)
        + "\n"
    )
    (out / "results.md").write_text(md)
    (out / "results.json").write_text(json.dumps(results))
    return md


if __name__ == "__main__":
    raise SystemExit(main())
