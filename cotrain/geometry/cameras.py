"""Fisheye camera models, written once for the whole project.

Every model is a pair of pure, batched functions over arrays (numpy or torch: one set of formulas,
the few spellings that differ chosen from the inputs' type by :mod:`cotrain.geometry._ops`; torch
is imported only when given a tensor):

- ``project(p, params) -> (q, valid)``: points ``p`` ``(..., 3)`` in the camera frame to
  pixels ``q`` ``(..., 2)``; ``valid`` ``(...)`` is False outside the model's projection
  domain (there ``q`` is finite but meaningless).
- ``unproject(q, params) -> (v, valid)``: pixels ``(..., 2)`` to unit rays ``(..., 3)``;
  ``valid`` is False outside the unprojection domain (there ``v`` is finite, unit, meaningless).

``params`` is ``(..., P)`` in Kalibr's intrinsics order (docs/conventions.md) and broadcasts against
the leading dimensions of the points. The off-axis angle is always taken from the 3-D ray
(``atan2(sqrt(x^2 + y^2), z)``), so rays beyond 90 degrees project correctly. Singularities
(the optical axis, the edge of the domain) are handled with ``where`` so that (torch) gradients
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
from typing import Any

import numpy as np

from cotrain.geometry._ops import ops

Array = Any  # a numpy array or a torch tensor (see cotrain.geometry._ops)

KB4_NEWTON_STEPS = 12  # fixed iteration count of the kb4 inverse (converges to 1e-12 rad)
_EPS = 1e-12


def _split(params: Array, n: int) -> list[Array]:
    """Split ``(..., P)`` into ``n`` arrays of shape ``(..., 1)``."""
    if params.shape[-1] != n:
        raise ValueError(f"expected {n} camera parameters, got {params.shape[-1]}")
    return ops(params).split(params, n)


def _safe_sqrt(x: Array) -> Array:
    """sqrt with a finite gradient at 0 (gradient 0 there)."""
    xp = ops(x).xp
    pos = x > _EPS
    return xp.where(pos, xp.sqrt(xp.where(pos, x, xp.ones_like(x))), xp.zeros_like(x))


def _pixels(mx: Array, my: Array, fx: Array, fy: Array, cx: Array, cy: Array) -> Array:
    return ops(mx, fx).cat([fx * mx + cx, fy * my + cy], -1)


def _normalised(q: Array, fx: Array, fy: Array, cx: Array, cy: Array) -> tuple[Array, Array]:
    return (q[..., :1] - cx) / fx, (q[..., 1:2] - cy) / fy


def _unit(v: Array) -> Array:
    o = ops(v)
    return v / o.clamp_min(o.norm(v, -1, True), _EPS)


def _ratio(a: Array) -> Array:
    """(1 - a) / a for a > 0.5, a / (1 - a) otherwise (the EUCM and DS domain bound w1)."""
    xp = ops(a).xp
    return xp.where(a > 0.5, (1 - a) / a, a / (1 - a))


# --------------------------------------------------------------------------------------------
# Kannala-Brandt / equidistant (kb4)
# --------------------------------------------------------------------------------------------
def _kb4_poly(theta: Array, k: list[Array]) -> tuple[Array, Array]:
    """Return d(theta) and d'(theta) for d = theta (1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8)."""
    t2 = theta * theta
    k1, k2, k3, k4 = k
    poly = 1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))
    dpoly = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
    return theta * poly, dpoly


def project_kb4(p: Array, params: Array) -> tuple[Array, Array]:
    """Kannala-Brandt projection. p: (..., 3), params: (..., 8) -> q (..., 2), valid (...)."""
    o = ops(p, params)
    xp = o.xp
    fx, fy, cx, cy, *k = _split(params, 8)
    x, y, z = p[..., :1], p[..., 1:2], p[..., 2:3]
    r2 = x * x + y * y
    r = _safe_sqrt(r2)
    theta = o.atan2(r, z)
    d, dd = _kb4_poly(theta, k)
    # d / r, with the limit 1 / z on the optical axis (z > 0 there).
    on_axis = r < 1e-9 * abs(z)
    z_safe = xp.where(on_axis & (z > 0), z, xp.ones_like(z))
    r_safe = xp.where(on_axis | (r <= 0), xp.ones_like(r), r)
    scale = xp.where(on_axis, 1.0 / z_safe, d / r_safe)
    q = _pixels(scale * x, scale * y, fx, fy, cx, cy)
    norm = xp.sqrt(r2 + z * z)
    valid = (norm[..., 0] > _EPS) & (dd[..., 0] > 0) & (theta[..., 0] < math.pi - 1e-6)
    valid = valid & ~(on_axis & (z <= 0))[..., 0]
    return q, valid


