"""A sample's appearance as one table of random numbers, and the batch's background and
occluders painted from the tables.

:func:`draw_appearance` takes every appearance number of one sample from its stream, in one fixed
order (numpy, no tensor operation); the painters stack a batch's tables into arrays and paint the
whole batch at once, a few kernels per shape, whatever the batch size.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from cotrain.render.config import RenderConfig
from cotrain.render.draws import SampleDraws, to_device

GLARE_STREAM = 104_729  # offset of a sample's glare stream's seed from its own


@dataclass
class Appearance:
    """One sample's appearance numbers (see :class:`RenderConfig` for their ranges)."""

    no_target: bool  # an image without the target
    black: float  # reflectance of the printed black
    white: float  # ... and white
    light: tuple[float, float]  # the light's gradient over the sheet, x and y
    background: dict[str, np.ndarray]  # float32 draws of the procedural background (see paint_background)
    distractors: list[tuple[float, ...]]  # (cx, cy in [0, 1), angle rad, square, nx, ny) of checker-like distractors
    occluders: list[tuple[float, ...]]  # (cx, cy, ax, ay, angle, value) ellipses in front of everything
    vignette: float  # darkening at the image circle's rim
    exposure: float  # gain before clipping (over 1 clips the whites)
    gamma: float  # applied after the exposure
    blur_sigma: float  # defocus sigma, px (0: none)
    motion: tuple[int, float, float] | None  # motion blur (kernel length px, angle deg, direction) or none
    noise: float  # read-noise sigma
    noise_uniforms: np.ndarray | None  # (M, 16) float32 uniforms of the noise field (draws.box_muller); None once stacked for the batch
    jpeg_quality: int  # 0: no JPEG round trip
    glare: tuple[float, float, float, float] = field(default=(0.0, 0.0, 0.0, 1.0))  # (peak, x, y, size) of the spot on the sheet


