"""Small SE(3) helpers named by the ``T_a_b`` rule of docs/conventions.md.

A pose ``T_a_b`` is a ``(..., 4, 4)`` homogeneous matrix mapping frame ``b`` to frame ``a``:
``p_a = T_a_b @ p_b`` and ``T_a_c = compose(T_a_b, T_b_c)``. Rotations as axis-angle
``(..., 3)`` (direction = axis, norm = angle in rad). All functions are batched and
differentiable; the small-angle limits use ``torch.where``.
"""

from __future__ import annotations

import torch
from torch import Tensor


def _skew(w: Tensor) -> Tensor:
    """(..., 3) -> (..., 3, 3) cross-product matrix."""
    z = torch.zeros_like(w[..., 0])
    x, y, zz = w[..., 0], w[..., 1], w[..., 2]
    return torch.stack([torch.stack([z, -zz, y], -1), torch.stack([zz, z, -x], -1), torch.stack([-y, x, z], -1)], -2)


def rotation_from_axis_angle(w: Tensor) -> Tensor:
    """Rodrigues: axis-angle (..., 3) -> rotation matrix (..., 3, 3)."""
    theta2 = (w * w).sum(-1, keepdim=True)[..., None]  # (..., 1, 1)
    small = theta2 < 1e-10
    theta2_safe = torch.where(small, torch.ones_like(theta2), theta2)
    theta = torch.sqrt(theta2_safe)
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / theta2_safe)
    K = _skew(w)
    eye = torch.eye(3, dtype=w.dtype, device=w.device).expand(K.shape)
    return eye + a * K + b * (K @ K)


def axis_angle_from_rotation(R: Tensor) -> Tensor:
    """Inverse Rodrigues: rotation (..., 3, 3) -> axis-angle (..., 3), angle in [0, pi]."""
    cos = ((R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2] - 1) / 2).clamp(-1.0, 1.0)
    theta = torch.acos(cos)
    vee = torch.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    sin = torch.sin(theta)
    small = theta < 1e-5
    near_pi = theta > torch.pi - 1e-3
    factor = torch.where(small, 0.5 + theta * theta / 12, theta / (2 * torch.where(small | near_pi, torch.ones_like(sin), sin)))
    w = vee * factor[..., None]
    # Near pi, the axis comes from the diagonal of (R + I) / 2 = a a^T.
    B = (R + torch.eye(3, dtype=R.dtype, device=R.device)) / 2
    diag = torch.stack([B[..., 0, 0], B[..., 1, 1], B[..., 2, 2]], -1).clamp_min(0)
    i = diag.argmax(-1, keepdim=True)
    col = torch.gather(B, -1, i[..., None, :].expand(*B.shape[:-1], 1))[..., 0]
    axis = col / col.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    sign = torch.where((axis * vee).sum(-1, keepdim=True) < 0, -1.0, 1.0).to(R.dtype)
    w_pi = axis * sign * theta[..., None]
    return torch.where(near_pi[..., None], w_pi, w)


def make_pose(R: Tensor, t: Tensor) -> Tensor:
    """Rotation (..., 3, 3) and translation (..., 3) -> pose (..., 4, 4)."""
    top = torch.cat([R, t[..., None]], dim=-1)
    bottom = torch.zeros_like(top[..., :1, :])
    bottom[..., 0, 3] = 1
    return torch.cat([top, bottom], dim=-2)


def pose_from_axis_angle(w: Tensor, t: Tensor) -> Tensor:
    """Axis-angle (..., 3) and translation (..., 3) -> pose (..., 4, 4)."""
    return make_pose(rotation_from_axis_angle(w), t)


def compose(T_a_b: Tensor, T_b_c: Tensor) -> Tensor:
    """T_a_c = T_a_b @ T_b_c, batched (..., 4, 4)."""
    return T_a_b @ T_b_c


def invert(T_a_b: Tensor) -> Tensor:
    """T_b_a from T_a_b (..., 4, 4), using R^T rather than a general inverse."""
    R = T_a_b[..., :3, :3]
    t = T_a_b[..., :3, 3]
    Rt = R.transpose(-1, -2)
    return make_pose(Rt, -(Rt @ t[..., None])[..., 0])


def transform_points(T_a_b: Tensor, p_b: Tensor) -> Tensor:
    """p_a = T_a_b p_b. T_a_b: (..., 4, 4), p_b: (..., N, 3) -> (..., N, 3)."""
    R = T_a_b[..., :3, :3]
    t = T_a_b[..., :3, 3]
    return p_b @ R.transpose(-1, -2) + t[..., None, :]


def look_at(eye: Tensor, target: Tensor, up: Tensor) -> Tensor:
    """T_world_cam of a camera at ``eye`` whose optical axis (z) points at ``target``.

    The camera's y axis (image down) is as close as possible to ``-up``. All (..., 3).
    """
    z = target - eye
    z = z / z.norm(dim=-1, keepdim=True)
    x = torch.linalg.cross(z, -up, dim=-1)
    x = x / x.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    y = torch.linalg.cross(z, x, dim=-1)
    R_world_cam = torch.stack([x, y, z], dim=-1)
    return make_pose(R_world_cam, eye)


def rotation_angle_deg(R: Tensor) -> Tensor:
    """Rotation angle (deg) of (..., 3, 3) rotations, numerically safe near 0."""
    return torch.rad2deg(axis_angle_from_rotation(R).norm(dim=-1))