def unproject_kb4(q: Array, params: Array) -> tuple[Array, Array]:
    """Kannala-Brandt unprojection (fixed-step Newton). q: (..., 2) -> v (..., 3), valid (...)."""
    o = ops(q, params)
    xp = o.xp
    fx, fy, cx, cy, *k = _split(params, 8)
    mx, my = _normalised(q, fx, fy, cx, cy)
    rd = _safe_sqrt(mx * mx + my * my)
    theta = rd
    for _ in range(KB4_NEWTON_STEPS):
        d, dd = _kb4_poly(theta, k)
        dd_safe = xp.where(abs(dd) > 1e-9, dd, xp.ones_like(dd))
        theta = o.clamp(theta - (d - rd) / dd_safe, 0.0, math.pi)
    d, dd = _kb4_poly(theta, k)
    ok = rd > 1e-12
    rd_safe = xp.where(ok, rd, xp.ones_like(rd))
    s = xp.where(ok, xp.sin(theta) / rd_safe, xp.ones_like(rd))
    v = o.cat([s * mx, s * my, xp.cos(theta)], -1)
    tol = 1e-4 if q.dtype == o.float32 else 1e-9
    valid = (dd[..., 0] > 0) & (abs(d - rd)[..., 0] < tol * (1 + rd[..., 0])) & (theta[..., 0] < math.pi - 1e-6)
    return _unit(v), valid


# --------------------------------------------------------------------------------------------
# Unified camera model (Mei / omni, no distortion)
# --------------------------------------------------------------------------------------------
def _ucm_bound(xi: Array) -> Array:
    """w of the UCM's projection domain: 1 / xi for xi > 1, xi otherwise (never dividing by 0)."""
    xp = ops(xi).xp
    big = xi > 1
    return xp.where(big, 1.0 / xp.where(big, xi, xp.ones_like(xi)), xi)


def project_ucm(p: Array, params: Array) -> tuple[Array, Array]:
    """UCM projection. p: (..., 3), params (xi, fx, fy, cx, cy): (..., 5) -> q, valid."""
    xp = ops(p, params).xp
    xi, fx, fy, cx, cy = _split(params, 5)
    x, y, z = p[..., :1], p[..., 1:2], p[..., 2:3]
    d = _safe_sqrt(x * x + y * y + z * z)
    den = z + xi * d
    w = _ucm_bound(xi)
    valid = (z > -w * d) & (den > _EPS) & (d > _EPS)
    den = xp.where(valid, den, xp.ones_like(den))
    return _pixels(x / den, y / den, fx, fy, cx, cy), valid[..., 0]


def unproject_ucm(q: Array, params: Array) -> tuple[Array, Array]:
    """UCM unprojection. q: (..., 2), params: (..., 5) -> v (..., 3), valid (...)."""
    o = ops(q, params)
    xi, fx, fy, cx, cy = _split(params, 5)
    mx, my = _normalised(q, fx, fy, cx, cy)
    r2 = mx * mx + my * my
    disc = 1 + (1 - xi * xi) * r2
    valid = disc >= 0
    factor = (xi + _safe_sqrt(o.clamp_min(disc, 0))) / (1 + r2)
    v = o.cat([factor * mx, factor * my, factor - xi], -1)
    # Beyond the valid domain of xi > 1 the second intersection is the wrong one.
    w = _ucm_bound(xi)
    vu = _unit(v)
    valid = valid & (vu[..., 2:3] > -w)
    return vu, valid[..., 0]


# --------------------------------------------------------------------------------------------
# Enhanced unified camera model
# --------------------------------------------------------------------------------------------
def project_eucm(p: Array, params: Array) -> tuple[Array, Array]:
    """EUCM projection. p: (..., 3), params (alpha, beta, fx, fy, cx, cy): (..., 6) -> q, valid."""
    xp = ops(p, params).xp
    alpha, beta, fx, fy, cx, cy = _split(params, 6)
    x, y, z = p[..., :1], p[..., 1:2], p[..., 2:3]
    rho = _safe_sqrt(beta * (x * x + y * y) + z * z)
    den = alpha * rho + (1 - alpha) * z
    w = _ratio(alpha)
    valid = (z > -w * rho) & (den > _EPS)
    den = xp.where(valid, den, xp.ones_like(den))
    return _pixels(x / den, y / den, fx, fy, cx, cy), valid[..., 0]


def unproject_eucm(q: Array, params: Array) -> tuple[Array, Array]:
    """EUCM unprojection. q: (..., 2), params: (..., 6) -> v (..., 3), valid (...)."""
    o = ops(q, params)
    alpha, beta, fx, fy, cx, cy = _split(params, 6)
    mx, my = _normalised(q, fx, fy, cx, cy)
    r2 = mx * mx + my * my
    disc = 1 - (2 * alpha - 1) * beta * r2
    valid = disc >= 0
    mz = (1 - alpha * alpha * beta * r2) / (alpha * _safe_sqrt(o.clamp_min(disc, 0)) + (1 - alpha))
    v = _unit(o.cat([mx, my, mz], -1))
    # Keep only the branch that projects back (the ray must lie in the projection domain).
    w = _ratio(alpha)
    rho = _safe_sqrt(beta * (v[..., :1] ** 2 + v[..., 1:2] ** 2) + v[..., 2:3] ** 2)
    valid = valid & (v[..., 2:3] > -w * rho)
    return v, valid[..., 0]


