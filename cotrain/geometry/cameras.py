"""Fisheye camera models, written once for the whole project.

Every model is a pair of pure, batched functions over torch tensors:

- ``project(p, params) -> (q, valid)``: points ``p`` ``(..., 3)`` in the camera frame to
  pixels ``q`` ``(..., 2)``; ``valid`` ``(...)`` is False outside the model's projection
  domain (there ``q`` is finite but meaningless).
- ``unproject(q, params) -> (v, valid)``: pixels ``(..., 2)`` to unit rays ``(..., 3)``;
  ``valid`` is False outside the unprojection domain (there ``v`` is finite, unit, meaningless).

``params`` is ``(..., P)`` in Kalibr's intrinsics order (docs/conventions.md) and broadcasts against
the leading dimensions of the points. The off-axis angle is always taken from the 3-D ray
(``atan2(sqrt(x^2 + y^2), z)``), so rays beyond 90 degrees project correctly. Singularities
(the optical axis, the edge of the domain) are handled with ``torch.where`` so that gradients
stay finite; the kb4 inverse uses a fixed number of Newton steps (traceable, exportable).

Models (pixel convention of docs/conventions.md: (0, 0) is the centre of the top-left pixel):

=====  ==========================  ====================================================
name   params                      projection
=====  ==========================  ====================================================
kb4    fx, fy, cx, cy, k1..k4      r = theta (1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8)
ucm    xi, fx, fy, cx, cy          u = fx x / (z + xi |p|) + cx
eucm   alpha, beta, fx, fy, cx, cy u = fx x / (alpha rho + (1 - alpha) z) + cx
ds     xi, alpha, fx, fy, cx, cy   Usenko et al. 2018 (double sphere)
=====  ==========================  ====================================================
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

KB4_NEWTON_STEPS = 12  # fixed iteration count of the kb4 inverse (converges to 1e-12 rad)
_EPS = 1e-12


def _split(params: Tensor, n: int) -> list[Tensor]:
    """Split ``(..., P)`` into ``n`` tensors of shape ``(..., 1)``."""
    if params.shape[-1] != n:
        raise ValueError(f"expected {n} camera parameters, got {params.shape[-1]}")
    return list(params.split(1, dim=-1))


def _safe_sqrt(x: Tensor) -> Tensor:
    """sqrt with a finite gradient at 0 (gradient 0 there)."""
    pos = x > _EPS
    return torch.where(pos, torch.sqrt(torch.where(pos, x, torch.ones_like(x))), torch.zeros_like(x))


def _pixels(mx: Tensor, my: Tensor, fx: Tensor, fy: Tensor, cx: Tensor, cy: Tensor) -> Tensor:
    return torch.cat([fx * mx + cx, fy * my + cy], dim=-1)


def _normalised(q: Tensor, fx: Tensor, fy: Tensor, cx: Tensor, cy: Tensor) -> tuple[Tensor, Tensor]:
    return (q[..., :1] - cx) / fx, (q[..., 1:2] - cy) / fy


def _unit(v: Tensor) -> Tensor:
    return v / v.norm(dim=-1, keepdim=True).clamp_min(_EPS)


# --------------------------------------------------------------------------------------------
# Kannala-Brandt / equidistant (kb4)
# --------------------------------------------------------------------------------------------
def _kb4_poly(theta: Tensor, k: list[Tensor]) -> tuple[Tensor, Tensor]:
    """Return d(theta) and d'(theta) for d = theta (1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8)."""
    t2 = theta * theta
    k1, k2, k3, k4 = k
    poly = 1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))
    dpoly = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
    return theta * poly, dpoly


def project_kb4(p: Tensor, params: Tensor) -> tuple[Tensor, Tensor]:
    """Kannala-Brandt projection. p: (..., 3), params: (..., 8) -> q (..., 2), valid (...)."""
    fx, fy, cx, cy, *k = _split(params, 8)
    x, y, z = p[..., :1], p[..., 1:2], p[..., 2:3]
    r2 = x * x + y * y
    r = _safe_sqrt(r2)
    theta = torch.atan2(r, z)
    d, dd = _kb4_poly(theta, k)
    # d / r, with the limit 1 / z on the optical axis (z > 0 there).
    on_axis = r < 1e-9 * z.abs()
    z_safe = torch.where(on_axis & (z > 0), z, torch.ones_like(z))
    r_safe = torch.where(on_axis | (r <= 0), torch.ones_like(r), r)
    scale = torch.where(on_axis, 1.0 / z_safe, d / r_safe)
    q = _pixels(scale * x, scale * y, fx, fy, cx, cy)
    norm = torch.sqrt(r2 + z * z)
    valid = (norm[..., 0] > _EPS) & (dd[..., 0] > 0) & (theta[..., 0] < math.pi - 1e-6)
    valid = valid & ~(on_axis & (z <= 0))[..., 0]
    return q, valid


