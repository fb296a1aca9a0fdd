"""The checkerboard target: corner ids, board coordinates, printed texture and symmetries.

The default is the checkerboard of docs/conventions.md: 10 x 7 squares of 0.04 m, 54 inner
corners, ids row-major, square (0, 0) black. Board frame: origin at the top-left outer corner of
the squares, x along ``squares_x``, y along ``squares_y``, z into the board (away from the viewer).
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # torch loads on first use: the detector path imports targets without it
    import torch
    from torch import Tensor

from cotrain.targets.target import TargetConfig, TargetError, array_module, clip

# The board's in-plane quarter turns (lattice coordinates (a, b) -> R @ (a, b)).
ROTATIONS = [np.array([[1, 0], [0, 1]]), np.array([[0, -1], [1, 0]]), np.array([[-1, 0], [0, -1]]), np.array([[0, 1], [-1, 0]])]


class Checkerboard:
    """A checkerboard target: geometry (corners, ids) and appearance (analytic intensity)."""

    kind = "checkerboard"
    front = -1  # z points into the board, away from the viewer

    def __init__(self, cfg: TargetConfig | None = None):
        cfg = cfg or TargetConfig()
        if cfg.kind != "checkerboard":
            raise TargetError(f"target.kind: {cfg.kind!r} is not a checkerboard")
        if cfg.squares_x < 2 or cfg.squares_y < 2:
            raise TargetError("target.squares_x and target.squares_y must be at least 2")
        if cfg.square_size <= 0:
            raise TargetError("target.square_size must be positive")
        self.cfg = cfg
        self.nx = cfg.squares_x - 1  # inner corners along x
        self.ny = cfg.squares_y - 1
        self.s = cfg.square_size

    def __repr__(self) -> str:
        return f"Checkerboard({self.cfg.squares_x} x {self.cfg.squares_y} squares of {self.s:g} m)"

    def __str__(self) -> str:
        return f"checkerboard {self.cfg.squares_x} x {self.cfg.squares_y} squares of {self.s:g} m"

    @property
    def n_corners(self) -> int:
        return self.nx * self.ny

    @property
    def spacing(self) -> float:
        """Distance between neighbouring corners, metres: the square size."""
        return self.s

    def to_json(self) -> dict:
        """The detection JSON's ``"target"`` entry (docs/conventions.md)."""
        return {"kind": "checkerboard", "squares_x": self.cfg.squares_x, "squares_y": self.cfg.squares_y, "square_size": self.s}

    def to_kalibr(self) -> dict:
        """Kalibr's target yaml: ``targetCols`` / ``targetRows`` count inner corners."""
        return {
            "target_type": "checkerboard",
            "targetCols": self.nx,
            "targetRows": self.ny,
            "rowSpacingMeters": self.s,
            "colSpacingMeters": self.s,
        }

    def symmetries(self) -> tuple[np.ndarray, ...]:
        """Corner-id permutations under which the board looks the same (see :func:`board_symmetries`)."""
        return board_symmetries(self.nx, self.ny)

    def ij_of(self, ids):
        """(...) corner ids -> (..., 2) grid indices (i, j) (numpy or torch)."""
        i, j = ids % self.nx, ids // self.nx
        if isinstance(ids, np.ndarray):
            return np.stack([i, j], -1)
        import torch  # only for torch ids: the detector passes numpy

        return torch.stack([i, j], -1)

    def id_of(self, ij):
        """(..., 2) grid indices (i, j) -> (...) corner ids, -1 off the board (numpy)."""
        ij = np.asarray(ij)
        on = (ij[..., 0] >= 0) & (ij[..., 0] < self.nx) & (ij[..., 1] >= 0) & (ij[..., 1] < self.ny)
        return np.where(on, ij[..., 1] * self.nx + ij[..., 0], -1)

    def board_xy(self) -> np.ndarray:
        """(N, 2) float64 board-frame x, y (metres) of the inner corners, row i = corner id i (numpy)."""
        return (self.ij_of(np.arange(self.n_corners)) + 1) * self.s

    def points(self, dtype: torch.dtype | None = None) -> Tensor:
        """(N, 3) board-frame coordinates (metres) of the inner corners, row i = corner id i
        (:meth:`board_xy` with z = 0)."""
        import torch

        xy = torch.from_numpy(self.board_xy()).to(torch.float64 if dtype is None else dtype)
        return torch.cat([xy, torch.zeros_like(xy[:, :1])], dim=-1)

    def grid_coordinates(self, xy: Tensor) -> tuple[Tensor, Tensor]:
        """Board points (..., 2) metres -> corner-grid coordinates (..., 2) (corner (i, j) at (i, j))
        and (...) bool: on the checker squares."""
        import torch

        u = xy[..., 0] / self.s - 1
        v = xy[..., 1] / self.s - 1
        inside = (u > -1) & (u < self.nx) & (v > -1) & (v < self.ny)
        return torch.stack([u, v], -1), inside

    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of the printed board including its margin, metres."""
        m = self.cfg.margin * self.s
        return (-m, -m, self.cfg.squares_x * self.s + m, self.cfg.squares_y * self.s + m)

    def intensity(self, xy: Tensor, footprint: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Appearance at board-plane points, area-filtered over a pixel footprint.

        Args:
            xy: (..., 2) board-frame x, y in metres (torch, or numpy: numpy out).
            footprint: (..., 2) width of the pixel's footprint along board x and y, metres.
                ``None`` gives point samples (a hard-edged pattern).
        Returns:
            intensity (...) in [0, 1] (0 black, 1 white) and coverage (...) in [0, 1], the
            fraction of the footprint on the printed board (0 off the board).

        The checker is the product of two box-filtered square waves, so edges are anti-aliased
        and every inner corner stays exactly at its saddle point (the filtered waves cross zero
        at the grid lines).
        """
        xp = array_module(xy)
        u = xy[..., 0] / self.s
        v = xy[..., 1] / self.s
        if footprint is None:
            wu = xp.full_like(u, 1e-6)
            wv = xp.full_like(v, 1e-6)
        else:
            wu = clip(footprint[..., 0] / self.s, 1e-6)
            wv = clip(footprint[..., 1] / self.s, 1e-6)
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
    grid line. Footprints wider than a cell fade to the mean (0). (numpy or torch.)
    """
    xp = array_module(u)
    r = xp.remainder(u, 2.0)
    sign = xp.where(r < 1.0, xp.ones_like(u), -xp.ones_like(u))
    frac = xp.remainder(u, 1.0)
    d = xp.minimum(frac, 1.0 - frac)
    return sign * clip(2 * d / w, hi=1.0) * clip(2.0 - w, 0.0, 1.0)


def _box_coverage(u: Tensor, lo: float, hi: float, w: Tensor) -> Tensor:
    """Fraction of the box [u - w/2, u + w/2] inside [lo, hi] (for w below hi - lo; numpy or torch)."""
    return clip((u - lo) / w + 0.5, 0.0, 1.0) * clip((hi - u) / w + 0.5, 0.0, 1.0)


@functools.lru_cache(maxsize=8)
def board_symmetries(nx: int, ny: int) -> tuple[np.ndarray, ...]:
    """Corner id permutations (nx ny,) under which a board of nx x ny inner corners looks the same:
    turns that map its squares onto squares of the same colour. None for the default 10 x 7
    squares; the half turn for boards whose square counts are both odd or both even (7 x 5, 8 x 6);
    also the quarter turns for square boards of an odd count. Such boards give each corner its id
    only up to these turns."""
    sx, sy = nx + 1, ny + 1
    sq = np.stack(np.meshgrid(np.arange(sx), np.arange(sy), indexing="ij"), -1).reshape(-1, 2)
    ij = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij"), -1).reshape(-1, 2)
    out = []
    for R in ROTATIONS[1:]:
        t = sq @ R.T
        t -= t.min(0)
        if not np.array_equal(t.max(0), [sx - 1, sy - 1]) or not np.array_equal(t.sum(1) % 2, sq.sum(1) % 2):
            continue
        c = ij @ R.T  # inner corners turn the same way (about the board centre)
        c -= c.min(0)
        perm = np.empty(nx * ny, int)
        perm[ij[:, 1] * nx + ij[:, 0]] = c[:, 1] * nx + c[:, 0]
        out.append(perm)
    return tuple(out)
