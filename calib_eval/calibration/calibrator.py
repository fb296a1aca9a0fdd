"""Multi-camera fisheye calibration (paper Sec. III-A): staged pipeline over the shared camera models.

1. Intrinsic initialisation per camera: a guess from the rough FoV and image size, per-view target
   poses from bearing vectors (valid beyond 90 degrees off-axis), frames added progressively
   (anchors first when the selector is on) with the intrinsics re-estimated at each step; the
   conditioning score gamma_k is recorded at every step.
2. Intrinsic refinement over all selected views of each camera (with outlier rejection).
3. Full calibration: extrinsics initialised from co-visible views, then intrinsics, extrinsics
   and target poses optimised together.

The solver is Levenberg-Marquardt on the block structure: target poses (6 each) are eliminated
with the Schur complement, leaving a small system in the camera parameters. Robust kernel: Huber.
Names follow docs/conventions.md: ``T_cam_rig`` (cam0 is the rig), ``T_rig_board`` per view.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from cotrain.geometry import cameras, poses
from cotrain.io.sequence import Observation, Sequence
from cotrain.targets import Target


@dataclass
class CalibConfig:
    model: str = "kb4"  # camera family for every camera (kb4, ucm, eucm, ds)
    fov: float = 200.0  # rough FoV (deg) from the lens data sheet
    huber_px: float = 1.0  # Huber kernel threshold (px)
    init_steps: list[int] = field(default_factory=lambda: [3, 4, 5, 6, 8, 10, 13, 16, 20, 25, 30])  # progressive prefix sizes
    init_iters: int = 15  # LM iterations per initialisation step
    refine_iters: int = 40  # LM iterations in stages 2 and 3
    outlier_px: float = 3.0  # observations beyond max(this, 5 x robust sigma) are dropped after stage 2
    min_views: int = 4  # fewer usable views for a camera is a failure
    min_corners: int = 6  # observations with fewer corners are ignored
    max_rms_px: float = 2.0  # success needs every camera's final RMS below this
    no_init: bool = False  # skip stage 1 (the paper's BA-only two-stage ablation)
    shared_intrinsics_guess_radius: float = 0.0  # image-circle radius (px) of the initial guess; 0: half the shorter side


class CalibrationFailed(RuntimeError):
    """Raised inside the pipeline; :func:`calibrate` turns it into a failure report."""


# --------------------------------------------------------------------------------------------
# Residuals and Jacobians
# --------------------------------------------------------------------------------------------
def _retract(T: Tensor, d: Tensor) -> Tensor:
    """Left increment: (R, t) -> (Exp(w) R, Exp(w) t + v), d = (w, v)."""
    R = poses.rotation_from_axis_angle(d[..., :3])
    return poses.make_pose(R @ T[..., :3, :3], (R @ T[..., :3, 3:])[..., 0] + d[..., 3:])


def _skew(p: Tensor) -> Tensor:
    """(O, 3) -> (O, 3, 3) with skew(p) w = p x w."""
    z = torch.zeros_like(p[:, 0])
    return torch.stack(
        [torch.stack([z, -p[:, 2], p[:, 1]], -1), torch.stack([p[:, 2], z, -p[:, 0]], -1), torch.stack([-p[:, 1], p[:, 0], z], -1)], -2
    )


def project_with_jacobians(model: str, p: Tensor, intr: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """q (O, 2), valid (O,), d q / d p (O, 2, 3) and d q / d intr (O, 2, P) through the shared
    camera model. Points are independent and the intrinsics are expanded per point, so two
    reverse passes (one per pixel coordinate) give every per-point Jacobian."""
    proj = cameras.get_model(model).project
    with torch.enable_grad():
        p_ = p.detach().requires_grad_(True)
        i_ = intr.detach().expand(p.shape[0], -1).clone().requires_grad_(True)
        q, valid = proj(p_, i_)
        gx = torch.autograd.grad(q[:, 0].sum(), (p_, i_), retain_graph=True)
        gy = torch.autograd.grad(q[:, 1].sum(), (p_, i_))
    return q.detach(), valid, torch.stack([gx[0], gy[0]], 1), torch.stack([gx[1], gy[1]], 1)


def _jacobians(model: str, intr: Tensor, T_cam_rig: Tensor, T_rig_board: Tensor, X: Tensor):
    """Per observation (O): predicted q (O, 2), d q / d intr (O, 2, P), d q / d cam increment
    (O, 2, 6) and d q / d pose increment (O, 2, 6). Poses are gathered per observation; the
    increments are the left perturbations of :func:`_retract` (rotation first)."""
    p_r = (T_rig_board[:, :3, :3] @ X[:, :, None])[..., 0] + T_rig_board[:, :3, 3]
    R_c = T_cam_rig[:, :3, :3]
    p_c = (R_c @ p_r[:, :, None])[..., 0] + T_cam_rig[:, :3, 3]
    q, _, Jq_p, Ji = project_with_jacobians(model, p_c, intr)
    eye = torch.eye(3, dtype=X.dtype).expand(X.shape[0], 3, 3)
    d_cam = torch.cat([-_skew(p_c), eye], -1)  # d p_c / d (w_c, v_c)
    d_pose = R_c @ torch.cat([-_skew(p_r), eye], -1)  # d p_c / d (w_p, v_p)
    return q, Ji, Jq_p @ d_cam, Jq_p @ d_pose


# --------------------------------------------------------------------------------------------
# The problem state and the LM solver
# --------------------------------------------------------------------------------------------
@dataclass
class Problem:
    """Observations flattened: per corner o, its camera, view, board point and pixel."""

    cam: Tensor  # (O,) long
    view: Tensor  # (O,) long, index into the active views
    X: Tensor  # (O, 3)
    q: Tensor  # (O, 2)
    w: Tensor  # (O,) observation weights
    n_views: int

    @staticmethod
    def build(obs: list[Observation], board: Target, view_index: dict[int, int], single_camera: bool = False) -> Problem:
        """Flatten ``obs``; ``single_camera`` maps every observation to camera 0 (per-camera stages)."""
        P = board.points().numpy()
        cam, view, X, q, w = [], [], [], [], []
        for o in obs:
            cam.append(np.full(len(o.ids), 0 if single_camera else o.cam))
            view.append(np.full(len(o.ids), view_index[o.view]))
            X.append(P[o.ids])
            q.append(o.q)
            w.append(o.weight)
        t = lambda a, dt=torch.float64: torch.from_numpy(np.concatenate(a)).to(dt)  # noqa: E731
        return Problem(t(cam, torch.long), t(view, torch.long), t(X), t(q), t(w), len(view_index))


@dataclass
class SolveResult:
    converged: bool
    cost: float
    rms: list[float]  # per camera RMS reprojection error (px) over the problem's observations
    iterations: int
    reason: str
    residuals: Tensor  # (O,) per-corner error norm (px)
    schur_cond: float  # gamma: log10 condition of the normalised pose-free intrinsic Schur block


def solve(
    prob: Problem,
    model: list[str],
    intr: list[Tensor],
    T_cam_rig: Tensor,
    T_rig_board: Tensor,
    *,
    opt_intr: bool = True,
    opt_extr: bool = False,
    iters: int = 30,
    huber: float = 1.0,
) -> tuple[list[Tensor], Tensor, Tensor, SolveResult]:
    """Levenberg-Marquardt with the target poses eliminated by the Schur complement.

    Camera parameters: intrinsics of every camera (if ``opt_intr``) and extrinsics of cameras 1..
    (if ``opt_extr``; cam0 is the gauge). Target poses T_rig_board (V, 4, 4) are always optimised.
    Returns updated (intr, T_cam_rig, T_rig_board, result).
    """
    C = len(model)
    V = prob.n_views
    intr = [x.clone() for x in intr]
    T_cam_rig = T_cam_rig.clone()
    T_rig_board = T_rig_board.clone()
    # Column layout of the camera block.
    offs = []
    n = 0
    for c in range(C):
        ni = intr[c].numel() if opt_intr else 0
        ne = 6 if (opt_extr and c > 0) else 0
        offs.append((n, ni, ne))
        n += ni + ne
    lam = 1e-3
    cams_present = [c for c in range(C) if bool((prob.cam == c).any())]

    def linearise(intr, T_cam_rig, T_rig_board):
        r_all = torch.zeros(prob.q.shape[0], 2, dtype=torch.float64)
        Jcam = torch.zeros(prob.q.shape[0], 2, max(1, n), dtype=torch.float64)
        Jpose = torch.zeros(prob.q.shape[0], 2, 6, dtype=torch.float64)
        for c in cams_present:
            sel = (prob.cam == c).nonzero()[:, 0]
            qh, Ji, Jc, Jp = _jacobians(model[c], intr[c], T_cam_rig[c].expand(len(sel), 4, 4), T_rig_board[prob.view[sel]], prob.X[sel])
            r_all[sel] = prob.q[sel] - qh
            o, ni, ne = offs[c]
            if ni:
                Jcam[sel, :, o : o + ni] = Ji
            if ne:
                Jcam[sel, :, o + ni : o + ni + ne] = Jc
            Jpose[sel] = Jp
        return r_all, Jcam[..., :n], Jpose

    def residuals(intr, T_cam_rig, T_rig_board):
        r_all = torch.zeros(prob.q.shape[0], 2, dtype=torch.float64)
        for c in cams_present:
            sel = (prob.cam == c).nonzero()[:, 0]
            T = T_cam_rig[c] @ T_rig_board[prob.view[sel]]
            p = (T[:, :3, :3] @ prob.X[sel][:, :, None])[..., 0] + T[:, :3, 3]
            r_all[sel] = prob.q[sel] - cameras.project(model[c], p, intr[c])[0]
        return r_all

    def cost_of(r):
        e = r.norm(dim=-1)
        rho = torch.where(e < huber, 0.5 * e * e, huber * (e - 0.5 * huber))
        return float((prob.w * rho).sum())

    r, Jc, Jp = linearise(intr, T_cam_rig, T_rig_board)
    cost = cost_of(r)
    if not math.isfinite(cost):
        return intr, T_cam_rig, T_rig_board, _result(False, cost, r, prob, C, 0, "non-finite initial residuals", float("nan"))
    converged, reason, it = False, "max iterations", 0
    gamma = float("nan")
    for it in range(1, iters + 1):
        e = r.norm(dim=-1)
        wr = prob.w * torch.where(e < huber, torch.ones_like(e), huber / e.clamp_min(1e-12))  # IRLS Huber weights
        # Normal equations (the residual is q - q_hat, so J of the residual is -J of q_hat).
        A = torch.einsum("o,oia,oib->ab", wr, Jc, Jc)
        g_c = torch.einsum("o,oia,oi->a", wr, Jc, r)
        Bo = torch.einsum("o,oia,oib->oab", wr, Jc, Jp)  # (O, n, 6)
        Co = torch.einsum("o,oia,oib->oab", wr, Jp, Jp)
        g_po = torch.einsum("o,oia,oi->oa", wr, Jp, r)
        B = torch.zeros(V, n, 6, dtype=torch.float64).index_add_(0, prob.view, Bo)
        Cm = torch.zeros(V, 6, 6, dtype=torch.float64).index_add_(0, prob.view, Co)
        g_p = torch.zeros(V, 6, dtype=torch.float64).index_add_(0, prob.view, g_po)
        if it == 1 and opt_intr:
            gamma = _schur_gamma(A, B, Cm, offs)
        improved = False
        for _ in range(10):
            Ad = A + lam * torch.diag(torch.diagonal(A).clamp_min(1e-9))
            Cd = Cm + lam * torch.diag_embed(torch.diagonal(Cm, dim1=-2, dim2=-1).clamp_min(1e-9))
            Cd = Cd + 1e-12 * torch.eye(6, dtype=torch.float64)
            Ci = torch.linalg.inv(Cd)
            S = Ad - torch.einsum("vai,vij,vbj->ab", B, Ci, B)
            rhs = g_c - torch.einsum("vai,vij,vj->a", B, Ci, g_p)
            try:
                dc = torch.linalg.solve(S, rhs) if n else torch.zeros(0, dtype=torch.float64)
            except RuntimeError:
                lam *= 10
                continue
            dp = torch.einsum("vij,vj->vi", Ci, g_p - torch.einsum("vai,a->vi", B, dc))
            new_intr, new_T = list(intr), T_cam_rig.clone()
            for c in range(C):
                o, ni, ne = offs[c]
                if ni:
                    new_intr[c] = cameras.get_model(model[c]).clamp(intr[c] + dc[o : o + ni])
                if ne:
                    new_T[c] = _retract(T_cam_rig[c], dc[o + ni : o + ni + ne])
            new_P = _retract(T_rig_board, dp)
            r_new = residuals(new_intr, new_T, new_P)
            c_new = cost_of(r_new)
            if math.isfinite(c_new) and c_new < cost:
                rel = (cost - c_new) / max(cost, 1e-300)
                intr, T_cam_rig, T_rig_board = new_intr, new_T, new_P
                r, Jc, Jp = linearise(intr, T_cam_rig, T_rig_board)
                cost = cost_of(r)
                lam = max(lam / 3, 1e-9)
                improved = True
                if rel < 1e-9:
                    converged, reason = True, "converged"
                break
            lam *= 8
            if lam > 1e10:
                break
        if not improved:
            # No decrease possible: at a minimum (converged) or stuck (divergent).
            converged, reason = True, "converged (no further decrease)"
            break
        if converged:
            break
    return intr, T_cam_rig, T_rig_board, _result(converged, cost, r, prob, C, it, reason, gamma)


def _result(converged, cost, r, prob, C, it, reason, gamma) -> SolveResult:
    e = r.norm(dim=-1)
    rms = [float(torch.sqrt((e[prob.cam == c] ** 2).mean())) if bool((prob.cam == c).any()) else float("nan") for c in range(C)]
    return SolveResult(converged, cost, rms, it, reason, e, gamma)


def _schur_gamma(A: Tensor, B: Tensor, Cm: Tensor, offs) -> float:
    """gamma = log10 kappa of the diagonally normalised pose-free Schur block of the intrinsics."""
    Ci = torch.linalg.pinv(Cm)
    S = A - torch.einsum("vai,vij,vbj->ab", B, Ci, B)
    idx = torch.cat([torch.arange(o, o + ni) for o, ni, _ in offs if ni])
    S = S[idx][:, idx]
    d = torch.diagonal(S).clamp_min(1e-300).rsqrt()
    ev = torch.linalg.eigvalsh(d[:, None] * S * d[None, :]).abs()
    return float(torch.log10(ev.max() / ev.min().clamp_min(1e-300)))


# --------------------------------------------------------------------------------------------
# Pose initialisation from bearing vectors
# --------------------------------------------------------------------------------------------
def pose_from_bearings(X: np.ndarray, v: np.ndarray) -> np.ndarray | None:
    """T_cam_board of a planar target from board points X (M, 3) with z = 0 and unit bearings v (M, 3).

    DLT on v x (H [x, y, 1]) = 0 with H = [r1 r2 t]; works for rays beyond 90 degrees because
    bearings are never divided by z. Returns None when degenerate.
    """
    if len(X) < 4:
        return None
    m = X[:, :2].mean(0)
    s = np.sqrt(((X[:, :2] - m) ** 2).sum(1).mean()) + 1e-12
    xn = np.c_[(X[:, :2] - m) / s, np.ones(len(X))]
    a, b, c = (v[:, i : i + 1] * xn for i in range(3))  # (M, 3) each: bearing component times x
    z = np.zeros_like(xn)
    rows = np.concatenate([np.c_[z, -c, b], np.c_[c, z, -a], np.c_[-b, a, z]], 0)  # rows of v x (H x) = 0
    _, _, Vt = np.linalg.svd(rows, full_matrices=False)
    H = Vt[-1].reshape(3, 3)
    # Undo the normalisation: x_n = N x with N = [[1/s, 0, -m/s], [0, 1/s, -m/s], [0, 0, 1]].
    N = np.array([[1 / s, 0, -m[0] / s], [0, 1 / s, -m[1] / s], [0, 0, 1]])
    H = H @ N
    scale = (np.linalg.norm(H[:, 0]) + np.linalg.norm(H[:, 1])) / 2
    if scale < 1e-12:
        return None
    H = H / scale
    if np.mean(np.einsum("ij,ij->i", (H @ np.c_[X[:, :2], np.ones(len(X))].T).T, v)) < 0:
        H = -H
    R = np.c_[H[:, 0], H[:, 1], np.cross(H[:, 0], H[:, 1])]
    U, _, Vt2 = np.linalg.svd(R)
    R = U @ np.diag([1, 1, np.linalg.det(U @ Vt2)]) @ Vt2
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = H[:, 2]
    return T


def _init_view_pose(model: str, intr: Tensor, o: Observation, board: Target) -> np.ndarray | None:
    v, ok = cameras.unproject(model, torch.from_numpy(o.q), intr)
    ok = ok.numpy()
    if ok.sum() < 4:
        return None
    return pose_from_bearings(board.points().numpy()[o.ids[ok]], v.numpy()[ok])


# --------------------------------------------------------------------------------------------
# The staged pipeline
# --------------------------------------------------------------------------------------------
@dataclass
class CalibrationResult:
    success: bool
    reason: str
    model: list[str]
    intrinsics: list[np.ndarray]  # per camera, Kalibr order
    T_cam_rig: np.ndarray  # (C, 4, 4), cam0 = identity
    T_rig_board: dict[int, np.ndarray]  # view -> pose
    rms_px: list[float]
    frames_per_stage: dict[str, list[int]]  # stage -> number of observations per camera
    gamma: list[list[float]]  # per camera, the conditioning trajectory of stage 1
    runtime_s: float
    stages: list[dict] = field(default_factory=list)


def initial_guess(model: str, fov: float, width: int, height: int, radius: float = 0.0) -> Tensor:
    """Intrinsics from the rough FoV and image size: the FoV fills a circle of ``radius`` (default
    half the shorter side) about the image centre; shape parameters at the family's defaults."""
    return cameras.make_camera(model, fov, width, height, radius or min(width, height) / 2.0)


