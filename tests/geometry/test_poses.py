import math

import numpy as np
import torch

from cotrain.geometry import (
    axis_angle_from_rotation,
    compose,
    invert,
    look_at,
    pose_from_axis_angle,
    rotation_angle_deg,
    rotation_from_axis_angle,
    transform_points,
)


def test_rodrigues_known_value():
    R = rotation_from_axis_angle(torch.tensor([0.0, 0.0, math.pi / 2], dtype=torch.float64))
    np.testing.assert_allclose(R.numpy(), [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)


def test_axis_angle_round_trip_including_small_and_near_pi():
    g = torch.Generator().manual_seed(0)
    axes = torch.nn.functional.normalize(torch.randn(200, 3, generator=g, dtype=torch.float64), dim=-1)
    angles = torch.cat([torch.tensor([0.0, 1e-9, 1e-4, math.pi - 1e-6, math.pi - 1e-3]), torch.rand(195, generator=g) * math.pi])
    w = axes * angles[:, None].double()
    R = rotation_from_axis_angle(w)
    assert torch.allclose(R @ R.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(200, 3, 3), atol=1e-12)
    R2 = rotation_from_axis_angle(axis_angle_from_rotation(R))
    assert (R2 - R).abs().max() < 1e-6


def test_compose_invert_apply():
    g = torch.Generator().manual_seed(1)
    T_a_b = pose_from_axis_angle(torch.randn(4, 3, generator=g, dtype=torch.float64), torch.randn(4, 3, generator=g, dtype=torch.float64))
    T_b_c = pose_from_axis_angle(torch.randn(4, 3, generator=g, dtype=torch.float64), torch.randn(4, 3, generator=g, dtype=torch.float64))
    p_c = torch.randn(4, 10, 3, generator=g, dtype=torch.float64)
    T_a_c = compose(T_a_b, T_b_c)
    assert torch.allclose(transform_points(T_a_c, p_c), transform_points(T_a_b, transform_points(T_b_c, p_c)))
    assert torch.allclose(compose(T_a_b, invert(T_a_b)), torch.eye(4, dtype=torch.float64).expand(4, 4, 4), atol=1e-12)


def test_rodrigues_gradcheck():
    w = torch.tensor([0.3, -0.2, 0.5], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(rotation_from_axis_angle, (w,))


def test_numpy_and_torch_poses_agree():
    """The pose helpers take numpy arrays (numpy out, torch not needed) as they take tensors."""
    rng = np.random.default_rng(2)
    w = rng.normal(size=(50, 3))
    w[0], w[1], w[2] = 0.0, [math.pi, 0, 0], [0, 1e-9, 0]
    t = rng.normal(size=(50, 3))
    T_n = pose_from_axis_angle(w, t)
    T_t = pose_from_axis_angle(torch.from_numpy(w), torch.from_numpy(t))
    assert isinstance(T_n, np.ndarray)
    np.testing.assert_allclose(T_n, T_t.numpy(), atol=1e-15)
    np.testing.assert_allclose(axis_angle_from_rotation(T_n[:, :3, :3]), axis_angle_from_rotation(T_t[:, :3, :3]).numpy(), atol=1e-12)
    np.testing.assert_allclose(invert(T_n) @ T_n, np.broadcast_to(np.eye(4), T_n.shape), atol=1e-12)
    np.testing.assert_allclose(rotation_angle_deg(T_n[:, :3, :3]), rotation_angle_deg(T_t[:, :3, :3]).numpy(), atol=1e-10)
    eye, target, up = np.array([1.0, 0.5, -2]), np.zeros(3), np.array([0.0, -1, 0])
    np.testing.assert_allclose(look_at(eye, target, up), look_at(*map(torch.from_numpy, (eye, target, up))).numpy(), atol=1e-15)
    P = rng.normal(size=(7, 3))
    np.testing.assert_allclose(transform_points(T_n[3], P), transform_points(T_t[3], torch.from_numpy(P)).numpy(), atol=1e-14)
