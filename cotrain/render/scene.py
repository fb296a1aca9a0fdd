"""A batch's scenes: a random fisheye camera and board pose per sample, and the exact labels of
the board's corners through them.

The draws are per sample (:class:`~cotrain.render.draws.SampleDraws`, numpy scalars, no tensor
operation); the labels are computed for the whole batch at once, one camera family at a time, in
float64 numpy on the CPU (a few hundred points per sample).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cotrain.geometry import cameras, poses
from cotrain.render.config import RenderConfig
from cotrain.render.draws import SampleDraws
from cotrain.targets import Target, board_points, sees_print, square_px


@dataclass
class Scene:
    """Per-sample cameras and poses of a batch of B samples (numpy float64; tensors given are
    converted)."""

    model: list[str]  # camera family per sample
    params: list[np.ndarray]  # camera parameters per sample, (P,) in Kalibr order
    fov: np.ndarray  # (B,) degrees
    radius: np.ndarray  # (B,) image-circle radius, pixels
    T_cam_board: np.ndarray  # (B, 4, 4)

    def __post_init__(self) -> None:
        self.params = [np.asarray(p, np.float64) for p in self.params]
        self.fov = np.asarray(self.fov, np.float64).reshape(-1)
        self.radius = np.asarray(self.radius, np.float64).reshape(-1)
        self.T_cam_board = np.asarray(self.T_cam_board, np.float64).reshape(-1, 4, 4)

    def __len__(self) -> int:
        return len(self.model)

    def families(self) -> dict[str, list[int]]:
        """Camera family -> its samples' indices, families in order of first appearance."""
        out: dict[str, list[int]] = {}
        for b, m in enumerate(self.model):
            out.setdefault(m, []).append(b)
        return out

    def family_params(self, idx: list[int]) -> np.ndarray:
        """(G, P) parameters of samples ``idx`` (one family)."""
        return np.stack([self.params[b] for b in idx])

    def principal_points(self) -> np.ndarray:
        """(B, 2) principal points (cx, cy) of the cameras."""
        return np.array([[p[cameras.get_model(m).index(k)] for k in ("cx", "cy")] for m, p in zip(self.model, self.params)])


def _monotonic_to_rim(model: str, params: np.ndarray, fov: float) -> bool:
    """Whether the whole image circle unprojects: the projection grows up to the FoV's edge."""
    th = np.linspace(0.0, math.radians(fov) / 2, 32)
    q, ok = cameras.get_model(model).project(np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], -1), params)
    return bool(ok.all()) and bool((q[1:, 0] - q[:-1, 0] > 0).all())


def sample_camera(cfg: RenderConfig, d: SampleDraws) -> tuple[str, np.ndarray, float, float]:
    """A random camera: (family, (P,) params, FoV degrees, image-circle radius px)."""
    w = np.asarray(cfg.model_weights, np.float64)
    model = cfg.models[d.choice(w / w.sum())]
    fov = d.uniform(*cfg.fov_range)
    radius = min(cfg.height, cfg.width) / 2.0 * d.uniform(*cfg.radius_range)
    jit = cfg.principal_jitter * min(cfg.height, cfg.width)
    principal = ((cfg.width - 1) / 2 + d.uniform(-jit, jit), (cfg.height - 1) / 2 + d.uniform(-jit, jit))
    m = cameras.get_model(model)
    scale = {n: cfg.kb4_k_scale for n in m.distortion_names} if model == "kb4" else {}
    params = None
    for _ in range(8):  # shapes until one sees the FoV and unprojects its whole circle
        shape = m.sample_shape(d.uniform, scale)
        try:
            params = cameras.make_camera(model, fov, cfg.width, cfg.height, radius, principal, dtype=np.float64, **shape)
        except ValueError:
            continue
        if _monotonic_to_rim(model, params, fov):
            break
        params = None
    if params is None:
        params = cameras.make_camera(model, fov, cfg.width, cfg.height, radius, principal, dtype=np.float64)
    params[m.index("fy")] *= 1 + d.uniform(-cfg.aspect_jitter, cfg.aspect_jitter)
    return model, params, fov, radius