def _focal_search(model: str, guess: Tensor, obs: list[Observation], board: Target) -> Tensor:
    """Scale the guess's focal length to best explain a few views (1-D search, bearing poses)."""
    m = cameras.get_model(model)
    best, best_cost = guess, float("inf")
    for scale in np.exp(np.linspace(math.log(0.4), math.log(2.5), 25)):
        g = guess.clone()
        g[m.index("fx")] *= scale
        g[m.index("fy")] *= scale
        costs = []
        for o in obs[:8]:
            T = _init_view_pose(model, g, o, board)
            if T is None:
                costs.append(1e6)
                continue
            pc = board.points().numpy()[o.ids] @ T[:3, :3].T + T[:3, 3]
            q, ok = cameras.project(model, torch.from_numpy(pc), g)
            err = np.linalg.norm(q.numpy() - o.q, axis=1)
            err[~ok.numpy()] = 1e3
            costs.append(float(np.median(err)))
        c = float(np.median(costs)) if costs else float("inf")
        if c < best_cost:
            best, best_cost = g, c
    return best


def _intrinsic_stage(
    model: str, intr: Tensor, obs: list[Observation], board: Target, cfg: CalibConfig, progressive: bool
) -> tuple[Tensor, dict[int, np.ndarray], list[float], SolveResult]:
    """Stage 1 (progressive, gamma recorded) or stage 2 (all at once) for one camera."""
    if progressive:
        steps = [k for k in cfg.init_steps if k < len(obs)] + ([len(obs)] if len(obs) <= max(cfg.init_steps) else [])
    else:
        steps = [len(obs)]
    poses_cb: dict[int, np.ndarray] = {}
    gammas: list[float] = []
    res = None
    for k in steps:
        prefix = obs[:k]
        active = []
        for o in prefix:
            if o.view not in poses_cb:
                T = _init_view_pose(model, intr, o, board)
                if T is None:
                    continue
                poses_cb[o.view] = T
            active.append(o)
        if len(active) < 2:
            continue
        vi = {o.view: i for i, o in enumerate(active)}
        prob = Problem.build(active, board, vi, single_camera=True)
        Tb = torch.from_numpy(np.stack([poses_cb[o.view] for o in active]))
        iters = cfg.init_iters if progressive else cfg.refine_iters
        out_intr, _, Tb, res = solve(prob, [model], [intr], torch.eye(4, dtype=torch.float64)[None], Tb, iters=iters, huber=cfg.huber_px)
        gammas.append(res.schur_cond)
        if not all(math.isfinite(v) for v in res.rms):
            raise CalibrationFailed(f"intrinsic {'initialisation' if progressive else 'refinement'} diverged at {k} frames")
        intr = out_intr[0]
        for o, T in zip(active, Tb.numpy()):
            poses_cb[o.view] = T
    if res is None:
        raise CalibrationFailed("too few usable views to initialise the intrinsics")
    return intr, poses_cb, gammas, res


