"""Camera models against independent math (numpy formulas written here), round trips, gradcheck."""

import math

import numpy as np
import pytest
import torch

from cotrain.geometry import MODELS, cameras, make_camera, off_axis_angle, project, unproject

FOVS = [180, 200, 220, 240]
SHAPES = {
    "kb4": {"k1": 0.03, "k2": -0.005, "k3": 0.001, "k4": -0.0002},
    "ucm": {"xi": 1.2},
    "eucm": {"alpha": 0.6, "beta": 1.1},
    "ds": {"xi": -0.15, "alpha": 0.58},
}


def np_project(model, p, prm):
    """Independent numpy projection straight from the formulas in docs/conventions.md / the papers."""
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    if model == "kb4":
        fx, fy, cx, cy, k1, k2, k3, k4 = prm
        r = np.hypot(x, y)
        th = np.arctan2(r, z)
        d = th * (1 + k1 * th**2 + k2 * th**4 + k3 * th**6 + k4 * th**8)
        return np.stack([fx * d * x / r + cx, fy * d * y / r + cy], -1)
    if model == "ucm":
        xi, fx, fy, cx, cy = prm
        den = z + xi * np.sqrt(x * x + y * y + z * z)
    elif model == "eucm":
        a, b, fx, fy, cx, cy = prm
        den = a * np.sqrt(b * (x * x + y * y) + z * z) + (1 - a) * z
    else:
        xi, a, fx, fy, cx, cy = prm
        d1 = np.sqrt(x * x + y * y + z * z)
        zz = xi * d1 + z
        d2 = np.sqrt(x * x + y * y + zz * zz)
        den = a * d2 + (1 - a) * zz
    return np.stack([fx * x / den + cx, fy * y / den + cy], -1)


def image_circle_grid(model, fov, dtype):
    prm = make_camera(model, fov, 1280, 720, radius=400, dtype=dtype, **SHAPES[model])
    ys, xs = torch.meshgrid(torch.linspace(0, 719, 73, dtype=dtype), torch.linspace(0, 1279, 129, dtype=dtype), indexing="ij")
    q = torch.stack([xs, ys], -1)
    return prm, q


@pytest.mark.parametrize("model", list(MODELS))
@pytest.mark.parametrize("fov", FOVS)
@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-8), (torch.float32, 1e-3)])
def test_round_trip_whole_circle(model, fov, dtype, tol):
    prm, q = image_circle_grid(model, fov, dtype)
    v, ok = unproject(model, q, prm)
    inside = ok & (off_axis_angle(v) <= math.radians(fov) / 2)
    assert inside.sum() > 3000  # the whole image circle of radius 400 px
    assert torch.rad2deg(off_axis_angle(v[inside])).max() > fov / 2 - 1.0  # reaches beyond 90 deg
    q2, ok2 = project(model, v * 2.5, prm)
    assert bool(ok2[inside].all())
    err = (q2 - q).norm(dim=-1)[inside]
    assert err.max().item() < tol


@pytest.mark.parametrize("model", list(MODELS))
def test_known_values_against_numpy(model):
    prm = make_camera(model, 220, 1280, 720, **SHAPES[model])
    rng = np.random.default_rng(0)
    th = rng.uniform(0.01, math.radians(109), 200)
    ph = rng.uniform(0, 2 * math.pi, 200)
    dist = rng.uniform(0.2, 5, 200)
    p = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1) * dist[:, None]
    q, ok = project(model, torch.from_numpy(p), prm)
    assert bool(ok.all())
    np.testing.assert_allclose(q.numpy(), np_project(model, p, prm.numpy()), atol=1e-9)


def test_ftheta_known_value():
    # f-theta: a ray 100 deg off-axis along +x lands f * 100deg right of the centre.
    prm = make_camera("kb4", 220, 1280, 720, radius=360)
    f = 360 / math.radians(110)
    assert prm[0].item() == pytest.approx(f)
    th = math.radians(100)
    q, ok = project("kb4", torch.tensor([math.sin(th), 0.0, math.cos(th)], dtype=torch.float64), prm)
    assert bool(ok)
    assert q[0].item() == pytest.approx(639.5 + f * th, abs=1e-9)
    assert q[1].item() == pytest.approx(359.5, abs=1e-9)


@pytest.mark.parametrize("model", list(MODELS))
def test_batch_shapes_and_broadcast(model):
    prm = make_camera(model, 200, 640, 480, **SHAPES[model]).float()
    p = torch.randn(2, 3, 5, 3)
    p[..., 2] = p[..., 2].abs() + 0.5
    q, ok = project(model, p, prm)
    assert q.shape == (2, 3, 5, 2) and ok.shape == (2, 3, 5) and q.dtype == torch.float32
    v, ok = unproject(model, q, prm)
    assert v.shape == (2, 3, 5, 3) and ok.shape == (2, 3, 5)
    # Per-point parameters broadcast against the points.
    q2, _ = project(model, p, prm.expand(2, 3, 5, -1))
    assert torch.allclose(q, q2)


