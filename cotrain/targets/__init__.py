"""Calibration targets: a :class:`Target` protocol and its kinds (the checkerboard, Kalibr's AprilGrid)."""

from cotrain.targets.aprilgrid import AprilGrid
from cotrain.targets.checkerboard import ROTATIONS, Checkerboard, board_symmetries
from cotrain.targets.descriptions import (
    load_target,
    make_target,
    target_from_boofcv,
    target_from_flags,
    target_from_json,
    target_from_kalibr,
)
from cotrain.targets.target import KINDS, Target, TargetConfig, TargetError, board_points, same_target, sees_print, square_px

__all__ = [
    "AprilGrid",
    "KINDS",
    "ROTATIONS",
    "Checkerboard",
    "Target",
    "TargetConfig",
    "TargetError",
    "board_points",
    "board_symmetries",
    "load_target",
    "make_target",
    "same_target",
    "sees_print",
    "square_px",
    "target_from_boofcv",
    "target_from_flags",
    "target_from_json",
    "target_from_kalibr",
]
