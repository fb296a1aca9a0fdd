"""Synthetic multi-fisheye rigs and sequences with ground truth (the paper's Sec. V-A setup).

Observations are ground-truth projections of the detectable corners plus detector-like noise,
computed with the shared camera models; no renderer is involved.

Two kinds of recording: independent random views (the paper's), or a continuous recording (a
board moving smoothly in front of the fixed rig at ``frame_rate_hz``), where cameras can be exposed
``time_offsets_s`` after their stamps and the board can be bent (``bend_m``): the causes a
calibration's verdict must name (:mod:`calib_eval.calibration.trust`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from cotrain.geometry import cameras, poses
from cotrain.io.sequence import CameraInfo, Observation, Sequence
from cotrain.targets import Target, TargetConfig, make_target, sees_print, square_px


@dataclass
class RigSpec:
    fov: float = 220.0  # degrees, every camera
    yaws_deg: list[float] = field(default_factory=lambda: [0.0, 90.0])  # yaw of each camera in the rig
    baseline: float = 0.05  # metres between neighbouring cameras
    model: str = "kb4"  # camera family
    width: int = 1280
    height: int = 720
    radius: float | None = None  # image-circle radius in px (default: fills the height... see make_rig)
    shape: dict = field(default_factory=dict)  # shape parameters (default: the model's DEFAULT_SHAPE)


@dataclass
class SynthSpec:
    n_frames: int = 480  # synchronised frames
    noise_px: float = 0.3  # Gaussian detector noise (px)
    outlier_rate: float = 0.0  # fraction of corners replaced by gross outliers
    min_corners: int = 6  # observations with fewer corners are dropped (as a detector would)
    min_square_px: float = 4.0  # corners whose local square is smaller are not detected
    distance_range: tuple[float, float] = (0.1, 1.0)  # rig-to-board distance, metres
    target: TargetConfig = field(default_factory=TargetConfig)
    motion: str = "random"  # "random": independent views; "continuous": a smooth trajectory through random poses
    frame_rate_hz: float = 20.0  # stamps of the views (and the trajectory's sampling when continuous)
    keyframe_s: float = 2.5  # continuous: seconds between the random poses the trajectory passes through
    time_offsets_s: tuple[float, ...] = ()  # per camera: exposed this long after its stamp (continuous; default 0)
    bend_m: float = 0.0  # the board bent as a cylinder along its x axis: out-of-plane offset at the centre (m, +z)


@dataclass
class GroundTruth:
    model: list[str]
    params: list[np.ndarray]  # per camera, Kalibr order
    T_cam_rig: np.ndarray  # (C, 4, 4); cam0 is the rig frame
    T_rig_board: np.ndarray  # (K, 4, 4), at each view's stamp
    time_offsets_s: list[float] = field(default_factory=list)  # per camera, exposure after the stamp
    warp_m: tuple[float, float] = (0.0, 0.0)  # the bend in the calibrator's warp terms (k_x, k_y), m


def paper_config(name: str) -> RigSpec:
    """``FoV220_90`` -> a stereo rig of 220-degree f-theta cameras with 90-degree relative yaw;
    ``Hex`` / ``FoV220_hex`` -> six cameras 60 degrees apart in a ring."""
    try:
        fov_part, yaw_part = name.split("_")
        fov = float(fov_part.removeprefix("FoV"))
    except ValueError:
        raise ValueError(f"{name}: configurations look like FoV220_90 or FoV200_hex") from None
    if yaw_part == "hex":
        return RigSpec(fov=fov, yaws_deg=[60.0 * i for i in range(6)], baseline=0.05)
    return RigSpec(fov=fov, yaws_deg=[0.0, float(yaw_part)])


def rig_radius(spec: RigSpec) -> float:
    """Image-circle radius (px) of the rig's cameras: ``spec.radius``, or 1.1 x half the height."""
    return spec.radius if spec.radius is not None else spec.height / 2.0 * 1.1