def _average_pose(Ts: list[np.ndarray]) -> np.ndarray:
    """Robust mean of poses: chordal mean of rotations near the median, median translation."""
    Rs = np.stack([T[:3, :3] for T in Ts])
    ts = np.stack([T[:3, 3] for T in Ts])
    t = np.median(ts, axis=0)
    M = np.median(Rs, axis=0)
    U, _, Vt = np.linalg.svd(M)
    R = U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R, t
    return out


def calibrate(seq: Sequence, cfg: CalibConfig, order: dict[int, list[int]] | None = None) -> CalibrationResult:
    """Run the staged pipeline on ``seq``.

    ``order``: per camera, the views in the order stage 1 should add them (the selector's anchors
    first); default: sequence order. Never raises for a bad sequence: the result says why.
    """
    t0 = time.time()
    board = seq.target
    C = len(seq.cameras)
    models = [cfg.model] * C
    frames: dict[str, list[int]] = {}
    gammas: list[list[float]] = [[] for _ in range(C)]
    stages: list[dict] = []

    def fail(reason: str, intr=None, T_cr=None) -> CalibrationResult:
        return CalibrationResult(
            False,
            reason,
            models,
            [np.asarray(x) for x in (intr or [])],
            T_cr if T_cr is not None else np.tile(np.eye(4), (C, 1, 1)),
            {},
            [float("nan")] * C,
            frames,
            gammas,
            time.time() - t0,
            stages,
        )

    try:
        cameras.get_model(cfg.model)
    except ValueError as e:
        return fail(str(e))
    if board is None:
        return fail("the sequence names no target (its detections carry none)")
    obs_by_cam = []
    for c in range(C):
        ob = [o for o in seq.by_camera(c) if len(o.ids) >= cfg.min_corners]
        if order and c in order:
            rank = {v: i for i, v in enumerate(order[c])}
            ob.sort(key=lambda o: rank.get(o.view, len(rank) + o.view))
        else:
            ob.sort(key=lambda o: o.view)
        if len(ob) < cfg.min_views:
            return fail(f"{seq.cameras[c].name}: only {len(ob)} usable views of the target (need {cfg.min_views})")
        obs_by_cam.append(ob)

    # Stages 1 and 2, per camera.
    intr: list[Tensor] = []
    cam_poses: list[dict[int, np.ndarray]] = []
    try:
        for c in range(C):
            info = seq.cameras[c]
            guess = initial_guess(cfg.model, cfg.fov, info.width, info.height, cfg.shared_intrinsics_guess_radius)
            guess = _focal_search(cfg.model, guess, obs_by_cam[c], board)
            if cfg.no_init:
                x, pc_, res = guess, {}, None
                frames.setdefault("init", []).append(0)
            else:
                x, pc_, g, res = _intrinsic_stage(cfg.model, guess, obs_by_cam[c], board, cfg, progressive=True)
                gammas[c] = g
                frames.setdefault("init", []).append(len(obs_by_cam[c]))
                stages.append({"stage": "init", "camera": c, "rms_px": res.rms[0], "iterations": res.iterations, "reason": res.reason})
            if not cfg.no_init:
                # Stage 2: refinement over all views, then outlier rejection and a final pass.
                x, pc_, _, res = _intrinsic_stage(cfg.model, x, obs_by_cam[c], board, cfg, progressive=False)
                keep = _reject_outliers(obs_by_cam[c], pc_, cfg.model, x, board, cfg)
                removed = sum(len(o.ids) for o in obs_by_cam[c]) - sum(len(o.ids) for o in keep)
                obs_by_cam[c] = keep
                if removed:
                    x, pc_, _, res = _intrinsic_stage(cfg.model, x, keep, board, cfg, progressive=False)
                frames.setdefault("refine", []).append(len(keep))
                stages.append({"stage": "refine", "camera": c, "rms_px": res.rms[0], "iterations": res.iterations, "reason": res.reason})
                if res.rms[0] > cfg.max_rms_px * 3:
                    return fail(f"{seq.cameras[c].name}: intrinsic refinement ended at RMS {res.rms[0]:.2f} px", intr + [x])
            intr.append(x)
            cam_poses.append(pc_)
    except CalibrationFailed as e:
        return fail(str(e), intr)

    # Stage 3: extrinsics from co-visible views (spanning tree from cam0), then everything jointly.
    T_cam_rig = np.tile(np.eye(4), (C, 1, 1))
    if cfg.no_init:
        for c in range(C):
            cam_poses[c] = {o.view: T for o in obs_by_cam[c] if (T := _init_view_pose(cfg.model, intr[c], o, board)) is not None}
    known = {0}
    while len(known) < C:
        added = False
        for c in range(C):
            if c in known:
                continue
            for k in list(known):
                shared = set(cam_poses[c]) & set(cam_poses[k])
                if len(shared) >= 1:
                    # T_c_rig = T_c_board T_board_k T_k_rig
                    cands = [cam_poses[c][v] @ np.linalg.inv(cam_poses[k][v]) @ T_cam_rig[k] for v in shared]
                    T_cam_rig[c] = _average_pose(cands)
                    known.add(c)
                    added = True
                    break
        if not added:
            missing = ", ".join(seq.cameras[c].name for c in range(C) if c not in known)
            return fail(f"no co-visible views link {missing} to cam0: extrinsics cannot be initialised", intr, T_cam_rig)
    views = sorted({v for c in range(C) for v in cam_poses[c]})
    T_rig_board = {}
    for v in views:
        cands = [np.linalg.inv(T_cam_rig[c]) @ cam_poses[c][v] for c in range(C) if v in cam_poses[c]]
        T_rig_board[v] = cands[0] if len(cands) == 1 else _average_pose(cands)
    vi = {v: i for i, v in enumerate(views)}
    used = [o for c in range(C) for o in obs_by_cam[c] if o.view in vi]
    prob = Problem.build(used, board, vi)
    Tb = torch.from_numpy(np.stack([T_rig_board[v] for v in views]))
    intr_t, Tcr, Tb, res = solve(
        prob,
        models,
        intr,
        torch.from_numpy(T_cam_rig),
        Tb,
        opt_extr=C > 1,
        iters=cfg.refine_iters * (2 if cfg.no_init else 1),
        huber=cfg.huber_px,
    )
    frames["full"] = [len(obs_by_cam[c]) for c in range(C)]
    stages.append({"stage": "full", "rms_px": res.rms, "iterations": res.iterations, "reason": res.reason})
    intr_np = [x.numpy() for x in intr_t]
    T_cr = Tcr.numpy()
    ok_finite = all(np.isfinite(x).all() for x in intr_np) and np.isfinite(T_cr).all()
    worst = max(res.rms) if res.rms else float("nan")
    success = ok_finite and math.isfinite(worst) and worst <= cfg.max_rms_px
    reason = "ok" if success else (f"final RMS {worst:.2f} px exceeds {cfg.max_rms_px} px" if ok_finite else "non-finite parameters")
    return CalibrationResult(
        success, reason, models, intr_np, T_cr, {v: Tb[i].numpy() for v, i in vi.items()}, res.rms, frames, gammas, time.time() - t0, stages
    )


def _reject_outliers(
    obs: list[Observation], poses_cb: dict[int, np.ndarray], model: str, intr: Tensor, board: Target, cfg: CalibConfig
) -> list[Observation]:
    errs = []
    per = []
    for o in obs:
        if o.view not in poses_cb:
            per.append(None)
            continue
        T = poses_cb[o.view]
        pc = board.points().numpy()[o.ids] @ T[:3, :3].T + T[:3, 3]
        q, ok = cameras.project(model, torch.from_numpy(pc), intr)
        e = np.where(ok.numpy(), np.linalg.norm(q.numpy() - o.q, axis=1), np.inf)
        per.append(e)
        errs.append(e[np.isfinite(e)])
    allerr = np.concatenate(errs) if errs else np.zeros(1)
    sigma = 1.4826 * np.median(allerr) / 1.1774 if len(allerr) else 1.0  # Rayleigh median -> sigma
    thr = max(cfg.outlier_px, 5 * sigma)
    out = []
    for o, e in zip(obs, per):
        if e is None:
            continue
        keep = e < thr
        if keep.sum() >= cfg.min_corners:
            out.append(Observation(o.cam, o.view, o.ids[keep], o.q[keep], o.weight[keep], o.frame))
    return out