def _background_draws(cfg: RenderConfig, d: SampleDraws, h: int, w: int) -> tuple[dict[str, np.ndarray], list[tuple[float, ...]]]:
    K, r = cfg.n_shapes, d.uniform32
    bg = {"base": r(1), "gx": r(1), "gy": r(1), "clouds": r(1, 6, 10), "clouds_amp": r(1)}
    bg |= {"fine": r(1, h // 4 + 1, w // 4 + 1), "fine_amp": r(1), "c": r(K, 2), "ang": r(K)}
    bg |= {"line": r(K, 1), "line_len": r(K, 1), "line_width": r(K, 1), "rect": r(K, 2), "val": r(K)}
    distractors = []
    if float(r(1)[0]) < cfg.p_distractor:
        for _ in range(int(r(1)[0] * 3) + 1):  # float32 products, as the tensors' were
            c, a, sq, nx, ny = r(2), *(float(x) for x in r(4))
            distractors.append(
                (float(c[0]), float(c[1]), a * math.pi, sq * 0.08 + 0.03, int(np.float32(nx) * 3) + 2, int(np.float32(ny) * 2) + 2)
            )
    return bg, distractors


def _occluder_draws(cfg: RenderConfig, d: SampleDraws) -> list[tuple[float, ...]]:
    if d.uniform() >= cfg.p_occluder:
        return []
    out = []
    for _ in range(1 + int(d.uniform() * 3)):
        cx, cy = d.uniform(-1, 1), d.uniform(-1, 1)
        ax, ay = d.uniform(0.05, 0.35), d.uniform(0.05, 0.35) * cfg.width / cfg.height
        out.append((cx, cy, ax, ay, d.uniform(0, math.pi), d.uniform(0.0, 1.0)))
    return out


def _optics_draws(cfg: RenderConfig, d: SampleDraws) -> tuple[float, tuple[int, float, float] | None]:
    sigma = d.uniform(0.3, cfg.max_blur_sigma) if d.uniform() < cfg.p_blur else 0.0
    motion = None
    if d.uniform() < cfg.p_motion:
        lo, hi = cfg.motion_kernel
        k = lo if lo == hi else lo + 2 * int(d.uniform() * ((hi - lo) // 2 + 1))  # odd lengths lo .. hi
        motion = (min(k, hi), d.uniform(0, 180), d.uniform(*cfg.motion_direction))
    return sigma, motion


def _glare_draws(cfg: RenderConfig, d: SampleDraws) -> tuple[float, float, float, float]:
    """The spot, from a stream of its own: a sample renders as it does without glare but for it."""
    g = SampleDraws((d.initial_seed() + GLARE_STREAM) % (2**63 - 1))
    spot = (g.uniform(), g.uniform(*cfg.glare_strength), g.uniform(-0.5, 0.5), g.uniform(-0.5, 0.5), g.uniform(*cfg.glare_size))
    return spot[1:] if spot[0] < cfg.p_glare else (0.0, 0.0, 0.0, 1.0)


def draw_appearance(cfg: RenderConfig, d: SampleDraws) -> Appearance:
    """Every appearance number of one sample, in the order the renderer has always drawn them."""
    ss = cfg.supersample
    no_target = d.uniform() < cfg.p_no_target
    black, white = d.uniform(*cfg.black_range), d.uniform(*cfg.white_range)
    light = (d.uniform(-0.5, 0.5), d.uniform(-0.5, 0.5))
    background, distractors = _background_draws(cfg, d, cfg.height * ss, cfg.width * ss)
    occluders = _occluder_draws(cfg, d)
    vignette = d.uniform(*cfg.vignette_range)
    exposure, gamma = d.uniform(*cfg.exposure_range), d.uniform(*cfg.gamma_range)
    sigma, motion = _optics_draws(cfg, d)
    noise = d.uniform(*cfg.noise_range)
    noise_uniforms = d.normal_uniforms(cfg.height * cfg.width)
    quality = int(d.uniform(35, 95)) if d.uniform() < cfg.p_jpeg else 0
    glare = _glare_draws(cfg, d) if cfg.p_glare > 0 else (0.0, 0.0, 0.0, 1.0)
    return Appearance(
        no_target,
        black,
        white,
        light,
        background,
        distractors,
        occluders,
        vignette,
        exposure,
        gamma,
        sigma,
        motion,
        noise,
        noise_uniforms,
        quality,
        glare,
    )


def column(tables: list[Appearance], name: str, device: torch.device) -> Tensor:
    """(B, 1, 1) float32 of one scalar field of every table, on ``device`` (float32: as the
    renderer's per-sample scalars have always been rounded)."""
    return scalars([getattr(t, name) for t in tables], device)


@functools.lru_cache(maxsize=8)
def coords(h: int, w: int, device: torch.device) -> tuple[Tensor, Tensor]:
    """(h, w) x and y from -1 to 1 across the image on ``device``; cached, never modified in place."""
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, h, device=device), torch.linspace(-1, 1, w, device=device), indexing="ij")
    return xx, yy


def scalars(values, device: torch.device) -> Tensor:
    """(G, 1, 1) float32 from Python numbers, each rounded as a Python scalar in a float32 op is."""
    return to_device(np.asarray(values, np.float64), device, torch.float32)[:, None, None]


def _paint_distractors(img: Tensor, tables: list[Appearance], xx: Tensor, yy: Tensor) -> Tensor:
    """Checker-like distractors that are not the target (2x2 .. 4x3 squares): the j-th of every
    sample that has one, together."""
    h, w = img.shape[-2:]
    for j in range(max((len(t.distractors) for t in tables), default=0)):
        idx = [b for b, t in enumerate(tables) if len(t.distractors) > j]
        at = to_device(np.array(idx), img.device)
        cx, cy, a0, sq, nx, ny = zip(*(tables[b].distractors[j] for b in idx))
        cos, sin, sq, nx, ny = (scalars(v, img.device) for v in ([math.cos(a) for a in a0], [math.sin(a) for a in a0], sq, nx, ny))
        cx, cy = scalars(cx, img.device) * 1.6 - 0.8, scalars(cy, img.device) * 1.6 - 0.8
        dx, dy = xx - cx, (yy - cy) * (h / w)
        u = (cos * dx + sin * dy) / sq + nx / 2
        v = (-sin * dx + cos * dy) / sq + ny / 2
        inside = (u > 0) & (u < nx) & (v > 0) & (v < ny)
        pattern = ((torch.floor(u) + torch.floor(v)) % 2 == 0).float() * 0.8 + 0.1
        img[at] = torch.where(inside, pattern, img[at])
    return img


def paint_background(cfg: RenderConfig, tables: list[Appearance], h: int, w: int, device: torch.device) -> Tensor:
    """(B, h, w) procedural backgrounds: gradients, clouds, rectangles, lines, distractors."""
    xx, yy = coords(h, w, device)

    def stacked(key: str) -> Tensor:
        return to_device(np.stack([t.background[key] for t in tables]), device)

    def per_sample(key: str) -> Tensor:  # (B, 1, 1) from (1,) draws
        return stacked(key)[:, :, None]

    img = per_sample("base") * 0.7 + 0.1
    img = img + (per_sample("gx") - 0.5) * 0.6 * xx + (per_sample("gy") - 0.5) * 0.6 * yy
    clouds = F.interpolate(stacked("clouds") - 0.5, size=(h, w), mode="bicubic", align_corners=False)[:, 0]
    img = img + clouds * 0.5 * per_sample("clouds_amp")
    fine = F.interpolate(stacked("fine") - 0.5, size=(h, w), mode="bilinear", align_corners=False)[:, 0]
    img = img + fine * 0.15 * per_sample("fine_amp")
    # Rectangles and lines (thin rectangles), rotated; painted one after the other.
    c = stacked("c") * 2.4 - 1.2  # (B, K, 2)
    ang = stacked("ang") * math.pi
    line = torch.cat([stacked("line_len") * 0.8 + 0.1, stacked("line_width") * 0.01 + 0.004], 2)
    half = torch.where(stacked("line") < 0.35, line, stacked("rect") * 0.4 + 0.03)  # (B, K, 2)
    val = stacked("val")
    ca, sa = torch.cos(ang)[:, :, None, None], torch.sin(ang)[:, :, None, None]
    for k in range(cfg.n_shapes):
        dx = xx[None] - c[:, k, 0, None, None]
        dy = (yy[None] - c[:, k, 1, None, None]) * (h / w)
        u = ca[:, k] * dx + sa[:, k] * dy
        v = -sa[:, k] * dx + ca[:, k] * dy
        inside = (u.abs() < half[:, k, 0, None, None]) & (v.abs() < half[:, k, 1, None, None])
        img = torch.where(inside, val[:, k, None, None], img)
    return _paint_distractors(img, tables, xx, yy).clamp(0, 1).float()


def paint_occluders(img: Tensor, tables: list[Appearance]) -> tuple[Tensor, Tensor]:
    """Ellipses in front of everything, the j-th of every sample together: (B, h, w) the image
    with them and their coverage."""
    occ = torch.zeros_like(img)
    xx, yy = coords(*img.shape[-2:], img.device)
    for j in range(max((len(t.occluders) for t in tables), default=0)):
        idx = [b for b, t in enumerate(tables) if len(t.occluders) > j]
        at = to_device(np.array(idx), img.device)
        cx, cy, ax, ay, a, val = zip(*(tables[b].occluders[j] for b in idx))
        cx, cy, ax, ay, val = (scalars(v, img.device) for v in (cx, cy, ax, ay, val))
        cos, sin = scalars([math.cos(t) for t in a], img.device), scalars([math.sin(t) for t in a], img.device)
        dx, dy = xx - cx, yy - cy
        uu = (cos * dx + sin * dy) / ax
        vv = (-sin * dx + cos * dy) / ay
        m = ((uu * uu + vv * vv) < 1).float()
        img[at] = img[at] * (1 - m) + val * m
        occ[at] = torch.maximum(occ[at], m)
    return img, occ
