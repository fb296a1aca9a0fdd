"""Online, physically grounded renderer of fisheye calibration images with exact labels.

Per sample: a random fisheye camera (kb4 / ucm / eucm / ds, FoV ~150-250 deg, image circle
inside or cropped by the frame, principal-point offset, random shape parameters) and a random
board pose covering the whole field of view (rays beyond 90 degrees, strong tilt, near and far,
partial views). The image is rendered by inverse mapping: every output pixel is unprojected to a
ray, intersected with the board plane and the board's appearance is area-filtered over the
pixel's footprint (so edges are anti-aliased and corners sit exactly on their saddle points),
then composited over a procedural background with lighting, vignetting, blur, noise, JPEG and
occluders. Outside the image circle the frame is black.

A batch is rendered as a batch, in four steps (docs/training.md, "The renderer"):

1. draws (:mod:`cotrain.render.draws`): each sample's random numbers come from its own stream,
   seeded by ``(seed, index)`` alone, as one table of scalars (:mod:`cotrain.render.scene`,
   :mod:`cotrain.render.appearance`), in numpy without a tensor operation per number;
2. labels: every corner of the batch through its camera, one camera family at a time (float64,
   on the CPU: a few hundred points per sample);
3. pixels: rays, the board, the background, occluders, the image circle, optics and sensor, for
   the whole batch at once on ``device``; the operations grow with the camera families and the
   shapes drawn, not with the batch;
4. the JPEG round trip, the one step on the CPU per sample (OpenCV's codec), in a thread pool.

So sample ``i`` of stream ``seed`` is the same scene whatever the batch, on whatever device.
"""

from __future__ import annotations

import dataclasses
import functools
from concurrent.futures import ThreadPoolExecutor

import cv2
import kornia
import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from cotrain.geometry import cameras
from cotrain.render.appearance import GLARE_STREAM, Appearance, column, draw_appearance, paint_background, paint_occluders, scalars
from cotrain.render.config import RenderConfig
from cotrain.render.draws import SampleDraws, box_muller, sample_draws, to_device
from cotrain.render.scene import Scene, corner_geometry, sample_scene
from cotrain.targets import Target, make_target, sees_print

__all__ = [
    "GLARE_STREAM",
    "LABEL_VERSION",
    "Prepared",
    "RenderConfig",
    "Scene",
    "prepare_batch",
    "render_batch",
    "render_prepared",
    "render_scene",
    "sample_draws",
    "sample_scene",
]

CPU = torch.device("cpu")

# Version of the labels' conventions (rendered sets cached with another one are rendered again,
# the same images): 2 = a corner's label moves with its image where motion blur moves it; 3 = a
# corner a glare spot washes out is not visible.
LABEL_VERSION = 3


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
    B, (H, W) = len(scene), grid.shape[:2]
    v_all = grid.new_empty(B, H, W, 3)
    ok_all = torch.empty(B, H, W, dtype=torch.bool, device=grid.device)
    for model, idx in scene.families().items():
        p = to_device(scene.family_params(idx), grid.device, torch.float32)[:, None, None, :]  # (G, 1, 1, P)
        v, ok = cameras.unproject(model, grid[None], p)
        half = to_device(np.radians(scene.fov[idx]) / 2, grid.device, v.dtype)
        at = to_device(np.array(idx), grid.device)
        v_all[at] = v
        ok_all[at] = ok & (cameras.off_axis_angle(v) <= half[:, None, None])
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
    """Exact labels of every corner slot, before the appearance (occluders, motion blur, glare)
    acts on them (see :func:`render_batch` for the keys); on the CPU."""
    geo = corner_geometry(board, scene)
    q = torch.from_numpy(geo["q"]).float()
    size = torch.from_numpy(geo["square_px"]).float()
    cos_inc = torch.from_numpy(geo["cos_inc"]).float()
    bp = cfg.border_px
    in_image = (q[..., 0] > bp - 0.5) & (q[..., 0] < cfg.width - 0.5 - bp) & (q[..., 1] > bp - 0.5) & (q[..., 1] < cfg.height - 0.5 - bp)
    r_px = (q - torch.from_numpy(scene.principal_points()).float()[:, None, :]).norm(dim=-1)
    in_circle = r_px < torch.from_numpy(scene.radius).float()[:, None] - bp
    vis = torch.from_numpy(geo["ok"]) & in_image & in_circle & (size > 0)
    learn_size = ((size - cfg.min_square_px) / (cfg.good_square_px - cfg.min_square_px)).clamp(0, 1)
    learn_inc = ((cos_inc - 0.08) / 0.25).clamp(0, 1)
    return {
        "corners": torch.where(vis[..., None], q, torch.zeros_like(q)),
        "corners_raw": q,
        "visible": vis,
        "square_px": size,
        "learn_geom": learn_size * learn_inc,
    }