def unproject_kb4(q: Tensor, params: Tensor) -> tuple[Tensor, Tensor]:
    """Kannala-Brandt unprojection (fixed-step Newton). q: (..., 2) -> v (..., 3), valid (...)."""
    fx, fy, cx, cy, *k = _split(params, 8)
    mx, my = _normalised(q, fx, fy, cx, cy)
    rd = _safe_sqrt(mx * mx + my * my)
    theta = rd
    for _ in range(KB4_NEWTON_STEPS):
        d, dd = _kb4_poly(theta, k)
        dd_safe = torch.where(dd.abs() > 1e-9, dd, torch.ones_like(dd))
        theta = (theta - (d - rd) / dd_safe).clamp(0.0, math.pi)
    d, dd = _kb4_poly(theta, k)
    ok = rd > 1e-12
    rd_safe = torch.where(ok, rd, torch.ones_like(rd))
    s = torch.where(ok, torch.sin(theta) / rd_safe, torch.ones_like(rd))
    v = torch.cat([s * mx, s * my, torch.cos(theta)], dim=-1)
    tol = 1e-4 if q.dtype == torch.float32 else 1e-9
    valid = (dd[..., 0] > 0) & ((d - rd).abs()[..., 0] < tol * (1 + rd[..., 0])) & (theta[..., 0] < math.pi - 1e-6)
    return _unit(v), valid


# --------------------------------------------------------------------------------------------
# Unified camera model (Mei / omni, no distortion)
# --------------------------------------------------------------------------------------------
def project_ucm(p: Tensor, params: Tensor) -> tuple[Tensor, Tensor]:
    """UCM projection. p: (..., 3), params (xi, fx, fy, cx, cy): (..., 5) -> q, valid."""
    xi, fx, fy, cx, cy = _split(params, 5)
    x, y, z = p[..., :1], p[..., 1:2], p[..., 2:3]
    d = _safe_sqrt(x * x + y * y + z * z)
    den = z + xi * d
    w = torch.where(xi > 1, 1.0 / xi, xi)
    valid = (z > -w * d) & (den > _EPS) & (d > _EPS)
    den = torch.where(valid, den, torch.ones_like(den))
    return _pixels(x / den, y / den, fx, fy, cx, cy), valid[..., 0]


def unproject_ucm(q: Tensor, params: Tensor) -> tuple[Tensor, Tensor]:
    """UCM unprojection. q: (..., 2), params: (..., 5) -> v (..., 3), valid (...)."""
    xi, fx, fy, cx, cy = _split(params, 5)
    mx, my = _normalised(q, fx, fy, cx, cy)
    r2 = mx * mx + my * my
    disc = 1 + (1 - xi * xi) * r2
    valid = disc >= 0
    factor = (xi + _safe_sqrt(disc.clamp_min(0))) / (1 + r2)
    v = torch.cat([factor * mx, factor * my, factor - xi], dim=-1)
    # Beyond the valid domain of xi > 1 the second intersection is the wrong one.
    w = torch.where(xi > 1, 1.0 / xi, xi)
    vu = _unit(v)
    valid = valid & (vu[..., 2:3] > -w)
    return vu, valid[..., 0]


# --------------------------------------------------------------------------------------------
# Enhanced unified camera model
# --------------------------------------------------------------------------------------------
def project_eucm(p: Tensor, params: Tensor) -> tuple[Tensor, Tensor]:
    """EUCM projection. p: (..., 3), params (alpha, beta, fx, fy, cx, cy): (..., 6) -> q, valid."""
    alpha, beta, fx, fy, cx, cy = _split(params, 6)
    x, y, z = p[..., :1], p[..., 1:2], p[..., 2:3]
    rho = _safe_sqrt(beta * (x * x + y * y) + z * z)
    den = alpha * rho + (1 - alpha) * z
    w = torch.where(alpha > 0.5, (1 - alpha) / alpha, alpha / (1 - alpha))
    valid = (z > -w * rho) & (den > _EPS)
    den = torch.where(valid, den, torch.ones_like(den))
    return _pixels(x / den, y / den, fx, fy, cx, cy), valid[..., 0]