def make_rig(spec: RigSpec) -> tuple[list[str], list[torch.Tensor], np.ndarray]:
    """Camera parameters and T_cam_rig (cam0 = rig). Cameras sit on a ring (or a line for 2)."""
    radius = rig_radius(spec)
    params = [cameras.make_camera(spec.model, spec.fov, spec.width, spec.height, radius, **spec.shape) for _ in spec.yaws_deg]
    n = len(spec.yaws_deg)
    T = []
    for i, yaw in enumerate(spec.yaws_deg):
        # Position: for a stereo pair, cam1 at +baseline along x; for a ring, on a circle.
        if n == 2:
            c = np.array([spec.baseline * i, 0.0, 0.0])
        else:
            ring_r = spec.baseline / (2 * math.sin(math.pi / n))
            a = math.radians(yaw)
            c = np.array([ring_r * math.sin(a), 0.0, ring_r * math.cos(a)])
        R_rig_cam = poses.rotation_from_axis_angle(torch.tensor([0.0, math.radians(yaw), 0.0], dtype=torch.float64)).numpy()
        T_rig_cam = np.eye(4)
        T_rig_cam[:3, :3] = R_rig_cam
        T_rig_cam[:3, 3] = c
        T.append(np.linalg.inv(T_rig_cam))
    T = np.stack(T)
    # Express everything relative to cam0 (the rig frame is cam0).
    T = T @ np.linalg.inv(T[0])
    return [spec.model] * n, params, T


def _sample_rig_poses(rng: np.random.Generator, n: int, board: Target, spec: SynthSpec, T_cam_rig: np.ndarray) -> np.ndarray:
    """T_rig_board for n views: the rig in front of the board, random viewing directions."""
    x0, y0, x1, y1 = board.extent()
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    out = []
    n_cam = T_cam_rig.shape[0]
    for _ in range(n):
        # Rig position in the board frame: on the printed side, on a cap of directions.
        d = math.exp(rng.uniform(math.log(spec.distance_range[0]), math.log(spec.distance_range[1])))
        el = math.radians(rng.uniform(0, 65))
        az = rng.uniform(0, 2 * math.pi)
        pos = centre + d * np.array([math.sin(el) * math.cos(az), math.sin(el) * math.sin(az), board.front * math.cos(el)])
        # Random viewing direction: one camera's axis points near the board, then jitter.
        look_cam = rng.integers(n_cam)
        target = centre + np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), 0.0])
        T_board_cam = poses.look_at(torch.tensor(pos), torch.tensor(target), torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)).numpy()
        # Rotate the camera away from the board by up to most of the half FoV (board off-axis).
        w = rng.normal(size=3)
        w = w / np.linalg.norm(w) * math.radians(rng.uniform(0, 100))
        R_off = poses.rotation_from_axis_angle(torch.tensor(w)).numpy()
        T_board_cam[:3, :3] = T_board_cam[:3, :3] @ R_off
        T_board_rig = T_board_cam @ T_cam_rig[look_cam]
        out.append(np.linalg.inv(T_board_rig))
    return np.stack(out)


def _continuous_poses(rng: np.random.Generator, board: Target, spec: SynthSpec, T_cam_rig: np.ndarray):
    """A smooth board trajectory: a function t (s) -> T_rig_board (len(t), 4, 4) through random
    poses every ``keyframe_s`` (cubic spline in position, scipy's RotationSpline in rotation)."""
    from scipy.interpolate import CubicSpline
    from scipy.spatial.transform import Rotation, RotationSpline

    duration = spec.n_frames / spec.frame_rate_hz
    n_key = int(math.ceil(duration / spec.keyframe_s)) + 3
    keys = _sample_rig_poses(rng, n_key, board, spec, T_cam_rig)
    t_key = (np.arange(n_key) - 1) * spec.keyframe_s
    rot = RotationSpline(t_key, Rotation.from_matrix(keys[:, :3, :3]))
    pos = CubicSpline(t_key, keys[:, :3, 3])

    def at(t: np.ndarray) -> np.ndarray:
        T = np.tile(np.eye(4), (len(t), 1, 1))
        T[:, :3, :3] = rot(t).as_matrix()
        T[:, :3, 3] = pos(t)
        return T

    return at