# --------------------------------------------------------------------------------------------
# Pixels of the batch
# --------------------------------------------------------------------------------------------
class _Print:
    """The printed sheet's light, per sample: its black and white, the light's gradient and the
    glare spot, as functions of sheet coordinates (-0.5 .. 0.5 over the board's extent)."""

    def __init__(self, board: Target, tables: list[Appearance], dev: torch.device):
        self.extent = board.extent()
        self.black, self.white = column(tables, "black", dev), column(tables, "white", dev)
        self.lx, self.ly = (scalars(v, dev) for v in zip(*(t.light for t in tables)))
        self.peak, self.sx, self.sy, self.size = (scalars(v, dev) for v in zip(*(t.glare for t in tables)))

    def on_sheet(self, x: Tensor, y: Tensor) -> tuple[Tensor, Tensor]:
        """Board metres -> the sheet's extent, -0.5 .. 0.5."""
        x0, y0, x1, y1 = self.extent
        return (x - (x0 + x1) / 2) / (x1 - x0), (y - (y0 + y1) / 2) / (y1 - y0)

    def shading(self, x: Tensor, y: Tensor) -> Tensor:
        """The light's gradient over the sheet (B, ...)."""
        return (1 + self.lx * x + self.ly * y).clamp(0.3, 1.6)

    def glare(self, x: Tensor, y: Tensor) -> Tensor:
        """Light mirrored by a glossy print, the same on black and white (B, ...): a Gaussian spot
        fixed on the board, so the print's contrast fades under it and its whites clip."""
        return self.peak * torch.exp(-((x - self.sx) ** 2 + (y - self.sy) ** 2) / (2 * self.size * self.size))


def _board_layer(cfg: RenderConfig, board: Target, scene: Scene, light: _Print, no_target: Tensor, grid: Tensor) -> dict[str, Tensor]:
    """The board through every camera at the sample positions ``grid`` (H, W, 2): its image
    (B, H, W), coverage (B, H, W), the checker squares' region ``in_squares`` and the board's
    corner-grid coordinates ``u``, ``v``."""
    v, in_circle = _rays(scene, grid)
    xy, hit = _board_hit(v, to_device(scene.T_cam_board, grid.device), board.front)
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
    uv_grid, in_pattern = board.grid_coordinates(xy_safe)
    bx, by = light.on_sheet(xy_safe[..., 0], xy_safe[..., 1])
    image = (light.black + (light.white - light.black) * value) * light.shading(bx, by)
    if cfg.p_glare > 0:
        image = image + light.glare(bx, by)
    return {
        "image": image,
        "cover": cover * ok * (~no_target)[:, None, None],
        "in_squares": ok & in_pattern,
        "u": uv_grid[..., 0] * ok if cfg.supersample > 1 else uv_grid[..., 0],
        "v": uv_grid[..., 1] * ok if cfg.supersample > 1 else uv_grid[..., 1],
    }


def _image_circle(tables: list[Appearance], img: Tensor, grid: Tensor, centres: Tensor, radius: Tensor) -> Tensor:
    """Black outside the image circles (``centres`` (B, 2), ``radius`` (B,) px), with a soft,
    anti-aliased rim and vignetting."""
    r_px = (grid[None] - centres[:, None, None, :]).norm(dim=-1)
    rad = radius[:, None, None]
    rim = (rad - r_px + 0.5).clamp(0, 1)
    vignette = 1 - column(tables, "vignette", img.device) * (r_px / rad).clamp(0, 1) ** 3
    return img * vignette * rim