def unproject_eucm(q: Tensor, params: Tensor) -> tuple[Tensor, Tensor]:
    """EUCM unprojection. q: (..., 2), params: (..., 6) -> v (..., 3), valid (...)."""
    alpha, beta, fx, fy, cx, cy = _split(params, 6)
    mx, my = _normalised(q, fx, fy, cx, cy)
    r2 = mx * mx + my * my
    disc = 1 - (2 * alpha - 1) * beta * r2
    valid = disc >= 0
    mz = (1 - alpha * alpha * beta * r2) / (alpha * _safe_sqrt(disc.clamp_min(0)) + (1 - alpha))
    v = _unit(torch.cat([mx, my, mz], dim=-1))
    # Keep only the branch that projects back (the ray must lie in the projection domain).
    w = torch.where(alpha > 0.5, (1 - alpha) / alpha, alpha / (1 - alpha))
    rho = _safe_sqrt(beta * (v[..., :1] ** 2 + v[..., 1:2] ** 2) + v[..., 2:3] ** 2)
    valid = valid & (v[..., 2:3] > -w * rho)
    return v, valid[..., 0]


# --------------------------------------------------------------------------------------------
# Double sphere
# --------------------------------------------------------------------------------------------
def project_ds(p: Tensor, params: Tensor) -> tuple[Tensor, Tensor]:
    """Double-sphere projection. p: (..., 3), params (xi, alpha, fx, fy, cx, cy) -> q, valid."""
    xi, alpha, fx, fy, cx, cy = _split(params, 6)
    x, y, z = p[..., :1], p[..., 1:2], p[..., 2:3]
    r2 = x * x + y * y
    d1 = _safe_sqrt(r2 + z * z)
    zeta = xi * d1 + z
    d2 = _safe_sqrt(r2 + zeta * zeta)
    den = alpha * d2 + (1 - alpha) * zeta
    w1 = torch.where(alpha > 0.5, (1 - alpha) / alpha, alpha / (1 - alpha))
    w2 = (w1 + xi) / torch.sqrt(2 * w1 * xi + xi * xi + 1)
    valid = (z > -w2 * d1) & (den > _EPS)
    den = torch.where(valid, den, torch.ones_like(den))
    return _pixels(x / den, y / den, fx, fy, cx, cy), valid[..., 0]


def unproject_ds(q: Tensor, params: Tensor) -> tuple[Tensor, Tensor]:
    """Double-sphere unprojection. q: (..., 2), params: (..., 6) -> v (..., 3), valid (...)."""
    xi, alpha, fx, fy, cx, cy = _split(params, 6)
    mx, my = _normalised(q, fx, fy, cx, cy)
    r2 = mx * mx + my * my
    disc1 = 1 - (2 * alpha - 1) * r2
    mz = (1 - alpha * alpha * r2) / (alpha * _safe_sqrt(disc1.clamp_min(0)) + 1 - alpha)
    disc2 = mz * mz + (1 - xi * xi) * r2
    k = (mz * xi + _safe_sqrt(disc2.clamp_min(0))) / (mz * mz + r2)
    v = _unit(torch.cat([k * mx, k * my, k * mz - xi], dim=-1))
    w1 = torch.where(alpha > 0.5, (1 - alpha) / alpha, alpha / (1 - alpha))
    w2 = (w1 + xi) / torch.sqrt(2 * w1 * xi + xi * xi + 1)
    valid = (disc1 >= 0) & (disc2 >= 0) & (v[..., 2:3] > -w2)
    return v, valid[..., 0]


