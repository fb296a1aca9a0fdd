import math

import numpy as np
import torch

from cotrain.geometry import (
    axis_angle_from_rotation,
    compose,
    invert,
    pose_from_axis_angle,
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
