"""The two pixel maps between an input image and the network's outputs.

- :class:`Letterbox`: input pixels -> processing pixels. The image is scaled by
  ``s = min(W / w, H / h)`` and placed top-left on a black ``H x W`` canvas, so a point maps as
  ``q = (x + 0.5) s - 0.5`` (pixel centres, docs/conventions.md) and back as ``x = (q + 0.5) / s - 0.5``.
- :class:`CellGrid`: processing pixels -> cells of a map at ``1 / stride`` resolution (the
  network's dense outputs, stride 4). Cell ``c`` covers processing pixels ``stride c .. stride c +
  stride - 1``, so its centre is ``q = stride c + (stride - 1) / 2`` (1.5 for stride 4).

Both work on numpy arrays and torch tensors of shape ``(..., 2)``; the network, the losses, the
training loop, the detector and the grid pass all go through them. :func:`to_processing` and
:func:`cell_mask_to_input` are the letterbox's maps for a known scale alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class CellGrid:
    """Processing pixels <-> cells of a ``1 / stride`` map."""

    stride: int = 4

    @property
    def offset(self) -> float:
        """Processing-pixel coordinate of cell 0's centre."""
        return (self.stride - 1) / 2

    def to_cell(self, q):
        """(..., 2) processing pixels -> (..., 2) continuous cell coordinates."""
        return (q - self.offset) / self.stride

    def to_pixel(self, c):
        """(..., 2) continuous cell coordinates -> (..., 2) processing pixels."""
        return c * self.stride + self.offset

    def nearest(self, q: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """Nearest cell (column, row) index arrays, clipped to a map of ``shape`` (h, w), for (K, 2) pixels."""
        c = np.rint(self.to_cell(q)).astype(int)
        h, w = shape
        return np.clip(c[:, 0], 0, w - 1), np.clip(c[:, 1], 0, h - 1)

    def sample(self, maps: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Values of (C, h, w) maps at (K, 2) processing pixels (nearest cell) -> (K, C)."""
        cx, cy = self.nearest(q, maps.shape[-2:])
        return maps[:, cy, cx].T


CELLS = CellGrid(4)  # the grid of the network's dense outputs


@dataclass(frozen=True)
class Letterbox:
    """An input image of ``width x height`` fitted into the processing canvas ``size = (H, W)``."""

    width: int  # input image width, pixels
    height: int  # input image height, pixels
    size: tuple[int, int]  # processing canvas (H, W)

    @property
    def scale(self) -> float:
        """Processing pixels per input pixel."""
        H, W = self.size
        return min(W / self.width, H / self.height)

    def to_processing(self, x):
        """(..., 2) input pixels -> processing pixels."""
        return (x + 0.5) * self.scale - 0.5

    def to_input(self, q):
        """(..., 2) processing pixels -> input pixels."""
        return (q + 0.5) / self.scale - 0.5

    def apply(self, grey: np.ndarray) -> np.ndarray:
        """(h, w) float32 image -> (H, W) processing canvas (INTER_AREA when shrinking)."""
        H, W = self.size
        s = self.scale
        nw, nh = max(1, round(self.width * s)), max(1, round(self.height * s))
        small = cv2.resize(grey, (nw, nh), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
        canvas = np.zeros((H, W), np.float32)
        canvas[:nh, :nw] = small[:H, :W]
        return canvas

    def cell_mask_to_input(self, mask: np.ndarray, cells: CellGrid = CELLS) -> np.ndarray:
        """A (h, w) uint8 mask over cells -> (height, width) bool mask over input pixels (nearest cell)."""
        # cell = (((x + 0.5) s - 0.5) - offset) / stride = k x + t
        s = self.scale
        k = s / cells.stride
        t = (0.5 * s - (0.5 + cells.offset)) / cells.stride
        M = np.array([[k, 0, t], [0, k, t]], np.float64)
        full = cv2.warpAffine(
            mask, M, (self.width, self.height), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE
        )
        return full > 0