# --------------------------------------------------------------------------------------------
# Registry and construction helpers
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CameraModel:
    """One camera family: its parameter names (Kalibr order) and its two functions."""

    name: str
    param_names: tuple[str, ...]
    project: Callable[[Tensor, Tensor], tuple[Tensor, Tensor]]
    unproject: Callable[[Tensor, Tensor], tuple[Tensor, Tensor]]
    shape_names: tuple[str, ...]  # the projection-shape parameters (not fx, fy, cx, cy)
    kalibr_model: str  # camera_model in Kalibr's camchain.yaml
    kalibr_distortion: str  # distortion_model in camchain.yaml
    distortion_names: tuple[str, ...]  # parameters Kalibr lists as distortion_coeffs (the rest are its intrinsics)
    bounds: dict[str, tuple[float, float]]  # valid range of each bounded parameter (solver increments are clamped to it)
    shape_ranges: dict[str, tuple[float, float]]  # uniform sampling range of each shape parameter for rendered cameras

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    def index(self, name: str) -> int:
        return self.param_names.index(name)

    def clamp(self, params: Tensor) -> Tensor:
        """(..., n_params) parameters clamped into :attr:`bounds` (a copy)."""
        out = params.clone()
        for name, (lo, hi) in self.bounds.items():
            i = self.index(name)
            out[..., i] = out[..., i].clamp(lo, hi)
        return out

    def sample_shape(self, uniform: Callable[[float, float], float], scale: dict[str, float] | None = None) -> dict[str, float]:
        """Shape parameters drawn from :attr:`shape_ranges` with ``uniform(lo, hi)`` (in
        :attr:`shape_names` order); ``scale`` multiplies a parameter's draw (e.g. the renderer's
        ``kb4_k_scale``)."""
        scale = scale or {}
        return {n: scale.get(n, 1.0) * uniform(*self.shape_ranges[n]) for n in self.shape_names}


MODELS: dict[str, CameraModel] = {
    "kb4": CameraModel(
        "kb4",
        ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
        project_kb4,
        unproject_kb4,
        ("k1", "k2", "k3", "k4"),
        "pinhole",
        "equidistant",
        ("k1", "k2", "k3", "k4"),
        {"fx": (1.0, math.inf), "fy": (1.0, math.inf)},
        {"k1": (-0.06, 0.06), "k2": (-0.015, 0.015), "k3": (-0.004, 0.004), "k4": (-0.001, 0.001)},
    ),
    "ucm": CameraModel(
        "ucm",
        ("xi", "fx", "fy", "cx", "cy"),
        project_ucm,
        unproject_ucm,
        ("xi",),
        "omni",
        "none",
        (),
        {"xi": (0.0, 5.0), "fx": (1.0, math.inf), "fy": (1.0, math.inf)},
        {"xi": (0.6, 1.5)},
    ),
    "eucm": CameraModel(
        "eucm",
        ("alpha", "beta", "fx", "fy", "cx", "cy"),
        project_eucm,
        unproject_eucm,
        ("alpha", "beta"),
        "eucm",
        "none",
        (),
        {"alpha": (1e-3, 0.999), "beta": (1e-3, math.inf), "fx": (1.0, math.inf), "fy": (1.0, math.inf)},
        {"alpha": (0.45, 0.7), "beta": (0.8, 1.3)},
    ),
    "ds": CameraModel(
        "ds",
        ("xi", "alpha", "fx", "fy", "cx", "cy"),
        project_ds,
        unproject_ds,
        ("xi", "alpha"),
        "ds",
        "none",
        (),
        {"xi": (-1.0, 1.0), "alpha": (1e-3, 0.999), "fx": (1.0, math.inf), "fy": (1.0, math.inf)},
        {"xi": (-0.3, 0.05), "alpha": (0.45, 0.65)},
    ),
}

DEFAULT_SHAPE: dict[str, dict[str, float]] = {
    "kb4": {"k1": 0.0, "k2": 0.0, "k3": 0.0, "k4": 0.0},  # f-theta
    "ucm": {"xi": 1.0},
    "eucm": {"alpha": 0.6, "beta": 1.0},
    "ds": {"xi": -0.1, "alpha": 0.57},
}


# Kalibr's camera model strings (kalibr_calibrate_cameras --models) and what we make of them.
KALIBR_NAMES: dict[str, str] = {"pinhole-equi": "kb4", "omni-none": "ucm", "eucm-none": "eucm", "ds-none": "ds"}
KALIBR_UNSUPPORTED: dict[str, str] = {
    "pinhole-radtan": "radial-tangential distortion does not reach beyond 90 degrees; for a fisheye use pinhole-equi",
    "pinhole-fov": "the FOV (ATAN) model is not supported; use pinhole-equi, ds-none or eucm-none",
    "omni-radtan": "omni with radtan distortion is not supported; use omni-none or ds-none",
}