def motion_blur_kernels(kernel_size: int, angles: list[float], directions: list[float]) -> Tensor:
    """(G, k, k) kornia's motion-blur kernels (``get_motion_kernel2d``, the kernels of
    ``kornia.filters.motion_blur``), made on the CPU."""
    return kornia.filters.get_motion_kernel2d(
        kernel_size, torch.tensor(angles, dtype=torch.float32), torch.tensor(directions, dtype=torch.float32)
    )


def motion_blur_shifts(kernel_size: int, angles: list[float], directions: list[float]) -> Tensor:
    """(G, 2) px: how far kornia's ``motion_blur(img, kernel_size, angle, direction)`` moves each
    image's content, the exposure-weighted mean position along the blur. A ``direction`` other
    than 0 weights one end of the blur more (kornia filters by correlation, so the content moves
    against the kernel's centroid): up to (length + 1) / 6 px (1 px for a 5 px blur)."""
    return _kernel_shifts(motion_blur_kernels(kernel_size, angles, directions))


def _kernel_shifts(kernels: Tensor) -> Tensor:
    """(G, 2) px how far correlating with ``kernels`` (G, k, k) moves an image's content."""
    k = kernels / kernels.sum((-2, -1), keepdim=True)
    c = torch.arange(k.shape[-1], dtype=k.dtype) - (k.shape[-1] - 1) / 2
    return -torch.stack([(k.sum(-2) * c).sum(-1), (k.sum(-1) * c).sum(-1)], -1).float()


def motion_blur_shift(kernel_size: int, angle: float, direction: float) -> Tensor:
    """(2,) px: :func:`motion_blur_shifts` of one image."""
    return motion_blur_shifts(kernel_size, [float(angle)], [float(direction)])[0]


def _motion_blur(img: Tensor, tables: list[Appearance]) -> tuple[Tensor, Tensor]:
    """Motion blur, the samples of one kernel length together (``kornia.filters.motion_blur``, its
    kernels made on the CPU and copied without a host sync): the image and (B, 2) how far it moved
    each sample's content (the labels follow)."""
    shift = torch.zeros(img.shape[0], 2)
    lengths: dict[int, list[int]] = {}
    for b, t in enumerate(tables):
        if t.motion is not None:
            lengths.setdefault(t.motion[0], []).append(b)
    for k, idx in lengths.items():
        _, angles, directions = zip(*(tables[b].motion for b in idx))
        kernels = motion_blur_kernels(k, list(angles), list(directions))
        shift[idx] = _kernel_shifts(kernels)
        at = to_device(np.array(idx), img.device)
        img[at] = kornia.filters.filter2d(img[at], to_device(kernels, img.device), "reflect")
    return img, to_device(shift, img.device)


def _jpeg(img: Tensor, qualities: list[int]) -> Tensor:
    """The JPEG round trip of the samples with a quality (0: none): OpenCV's codec on the CPU, one
    image per task in a thread pool (the codec releases the GIL), the batch copied once each way."""
    idx = [b for b, q in enumerate(qualities) if q > 0]
    if not idx:
        return img
    at = to_device(np.array(idx), img.device)
    q8 = (img[at, 0] * 255).round().to(torch.uint8).cpu().numpy()  # on a GPU: the one wait of a rendered batch

    def round_trip(i: int) -> np.ndarray | None:
        ok, buf = cv2.imencode(".jpg", q8[i], [cv2.IMWRITE_JPEG_QUALITY, qualities[idx[i]]])
        return cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE).astype(np.float32) / 255.0 if ok else None

    with ThreadPoolExecutor(max_workers=max(1, min(len(idx), torch.get_num_threads()))) as pool:
        decoded = list(pool.map(round_trip, range(len(idx))))
    done = [i for i, d in enumerate(decoded) if d is not None]
    if done:
        img[to_device(np.array([idx[i] for i in done]), img.device), 0] = to_device(np.stack([decoded[i] for i in done]), img.device)
    return img