@pytest.mark.parametrize("model", list(MODELS))
def test_gradcheck_float64(model):
    prm = make_camera(model, 220, 640, 480, **SHAPES[model]).requires_grad_(True)
    p = torch.tensor([[0.3, -0.2, 1.0], [0.9, 0.4, -0.3], [0.01, 0.02, 2.0]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: project(model, a, b)[0], (p, prm))
    q = project(model, p, prm)[0].detach().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda a, b: unproject(model, a, b)[0], (q, prm))


@pytest.mark.parametrize("model", list(MODELS))
def test_invalid_domain_flagged_and_finite(model):
    prm = make_camera(model, 200, 640, 480, **SHAPES[model])
    behind = torch.tensor([[0.0, 0.0, -1.0], [0.01, 0.0, -1.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
    q, ok = project(model, behind, prm)
    assert not bool(ok.any())
    assert bool(torch.isfinite(q).all())
    far = torch.tensor([[1e5, 1e5], [-4e4, 3e4]], dtype=torch.float64)
    v, ok = unproject(model, far, prm)
    assert bool(torch.isfinite(v).all())
    if model in ("eucm", "ds", "ucm"):  # these have a bounded unprojection domain with these shapes
        assert not bool(ok.any())


def test_on_axis_is_finite_with_gradient():
    for model in MODELS:
        prm = make_camera(model, 200, 640, 480)
        p = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64, requires_grad=True)
        q, ok = project(model, p, prm)
        q.sum().backward()
        assert bool(ok.all()) and bool(torch.isfinite(p.grad).all())
        np.testing.assert_allclose(q.detach().numpy()[0], prm.numpy()[[-2, -1]] if model != "kb4" else prm.numpy()[2:4])


def test_make_camera_rejects_impossible_fov():
    with pytest.raises(ValueError, match="cannot see"):
        make_camera("ucm", 250, 640, 480, xi=0.3)
    with pytest.raises(ValueError, match="unknown camera model"):
        make_camera("pinhole", 100, 640, 480)


@pytest.mark.parametrize("model", list(cameras.MODELS))
def test_model_owns_bounds_and_sampling(model):
    """Every model says its own valid ranges; the solver's clamp uses them without knowing positions."""
    m = cameras.get_model(model)
    assert set(m.shape_ranges) == set(m.shape_names)
    assert {"fx", "fy"} <= set(m.bounds)
    low, high = (
        m.clamp(torch.full((2, m.n_params), -10.0, dtype=torch.float64)),
        m.clamp(torch.full((2, m.n_params), 1e6, dtype=torch.float64)),
    )
    for name, (lo, hi) in m.bounds.items():
        assert bool((low[:, m.index(name)] == lo).all())
        assert bool((high[:, m.index(name)] == min(hi, 1e6)).all())
    free = [n for n in m.param_names if n not in m.bounds]
    assert all(bool((low[:, m.index(n)] == -10).all()) for n in free)
    assert m.sample_shape(lambda lo, hi: hi) == {n: m.shape_ranges[n][1] for n in m.shape_names}
    scaled = m.sample_shape(lambda lo, hi: lo, {n: 0.5 for n in m.shape_names})
    assert scaled == {n: 0.5 * m.shape_ranges[n][0] for n in m.shape_names}
    # The default camera and the middle of the sampling ranges lie inside the bounds.
    mid = {n: sum(m.shape_ranges[n]) / 2 for n in m.shape_names}
    for shape in ({}, mid):
        p = cameras.make_camera(model, 200, 1280, 720, **shape)
        assert torch.equal(m.clamp(p), p)


@pytest.mark.parametrize("model", list(MODELS))
def test_numpy_and_torch_share_one_model(model):
    """The same functions on numpy arrays (the calibrator's, torch-free) and on tensors give the same
    pixels, rays and masks, and numpy in gives numpy out."""
    prm_t = make_camera(model, 220, 1280, 720, **SHAPES[model])
    prm_n = make_camera(model, 220, 1280, 720, dtype=np.float64, **SHAPES[model])
    assert isinstance(prm_n, np.ndarray) and torch.is_tensor(prm_t)
    np.testing.assert_array_equal(prm_n, prm_t.numpy())
    p = np.random.default_rng(0).normal(size=(400, 3))
    p[0] = [0.0, 0.0, 0.7]  # the optical axis
    q_n, ok_n = project(model, p, prm_n)
    q_t, ok_t = project(model, torch.from_numpy(p), prm_t)
    assert isinstance(q_n, np.ndarray) and isinstance(ok_n, np.ndarray) and ok_n.dtype == bool
    np.testing.assert_allclose(q_n, q_t.numpy(), rtol=1e-13, atol=1e-9)
    np.testing.assert_array_equal(ok_n, ok_t.numpy())
    v_n, vok_n = unproject(model, q_n, prm_n)
    v_t, vok_t = unproject(model, q_t, prm_t)
    np.testing.assert_allclose(v_n, v_t.numpy(), atol=1e-12)
    np.testing.assert_array_equal(vok_n, vok_t.numpy())
    np.testing.assert_allclose(off_axis_angle(p), off_axis_angle(torch.from_numpy(p)).numpy(), atol=1e-15)
    clamped = MODELS[model].clamp(prm_n * 0)
    assert isinstance(clamped, np.ndarray) and (clamped == MODELS[model].clamp(prm_t * 0).numpy()).all()