def model_from_name(name: str) -> str:
    """Our model name from ours (kb4, ucm, eucm, ds) or Kalibr's (pinhole-equi, omni-none,
    eucm-none, ds-none); a one-line ValueError with the reason for anything else."""
    if name in MODELS:
        return name
    if name in KALIBR_NAMES:
        return KALIBR_NAMES[name]
    if name in KALIBR_UNSUPPORTED:
        raise ValueError(f"camera model {name!r}: {KALIBR_UNSUPPORTED[name]}")
    known = ", ".join([*MODELS, *KALIBR_NAMES])
    raise ValueError(f"unknown camera model {name!r}; choose one of {known}")


def get_model(name: str) -> CameraModel:
    """Look a camera family up by name (kb4, ucm, eucm, ds)."""
    try:
        return MODELS[name]
    except KeyError:
        raise ValueError(f"unknown camera model {name!r}; choose one of {', '.join(MODELS)}") from None


def project(model: str, p: Tensor, params: Tensor) -> tuple[Tensor, Tensor]:
    """Project ``p`` (..., 3) with camera family ``model``; see the module docstring."""
    return get_model(model).project(p, params)


def unproject(model: str, q: Tensor, params: Tensor) -> tuple[Tensor, Tensor]:
    """Unproject ``q`` (..., 2) with camera family ``model``; see the module docstring."""
    return get_model(model).unproject(q, params)


def assemble_params(model: str, fx: float, fy: float, cx: float, cy: float, shape: dict[str, float]) -> list[float]:
    """Parameters in Kalibr order from focal lengths, principal point and shape parameters."""
    m = get_model(model)
    values = {"fx": fx, "fy": fy, "cx": cx, "cy": cy, **shape}
    missing = [n for n in m.param_names if n not in values]
    if missing:
        raise ValueError(f"{model}: missing parameters {missing}")
    return [float(values[n]) for n in m.param_names]


def make_camera(
    model: str,
    fov_deg: float,
    width: int,
    height: int,
    radius: float | None = None,
    principal: tuple[float, float] | None = None,
    dtype: torch.dtype = torch.float64,
    **shape: float,
) -> Tensor:
    """Build the parameter vector of "a ``fov_deg`` camera of family ``model``, ``width`` x ``height``".

    The focal length is chosen so that a ray ``fov_deg / 2`` off-axis lands ``radius`` pixels from
    the principal point (the image-circle radius; default ``min(width, height) / 2``, a circle
    touching the shorter image side). ``principal`` defaults to the image centre
    ``((width - 1) / 2, (height - 1) / 2)``. Shape parameters (k1..k4, xi, alpha, beta) default to
    :data:`DEFAULT_SHAPE`. Returns ``(P,)`` params in Kalibr order.

    Example: ``make_camera("kb4", 220, 1280, 720)`` is a 220-degree f-theta camera.
    """
    m = get_model(model)
    full_shape = {**DEFAULT_SHAPE[model], **shape}
    unknown = set(full_shape) - set(m.shape_names)
    if unknown:
        raise ValueError(f"{model}: unknown shape parameters {sorted(unknown)}")
    if radius is None:
        radius = min(width, height) / 2.0
    if principal is None:
        principal = ((width - 1) / 2.0, (height - 1) / 2.0)
    half = math.radians(fov_deg) / 2.0
    unit = torch.tensor(assemble_params(model, 1.0, 1.0, 0.0, 0.0, full_shape), dtype=torch.float64)
    ray = torch.tensor([math.sin(half), 0.0, math.cos(half)], dtype=torch.float64)
    q, valid = m.project(ray, unit)
    if not bool(valid) or float(q[0]) <= 0:
        raise ValueError(f"{model} with {full_shape} cannot see {fov_deg} degrees; change its shape parameters")
    f = radius / float(q[0])
    params = assemble_params(model, f, f, principal[0], principal[1], full_shape)
    return torch.tensor(params, dtype=dtype)


def off_axis_angle(v: Tensor) -> Tensor:
    """Angle (rad) between ray(s) ``v`` (..., 3) and the optical axis, from the 3-D ray. -> (...)."""
    return torch.atan2(v[..., :2].norm(dim=-1), v[..., 2])