def bent_points(board: Target, bend_m: float) -> np.ndarray:
    """The board's points (N, 3) bent as a cylinder along x: a circular arc over the corner grid's
    x extent with sagitta ``bend_m`` at its centre (along +z), the grid's ends in the plane."""
    P = board.points().numpy().copy()
    if bend_m == 0:
        return P
    x0, x1 = P[:, 0].min(), P[:, 0].max()
    a, s = (x1 - x0) / 2, abs(bend_m)
    R = (a * a + s * s) / (2 * s)
    dx = P[:, 0] - (x0 + x1) / 2
    P[:, 2] += math.copysign(1.0, bend_m) * (np.sqrt(R * R - dx * dx) - (R - s))
    return P


def _observe(model, prm, T: np.ndarray, P: np.ndarray, board: Target, rig: RigSpec, spec: SynthSpec, rng):
    """(ids, noisy pixels) of the corners camera (model, prm) detects at T_cam_board, or (None, None)."""
    if not sees_print(board.front, T[:3, 2], T[:3, 3]):  # printed side faces away
        return None, None
    pc = P @ T[:3, :3].T + T[:3, 3]
    q, ok = cameras.project(model, torch.from_numpy(pc), prm)
    q = q.numpy()
    ok = ok.numpy() & (cameras.off_axis_angle(torch.from_numpy(pc)).numpy() <= math.radians(rig.fov) / 2 * 0.995)
    ok &= (q[:, 0] > 1) & (q[:, 0] < rig.width - 2) & (q[:, 1] > 1) & (q[:, 1] < rig.height - 2)
    # Detectable: the local square is large enough.
    ok &= square_px(model, prm, torch.from_numpy(T), board).numpy() >= spec.min_square_px
    if ok.sum() < spec.min_corners:
        return None, None
    ids = np.nonzero(ok)[0]
    qn = q[ids] + rng.normal(scale=spec.noise_px, size=(len(ids), 2))
    if spec.outlier_rate > 0:
        bad = rng.random(len(ids)) < spec.outlier_rate
        qn[bad] += rng.uniform(8, 40, size=(bad.sum(), 2)) * rng.choice([-1, 1], size=(bad.sum(), 2))
    return ids, qn


def make_sequence(rig: RigSpec, spec: SynthSpec, seed: int = 0) -> tuple[Sequence, GroundTruth]:
    """A synthetic sequence with ground truth. Observations: detectable corners + noise."""
    rng = np.random.default_rng(seed)
    board = make_target(spec.target)
    models, params, T_cam_rig = make_rig(rig)
    stamps = np.arange(spec.n_frames) / spec.frame_rate_hz
    offsets = list(spec.time_offsets_s) + [0.0] * (len(models) - len(spec.time_offsets_s))
    if spec.motion == "continuous":
        trajectory = _continuous_poses(rng, board, spec, T_cam_rig)
        T_rig_board = trajectory(stamps)
        seen = [trajectory(stamps + dt) for dt in offsets]
    elif spec.motion == "random":
        if any(offsets):
            raise ValueError("time offsets need a continuous recording (motion='continuous')")
        T_rig_board = _sample_rig_poses(rng, spec.n_frames, board, spec, T_cam_rig)
        seen = [T_rig_board] * len(models)
    else:
        raise ValueError(f"motion {spec.motion!r}: 'random' or 'continuous'")
    P = bent_points(board, spec.bend_m)
    obs = []
    for k in range(spec.n_frames):
        for c, (model, prm) in enumerate(zip(models, params)):
            ids, qn = _observe(model, prm, T_cam_rig[c] @ seen[c][k], P, board, rig, spec, rng)
            if ids is not None:
                obs.append(Observation(c, k, ids, qn, np.ones(len(ids)), f"{k:06d}"))
    cams = [CameraInfo(f"cam{i}", rig.width, rig.height) for i in range(len(models))]
    seq = Sequence(cams, spec.n_frames, obs, np.round(stamps * 1e9).astype(np.int64), board)
    gt = GroundTruth(models, [p.numpy() for p in params], T_cam_rig, T_rig_board, offsets, (spec.bend_m, 0.0))
    return seq, gt
