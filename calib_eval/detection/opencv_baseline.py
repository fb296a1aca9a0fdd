"""OpenCV's chessboard detectors, the baseline users would otherwise pick, wrapped once.

- ``sb``: ``cv2.findChessboardCornersSB`` with EXHAUSTIVE | ACCURACY;
- ``classic``: ``cv2.findChessboardCorners`` (adaptive threshold, normalised image) refined by
  ``cv2.cornerSubPix`` in a 5 x 5 window.

Both find the whole board or nothing. OpenCV orders a board's corners row-major but only up to
its turns: on a board that is symmetric under a half turn (both square counts odd or both even)
the geometry is the same either way, so calibration is unaffected; for asymmetric boards the ids
are only as reliable as OpenCV's order. The detection evaluation treats them as unidentified.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from cotrain.detect.images import ImageError, load_image
from cotrain.progress import progress_bar
from cotrain.targets import Checkerboard

METHODS = ("sb", "classic")


def find_chessboard(grey_u8: np.ndarray, pattern: tuple[int, int], method: str = "sb") -> np.ndarray | None:
    """Inner corners (nx ny, 2) in OpenCV's row-major order of an 8-bit grey image, or None.
    ``pattern`` = (inner corners along x, along y)."""
    if method == "sb":
        ok, c = cv2.findChessboardCornersSB(grey_u8, pattern, flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
    elif method == "classic":
        ok, c = cv2.findChessboardCorners(grey_u8, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if ok:
            c = cv2.cornerSubPix(grey_u8, c, (5, 5), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01))
    else:
        raise ValueError(f"OpenCV method must be one of {', '.join(METHODS)}, not {method!r}")
    return c.reshape(-1, 2).astype(np.float64) if ok else None


def load_u8(path: Path) -> np.ndarray:
    """An image file as 8-bit grey (16-bit and colour images converted); raises ImageError."""
    return (load_image(path) * 255).round().astype(np.uint8)


def opencv_detect(paths: list[Path], target: Checkerboard, method: str = "sb", progress: bool = True) -> dict:
    """The detection JSON (docs/conventions.md) of OpenCV's detector over image files."""
    if not isinstance(target, Checkerboard):
        raise ValueError(f"OpenCV's chessboard detectors find checkerboards, not {target.kind}")
    pattern = (target.nx, target.ny)
    images = []
    for p in progress_bar(paths, desc=f"opencv {method}", unit="img", enabled=progress):
        e = {"path": str(p), "width": 0, "height": 0, "corners": [], "error": None}
        try:
            g = load_u8(p)
            e["height"], e["width"] = g.shape
            c = find_chessboard(g, pattern, method)
            if c is not None:
                e["corners"] = [{"id": i, "x": float(x), "y": float(y), "confidence": 1.0} for i, (x, y) in enumerate(c)]
        except ImageError as err:
            e["error"] = str(err)
        images.append(e)
    return {"model": f"opencv_{method}", "target": target.to_json(), "images": images}