def sample_pose(cfg: RenderConfig, board: Target, fov: float, d: SampleDraws) -> np.ndarray:
    """(4, 4) T_cam_board: board centre along a random ray (up to FoV/2 + margin off-axis), tilted."""
    half = min(math.radians(fov / 2 + cfg.offaxis_margin_deg), math.radians(150))
    if cfg.offaxis_min_deg > 0:
        lo = min(math.radians(cfg.offaxis_min_deg), half)
        theta = math.sqrt(lo * lo + d.uniform() * (half * half - lo * lo))  # uniform over the ring's area
    else:
        theta = half * math.sqrt(d.uniform())  # denser towards the edge, where real detectors fail
    phi = d.uniform(0, 2 * math.pi)
    dist = math.exp(d.uniform(math.log(cfg.distance_range[0]), math.log(cfg.distance_range[1])))
    ray = np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])
    # Board facing the camera: its z axis (into the board) along the viewing ray, or against it
    # for a target whose print faces +z (then turned half a turn about its x axis).
    up = np.array([0.0, -1.0, 0.0]) if abs(float(ray @ [0.0, -1.0, 0.0])) <= 0.95 else np.array([1.0, 0.0, 0.0])
    R_face = poses.look_at(np.zeros(3), ray, up)[:3, :3]  # columns x, y, z
    if board.front > 0:
        R_face = R_face @ np.diag([1.0, -1.0, -1.0])
    tilt = math.radians(cfg.max_tilt_deg) * d.uniform() ** 0.7
    tilt_axis_angle = d.uniform(0, 2 * math.pi)
    w_tilt = np.array([math.cos(tilt_axis_angle), math.sin(tilt_axis_angle), 0.0]) * tilt
    w_roll = np.array([0.0, 0.0, d.uniform(-math.pi, math.pi)])
    R_cam_board = R_face @ poses.rotation_from_axis_angle(w_tilt) @ poses.rotation_from_axis_angle(w_roll)
    x0, y0, x1, y1 = board.extent()
    c_board = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    c_board[0] += d.uniform(-0.3, 0.3) * (x1 - x0)  # the board's centre off the drawn ray
    c_board[1] += d.uniform(-0.3, 0.3) * (y1 - y0)
    return poses.make_pose(R_cam_board, dist * ray - R_cam_board @ c_board)


def sample_scene(cfg: RenderConfig, board: Target, draws: list[SampleDraws]) -> Scene:
    """One random camera and pose per sample, from the sample's own stream."""
    cams = [sample_camera(cfg, d) for d in draws]
    Ts = [sample_pose(cfg, board, fov, d) for (_, _, fov, _), d in zip(cams, draws)] if draws else []
    # FoV and radius in float32, as the renderer has always kept them (the scenes stay those of
    # the rendered sets).
    return Scene(
        [c[0] for c in cams],
        [c[1] for c in cams],
        np.float32([c[2] for c in cams]),
        np.float32([c[3] for c in cams]),
        np.stack(Ts) if Ts else np.zeros((0, 4, 4)),
    )


def corner_geometry(board: Target, scene: Scene) -> dict[str, np.ndarray]:
    """Every corner of every sample through its camera, float64, one family at a time:

    q: (B, N, 2) projections (meaningless where not ``ok``); ok: (B, N) projected, within the
    FoV, printed side towards the camera; square_px: (B, N) local pixels per square;
    cos_inc: (B, N) cosine of the viewing ray's incidence on the print."""
    P = board_points(board)
    B, N = len(scene), P.shape[0]
    out = {"q": np.zeros((B, N, 2)), "ok": np.zeros((B, N), bool), "square_px": np.zeros((B, N)), "cos_inc": np.zeros((B, N))}
    for model, idx in scene.families().items():
        T = scene.T_cam_board[idx]
        params = scene.family_params(idx)
        pc = poses.transform_points(T, P)  # (G, N, 3)
        q, ok = cameras.project(model, pc, params[:, None, :])
        ok &= cameras.off_axis_angle(pc) <= np.radians(scene.fov[idx])[:, None] / 2
        n, t = T[:, :3, 2], T[:, :3, 3]
        ray = pc / np.linalg.norm(pc, axis=-1, keepdims=True)
        out["q"][idx] = q
        out["ok"][idx] = ok & sees_print(board.front, n, t)[:, None]
        out["square_px"][idx] = square_px(model, params, T, board)
        out["cos_inc"][idx] = np.clip(-board.front * np.einsum("gnc,gc->gn", ray, n), 0, 1)
    return out
