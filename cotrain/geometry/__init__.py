"""Camera models and poses, shared by the renderer, the labels, the selector and the calibrator."""

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