# --------------------------------------------------------------------------------------------
# Double sphere
# --------------------------------------------------------------------------------------------
def project_ds(p: Array, params: Array) -> tuple[Array, Array]:
    """Double-sphere projection. p: (..., 3), params (xi, alpha, fx, fy, cx, cy) -> q, valid."""
    xp = ops(p, params).xp
    xi, alpha, fx, fy, cx, cy = _split(params, 6)
    x, y, z = p[..., :1], p[..., 1:2], p[..., 2:3]
    r2 = x * x + y * y
    d1 = _safe_sqrt(r2 + z * z)
    zeta = xi * d1 + z
    d2 = _safe_sqrt(r2 + zeta * zeta)
    den = alpha * d2 + (1 - alpha) * zeta
    w1 = _ratio(alpha)
    w2 = (w1 + xi) / xp.sqrt(2 * w1 * xi + xi * xi + 1)
    valid = (z > -w2 * d1) & (den > _EPS)
    den = xp.where(valid, den, xp.ones_like(den))
    return _pixels(x / den, y / den, fx, fy, cx, cy), valid[..., 0]


def unproject_ds(q: Array, params: Array) -> tuple[Array, Array]:
    """Double-sphere unprojection. q: (..., 2), params: (..., 6) -> v (..., 3), valid (...)."""
    o = ops(q, params)
    xi, alpha, fx, fy, cx, cy = _split(params, 6)
    mx, my = _normalised(q, fx, fy, cx, cy)
    r2 = mx * mx + my * my
    disc1 = 1 - (2 * alpha - 1) * r2
    mz = (1 - alpha * alpha * r2) / (alpha * _safe_sqrt(o.clamp_min(disc1, 0)) + 1 - alpha)
    disc2 = mz * mz + (1 - xi * xi) * r2
    k = (mz * xi + _safe_sqrt(o.clamp_min(disc2, 0))) / (mz * mz + r2)
    v = _unit(o.cat([k * mx, k * my, k * mz - xi], -1))
    w1 = _ratio(alpha)
    w2 = (w1 + xi) / o.xp.sqrt(2 * w1 * xi + xi * xi + 1)
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
    project: Callable[[Array, Array], tuple[Array, Array]]
    unproject: Callable[[Array, Array], tuple[Array, Array]]
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

    def clamp(self, params: Array) -> Array:
        """(..., n_params) parameters (numpy or torch) clamped into :attr:`bounds` (a copy)."""
        o = ops(params)
        out = o.copy(params)
        for name, (lo, hi) in self.bounds.items():
            i = self.index(name)
            out[..., i] = o.clamp(out[..., i], lo, hi)
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


def project(model: str, p: Array, params: Array) -> tuple[Array, Array]:
    """Project ``p`` (..., 3) with camera family ``model``; see the module docstring."""
    return get_model(model).project(p, params)


def unproject(model: str, q: Array, params: Array) -> tuple[Array, Array]:
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
    dtype: Any = None,
    **shape: float,
) -> Array:
    """Build the parameter vector of "a ``fov_deg`` camera of family ``model``, ``width`` x ``height``".

    The focal length is chosen so that a ray ``fov_deg / 2`` off-axis lands ``radius`` pixels from
    the principal point (the image-circle radius; default ``min(width, height) / 2``, a circle
    touching the shorter image side). ``principal`` defaults to the image centre
    ``((width - 1) / 2, (height - 1) / 2)``. Shape parameters (k1..k4, xi, alpha, beta) default to
    :data:`DEFAULT_SHAPE`. Returns ``(P,)`` params in Kalibr order: a torch tensor of ``dtype``
    (default, ``None``: torch.float64), or a numpy array where ``dtype`` is a numpy dtype
    (``np.float64``: the calibrator's, without torch).

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
    unit = np.array(assemble_params(model, 1.0, 1.0, 0.0, 0.0, full_shape), dtype=np.float64)
    ray = np.array([math.sin(half), 0.0, math.cos(half)], dtype=np.float64)
    q, valid = m.project(ray, unit)
    if not bool(valid) or float(q[0]) <= 0:
        raise ValueError(f"{model} with {full_shape} cannot see {fov_deg} degrees; change its shape parameters")
    f = radius / float(q[0])
    params = assemble_params(model, f, f, principal[0], principal[1], full_shape)
    if dtype is not None and type(dtype).__module__.split(".")[0] != "torch":
        return np.array(params, dtype=dtype)
    import torch

    return torch.tensor(params, dtype=torch.float64 if dtype is None else dtype)


def off_axis_angle(v: Array) -> Array:
    """Angle (rad) between ray(s) ``v`` (..., 3) (numpy or torch) and the optical axis, from the
    3-D ray. -> (...)."""
    o = ops(v)
    return o.atan2(o.norm(v[..., :2], -1), v[..., 2])
