"""Kalibr's AprilGrid target: corner ids, board coordinates and printed texture (docs/conventions.md).

A grid of ``tag_cols`` x ``tag_rows`` tag36h11 tags of side ``tag_size`` with gaps of
``tag_spacing * tag_size``; each tag has Kalibr's 2-bit black border (10 x 10 cells over the tag)
and a black square fills every gap crossing, so each tag corner is an X-junction.

Corner ids and board coordinates are Kalibr's ``GridCalibrationTargetAprilgrid::createGridPoints``:
point (r, c) of the 2 tag_rows x 2 tag_cols grid has id ``r * 2 * tag_cols + c`` and
``x = (c // 2) * (1 + tag_spacing) * tag_size + (c % 2) * tag_size`` (y likewise from r). The
board frame is Kalibr's page: seen from the printed side, x to the right and y up (tag 0 at the
bottom left), so z points out of the print, toward the viewer.

The texture is what Kalibr's ``createTargetPDF.py`` draws. The tag codes come from OpenCV's
``DICT_APRILTAG_36h11`` (no code table here): Kalibr draws each tag's code turned by a half turn
relative to OpenCV's marker image, so the printed data bits, seen from the printed side with y up,
are OpenCV's marker bits turned by a half turn.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import cv2
import numba
import numpy as np

if TYPE_CHECKING:  # torch loads on first use: the detector path imports targets without it
    import torch
    from torch import Tensor

from cotrain.targets.target import TargetConfig, TargetError, array_module, clip

BORDER_BITS = 2  # Kalibr's black border, in cells
DATA_BITS = 6  # tag36h11: 6 x 6 data cells
CELLS = DATA_BITS + 2 * BORDER_BITS  # cells across a tag (10)
N_CODES = 587  # tag36h11 family size


@functools.lru_cache(maxsize=4)
def tag_bits(n: int) -> np.ndarray:
    """(n, 6, 6) uint8 data bits of tag36h11 ids 0 .. n-1 as OpenCV draws the marker (row 0 at the
    top, 1 = white)."""
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    out = np.empty((n, DATA_BITS, DATA_BITS), np.uint8)
    for t in range(n):
        img = cv2.aruco.generateImageMarker(d, t, DATA_BITS + 2, borderBits=1)  # one pixel per cell
        out[t] = img[1:-1, 1:-1] > 127
    return out


def printed_bits(n: int) -> np.ndarray:
    """(n, 6, 6) uint8 data bits of tag36h11 ids 0 .. n-1 as Kalibr prints them, indexed
    ``[t, j, i]``: data row j counted from the tag's bottom edge on the page (y up), column i from
    its left edge (x right); 1 = white. Kalibr draws OpenCV's marker turned by a half turn, so
    page cell (i, j) shows marker cell (row j, column 5 - i)."""
    return np.ascontiguousarray(tag_bits(n)[:, :, ::-1])


def _as_index(x):
    """Whole-number floats (numpy or torch) as integer indices."""
    return x.astype(np.int64) if isinstance(x, (np.ndarray, np.generic)) else x.long()


def _as_type(x, like):
    """``x`` (numpy or torch) in the dtype of ``like``."""
    return x.astype(like.dtype) if isinstance(x, (np.ndarray, np.generic)) else x.to(like.dtype)


@numba.njit(cache=True, nogil=True)
def _point_intensity(x, y, bits, P, S, tc, tr, x0, y0, x1, y1):
    """:meth:`AprilGrid.intensity`'s point samples at finite board points x, y (N,) float64,
    compiled in the arithmetic of :meth:`AprilGrid._value` (tag period ``P``, side ``S``, ``tc`` x
    ``tr`` tags, ``bits`` (T, 6, 6) as printed; the sheet ``x0, y0, x1, y1``): intensity and
    coverage (N,)."""
    n = x.shape[0]
    value, cover = np.empty(n), np.empty(n)
    cell = S / CELLS
    for i in range(n):
        kx, ky = np.floor(x[i] / P), np.floor(y[i] / P)  # floats: never an integer conversion out of range
        fx, fy = x[i] - kx * P, y[i] - ky * P
        in_x, in_y = fx < S, fy < S
        if in_x and in_y and 0 <= kx < tc and 0 <= ky < tr:
            bx = int(min(max(np.floor(fx / cell), 0.0), CELLS - 1.0))
            by = int(min(max(np.floor(fy / cell), 0.0), CELLS - 1.0))
            if BORDER_BITS <= bx < CELLS - BORDER_BITS and BORDER_BITS <= by < CELLS - BORDER_BITS:
                v = float(bits[int(ky) * tc + int(kx), by - BORDER_BITS, bx - BORDER_BITS])
            else:
                v = 0.0  # the border is black
        else:
            v = 1.0
        if not in_x and not in_y and -1 <= kx < tc and -1 <= ky < tr:
            v = 0.0  # a gap crossing's square
        c = 1.0 if x0 <= x[i] <= x1 and y0 <= y[i] <= y1 else 0.0
        value[i], cover[i] = (v if c > 0 else 1.0), c
    return value, cover


class AprilGrid:
    """Kalibr's AprilGrid: geometry (corners, ids, tags) and appearance (area-sampled intensity)."""

    kind = "aprilgrid"
    front = 1  # Kalibr's page frame: y up on the print, z toward the viewer

    def __init__(self, cfg: TargetConfig | None = None):
        cfg = cfg or TargetConfig(kind="aprilgrid")
        if cfg.kind != "aprilgrid":
            raise TargetError(f"target.kind: {cfg.kind!r} is not an aprilgrid")
        if cfg.tag_cols < 1 or cfg.tag_rows < 1:
            raise TargetError("target.tag_cols and target.tag_rows must be at least 1")
        if cfg.tag_cols * cfg.tag_rows > N_CODES:
            raise TargetError(f"an aprilgrid of {cfg.tag_cols} x {cfg.tag_rows} tags needs more than tag36h11's {N_CODES} codes")
        if cfg.tag_size <= 0:
            raise TargetError("target.tag_size must be positive")
        if not 0 < cfg.tag_spacing <= 1:
            raise TargetError("target.tag_spacing must be in (0, 1] (a fraction of tag_size, as Kalibr's)")
        self.cfg = cfg
        self.tc, self.tr = cfg.tag_cols, cfg.tag_rows
        self.S = cfg.tag_size
        self.gap = cfg.tag_spacing * cfg.tag_size
        self.P = self.S + self.gap  # period of the tag grid
        self.nx, self.ny = 2 * self.tc, 2 * self.tr  # corner grid (columns, rows)
        self.printed = printed_bits(self.n_tags)  # (tags, 6, 6) the data bits on the page (see printed_bits)

    def __repr__(self) -> str:
        return f"AprilGrid({self.tc} x {self.tr} tags of {self.S:g} m, spacing {self.cfg.tag_spacing:g})"

    def __str__(self) -> str:
        return f"aprilgrid {self.tc} x {self.tr} tags of {self.S:g} m, spacing {self.cfg.tag_spacing:g}"

    @property
    def n_corners(self) -> int:
        return self.nx * self.ny

    @property
    def n_tags(self) -> int:
        return self.tc * self.tr

    @property
    def spacing(self) -> float:
        """The tag's side, metres: the scale at which its corners and bits are read."""
        return self.S

    def to_json(self) -> dict:
        """The detection JSON's ``"target"`` entry (docs/conventions.md)."""
        return {"kind": "aprilgrid", "tag_cols": self.tc, "tag_rows": self.tr, "tag_size": self.S, "tag_spacing": self.cfg.tag_spacing}

    def to_kalibr(self) -> dict:
        """Kalibr's target yaml."""
        return {"target_type": "aprilgrid", "tagCols": self.tc, "tagRows": self.tr, "tagSize": self.S, "tagSpacing": self.cfg.tag_spacing}

    def symmetries(self) -> tuple[np.ndarray, ...]:
        """None: every tag names itself."""
        return ()

    def ij_of(self, ids):
        """(...) corner ids -> (..., 2) grid indices (c, r) (numpy or torch)."""
        c, r = ids % self.nx, ids // self.nx
        if isinstance(ids, np.ndarray):
            return np.stack([c, r], -1)
        import torch  # only for torch ids: the detector passes numpy

        return torch.stack([c, r], -1)

    def id_of(self, ij):
        """(..., 2) grid indices (c, r) -> (...) corner ids, -1 off the grid (numpy)."""
        ij = np.asarray(ij)
        on = (ij[..., 0] >= 0) & (ij[..., 0] < self.nx) & (ij[..., 1] >= 0) & (ij[..., 1] < self.ny)
        return np.where(on, ij[..., 1] * self.nx + ij[..., 0], -1)

    def tag_corners(self, t) -> np.ndarray:
        """(..., 4) corner ids of tags ``t``: Kalibr's b, b+1, b + 2 tag_cols + 1, b + 2 tag_cols
        with b = (t // tag_cols) * 4 tag_cols + (t % tag_cols) * 2: bottom left, bottom right,
        top right, top left on the page (counter-clockwise seen from the printed side)."""
        t = np.asarray(t)
        b = (t // self.tc) * 4 * self.tc + (t % self.tc) * 2
        return np.stack([b, b + 1, b + self.nx + 1, b + self.nx], -1)

    def board_xy(self) -> np.ndarray:
        """(N, 2) float64 board-frame x, y (metres) of corner ids 0..N-1 (Kalibr's createGridPoints; numpy)."""
        cr = self.ij_of(np.arange(self.n_corners))
        return (cr // 2) * self.P + (cr % 2) * self.S

    def points(self, dtype: torch.dtype | None = None) -> Tensor:
        """(N, 3) board-frame coordinates (metres) of corner ids 0..N-1 (:meth:`board_xy` with z = 0)."""
        import torch

        xy = torch.from_numpy(self.board_xy()).to(torch.float64 if dtype is None else dtype)
        return torch.cat([xy, torch.zeros_like(xy[:, :1])], dim=-1)

    def _axis_grid(self, x: Tensor) -> Tensor:
        """Board coordinate along one axis -> corner-grid coordinate (corner k at k; piecewise linear)."""
        import torch

        k = torch.floor(x / self.P)
        f = x - k * self.P
        return torch.where(f <= self.S, 2 * k + f / self.S, 2 * k + 1 + (f - self.S) / self.gap)

    def grid_coordinates(self, xy: Tensor) -> tuple[Tensor, Tensor]:
        """Board points (..., 2) metres -> corner-grid coordinates (..., 2) (corner (c, r) at (c, r))
        and (...) bool: on the pattern (tags and the corner squares around them)."""
        import torch

        u, v = self._axis_grid(xy[..., 0]), self._axis_grid(xy[..., 1])
        inside = (u > -1) & (u < self.nx) & (v > -1) & (v < self.ny)
        return torch.stack([u, v], -1), inside

    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of the printed sheet: the pattern with its outer corner
        squares, and a white margin of ``margin`` tag sizes."""
        m = self.cfg.margin * self.S
        return (-self.gap - m, -self.gap - m, self.tc * self.P + m, self.tr * self.P + m)

    def _value(self, x: Tensor, y: Tensor, bits: Tensor) -> Tensor:
        """Point-sampled print at board points: 0 black, 1 white (numpy or torch, as ``bits``)."""
        xp = array_module(x)
        kx, ky = xp.floor(x / self.P), xp.floor(y / self.P)
        fx, fy = x - kx * self.P, y - ky * self.P
        in_tag_x, in_tag_y = fx < self.S, fy < self.S
        col_ok = (kx >= 0) & (kx < self.tc)
        row_ok = (ky >= 0) & (ky < self.tr)
        tag = in_tag_x & in_tag_y & col_ok & row_ok
        # Gap crossings next to a tag corner: gap index -1 .. tc - 1 (before / after each tag).
        gx = ~in_tag_x & (kx >= -1) & (kx < self.tc)
        gy = ~in_tag_y & (ky >= -1) & (ky < self.tr)
        crossing = gx & gy
        cell = self.S / CELLS
        bx = _as_index(clip(xp.floor(fx / cell), 0, CELLS - 1))
        by = _as_index(clip(xp.floor(fy / cell), 0, CELLS - 1))
        data = (bx >= BORDER_BITS) & (bx < CELLS - BORDER_BITS) & (by >= BORDER_BITS) & (by < CELLS - BORDER_BITS)
        t = _as_index(clip(ky, 0, self.tr - 1) * self.tc + clip(kx, 0, self.tc - 1))
        row = clip(by - BORDER_BITS, 0, DATA_BITS - 1)  # page data cell, counted from the bottom (see printed_bits)
        col = clip(bx - BORDER_BITS, 0, DATA_BITS - 1)
        bit = _as_type(bits[t, row, col], x)
        inside_tag = xp.where(data, bit, xp.zeros_like(x))  # the border is black
        value = xp.ones_like(x)
        value = xp.where(tag, inside_tag, value)
        return xp.where(crossing, xp.zeros_like(x), value)

    def intensity(self, xy: Tensor, footprint: Tensor | None = None, samples: int = 4) -> tuple[Tensor, Tensor]:
        """Appearance at board-plane points, averaged over a pixel footprint.

        Args:
            xy: (..., 2) board-frame x, y in metres (torch, or numpy for point samples: numpy out).
            footprint: (..., 2) width of the pixel's footprint along board x and y, metres;
                ``None`` gives point samples.
            samples: sub-samples per axis over the footprint (a box filter).
        Returns:
            intensity (...) in [0, 1] (0 black, 1 white) and coverage (...) in [0, 1], the fraction
            of the footprint on the printed sheet.
        """
        x, y = xy[..., 0], xy[..., 1]
        x0, y0, x1, y1 = self.extent()
        if footprint is None:
            xp = array_module(xy)
            if xp is np and xy.dtype == np.float64 and xy.size and np.isfinite(xy).all():
                # Compiled (the detector renders patches of the print many times a frame); the same arithmetic.
                v, cover = _point_intensity(
                    np.ascontiguousarray(x).ravel(),
                    np.ascontiguousarray(y).ravel(),
                    self.printed,
                    self.P,
                    self.S,
                    self.tc,
                    self.tr,
                    x0,
                    y0,
                    x1,
                    y1,
                )
                return v.reshape(x.shape), cover.reshape(x.shape)
            bits = self.printed if xp is np else xp.from_numpy(self.printed).to(xy.device)
            v = self._value(x, y, bits)
            cover = _as_type((x >= x0) & (x <= x1) & (y >= y0) & (y <= y1), x)
            return xp.where(cover > 0, v, xp.ones_like(v)), cover
        import torch

        bits = torch.from_numpy(self.printed).to(xy.device)
        xy, footprint = torch.broadcast_tensors(xy, footprint)
        x, y = xy[..., 0], xy[..., 1]
        # Only points whose footprint reaches the sheet are sampled (the rest are white, uncovered).
        fx, fy = footprint[..., 0].abs() / 2, footprint[..., 1].abs() / 2
        near = (x >= x0 - fx) & (x <= x1 + fx) & (y >= y0 - fy) & (y <= y1 + fy)
        x, y, fp = x[near], y[near], footprint[near]
        off = (torch.arange(samples, dtype=xy.dtype, device=xy.device) + 0.5) / samples - 0.5
        sx = x[..., None, None] + off[:, None] * fp[..., 0, None, None]
        sy = y[..., None, None] + off[None, :] * fp[..., 1, None, None]
        sx, sy = torch.broadcast_tensors(sx, sy)
        on = (sx >= x0) & (sx <= x1) & (sy >= y0) & (sy <= y1)
        v = torch.where(on, self._value(sx, sy, bits), torch.ones_like(sx))
        value = torch.ones(xy.shape[:-1], dtype=xy.dtype, device=xy.device)
        cover = torch.zeros_like(value)
        value[near] = v.mean(dim=(-1, -2))
        cover[near] = on.to(xy.dtype).mean(dim=(-1, -2))
        return value, cover
