"""Online, physically grounded renderer of fisheye calibration images with exact labels.

Per sample: a random fisheye camera (kb4 / ucm / eucm / ds, FoV ~150-250 deg, image circle
inside or cropped by the frame, principal-point offset, random shape parameters) and a random
board pose covering the whole field of view (rays beyond 90 degrees, strong tilt, near and far,
partial views). The image is rendered by inverse mapping: every output pixel is unprojected to a
ray, intersected with the board plane and the board's appearance is area-filtered over the
pixel's footprint (so edges are anti-aliased and corners sit exactly on their saddle points),
then composited over a procedural background with lighting, vignetting, blur, noise, JPEG and
occluders. Outside the image circle the frame is black.

Sample ``i`` depends only on ``(seed, i)``: parameters are drawn per sample from a generator
seeded by both, and the pixel work is batched tensor code (no per-pixel Python loops).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import cv2
import kornia
import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from cotrain.geometry import cameras, poses
from cotrain.targets import Target, TargetConfig, make_target, sees_print, square_px


@dataclass
class RenderConfig:
    height: int = 216  # output image height, pixels
    width: int = 384  # output image width, pixels
    models: list[str] = field(default_factory=lambda: list(cameras.MODELS))  # camera families drawn
    model_weights: list[float] = field(default_factory=lambda: [0.4, 0.2, 0.2, 0.2])  # their probabilities
    fov_range: tuple[float, float] = (150.0, 250.0)  # FoV (deg) drawn uniformly
    radius_range: tuple[float, float] = (0.8, 1.9)  # image-circle radius / (min(h, w) / 2); >1 is cropped
    principal_jitter: float = 0.04  # principal-point offset, fraction of min(h, w)
    aspect_jitter: float = 0.02  # fy / fx - 1 drawn in +-this
    kb4_k_scale: float = 1.0  # scale of the random k1..k4 of kb4 cameras (0 = the paper's f-theta model)
    p_no_target: float = 0.03  # probability of an image without the target (negatives)
    distance_range: tuple[float, float] = (0.12, 0.9)  # board-centre distance, metres
    max_tilt_deg: float = 70.0  # board tilt away from facing the camera
    offaxis_margin_deg: float = 12.0  # board centres drawn up to FoV/2 + this (partial views)
    offaxis_min_deg: float = 0.0  # ... and at least this far off-axis (a row of boards at the rim)
    supersample: int = 1  # extra supersampling on top of the analytic area filter
    p_blur: float = 0.5  # probability of defocus blur
    max_blur_sigma: float = 1.2  # defocus sigma (pixels) upper bound
    p_motion: float = 0.15  # probability of motion blur
    motion_kernel: tuple[int, int] = (5, 5)  # motion-blur length (pixels, odd) drawn in this range
    motion_direction: tuple[float, float] = (-1.0, 1.0)  # kornia's weighting along the blur (0: even, the label at mid-exposure)
    exposure_range: tuple[float, float] = (0.6, 1.4)  # exposure gain (over 1 clips the whites)
    gamma_range: tuple[float, float] = (0.7, 1.4)  # gamma after the exposure
    black_range: tuple[float, float] = (0.02, 0.2)  # reflectance of the printed black
    white_range: tuple[float, float] = (0.6, 1.0)  # reflectance of the printed white (grey on a dull print)
    vignette_range: tuple[float, float] = (0.0, 0.6)  # darkening at the image circle's rim (share of the centre)
    p_glare: float = 0.0  # probability of a specular highlight on the print (0: no draws, renders as before)
    glare_strength: tuple[float, float] = (0.4, 1.5)  # its peak, added reflectance (the print's white is white_range)
    glare_size: tuple[float, float] = (0.08, 0.3)  # its Gaussian sigma, share of the board's extent along each axis
    noise_range: tuple[float, float] = (0.0, 0.04)  # Gaussian read-noise sigma (intensity units)
    p_jpeg: float = 0.3  # probability of JPEG compression
    p_occluder: float = 0.3  # probability of 1-3 occluders in front of the board
    p_distractor: float = 0.5  # probability of checker-like distractors in the background
    n_shapes: int = 8  # rectangles and lines in the background
    min_square_px: float = 3.0  # learnability is 0 below this projected square size (pixels)
    good_square_px: float = 7.0  # learnability is 1 (size term) above this
    border_px: float = 2.0  # corners closer than this to the frame or circle edge are not visible
    target: TargetConfig = field(default_factory=TargetConfig)  # the calibration target


@dataclass
class Scene:
    """Per-sample parameters of a batch (B samples)."""

    model: list[str]  # camera family per sample
    params: list[Tensor]  # camera parameters per sample, (P,) float64
    fov: Tensor  # (B,) degrees
    radius: Tensor  # (B,) image-circle radius, pixels
    T_cam_board: Tensor  # (B, 4, 4)

    def principal_points(self) -> Tensor:
        """(B, 2) float32 principal points (cx, cy) of the cameras."""
        pp = [
            torch.stack([p[cameras.get_model(m).index("cx")], p[cameras.get_model(m).index("cy")]]) for m, p in zip(self.model, self.params)
        ]
        return torch.stack(pp).float()

    def to(self, device: torch.device) -> Scene:
        """The same scene with its tensors on ``device``."""
        return Scene(
            self.model, [p.to(device) for p in self.params], self.fov.to(device), self.radius.to(device), self.T_cam_board.to(device)
        )


CPU = torch.device("cpu")
GLARE_STREAM = 104_729  # offset of a sample's glare generator's seed from its own (see render_scene)


def sample_generator(seed: int, index: int) -> torch.Generator:
    """The generator of sample ``index`` under ``seed`` (independent of batch composition)."""
    g = torch.Generator()
    g.manual_seed((seed * 1_000_003 + index * 7_919 + 12_345) % (2**63 - 1))
    return g


def _u(g: torch.Generator, lo: float = 0.0, hi: float = 1.0) -> float:
    return lo + (hi - lo) * float(torch.rand((), generator=g, dtype=torch.float64))


def _sample_camera(cfg: RenderConfig, g: torch.Generator) -> tuple[str, Tensor, float, float]:
    w = torch.tensor(cfg.model_weights, dtype=torch.float64)
    model = cfg.models[int(torch.multinomial(w / w.sum(), 1, generator=g))]
    fov = _u(g, *cfg.fov_range)
    base = min(cfg.height, cfg.width) / 2.0
    radius = base * _u(g, *cfg.radius_range)
    jit = cfg.principal_jitter * min(cfg.height, cfg.width)
    principal = ((cfg.width - 1) / 2 + _u(g, -jit, jit), (cfg.height - 1) / 2 + _u(g, -jit, jit))
    params = None
    for _ in range(8):
        m = cameras.get_model(model)
        scale = {n: cfg.kb4_k_scale for n in m.distortion_names} if model == "kb4" else {}
        shape = m.sample_shape(lambda lo, hi: _u(g, lo, hi), scale)
        try:
            params = cameras.make_camera(model, fov, cfg.width, cfg.height, radius, principal, **shape)
        except ValueError:
            continue
        # The whole circle must also unproject (monotonic projection up to the FoV).
        m = cameras.get_model(model)
        half = math.radians(fov) / 2
        th = torch.linspace(0.0, half, 32, dtype=torch.float64)
        rays = torch.stack([torch.sin(th), torch.zeros_like(th), torch.cos(th)], -1)
        q, ok = m.project(rays, params)
        if bool(ok.all()) and bool((q[1:, 0] - q[:-1, 0] > 0).all()):
            break
        params = None
    if params is None:
        params = cameras.make_camera(model, fov, cfg.width, cfg.height, radius, principal)
    params = params.clone()
    params[cameras.get_model(model).index("fy")] *= 1 + _u(g, -cfg.aspect_jitter, cfg.aspect_jitter)
    return model, params, fov, radius


def _sample_pose(cfg: RenderConfig, board: Target, fov: float, g: torch.Generator) -> Tensor:
    """T_cam_board: board centre along a random ray (up to FoV/2 + margin off-axis), tilted."""
    half = min(math.radians(fov / 2 + cfg.offaxis_margin_deg), math.radians(150))
    if cfg.offaxis_min_deg > 0:
        lo = min(math.radians(cfg.offaxis_min_deg), half)
        theta = math.sqrt(lo * lo + _u(g) * (half * half - lo * lo))  # uniform over the ring's area
    else:
        theta = half * math.sqrt(_u(g))  # denser towards the edge, where real detectors fail
    phi = _u(g, 0, 2 * math.pi)
    d = math.exp(_u(g, math.log(cfg.distance_range[0]), math.log(cfg.distance_range[1])))
    ray = torch.tensor([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)], dtype=torch.float64)
    centre = d * ray
    # Board facing the camera: its z axis (into the board) along the viewing ray, or against it
    # for a target whose print faces +z.
    up = torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)
    if abs(float(ray @ up)) > 0.95:
        up = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    R_face = poses.look_at(torch.zeros(3, dtype=torch.float64), ray, up)[:3, :3]  # columns x, y, z
    if board.front > 0:  # the print faces +z: turn the board half a turn about its x axis to face the camera
        R_face = R_face @ torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))
    tilt = math.radians(cfg.max_tilt_deg) * _u(g) ** 0.7
    tilt_axis_angle = _u(g, 0, 2 * math.pi)
    w_tilt = torch.tensor([math.cos(tilt_axis_angle), math.sin(tilt_axis_angle), 0.0], dtype=torch.float64) * tilt
    w_roll = torch.tensor([0.0, 0.0, _u(g, -math.pi, math.pi)], dtype=torch.float64)
    R_cam_board = R_face @ poses.rotation_from_axis_angle(w_tilt) @ poses.rotation_from_axis_angle(w_roll)
    x0, y0, x1, y1 = board.extent()
    c_board = torch.tensor([(x0 + x1) / 2, (y0 + y1) / 2, 0.0], dtype=torch.float64)
    # Jitter the centre so the board's centre is not always on the sampled ray.
    c_board[:2] += torch.tensor([_u(g, -0.3, 0.3) * (x1 - x0), _u(g, -0.3, 0.3) * (y1 - y0)], dtype=torch.float64)
    t = centre - R_cam_board @ c_board
    return poses.make_pose(R_cam_board, t)


def sample_scene(cfg: RenderConfig, board: Target, gens: list[torch.Generator]) -> Scene:
    models, params, fovs, radii, Ts = [], [], [], [], []
    for g in gens:
        model, p, fov, radius = _sample_camera(cfg, g)
        models.append(model)
        params.append(p)
        fovs.append(fov)
        radii.append(radius)
        Ts.append(_sample_pose(cfg, board, fov, g))
    return Scene(models, params, torch.tensor(fovs), torch.tensor(radii), torch.stack(Ts))


# --------------------------------------------------------------------------------------------
# Geometry of the batch: rays, board intersection, labels
# --------------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=8)
def _pixel_grid(h: int, w: int, ss: int, device: torch.device = CPU) -> Tensor:
    """(h*ss, w*ss, 2) sample positions in output-pixel coordinates (centre convention) on
    ``device``; cached, never modified in place."""
    off = (torch.arange(ss, dtype=torch.float32) + 0.5) / ss - 0.5
    xs = (torch.arange(w, dtype=torch.float32)[:, None] + off[None]).reshape(-1)
    ys = (torch.arange(h, dtype=torch.float32)[:, None] + off[None]).reshape(-1)
    yy, xx = torch.meshgrid(ys, xs, indexing="ij")
    return torch.stack([xx, yy], dim=-1).to(device)


def _rays(scene: Scene, grid: Tensor) -> tuple[Tensor, Tensor]:
    """Unit rays (B, H, W, 3) and the in-circle mask (B, H, W) for every sample position (grid
    (H, W, 2)). The samples of one camera family are unprojected together (their parameters
    broadcast over the grid), so a batch costs a few kernels per family, not per sample."""
    B, (H, W) = len(scene.model), grid.shape[:2]
    v_all = grid.new_empty(B, H, W, 3)
    ok_all = torch.empty(B, H, W, dtype=torch.bool, device=grid.device)
    for model in dict.fromkeys(scene.model):  # each family once, in order of appearance
        idx = [b for b, m in enumerate(scene.model) if m == model]
        p = torch.stack([scene.params[b].float() for b in idx])[:, None, None, :]  # (G, 1, 1, P)
        v, ok = cameras.unproject(model, grid[None], p)
        # The half FoV per sample, rounded to float32 as a Python scalar would be.
        half = torch.tensor([math.radians(float(scene.fov[b])) / 2 for b in idx], dtype=v.dtype, device=v.device)
        v_all[idx] = v
        ok_all[idx] = ok & (cameras.off_axis_angle(v) <= half[:, None, None])
    return v_all, ok_all


def _board_hit(v: Tensor, T_cam_board: Tensor, front: int = -1) -> tuple[Tensor, Tensor]:
    """Board-plane coordinates (B, H, W, 2) hit by rays v (B, H, W, 3), and hit mask (in front,
    printed side toward the camera; ``front``: :attr:`Target.front`)."""
    R = T_cam_board[:, :3, :3].float()
    t = T_cam_board[:, :3, 3].float()
    n = R[:, :, 2]  # board z axis in the camera frame
    num = (n * t).sum(-1)  # n . t
    den = torch.einsum("bhwc,bc->bhw", v, n)
    lam = num[:, None, None] / torch.where(den.abs() > 1e-8, den, torch.full_like(den, 1e-8))
    hit = (lam > 0) & sees_print(front, n, t)[:, None, None]  # in front, and the printed side faces the camera
    p_cam = lam[..., None] * v - t[:, None, None, :]
    xy = torch.einsum("bhwc,bcd->bhwd", p_cam, R)[..., :2]  # R^T (p - t)
    return xy, hit


def corner_labels(cfg: RenderConfig, board: Target, scene: Scene) -> dict[str, Tensor]:
    """Exact labels of every corner slot (see :func:`render_batch` for the keys)."""
    P = board.points(torch.float64)  # (N, 3)
    N = P.shape[0]
    qs, valid, l_size, cos_inc = [], [], [], []
    for b, (model, p) in enumerate(zip(scene.model, scene.params)):
        T = scene.T_cam_board[b]
        pc = poses.transform_points(T, P)
        q, ok = cameras.project(model, pc, p)
        ok = ok & (cameras.off_axis_angle(pc) <= math.radians(float(scene.fov[b])) / 2)
        size = square_px(model, p, T, board)  # local pixels per square
        n = T[:3, 2]
        ray = pc / pc.norm(dim=-1, keepdim=True)
        cos_inc.append((-board.front * (ray @ n)).clamp(0, 1))
        # Printed side towards the camera.
        ok = ok & bool(sees_print(board.front, n, T[:3, 3]))
        qs.append(q)
        valid.append(ok)
        l_size.append(size)
    q = torch.stack(qs).float()
    ok = torch.stack(valid)
    size = torch.stack(l_size).float()
    cos_inc = torch.stack(cos_inc).float()
    bp = cfg.border_px
    in_image = (q[..., 0] > bp - 0.5) & (q[..., 0] < cfg.width - 0.5 - bp) & (q[..., 1] > bp - 0.5) & (q[..., 1] < cfg.height - 0.5 - bp)
    centres = scene.principal_points()
    r_px = (q - centres[:, None, :]).norm(dim=-1)
    in_circle = r_px < scene.radius[:, None].float() - bp
    vis = ok & in_image & in_circle & (size > 0)
    learn_size = ((size - cfg.min_square_px) / (cfg.good_square_px - cfg.min_square_px)).clamp(0, 1)
    learn_inc = ((cos_inc - 0.08) / 0.25).clamp(0, 1)
    return {
        "corners": torch.where(vis[..., None], q, torch.zeros_like(q)),
        "corners_raw": q,
        "visible": vis,
        "square_px": size,
        "learn_geom": learn_size * learn_inc,
        "n": torch.tensor(N),
    }


# --------------------------------------------------------------------------------------------
# Appearance
# --------------------------------------------------------------------------------------------
def _coords(h: int, w: int, device: torch.device = CPU) -> tuple[Tensor, Tensor]:
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, h, device=device), torch.linspace(-1, 1, w, device=device), indexing="ij")
    return xx, yy


def _background(cfg: RenderConfig, gens: list[torch.Generator], h: int, w: int, device: torch.device = CPU) -> Tensor:
    """Procedural backgrounds (B, 1, h, w) on ``device``: gradients, clouds, rectangles, lines,
    distractors. Each sample's random numbers are drawn from its CPU generator in ``gens`` first
    (so every device renders the same), then the pixels are painted for the whole batch at once
    (a few kernels per shape, not per sample: on a GPU the per-sample ops were launch-bound)."""
    xx, yy = _coords(h, w, device)
    K = cfg.n_shapes

    def draw(g: torch.Generator) -> dict:  # every random number of one sample, in drawing order
        r = lambda *shape: torch.rand(*shape, generator=g)  # noqa: E731
        d = {"base": r(1), "gx": r(1), "gy": r(1), "clouds": r(1, 1, 6, 10), "clouds_amp": r(1)}
        d |= {"fine": r(1, 1, h // 4 + 1, w // 4 + 1), "fine_amp": r(1), "c": r(K, 2), "ang": r(K)}
        d |= {"line": r(K, 1), "line_len": r(K, 1), "line_width": r(K, 1), "rect": r(K, 2), "val": r(K)}
        d["distractors"] = []
        if float(r(1)) < cfg.p_distractor:
            for _ in range(int(r(1) * 3) + 1):
                d["distractors"].append((r(2), r(1), r(1), r(1), r(1)))  # centre, angle, square, nx, ny
        return d

    ds = [draw(g) for g in gens]

    def stacked(key: str) -> Tensor:
        return torch.stack([d[key] for d in ds]).to(device)

    def per_sample(key: str) -> Tensor:  # (B, 1, 1) from (1,) draws
        return stacked(key)[:, :, None]

    img = per_sample("base") * 0.7 + 0.1
    img = img + (per_sample("gx") - 0.5) * 0.6 * xx + (per_sample("gy") - 0.5) * 0.6 * yy
    clouds = F.interpolate(stacked("clouds")[:, 0] - 0.5, size=(h, w), mode="bicubic", align_corners=False)[:, 0]
    img = img + clouds * 0.5 * per_sample("clouds_amp")
    fine = F.interpolate(stacked("fine")[:, 0] - 0.5, size=(h, w), mode="bilinear", align_corners=False)[:, 0]
    img = img + fine * 0.15 * per_sample("fine_amp")
    # Rectangles and lines (thin rectangles), rotated; painted one after the other.
    c = stacked("c") * 2.4 - 1.2  # (B, K, 2)
    ang = stacked("ang") * math.pi
    line = torch.cat([stacked("line_len") * 0.8 + 0.1, stacked("line_width") * 0.01 + 0.004], 2)
    half = torch.where(stacked("line") < 0.35, line, stacked("rect") * 0.4 + 0.03)  # (B, K, 2)
    val = stacked("val")
    ca, sa = torch.cos(ang)[:, :, None, None], torch.sin(ang)[:, :, None, None]
    for k in range(K):
        dx = xx[None] - c[:, k, 0, None, None]
        dy = (yy[None] - c[:, k, 1, None, None]) * (h / w)
        u = ca[:, k] * dx + sa[:, k] * dy
        v = -sa[:, k] * dx + ca[:, k] * dy
        inside = (u.abs() < half[:, k, 0, None, None]) & (v.abs() < half[:, k, 1, None, None])
        img = torch.where(inside, val[:, k, None, None], img)
    # Checker-like distractors that are not the target (2x2 .. 4x3 squares): the j-th of every
    # sample that has one, together.
    for j in range(max((len(d["distractors"]) for d in ds), default=0)):
        idx = [b for b, d in enumerate(ds) if len(d["distractors"]) > j]
        items = [ds[b]["distractors"][j] for b in idx]
        c0 = (torch.stack([it[0] for it in items]) * 1.6 - 0.8).to(device)[:, :, None, None]  # (G, 2, 1, 1)
        a0 = [float(it[1]) * math.pi for it in items]
        sq = _scalars([float(it[2]) * 0.08 + 0.03 for it in items], device)
        nx = _scalars([int(it[3] * 3) + 2 for it in items], device)
        ny = _scalars([int(it[4] * 2) + 2 for it in items], device)
        cos, sin = _scalars([math.cos(a) for a in a0], device), _scalars([math.sin(a) for a in a0], device)
        dx = xx - c0[:, 0]
        dy = (yy - c0[:, 1]) * (h / w)
        u = (cos * dx + sin * dy) / sq + nx / 2
        v = (-sin * dx + cos * dy) / sq + ny / 2
        inside = (u > 0) & (u < nx) & (v > 0) & (v < ny)
        pattern = ((torch.floor(u) + torch.floor(v)) % 2 == 0).float() * 0.8 + 0.1
        img[idx] = torch.where(inside, pattern, img[idx])
    return img[:, None].clamp(0, 1).float()


def _scalars(values: list[float] | tuple[float, ...], device: torch.device) -> Tensor:
    """(G, 1, 1) float32 from Python numbers, each rounded as a Python scalar in a float32 op is."""
    return torch.tensor(values, dtype=torch.float32, device=device)[:, None, None]


# Version of the labels' conventions (rendered sets cached with another one are rendered again,
# the same images): 2 = a corner's label moves with its image where motion blur moves it; 3 = a
# corner a glare spot washes out is not visible.
LABEL_VERSION = 3


def motion_blur_shift(kernel_size: int, angle: float, direction: float) -> torch.Tensor:
    """(2,) px: how far kornia's ``motion_blur(img, kernel_size, angle, direction)`` moves an image's
    content, the exposure-weighted mean position along the blur. A ``direction`` other than 0
    weights one end of the blur more (kornia filters by correlation, so the content moves against
    the kernel's centroid): up to (length + 1) / 6 px (1 px for a 5 px blur)."""
    k = kornia.filters.get_motion_kernel2d(kernel_size, torch.tensor([float(angle)]), torch.tensor([float(direction)]))[0]
    k = k / k.sum()
    c = torch.arange(k.shape[-1], dtype=k.dtype) - (k.shape[-1] - 1) / 2
    return -torch.stack([(k.sum(0) * c).sum(), (k.sum(1) * c).sum()]).float()


def render_batch(
    cfg: RenderConfig, indices: list[int], seed: int = 0, board: Target | None = None, device: str | torch.device = CPU
) -> dict[str, Tensor]:
    """Render samples ``indices`` of the stream ``seed`` on ``device`` (a GPU renders the same
    samples: the random draws come from per-sample CPU generators, the pixels are computed there).

    Returns a dict:
        image: (B, 1, H, W) float32 in [0, 1], grey
        corners: (B, N, 2) pixel positions (0 where not visible)
        corners_raw: (B, N, 2) projected positions whatever their visibility (may be meaningless),
            moved with the image where motion blur moved it (:func:`motion_blur_shift`)
        visible: (B, N) bool, in front / in the domain / in image and circle / facing / unoccluded
        learnability: (B, N) float in [0, 1] (0 where not visible)
        square_px: (B, N) local pixels per square (smallest singular value of the local map)
        board_mask: (B, 1, H, W) float, fraction of the pixel on the checker squares region
        board_uv: (B, 2, H, W) board coordinates in corner-grid units (corner (i, j) at (i, j))
        blur_sigma: (B,) defocus sigma in pixels
        fov: (B,) degrees; model_index: (B,) index into ``cfg.models``
        T_cam_board: (B, 4, 4); params: list of per-sample camera parameter tensors
    """
    board = board or make_target(cfg.target)
    gens = [sample_generator(seed, i) for i in indices]
    return render_scene(cfg, board, sample_scene(cfg, board, gens), gens, device)


def render_scene(
    cfg: RenderConfig, board: Target, scene: Scene, gens: list[torch.Generator], device: str | torch.device = CPU
) -> dict[str, Tensor]:
    """Render given cameras and poses (``scene``) on ``device``; appearance is drawn from ``gens``
    (one per sample). Returns the dict of :func:`render_batch`, every tensor on ``device``."""
    dev = torch.device(device)
    B, H, W, ss = len(gens), cfg.height, cfg.width, cfg.supersample
    labels = {k: v.to(dev) for k, v in corner_labels(cfg, board, scene).items()}  # a few points: computed on the CPU
    no_target = torch.tensor([_u(g) < cfg.p_no_target for g in gens], device=dev)
    scene = scene.to(dev)

    grid = _pixel_grid(H, W, ss, dev)
    v, in_circle = _rays(scene, grid)
    xy, hit = _board_hit(v, scene.T_cam_board, board.front)
    # Footprint of a sample in board metres, from finite differences across neighbouring samples.
    gx = torch.zeros_like(xy)
    gy = torch.zeros_like(xy)
    gx[:, :, 1:-1] = (xy[:, :, 2:] - xy[:, :, :-2]) / 2
    gy[:, 1:-1] = (xy[:, 2:] - xy[:, :-2]) / 2
    gx[:, :, 0], gx[:, :, -1] = gx[:, :, 1], gx[:, :, -2]
    gy[:, 0], gy[:, -1] = gy[:, 1], gy[:, -2]
    foot = (gx.abs() + gy.abs()).nan_to_num(0.0, 1.0, 1.0)
    ok = hit & in_circle
    xy_safe = torch.where(ok[..., None], xy, torch.full_like(xy, -1e3))
    value, cover = board.intensity(xy_safe, foot.clamp(max=1.0))
    cover = cover * ok * (~no_target)[:, None, None]
    # Board region of the checker squares (for the auxiliary mask) and board (u, v) coordinates.
    uv_grid, in_pattern = board.grid_coordinates(xy_safe)
    u, vv = uv_grid[..., 0], uv_grid[..., 1]
    in_sq = ok & in_pattern

    # Per-sample appearance parameters.
    def rr(g: torch.Generator, lo: float = 0.0, hi: float = 1.0) -> float:
        return _u(g, lo, hi)

    black = _scalars([rr(g, *cfg.black_range) for g in gens], dev)
    white = _scalars([rr(g, *cfg.white_range) for g in gens], dev)
    lx = _scalars([rr(g, -0.5, 0.5) for g in gens], dev)
    ly = _scalars([rr(g, -0.5, 0.5) for g in gens], dev)
    ext = board.extent()

    def on_sheet(x: Tensor, y: Tensor) -> tuple[Tensor, Tensor]:  # board metres -> the sheet's extent, -0.5 .. 0.5
        return (x - (ext[0] + ext[2]) / 2) / (ext[2] - ext[0]), (y - (ext[1] + ext[3]) / 2) / (ext[3] - ext[1])

    def shading(x: Tensor, y: Tensor) -> Tensor:  # the light's gradient over the sheet (B, ...)
        return (1 + lx * x + ly * y).clamp(0.3, 1.6)

    bx, by = on_sheet(xy_safe[..., 0], xy_safe[..., 1])
    board_img = (black + (white - black) * value) * shading(bx, by)
    if cfg.p_glare > 0:
        # Glare: light mirrored by a glossy print, the same on black and white, so the print's
        # contrast fades under it and its whites clip; a Gaussian spot fixed on the board. Drawn
        # from a stream of its own, so a sample renders as it does without glare but for the spot.
        spots = []
        for g in gens:
            gg = torch.Generator().manual_seed((g.initial_seed() + GLARE_STREAM) % (2**63 - 1))
            spot = (rr(gg), rr(gg, *cfg.glare_strength), rr(gg, -0.5, 0.5), rr(gg, -0.5, 0.5), rr(gg, *cfg.glare_size))
            spots.append(spot[1:] if spot[0] < cfg.p_glare else (0.0, 0.0, 0.0, 1.0))
        peak, sx, sy, size = (_scalars(x, dev) for x in zip(*spots))

        def glare(x: Tensor, y: Tensor) -> Tensor:  # added light at board-extent coordinates (B, ...)
            return peak * torch.exp(-((x - sx) ** 2 + (y - sy) ** 2) / (2 * size * size))

        board_img = board_img + glare(bx, by)

    bg = _background(cfg, gens, H * ss, W * ss, dev)[:, 0]
    img = bg * (1 - cover) + board_img * cover

    # Occluders: ellipses in front of everything (1-3 in some samples), drawn per sample, painted
    # the j-th of every sample together.
    occ = torch.zeros(B, H * ss, W * ss, device=dev)
    xx, yy = _coords(H * ss, W * ss, dev)
    ellipses: list[list[tuple[float, ...]]] = [[] for _ in gens]  # (cx, cy, ax, ay, angle, value)
    for b, g in enumerate(gens):
        if rr(g) < cfg.p_occluder:
            for _ in range(1 + int(rr(g) * 3)):
                cxo, cyo = rr(g, -1, 1), rr(g, -1, 1)
                ax, ay = rr(g, 0.05, 0.35), rr(g, 0.05, 0.35) * W / H
                ellipses[b].append((cxo, cyo, ax, ay, rr(g, 0, math.pi), rr(g, 0.0, 1.0)))
    for j in range(max(len(e) for e in ellipses)):
        idx = [b for b, e in enumerate(ellipses) if len(e) > j]
        cxo, cyo, ax, ay, a, val = zip(*(ellipses[b][j] for b in idx))
        cos, sin = _scalars([math.cos(t) for t in a], dev), _scalars([math.sin(t) for t in a], dev)
        dx, dy = xx - _scalars(cxo, dev), yy - _scalars(cyo, dev)
        uu = (cos * dx + sin * dy) / _scalars(ax, dev)
        vv2 = (-sin * dx + cos * dy) / _scalars(ay, dev)
        m = ((uu * uu + vv2 * vv2) < 1).float()
        img[idx] = img[idx] * (1 - m) + _scalars(val, dev) * m
        occ[idx] = torch.maximum(occ[idx], m)

    # Image circle: black outside, with a soft, anti-aliased rim and vignetting.
    centres = scene.principal_points()
    r_px = (grid[None] - centres[:, None, None, :]).norm(dim=-1)
    rad = scene.radius[:, None, None].float()
    rim = (rad - r_px + 0.5).clamp(0, 1)
    vig_strength = _scalars([rr(g, *cfg.vignette_range) for g in gens], dev)
    vignette = 1 - vig_strength * (r_px / rad).clamp(0, 1) ** 3
    img = img * vignette * rim

    img = img[:, None]
    if ss > 1:
        img = F.avg_pool2d(img, ss)
        cover_m = F.avg_pool2d((in_sq.float() * cover)[:, None], ss)
        occ = F.avg_pool2d(occ[:, None], ss)[:, 0]
        u = F.avg_pool2d((u * ok)[:, None], ss)[:, 0]
        vv = F.avg_pool2d((vv * ok)[:, None], ss)[:, 0]
    else:
        cover_m = (in_sq.float() * cover)[:, None]

    # Optics and sensor: exposure and gamma, defocus, motion blur, noise, JPEG.
    exposure = _scalars([rr(g, *cfg.exposure_range) for g in gens], dev)[..., None]
    gamma = _scalars([rr(g, *cfg.gamma_range) for g in gens], dev)[..., None]
    img = (img * exposure).clamp(0, 1) ** gamma
    sig = torch.tensor([rr(g, 0.3, cfg.max_blur_sigma) if rr(g) < cfg.p_blur else 0.0 for g in gens], device=dev)
    if bool((sig > 0).any()):
        blurred = kornia.filters.gaussian_blur2d(img, (7, 7), torch.stack([sig.clamp_min(0.05)] * 2, -1))
        img = torch.where(sig[:, None, None, None] > 0, blurred, img)
    motion_shift = torch.zeros(B, 2, device=dev)  # where motion blur moved the image: the labels follow
    motion: dict[int, list[tuple[int, float, float]]] = {}  # kernel length -> (sample, angle, direction)
    for b, g in enumerate(gens):
        if rr(g) < cfg.p_motion:
            lo, hi = cfg.motion_kernel
            k = lo if lo == hi else lo + 2 * int(rr(g) * ((hi - lo) // 2 + 1))  # odd lengths lo .. hi
            angle, direction = rr(g, 0, 180), rr(g, *cfg.motion_direction)
            motion.setdefault(min(k, hi), []).append((b, angle, direction))
            motion_shift[b] = motion_blur_shift(min(k, hi), angle, direction).to(dev)
    for k, items in motion.items():  # the samples of one kernel length blurred together
        idx = [b for b, _, _ in items]
        angle = torch.tensor([a for _, a, _ in items], device=dev)
        direction = torch.tensor([d for _, _, d in items], device=dev)
        img[idx] = kornia.filters.motion_blur(img[idx], k, angle, direction)
    noise = _scalars([rr(g, *cfg.noise_range) for g in gens], dev)[..., None]
    noise_fields = torch.stack([torch.randn(1, H, W, generator=g) for g in gens]).to(dev)
    img = (img + noise * noise_fields * (0.5 + img)).clamp(0, 1)
    for b, g in enumerate(gens):
        if rr(g) < cfg.p_jpeg:
            q8 = (img[b, 0] * 255).round().to(torch.uint8).cpu().numpy()
            ok_enc, buf = cv2.imencode(".jpg", q8, [cv2.IMWRITE_JPEG_QUALITY, int(rr(g, 35, 95))])
            if ok_enc:
                img[b, 0] = torch.from_numpy(cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE).astype(np.float32) / 255.0).to(dev)

    # Occlusion and blur enter the labels; a corner's label is where the exposure puts its image.
    q = labels["corners_raw"] + motion_shift[:, None, :].to(labels["corners_raw"].dtype)
    occ_d = F.max_pool2d(occ[:, None], 5, 1, 2)[:, 0]
    qi = q.round().long()
    qi[..., 0] = qi[..., 0].clamp(0, W - 1)
    qi[..., 1] = qi[..., 1].clamp(0, H - 1)
    occluded = occ_d[torch.arange(B, device=dev)[:, None], qi[..., 1], qi[..., 0]] > 0.01
    visible = labels["visible"] & ~occluded & ~no_target[:, None]
    if cfg.p_glare > 0:
        # A corner the spot washes out (its print's contrast after exposure, vignetting and
        # clipping under 2 % of the range, 5 grey levels) is not visible: nothing is left of it to find.
        p_board = board.points(torch.float32)[:, :2].to(dev)
        cx, cy = (c[None].expand(B, -1) for c in on_sheet(p_board[:, 0], p_board[:, 1]))
        lit = shading(cx[..., None], cy[..., None])[..., 0]  # (B, N)
        r_rel = ((labels["corners_raw"].to(dev).float() - centres[:, None, :]).norm(dim=-1) / rad[:, 0]).clamp(0, 1)
        e = exposure[:, 0, 0] * (1 - vig_strength[:, 0] * r_rel**3)  # the vignetting before the exposure
        gm = gamma[:, 0, 0]

        def contrast(spot: Tensor) -> Tensor:  # (B, N) of the print at the corners, as the image path computes it
            return ((white[:, 0] * lit + spot) * e).clamp(0, 1) ** gm - ((black[:, 0] * lit + spot) * e).clamp(0, 1) ** gm

        # Only corners the spot washes out: the labels of a sample without one stay as they were.
        washed = (contrast(glare(cx[..., None], cy[..., None])[..., 0]) < 0.02) & (contrast(torch.zeros_like(cx)) >= 0.02)
        visible = visible & ~washed
    blur_term = (1 - ((sig - 0.8) / 1.5).clamp(0, 1))[:, None]
    learn = labels["learn_geom"] * blur_term * visible.float()
    return {
        "image": img.float(),
        "corners": torch.where(visible[..., None], q, torch.zeros_like(q)),
        "corners_raw": q,
        "visible": visible,
        "learnability": learn,
        "square_px": labels["square_px"],
        "board_mask": cover_m.clamp(0, 1),
        "board_uv": torch.stack([u, vv], 1) * (cover_m > 0.5),
        "blur_sigma": sig,
        "fov": scene.fov.float(),
        "has_target": ~no_target,
        "radius": scene.radius.float(),
        "model_index": torch.tensor([cfg.models.index(m) if m in cfg.models else -1 for m in scene.model], device=dev),
        "T_cam_board": scene.T_cam_board,
        "params": scene.params,
    }


class RenderedDataset(torch.utils.data.Dataset):
    """Map-style dataset over an endless stream: item ``idxs`` (a list) renders that batch.

    Use with ``DataLoader(ds, batch_size=None, sampler=BatchSampler(...))`` so that a batch is
    rendered with tensor ops in one call; works in DataLoader workers.
    """

    def __init__(self, cfg: RenderConfig, seed: int = 0, length: int = 10**9):
        self.cfg, self.seed, self.length = cfg, seed, length
        self.board = make_target(cfg.target)

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, idxs: list[int]) -> dict[str, Tensor]:
        out = render_batch(self.cfg, list(idxs), self.seed, self.board)
        out.pop("params")
        return out
