"""Calibration targets: 3-D corner points with their ids, and the target's appearance.

The default is the checkerboard of CONVENTIONS.md: 10 x 7 squares of 0.04 m, 54 inner corners,
ids row-major, square (0, 0) black. Board frame: origin at the top-left outer corner of the
squares, x along ``squares_x``, y along ``squares_y``, z into the board (away from the viewer).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass
class TargetConfig:
    kind: str = "checkerboard"  # only "checkerboard" for now
    squares_x: int = 10  # squares along the board's x axis
    squares_y: int = 7  # squares along the board's y axis
    square_size: float = 0.04  # side of one square, metres
    margin: float = 0.5  # white border around the squares, in squares (0 = no border)


class Checkerboard:
    """A checkerboard target: geometry (corners, ids) and appearance (analytic intensity)."""

    def __init__(self, cfg: TargetConfig | None = None):
        cfg = cfg or TargetConfig()
        if cfg.kind != "checkerboard":
            raise ValueError(f"target.kind: unsupported target {cfg.kind!r} (only 'checkerboard')")
        if cfg.squares_x < 2 or cfg.squares_y < 2:
            raise ValueError("target.squares_x and target.squares_y must be at least 2")
        if cfg.square_size <= 0:
            raise ValueError("target.square_size must be positive")
        self.cfg = cfg
        self.nx = cfg.squares_x - 1  # inner corners along x
        self.ny = cfg.squares_y - 1
        self.s = cfg.square_size

    @property
    def n_corners(self) -> int:
        return self.nx * self.ny

    def grid_ij(self) -> Tensor:
        """(N, 2) integer grid indices (i, j) of corner ids 0..N-1 (id = j * nx + i)."""
        j, i = torch.meshgrid(torch.arange(self.ny), torch.arange(self.nx), indexing="ij")
        return torch.stack([i.reshape(-1), j.reshape(-1)], dim=-1)

    def points(self, dtype: torch.dtype = torch.float64) -> Tensor:
        """(N, 3) board-frame coordinates (metres) of the inner corners, row i = corner id i."""
        ij = self.grid_ij().to(dtype)
        xy = (ij + 1) * self.s
        return torch.cat([xy, torch.zeros_like(xy[:, :1])], dim=-1)

    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of the printed board including its margin, metres."""
        m = self.cfg.margin * self.s
        return (-m, -m, self.cfg.squares_x * self.s + m, self.cfg.squares_y * self.s + m)

    def intensity(self, xy: Tensor, footprint: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Appearance at board-plane points, area-filtered over a pixel footprint.

        Args:
            xy: (..., 2) board-frame x, y in metres.
            footprint: (..., 2) width of the pixel's footprint along board x and y, metres.
                ``None`` gives point samples (a hard-edged pattern).
        Returns:
            intensity (...) in [0, 1] (0 black, 1 white) and coverage (...) in [0, 1], the
            fraction of the footprint on the printed board (0 off the board).

        The checker is the product of two box-filtered square waves, so edges are anti-aliased
        and every inner corner stays exactly at its saddle point (the filtered waves cross zero
        at the grid lines).
        """
        u = xy[..., 0] / self.s
        v = xy[..., 1] / self.s
        if footprint is None:
            wu = torch.full_like(u, 1e-6)
            wv = torch.full_like(v, 1e-6)
        else:
            wu = (footprint[..., 0] / self.s).clamp_min(1e-6)
            wv = (footprint[..., 1] / self.s).clamp_min(1e-6)
        # Square wave sign: +1 on even cells, -1 on odd cells; filtered over a box of width w.
        su = _filtered_square_wave(u, wu)
        sv = _filtered_square_wave(v, wv)
        # Black where (cell_x + cell_y) is even, i.e. su * sv > 0.
        checker = 0.5 - 0.5 * su * sv
        # Outside the squares but inside the margin: white.
        inside_u = _box_coverage(u, 0.0, float(self.cfg.squares_x), wu)
        inside_v = _box_coverage(v, 0.0, float(self.cfg.squares_y), wv)
        in_squares = inside_u * inside_v
        value = in_squares * checker + (1 - in_squares) * 1.0
        m = self.cfg.margin
        cover = _box_coverage(u, -m, self.cfg.squares_x + m, wu) * _box_coverage(v, -m, self.cfg.squares_y + m, wv)
        return value, cover

    def square_is_black(self, cx: int, cy: int) -> bool:
        """True if square (cx, cy) (column, row) is black; square (0, 0) is black."""
        return (cx + cy) % 2 == 0


def _filtered_square_wave(u: Tensor, w: Tensor) -> Tensor:
    """Box filter (width ``w``, in cells) of the square wave that is +1 on even cells, -1 on odd.

    Inside a box narrower than a cell there is at most one edge, at distance ``d`` from ``u``;
    the filtered value is ``sign * min(2 d / w, 1)``, a linear ramp through 0 exactly on the
    grid line. Footprints wider than a cell fade to the mean (0).
    """
    r = torch.remainder(u, 2.0)
    sign = torch.where(r < 1.0, 1.0, -1.0).to(u.dtype)
    frac = torch.remainder(u, 1.0)
    d = torch.minimum(frac, 1.0 - frac)
    return sign * torch.clamp(2 * d / w, max=1.0) * torch.clamp(2.0 - w, 0.0, 1.0)


def _box_coverage(u: Tensor, lo: float, hi: float, w: Tensor) -> Tensor:
    """Fraction of the box [u - w/2, u + w/2] inside [lo, hi] (for w below hi - lo)."""
    return torch.clamp((u - lo) / w + 0.5, 0.0, 1.0) * torch.clamp((hi - u) / w + 0.5, 0.0, 1.0)
