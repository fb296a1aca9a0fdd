"""What every calibration target is: the :class:`Target` protocol and its config section.

A Target is the one home of what a calibration target is: corner ids and board coordinates, the
printed texture the renderer warps, its symmetries, and how it is written to the detection JSON
and a Kalibr target yaml (docs/conventions.md). Renderer, training, detector, evaluation,
sequences, selector and calibrator take a Target. Reading descriptions back:
:mod:`cotrain.targets.descriptions`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:  # torch loads on first use: the detector path imports targets without it
    import torch
    from torch import Tensor

KINDS = ("checkerboard", "aprilgrid")  # target kinds this release knows


class TargetError(ValueError):
    """A target description that cannot be used (one-line message)."""


@dataclass
class TargetConfig:
    """The ``target:`` section of a config (one kind's fields are used)."""

    kind: str = "checkerboard"  # one of KINDS
    squares_x: int = 10  # checkerboard: squares along the board's x axis
    squares_y: int = 7  # checkerboard: squares along the board's y axis
    square_size: float = 0.04  # checkerboard: side of one square, metres
    tag_cols: int = 6  # aprilgrid: tags along the board's x axis (Kalibr's tagCols)
    tag_rows: int = 6  # aprilgrid: tags along the board's y axis (tagRows)
    tag_size: float = 0.055  # aprilgrid: side of one tag including its black border, metres (tagSize)
    tag_spacing: float = 0.3  # aprilgrid: gap between tags as a fraction of tag_size (tagSpacing)
    margin: float = 0.5  # white border around the pattern, in squares / tag sizes (0 = no border); rendering only


@runtime_checkable
class Target(Protocol):
    """A planar calibration target with identified corners (board frame: docs/conventions.md)."""

    kind: str
    front: int  # the printed side faces the board's +z (+1: Kalibr's AprilGrid page) or -z (-1: our checkerboard, z into the board)

    @property
    def n_corners(self) -> int:
        """Number of corner ids (0 .. n_corners - 1)."""

    @property
    def spacing(self) -> float:
        """Distance between neighbouring corners on the board, metres (the local 'square')."""

    def board_xy(self) -> np.ndarray:
        """(N, 2) float64 board-frame x, y of corner ids 0 .. N - 1, metres (numpy: the detector's)."""

    def points(self, dtype: torch.dtype | None = None) -> Tensor:
        """(N, 3) board-frame coordinates of corner ids 0 .. N - 1, metres (z = 0): :meth:`board_xy`
        with z; ``dtype`` default torch.float64 (numpy, without torch: :func:`board_points`)."""

    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of the printed sheet, metres."""

    def grid_coordinates(self, xy: Tensor) -> tuple[Tensor, Tensor]:
        """Board points (..., 2) -> corner-grid coordinates (..., 2) and (...) bool: on the pattern."""

    def intensity(self, xy: Tensor, footprint: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Printed texture at board points (..., 2): intensity in [0, 1] and coverage (on the sheet).
        Numpy points (point samples, ``footprint`` None) give numpy arrays, without torch."""

    def symmetries(self) -> tuple[np.ndarray, ...]:
        """Corner-id permutations (N,) under which the target looks the same (empty: every id is unique)."""

    def to_json(self) -> dict:
        """The detection JSON's ``"target"`` entry."""

    def to_kalibr(self) -> dict:
        """The target as a Kalibr target yaml mapping."""


def array_module(x):
    """numpy for a numpy array, torch for a tensor (torch is imported only then): a target's
    point-sampled print takes either, so that the detector runs without torch."""
    if isinstance(x, (np.ndarray, np.generic)):
        return np
    import torch

    return torch


def clip(x, lo: float | None = None, hi: float | None = None):
    """``x`` (numpy or torch) clipped to [lo, hi] (None: unbounded)."""
    return np.clip(x, lo, hi) if isinstance(x, (np.ndarray, np.generic)) else x.clamp(lo, hi)


def board_points(target: Target) -> np.ndarray:
    """(N, 3) float64 board-frame coordinates of corner ids 0 .. N - 1, metres (z = 0), as numpy:
    :meth:`Target.points` without torch (the calibrator's)."""
    xy = np.asarray(target.board_xy(), dtype=np.float64)
    return np.concatenate([xy, np.zeros_like(xy[:, :1])], axis=-1)


def same_target(a: Target, b: Target) -> bool:
    """True when two targets describe the same printed board (kind, layout, size within 1e-6 m)."""
    ja, jb = a.to_json(), b.to_json()
    if ja.keys() != jb.keys():
        return False
    for k, va in ja.items():
        vb = jb[k]
        if isinstance(va, float) or isinstance(vb, float):
            if not math.isclose(float(va), float(vb), rel_tol=1e-6, abs_tol=1e-9):
                return False
        elif va != vb:
            return False
    return True


def sees_print(front: int, n_cam: Tensor | np.ndarray, t_cam: Tensor | np.ndarray):
    """Whether a camera sees the printed side of a target whose z axis is ``n_cam`` (..., 3) and
    origin ``t_cam`` (..., 3) in the camera frame (``front``: :attr:`Target.front`)."""
    return -front * (n_cam * t_cam).sum(-1) > 0


def square_px(model: str, params, T_cam_board, target: Target):
    """Local size of the target's square in pixels at every corner: the smaller singular value of
    the board -> image map over one ``target.spacing`` (central differences). 0 where any of the
    four sample points does not project. The one definition of "local square size" (renderer
    labels, synthetic rigs). ``params`` (..., P) and ``T_cam_board`` (..., 4, 4), numpy or torch
    (batched alike) -> (..., N) float64 of the same kind."""
    from cotrain.geometry import cameras, poses
    from cotrain.geometry._ops import is_tensor

    s = target.spacing
    P = board_points(target)
    steps = np.array([[s / 2, 0, 0], [-s / 2, 0, 0], [0, s / 2, 0], [0, -s / 2, 0]])
    if is_tensor(T_cam_board):
        import torch

        P, steps = (torch.from_numpy(a).to(T_cam_board.device) for a in (P, steps))
    q, ok = [], True
    for d in steps:
        qi, oki = cameras.project(model, poses.transform_points(T_cam_board, P + d), params[..., None, :])
        q.append(qi)
        ok = ok & oki
    if is_tensor(T_cam_board):
        smallest = torch.linalg.svdvals(torch.stack([q[0] - q[1], q[2] - q[3]], -1))[..., -1]  # J: (..., N, 2, 2) px per square
        return torch.where(ok, smallest, torch.zeros_like(smallest))
    smallest = np.linalg.svd(np.stack([q[0] - q[1], q[2] - q[3]], -1), compute_uv=False)[..., -1]
    return np.where(ok, smallest, 0.0)