def _optics(img: Tensor, tables: list[Appearance], noise_uniforms: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Exposure and gamma, defocus, motion blur, read noise (``noise_uniforms`` (B, M, 16), see
    :func:`box_muller`) and JPEG on (B, 1, H, W): the image, (B, 2) the motion blur's shift of each
    sample's content and (B,) the defocus sigma."""
    B, _, H, W = img.shape
    dev = img.device
    exposure, gamma = column(tables, "exposure", dev)[..., None], column(tables, "gamma", dev)[..., None]
    img = (img * exposure).clamp(0, 1) ** gamma
    sigma = np.float32([t.blur_sigma for t in tables])
    sig = to_device(sigma, dev)
    if (sigma > 0).any():  # sigma given on the CPU: kornia checks it there, not on the device
        blurred = kornia.filters.gaussian_blur2d(img, (7, 7), torch.from_numpy(np.stack([np.maximum(sigma, 0.05)] * 2, -1)))
        img = torch.where(sig[:, None, None, None] > 0, blurred, img)
    img, shift = _motion_blur(img, tables)
    fields = box_muller(to_device(noise_uniforms, dev), H * W).reshape(B, 1, H, W)
    img = (img + column(tables, "noise", dev)[..., None] * fields * (0.5 + img)).clamp(0, 1)
    return _jpeg(img, [t.jpeg_quality for t in tables]), shift, sig


def _washed_out(board: Target, tables: list[Appearance], light: _Print, corners_raw: Tensor, centres: Tensor, radius: Tensor) -> Tensor:
    """(B, N) corners a glare spot washes out: the print's contrast there, after exposure,
    vignetting (image circles ``centres``, ``radius``) and clipping, under 2 % of the range (5 grey
    levels) with the spot and not without."""
    dev = corners_raw.device
    B = len(tables)
    p_board = to_device(board.points(torch.float32)[:, :2].contiguous(), dev)
    cx, cy = (c[None].expand(B, -1) for c in light.on_sheet(p_board[:, 0], p_board[:, 1]))
    lit = light.shading(cx[..., None], cy[..., None])[..., 0]  # (B, N)
    r_rel = ((corners_raw.float() - centres[:, None, :]).norm(dim=-1) / radius[:, None]).clamp(0, 1)
    e = column(tables, "exposure", dev)[:, 0] * (1 - column(tables, "vignette", dev)[:, 0] * r_rel**3)  # the vignetting before the exposure
    gm = column(tables, "gamma", dev)[:, 0]

    def contrast(spot: Tensor) -> Tensor:  # (B, N) of the print at the corners, as the image path computes it
        white, black = light.white[:, 0] * lit + spot, light.black[:, 0] * lit + spot
        return (white * e).clamp(0, 1) ** gm - (black * e).clamp(0, 1) ** gm

    return (contrast(light.glare(cx[..., None], cy[..., None])[..., 0]) < 0.02) & (contrast(torch.zeros_like(cx)) >= 0.02)


def _occluded(occ: Tensor, q: Tensor) -> Tensor:
    """(B, N) corners at q (B, N, 2) within 2 px of an occluder ((B, H, W) coverage)."""
    B, H, W = occ.shape
    occ_d = F.max_pool2d(occ[:, None], 5, 1, 2)[:, 0]
    qi = q.round().long()
    qi[..., 0] = qi[..., 0].clamp(0, W - 1)
    qi[..., 1] = qi[..., 1].clamp(0, H - 1)
    return occ_d[torch.arange(B, device=occ.device)[:, None], qi[..., 1], qi[..., 0]] > 0.01


def render_batch(
    cfg: RenderConfig, indices: list[int], seed: int = 0, board: Target | None = None, device: str | torch.device = CPU
) -> dict[str, Tensor]:
    """Render samples ``indices`` of the stream ``seed`` on ``device`` (a GPU renders the same
    samples: the random draws come from per-sample CPU streams, the pixels are computed there).

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
    return render_prepared(cfg, board, prepare_batch(cfg, indices, seed, board), device)


@dataclasses.dataclass
class Prepared:
    """A batch's CPU half (steps 1-3 of the module docstring): its scenes, appearance tables and
    corner labels, all the random draws done. Picklable: a render worker can prepare batches and
    the training process render their pixels on its device (:func:`render_prepared`)."""

    scene: Scene
    tables: list[Appearance]  # their noise_uniforms moved into ``noise``
    labels: dict[str, Tensor]  # corner_labels, on the CPU
    noise: Tensor  # (B, M, 16) float32 uniforms of the noise fields (a tensor: it crosses processes in shared memory)


def prepare_scene(cfg: RenderConfig, board: Target, scene: Scene, draws: list[SampleDraws]) -> Prepared:
    """The CPU half of rendering ``scene``, the appearance drawn from ``draws`` (one per sample)."""
    tables = [draw_appearance(cfg, d) for d in draws]
    noise = torch.from_numpy(np.stack([t.noise_uniforms for t in tables]))
    tables = [dataclasses.replace(t, noise_uniforms=None) for t in tables]
    return Prepared(scene, tables, corner_labels(cfg, board, scene), noise)


def prepare_batch(cfg: RenderConfig, indices: list[int], seed: int = 0, board: Target | None = None) -> Prepared:
    """The CPU half of :func:`render_batch`."""
    board = board or make_target(cfg.target)
    draws = [sample_draws(seed, i) for i in indices]
    return prepare_scene(cfg, board, sample_scene(cfg, board, draws), draws)


def render_scene(
    cfg: RenderConfig, board: Target, scene: Scene, draws: list[SampleDraws], device: str | torch.device = CPU
) -> dict[str, Tensor]:
    """Render given cameras and poses (``scene``) on ``device``; appearance is drawn from ``draws``
    (one stream per sample). Returns the dict of :func:`render_batch`, every tensor on ``device``
    (but ``params``, per-sample CPU tensors)."""
    return render_prepared(cfg, board, prepare_scene(cfg, board, scene, draws), device)


def render_prepared(cfg: RenderConfig, board: Target, prepared: Prepared, device: str | torch.device = CPU) -> dict[str, Tensor]:
    """The pixels of a prepared batch on ``device`` (steps 4-5): the dict of :func:`render_batch`."""
    dev = torch.device(device)
    H, W, ss = cfg.height, cfg.width, cfg.supersample
    scene, tables = prepared.scene, prepared.tables
    labels = {k: to_device(v, dev) for k, v in prepared.labels.items()}
    no_target = to_device(np.array([t.no_target for t in tables], bool), dev)
    light = _Print(board, tables, dev)
    grid = _pixel_grid(H, W, ss, dev)
    centres, radius = to_device(scene.principal_points(), dev, torch.float32), to_device(scene.radius, dev, torch.float32)
    layer = _board_layer(cfg, board, scene, light, no_target, grid)
    img = paint_background(cfg, tables, H * ss, W * ss, dev) * (1 - layer["cover"]) + layer["image"] * layer["cover"]
    img, occ = paint_occluders(img, tables)
    img = _image_circle(tables, img, grid, centres, radius)[:, None]
    squares, u, v = (layer["in_squares"].float() * layer["cover"])[:, None], layer["u"], layer["v"]
    if ss > 1:
        img, squares = F.avg_pool2d(img, ss), F.avg_pool2d(squares, ss)
        occ, u, v = (F.avg_pool2d(x[:, None], ss)[:, 0] for x in (occ, u, v))
    img, shift, sig = _optics(img, tables, prepared.noise)

    # Occlusion and blur enter the labels; a corner's label is where the exposure puts its image.
    q = labels["corners_raw"] + shift[:, None, :].to(labels["corners_raw"].dtype)
    visible = labels["visible"] & ~_occluded(occ, q) & ~no_target[:, None]
    if cfg.p_glare > 0:  # only corners the spot washes out: the labels of a sample without one stay as they were
        visible = visible & ~_washed_out(board, tables, light, labels["corners_raw"], centres, radius)
    blur_term = (1 - ((sig - 0.8) / 1.5).clamp(0, 1))[:, None]
    return {
        "image": img.float(),
        "corners": torch.where(visible[..., None], q, torch.zeros_like(q)),
        "corners_raw": q,
        "visible": visible,
        "learnability": labels["learn_geom"] * blur_term * visible.float(),
        "square_px": labels["square_px"],
        "board_mask": squares.clamp(0, 1),
        "board_uv": torch.stack([u, v], 1) * (squares > 0.5),
        "blur_sigma": sig,
        "fov": to_device(scene.fov, dev, torch.float32),
        "has_target": ~no_target,
        "radius": radius,
        "model_index": to_device(np.array([cfg.models.index(m) if m in cfg.models else -1 for m in scene.model], np.int64), dev),
        "T_cam_board": to_device(scene.T_cam_board, dev),
        "params": [torch.from_numpy(p) for p in scene.params],
    }
