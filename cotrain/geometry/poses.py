"""Small SE(3) helpers named by the ``T_a_b`` rule of docs/conventions.md.

A pose ``T_a_b`` is a ``(..., 4, 4)`` homogeneous matrix mapping frame ``b`` to frame ``a``:
``p_a = T_a_b @ p_b`` and ``T_a_c = compose(T_a_b, T_b_c)``. Rotations as axis-angle
``(..., 3)`` (direction = axis, norm = angle in rad). All functions are batched and take arrays,
numpy or torch (:mod:`cotrain.geometry._ops`; torch is imported only when given a tensor); on
tensors they are differentiable, the small-angle limits using ``where``.
"""

from __future__ import annotations

from typing import Any

from cotrain.geometry._ops import ops

Array = Any  # a numpy array or a torch tensor


def _skew(w: Array) -> Array:
    """(..., 3) -> (..., 3, 3) cross-product matrix."""
    xp = ops(w).xp
    z = xp.zeros_like(w[..., 0])
    x, y, zz = w[..., 0], w[..., 1], w[..., 2]
    return xp.stack([xp.stack([z, -zz, y], -1), xp.stack([zz, z, -x], -1), xp.stack([-y, x, z], -1)], -2)


def rotation_from_axis_angle(w: Array) -> Array:
    """Rodrigues: axis-angle (..., 3) -> rotation matrix (..., 3, 3)."""
    o = ops(w)
    xp = o.xp
    theta2 = o.sum(w * w, -1, True)[..., None]  # (..., 1, 1)
    small = theta2 < 1e-10
    theta2_safe = xp.where(small, xp.ones_like(theta2), theta2)
    theta = xp.sqrt(theta2_safe)
    a = xp.where(small, 1 - theta2 / 6, xp.sin(theta) / theta)
    b = xp.where(small, 0.5 - theta2 / 24, (1 - xp.cos(theta)) / theta2_safe)
    K = _skew(w)
    eye = o.eye(3, w)
    return eye + a * K + b * (K @ K)


def axis_angle_from_rotation(R: Array) -> Array:
    """Inverse Rodrigues: rotation (..., 3, 3) -> axis-angle (..., 3), angle in [0, pi]."""
    o = ops(R)
    xp = o.xp
    cos = o.clamp((R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2] - 1) / 2, -1.0, 1.0)
    theta = o.acos(cos)
    vee = xp.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    sin = xp.sin(theta)
    small = theta < 1e-5
    near_pi = theta > o.pi - 1e-3
    factor = xp.where(small, 0.5 + theta * theta / 12, theta / (2 * xp.where(small | near_pi, xp.ones_like(sin), sin)))
    w = vee * factor[..., None]
    # Near pi, the axis comes from the diagonal of (R + I) / 2 = a a^T.
    B = (R + o.eye(3, R)) / 2
    diag = o.clamp_min(xp.stack([B[..., 0, 0], B[..., 1, 1], B[..., 2, 2]], -1), 0)
    i = o.argmax(diag, -1, True)
    col = o.gather(B, -1, xp.broadcast_to(i[..., None, :], (*B.shape[:-1], 1)))[..., 0]
    axis = col / o.clamp_min(o.norm(col, -1, True), 1e-12)
    one = xp.ones_like(theta[..., None])
    sign = xp.where(o.sum(axis * vee, -1, True) < 0, -one, one)
    w_pi = axis * sign * theta[..., None]
    return xp.where(near_pi[..., None], w_pi, w)


def make_pose(R: Array, t: Array) -> Array:
    """Rotation (..., 3, 3) and translation (..., 3) -> pose (..., 4, 4)."""
    o = ops(R, t)
    top = o.cat([R, t[..., None]], -1)
    bottom = o.xp.zeros_like(top[..., :1, :])
    bottom[..., 0, 3] = 1
    return o.cat([top, bottom], -2)


def pose_from_axis_angle(w: Array, t: Array) -> Array:
    """Axis-angle (..., 3) and translation (..., 3) -> pose (..., 4, 4)."""
    return make_pose(rotation_from_axis_angle(w), t)


def compose(T_a_b: Array, T_b_c: Array) -> Array:
    """T_a_c = T_a_b @ T_b_c, batched (..., 4, 4)."""
    return T_a_b @ T_b_c


def invert(T_a_b: Array) -> Array:
    """T_b_a from T_a_b (..., 4, 4), using R^T rather than a general inverse."""
    R = T_a_b[..., :3, :3]
    t = T_a_b[..., :3, 3]
    Rt = R.swapaxes(-1, -2)
    return make_pose(Rt, -(Rt @ t[..., None])[..., 0])


def transform_points(T_a_b: Array, p_b: Array) -> Array:
    """p_a = T_a_b p_b. T_a_b: (..., 4, 4), p_b: (..., N, 3) -> (..., N, 3)."""
    R = T_a_b[..., :3, :3]
    t = T_a_b[..., :3, 3]
    return p_b @ R.swapaxes(-1, -2) + t[..., None, :]


def look_at(eye: Array, target: Array, up: Array) -> Array:
    """T_world_cam of a camera at ``eye`` whose optical axis (z) points at ``target``.

    The camera's y axis (image down) is as close as possible to ``-up``. All (..., 3).
    """
    o = ops(eye, target, up)
    z = target - eye
    z = z / o.norm(z, -1, True)
    x = o.cross(z, -up)
    x = x / o.clamp_min(o.norm(x, -1, True), 1e-12)
    y = o.cross(z, x)
    R_world_cam = o.xp.stack([x, y, z], -1)
    return make_pose(R_world_cam, eye)


def rotation_angle_deg(R: Array) -> Array:
    """Rotation angle (deg) of (..., 3, 3) rotations, numerically safe near 0."""
    o = ops(R)
    return o.xp.rad2deg(o.norm(axis_angle_from_rotation(R), -1))
