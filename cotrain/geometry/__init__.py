"""Camera models and poses, shared by the renderer, the labels, the selector and the calibrator.

The names below load lazily (PEP 562) so that the detector, which imports
:mod:`cotrain.geometry.letterbox`, does not import torch through :mod:`cotrain.geometry.cameras`.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from cotrain.geometry.cameras import (
        DEFAULT_SHAPE,
        MODELS,
        CameraModel,
        assemble_params,
        get_model,
        make_camera,
        model_from_name,
        off_axis_angle,
        project,
        unproject,
    )
    from cotrain.geometry.poses import (
        axis_angle_from_rotation,
        compose,
        invert,
        look_at,
        make_pose,
        pose_from_axis_angle,
        rotation_angle_deg,
        rotation_from_axis_angle,
        transform_points,
    )

__all__ = [
    "DEFAULT_SHAPE",
    "MODELS",
    "CameraModel",
    "assemble_params",
    "axis_angle_from_rotation",
    "compose",
    "get_model",
    "model_from_name",
    "invert",
    "look_at",
    "make_camera",
    "make_pose",
    "off_axis_angle",
    "pose_from_axis_angle",
    "project",
    "rotation_angle_deg",
    "rotation_from_axis_angle",
    "transform_points",
    "unproject",
]

_CAMERAS = "cotrain.geometry.cameras"
_POSES = "cotrain.geometry.poses"
_SOURCES = {
    "DEFAULT_SHAPE": _CAMERAS,
    "MODELS": _CAMERAS,
    "CameraModel": _CAMERAS,
    "assemble_params": _CAMERAS,
    "get_model": _CAMERAS,
    "make_camera": _CAMERAS,
    "model_from_name": _CAMERAS,
    "off_axis_angle": _CAMERAS,
    "project": _CAMERAS,
    "unproject": _CAMERAS,
    "axis_angle_from_rotation": _POSES,
    "compose": _POSES,
    "invert": _POSES,
    "look_at": _POSES,
    "make_pose": _POSES,
    "pose_from_axis_angle": _POSES,
    "rotation_angle_deg": _POSES,
    "rotation_from_axis_angle": _POSES,
    "transform_points": _POSES,
}


def __getattr__(name: str) -> Any:
    source = _SOURCES.get(name)
    if source is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(source), name)
    globals()[name] = value  # later look-ups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
