"""Reading a frame again at half resolution: the corners a pass finds there and not at full resolution.

A blur of a few pixels, or squares and tags of 40-120 px, defeat the passes' windows, circles and
steps, which are fixed in pixels; at half resolution they look half as long. Both passes (the
tag pass, :mod:`cotrain.detect.tag_pass`, and the grid pass with the detector,
:mod:`cotrain.detect.grid_pass`) read a frame where they found little again at half resolution
and add what only that finds, through :func:`corners_at_half_resolution`: the two results must
agree where both report a corner, and each added corner is fitted again at full resolution and
checked against the print around it (:func:`cotrain.detect.verification.print_check`) and
against where its neighbours put it (:func:`cotrain.detect.verification.print_moved`).

Pure functions over numpy arrays; pixels follow docs/conventions.md.
"""

from __future__ import annotations

import cv2
import numpy as np

from cotrain.detect.grid_config import GridConfig
from cotrain.detect.image_circle import EquidistantLens
from cotrain.detect.print_model import CompletionConfig
from cotrain.detect.saddle import fit_saddles, outside_circle, pixel_index, smooth_cached
from cotrain.detect.verification import print_check, print_moved
from cotrain.targets import Target

# origin: not recorded (set in 771ed0f, "Checkerboard: a frame where the grid pass finds no board is read again at half resolution")
AGREE_PX = 1.5  # a corner both resolutions report must lie this close (px) in both, else the half-resolution result is not used


def halve(grey: np.ndarray) -> np.ndarray:
    """The (H, W) image at half resolution, (H // 2, W // 2), area-averaged."""
    H, W = grey.shape
    return cv2.resize(grey, (W // 2, H // 2), interpolation=cv2.INTER_AREA)


def to_full_resolution(xy: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Pixels (..., 2) of :func:`halve`'s image of a frame of ``shape`` (H, W) in the frame's
    pixels (a scale of 2, a little more along an odd side; pixel centres as docs/conventions.md)."""
    H, W = shape
    return (np.asarray(xy, np.float64) + 0.5) * np.array([W / (W // 2), H / (H // 2)]) - 0.5


def corners_at_half_resolution(
    grey: np.ndarray,
    ids: np.ndarray,
    xy: np.ndarray,
    half_ids: np.ndarray,
    half_xy: np.ndarray,
    board: Target,
    grid: GridConfig,
    check: CompletionConfig,
    min_corr: float = -1.0,
    rim_px: float = 0.0,
    lens: EquidistantLens | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """The corners a pass found at half resolution (``half_ids`` (L,) at ``half_xy`` (L, 2) in
    :func:`halve`'s pixels) that it did not find at full resolution (``ids`` (K,) at ``xy`` (K, 2))
    in the (H, W) image ``grey``, and that hold there: each is fitted again at full resolution
    (``grid.final_max_half``; it keeps its position mapped back where that fit fails or moves it
    1 px or more), lies ``rim_px`` or more from the image circle's rim, is kept by the print
    check among all the corners (held to its small margin and to ``min_corr``), and lies where its
    neighbours' maps put it (:func:`cotrain.detect.verification.print_moved`, through ``lens``,
    in the frame's pixels, where given: a heavy blur lets the half-resolution growth slide a
    corner along its tag's side, where its own print still matches best).

    Returns the indices (into ``half_ids``) of the corners added and their positions (n, 2) in the
    frame's pixels; None where a corner both report lies :data:`AGREE_PX` or more apart in the two
    (the two place the board differently: the full-resolution result stands)."""
    q = to_full_resolution(half_xy, grey.shape).reshape(-1, 2)
    at_full = dict(zip(ids.tolist(), np.asarray(xy).reshape(-1, 2)))
    if any(np.linalg.norm(at_full[i] - p) > AGREE_PX for i, p in zip(half_ids.tolist(), q) if i in at_full):
        return None
    new = np.nonzero(~np.isin(half_ids, ids))[0]
    if not len(new):
        return new, np.zeros((0, 2))
    allowed = ~outside_circle(grey)
    rim_dist = cv2.distanceTransform(allowed.astype(np.uint8), cv2.DIST_L2, 3)
    smoothed: dict[int, np.ndarray] = {}
    q_fit, fitted, _ = fit_saddles(grey, smoothed, q[new], grid.final_max_half, grid, rim_dist)
    q_new = np.where((fitted & (np.linalg.norm(q_fit - q[new], axis=1) < 1.0))[:, None], q_fit, q[new])
    all_ids = np.concatenate([ids, half_ids[new]])
    added = np.arange(len(all_ids)) >= len(ids)
    all_xy = np.concatenate([np.asarray(xy).reshape(-1, 2), q_new])
    sm = smooth_cached(smoothed, grey, 1)
    ok = print_check(sm, rim_dist, board, all_ids, all_xy, check, strict=added, min_corr=min_corr)[added]
    kept = np.concatenate([np.ones(len(ids), bool), ok])  # the maps of print_moved: of these corners only
    ok[ok] = ~print_moved(sm, rim_dist, board, all_ids[kept], all_xy[kept], check, lens)[len(ids) :]
    x, y = pixel_index(q_new, grey.shape[1], grey.shape[0]).T
    ok &= rim_dist[y, x] >= rim_px
    return new[ok], q_new[ok]
