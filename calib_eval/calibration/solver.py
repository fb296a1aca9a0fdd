"""The calibration solver: Levenberg-Marquardt over camera intrinsics, camera poses in the rig and
target poses, with the target poses eliminated by the Schur complement and a Huber kernel.

Each camera model owns its parameters and their bounds (:class:`cotrain.geometry.cameras.CameraModel`):
the solver clamps an increment with ``model.clamp`` and never knows parameter positions. Pose
increments are left perturbations (:func:`retract`, rotation first).

Two optional global parameters join the camera block: the board's out-of-plane warp (mrcal's
two-parameter ``calobject_warp``, :func:`warp_basis`) and each camera's time offset to cam0 (the
board's pose at a view moved along its velocity, ``Problem.velocity``, by the offset).
:func:`covariance` gives the camera block's covariance at a solution, scaled by the measured noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from cotrain.geometry import cameras, poses
from cotrain.io.sequence import Observation
from cotrain.targets import Target


# --------------------------------------------------------------------------------------------
# Residuals and Jacobians
# --------------------------------------------------------------------------------------------
def retract(T: Tensor, d: Tensor) -> Tensor:
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


def observation_jacobians(model: str, intr: Tensor, T_cam_rig: Tensor, T_rig_board: Tensor, X: Tensor):
    """Per observation (O): predicted q (O, 2), d q / d intr (O, 2, P), d q / d cam increment
    (O, 2, 6) and d q / d pose increment (O, 2, 6). Poses are gathered per observation; the
    increments are the left perturbations of :func:`retract` (rotation first)."""
    q, Ji, Jc, Jp, _ = observation_blocks(model, intr, T_cam_rig, T_rig_board, X)
    return q, Ji, Jc, Jp


def observation_blocks(model: str, intr: Tensor, T_cam_rig: Tensor, T_rig_board: Tensor, X: Tensor):
    """:func:`observation_jacobians` plus d q / d z (O, 2): the corner moved along the board's z
    axis (the board's out-of-plane warp)."""
    p_r = (T_rig_board[:, :3, :3] @ X[:, :, None])[..., 0] + T_rig_board[:, :3, 3]
    R_c = T_cam_rig[:, :3, :3]
    p_c = (R_c @ p_r[:, :, None])[..., 0] + T_cam_rig[:, :3, 3]
    q, _, Jq_p, Ji = project_with_jacobians(model, p_c, intr)
    eye = torch.eye(3, dtype=X.dtype).expand(X.shape[0], 3, 3)
    d_cam = torch.cat([-_skew(p_c), eye], -1)  # d p_c / d (w_c, v_c)
    d_pose = R_c @ torch.cat([-_skew(p_r), eye], -1)  # d p_c / d (w_p, v_p)
    d_z = R_c @ T_rig_board[:, :3, 2:3]  # d p_c / d z_board
    return q, Ji, Jq_p @ d_cam, Jq_p @ d_pose, (Jq_p @ d_z)[..., 0]


# --------------------------------------------------------------------------------------------
# The problem, its parameters and their column layout
# --------------------------------------------------------------------------------------------
def warp_basis(X: Tensor, points: Tensor) -> Tensor:
    """mrcal's two-parameter board warp: the out-of-plane offset of a corner at board point X
    (O, 3) is ``k_x (1 - x^2) + k_y (1 - y^2)``, x and y running from -1 to 1 over the extent of
    the target's corner grid ``points`` (N, 3). Returns the basis (O, 2), 1 at the grid's centre."""
    lo, hi = points[:, :2].min(0).values, points[:, :2].max(0).values
    u = (2 * X[:, :2] - (lo + hi)) / (hi - lo).clamp_min(1e-12)
    return 1 - u * u


@dataclass
class Problem:
    """Observations flattened: per corner o, its camera, view, board point and pixel."""

    cam: Tensor  # (O,) long
    view: Tensor  # (O,) long, index into the active views
    X: Tensor  # (O, 3) board coordinates (m)
    q: Tensor  # (O, 2) pixels
    w: Tensor  # (O,) observation weights
    n_views: int
    warp_basis: Tensor | None = None  # (O, 2) :func:`warp_basis` of each corner
    velocity: Tensor | None = None  # (V, 6) at each view: the board's angular velocity (rad/s, rig frame) and its origin's velocity (m/s)
    acceleration: Tensor | None = None  # (V, 6) their rates of change (per second); None: constant velocity

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
        Xt = t(X)
        return Problem(t(cam, torch.long), t(view, torch.long), Xt, t(q), t(w), len(view_index), warp_basis(Xt, torch.from_numpy(P)))

    def select(self, keep: Tensor, one_camera: bool = False) -> tuple[Problem, Tensor]:
        """The corners ``keep`` (O,) bool, their views renumbered in order; ``one_camera`` maps them
        to camera 0. Returns the sub-problem and its views' indices in this one (V',)."""
        views = torch.unique(self.view[keep])  # sorted
        index = torch.full((self.n_views,), -1, dtype=torch.long)
        index[views] = torch.arange(len(views))
        rows = lambda a: a[views] if a is not None else None  # noqa: E731
        cam = torch.zeros(int(keep.sum()), dtype=torch.long) if one_camera else self.cam[keep]
        basis = self.warp_basis[keep] if self.warp_basis is not None else None
        sub = Problem(cam, index[self.view[keep]], self.X[keep], self.q[keep], self.w[keep], len(views), basis)
        sub.velocity, sub.acceleration = rows(self.velocity), rows(self.acceleration)
        return sub, views


@dataclass
class Params:
    """Everything the solver estimates."""

    intr: list[Tensor]  # per camera, Kalibr order
    T_cam_rig: Tensor  # (C, 4, 4); cam0 is the gauge
    T_rig_board: Tensor  # (V, 4, 4), the board at each view's time (cam0's stamp)
    warp: Tensor  # (2,) m: the board's out-of-plane offset at its centre along x and y (z into the board)
    time_offsets: Tensor  # (C,) s: camera c sees the board of view v as it was at t_v + time_offsets[c]

    def clone(self) -> Params:
        return Params(
            [x.clone() for x in self.intr], self.T_cam_rig.clone(), self.T_rig_board.clone(), self.warp.clone(), self.time_offsets.clone()
        )


@dataclass(frozen=True)
class Free:
    """Which parameter groups a solve estimates (target poses always)."""

    intr: bool = True  # every camera's intrinsics
    extr: bool = False  # cameras 1..'s poses in the rig
    warp: bool = False  # the board's two warp coefficients
    time: bool = False  # cameras 1..'s time offsets (needs Problem.velocity)
    time_cameras: frozenset[int] | None = None  # with ``time``: only these cameras' offsets (None: every camera 1..)


@dataclass(frozen=True)
class Layout:
    """Columns of the camera block: per camera (offset, count) of its intrinsics, its pose in the rig
    and its time offset, then the board warp."""

    intr: tuple[tuple[int, int], ...]
    extr: tuple[tuple[int, int], ...]
    time: tuple[tuple[int, int], ...]
    warp: tuple[int, int]
    n: int

    @staticmethod
    def make(n_intr: list[int], free: Free) -> Layout:
        n, intr, extr, time_ = 0, [], [], []
        for c, ni in enumerate(n_intr):
            timed = free.time and c > 0 and (free.time_cameras is None or c in free.time_cameras)
            counts = (ni if free.intr else 0, 6 if free.extr and c > 0 else 0, 1 if timed else 0)
            for block, count in zip((intr, extr, time_), counts):
                block.append((n, count))
                n += count
        warp = (n, 2 if free.warp else 0)
        return Layout(tuple(intr), tuple(extr), tuple(time_), warp, n + warp[1])


def _effective(prob: Problem, p: Params, sel: Tensor, c: int) -> tuple[Tensor, Tensor, Tensor]:
    """For camera c's corners ``sel``: the board pose it saw, the warped board points, and the
    pose's rate of change with the time offset as a left increment (O, 6).

    The board seen dt after the view's stamp, to second order: R = Exp(dt w + dt^2 alpha / 2) R_v,
    t = t_v + dt u + dt^2 a / 2 (``Problem.velocity`` = (w, u), ``Problem.acceleration`` =
    (alpha, a)). Its rate as a left increment: (w + dt alpha, u + dt a - (w + dt alpha) x t)."""
    T_rb = p.T_rig_board[prob.view[sel]]
    zero = torch.zeros(len(sel), 6, dtype=torch.float64)
    vel = prob.velocity[prob.view[sel]] if prob.velocity is not None else zero
    acc = prob.acceleration[prob.view[sel]] if prob.acceleration is not None else zero
    dt = p.time_offsets[c]
    if float(dt) != 0.0:
        d = dt * vel + 0.5 * dt * dt * acc
        R = poses.rotation_from_axis_angle(d[:, :3]) @ T_rb[:, :3, :3]
        T_rb = poses.make_pose(R, T_rb[:, :3, 3] + d[:, 3:])
    rate = vel + dt * acc
    rate = torch.cat([rate[:, :3], rate[:, 3:] - torch.linalg.cross(rate[:, :3], T_rb[:, :3, 3])], -1)
    X = prob.X[sel]
    if prob.warp_basis is not None and bool((p.warp != 0).any()):
        X = X.clone()
        X[:, 2] = X[:, 2] + prob.warp_basis[sel] @ p.warp
    return T_rb, X, rate


def residuals(prob: Problem, model: list[str], p: Params) -> Tensor:
    """Observed minus predicted pixels (O, 2)."""
    r = torch.zeros(prob.q.shape[0], 2, dtype=torch.float64)
    for c in range(len(model)):
        sel = (prob.cam == c).nonzero()[:, 0]
        if not len(sel):
            continue
        T_rb, X, _ = _effective(prob, p, sel, c)
        T = p.T_cam_rig[c] @ T_rb
        pc = (T[:, :3, :3] @ X[:, :, None])[..., 0] + T[:, :3, 3]
        r[sel] = prob.q[sel] - cameras.project(model[c], pc, p.intr[c])[0]
    return r


def linearise(prob: Problem, model: list[str], layout: Layout, p: Params) -> tuple[Tensor, Tensor, Tensor]:
    """Residuals (O, 2), d q / d camera block (O, 2, n) and d q / d pose increment (O, 2, 6)."""
    n_obs = prob.q.shape[0]
    r = torch.zeros(n_obs, 2, dtype=torch.float64)
    Jc = torch.zeros(n_obs, 2, max(1, layout.n), dtype=torch.float64)
    Jp = torch.zeros(n_obs, 2, 6, dtype=torch.float64)
    for c in range(len(model)):
        sel = (prob.cam == c).nonzero()[:, 0]
        if not len(sel):
            continue
        T_rb, X, vel = _effective(prob, p, sel, c)
        qh, Ji, Jx, Jpose, Jz = observation_blocks(model[c], p.intr[c], p.T_cam_rig[c].expand(len(sel), 4, 4), T_rb, X)
        r[sel] = prob.q[sel] - qh
        (oi, ni), (oe, ne), (ot, nt) = layout.intr[c], layout.extr[c], layout.time[c]
        if ni:
            Jc[sel, :, oi : oi + ni] = Ji
        if ne:
            Jc[sel, :, oe : oe + ne] = Jx
        if nt:
            Jc[sel, :, ot] = (Jpose @ vel[:, :, None])[..., 0]  # d/d dt through the pose block: the pose's rate
        ow, nw = layout.warp
        if nw:
            Jc[sel, :, ow : ow + nw] = Jz[:, :, None] * prob.warp_basis[sel][:, None, :]
        Jp[sel] = Jpose
    return r, Jc[..., : layout.n], Jp


def huber_weights(prob: Problem, r: Tensor, huber: float) -> Tensor:
    """IRLS weights (O,): the observation weight times the Huber kernel's weight of each corner."""
    e = r.norm(dim=-1)
    return prob.w * torch.where(e < huber, torch.ones_like(e), huber / e.clamp_min(1e-12))


def huber_cost(prob: Problem, r: Tensor, huber: float) -> float:
    e = r.norm(dim=-1)
    rho = torch.where(e < huber, 0.5 * e * e, huber * (e - 0.5 * huber))
    return float((prob.w * rho).sum())


@dataclass
class Normal:
    """The normal equations in blocks: camera block A (n, n) and gradient g_c (n,), per view the
    coupling B (V, n, 6), the pose block Cm (V, 6, 6) and gradient g_p (V, 6)."""

    A: Tensor
    g_c: Tensor
    B: Tensor
    Cm: Tensor
    g_p: Tensor

    @staticmethod
    def build(prob: Problem, wr: Tensor, r: Tensor, Jc: Tensor, Jp: Tensor) -> Normal:
        V, n = prob.n_views, Jc.shape[-1]
        # The residual is q - q_hat, so J of the residual is -J of q_hat: the signs cancel in g.
        A = torch.einsum("o,oia,oib->ab", wr, Jc, Jc)
        g_c = torch.einsum("o,oia,oi->a", wr, Jc, r)
        B = torch.zeros(V, n, 6, dtype=torch.float64).index_add_(0, prob.view, torch.einsum("o,oia,oib->oab", wr, Jc, Jp))
        Cm = torch.zeros(V, 6, 6, dtype=torch.float64).index_add_(0, prob.view, torch.einsum("o,oia,oib->oab", wr, Jp, Jp))
        g_p = torch.zeros(V, 6, dtype=torch.float64).index_add_(0, prob.view, torch.einsum("o,oia,oi->oa", wr, Jp, r))
        return Normal(A, g_c, B, Cm, g_p)

    def schur(self, lam: float = 0.0) -> tuple[Tensor, Tensor, Tensor]:
        """Poses eliminated at Levenberg-Marquardt damping ``lam``: S (n, n), its right-hand side
        (n,) and the damped pose blocks' inverses (V, 6, 6)."""
        Ad = self.A + lam * torch.diag(torch.diagonal(self.A).clamp_min(1e-9))
        Cd = self.Cm + lam * torch.diag_embed(torch.diagonal(self.Cm, dim1=-2, dim2=-1).clamp_min(1e-9))
        Ci = torch.linalg.inv(Cd + 1e-12 * torch.eye(6, dtype=torch.float64))
        S = Ad - torch.einsum("vai,vij,vbj->ab", self.B, Ci, self.B)
        rhs = self.g_c - torch.einsum("vai,vij,vj->a", self.B, Ci, self.g_p)
        return S, rhs, Ci


# --------------------------------------------------------------------------------------------
# The LM solver
# --------------------------------------------------------------------------------------------
@dataclass
class SolveResult:
    converged: bool
    cost: float
    rms: list[float]  # per camera RMS reprojection error (px) over the problem's observations
    iterations: int
    reason: str
    residuals: Tensor  # (O,) per-corner error norm (px)
    schur_cond: float  # gamma: log10 condition of the normalised pose-free intrinsic Schur block
    warp: Tensor | None = None  # (2,) m, the board warp at the end (zeros unless estimated)
    time_offsets: Tensor | None = None  # (C,) s, the cameras' time offsets at the end


def _apply(p: Params, dc: Tensor, dp: Tensor, layout: Layout, model: list[str]) -> Params:
    """The parameters moved by camera-block increment dc (n,) and pose increments dp (V, 6)."""
    new = Params(list(p.intr), p.T_cam_rig.clone(), retract(p.T_rig_board, dp), p.warp.clone(), p.time_offsets.clone())
    for c in range(len(model)):
        (oi, ni), (oe, ne), (ot, nt) = layout.intr[c], layout.extr[c], layout.time[c]
        if ni:
            new.intr[c] = cameras.get_model(model[c]).clamp(p.intr[c] + dc[oi : oi + ni])
        if ne:
            new.T_cam_rig[c] = retract(p.T_cam_rig[c], dc[oe : oe + ne])
        if nt:
            new.time_offsets[c] = p.time_offsets[c] + dc[ot]
    ow, nw = layout.warp
    if nw:
        new.warp = p.warp + dc[ow : ow + nw]
    return new


def _lm_step(prob, model, layout, p, eqs: Normal, cost: float, lam: float, huber: float):
    """One damped step: (new params or None, its cost, the damping to go on with)."""
    for _ in range(10):
        S, rhs, Ci = eqs.schur(lam)
        try:
            dc = torch.linalg.solve(S, rhs) if layout.n else torch.zeros(0, dtype=torch.float64)
        except RuntimeError:
            lam *= 10
            continue
        dp = torch.einsum("vij,vj->vi", Ci, eqs.g_p - torch.einsum("vai,a->vi", eqs.B, dc))
        new = _apply(p, dc, dp, layout, model)
        c_new = huber_cost(prob, residuals(prob, model, new), huber)
        if math.isfinite(c_new) and c_new < cost:
            return new, c_new, max(lam / 3, 1e-9)
        lam *= 8
        if lam > 1e10:
            break
    return None, cost, lam


def solve(
    prob: Problem,
    model: list[str],
    intr: list[Tensor],
    T_cam_rig: Tensor,
    T_rig_board: Tensor,
    *,
    opt_intr: bool = True,
    opt_extr: bool = False,
    opt_warp: bool = False,
    opt_time: bool = False,
    time_cameras: frozenset[int] | None = None,
    warp: Tensor | None = None,
    time_offsets: Tensor | None = None,
    iters: int = 30,
    huber: float = 1.0,
) -> tuple[list[Tensor], Tensor, Tensor, SolveResult]:
    """Levenberg-Marquardt with the target poses eliminated by the Schur complement.

    Camera parameters: intrinsics of every camera (if ``opt_intr``), extrinsics of cameras 1..
    (if ``opt_extr``; cam0 is the gauge), the board warp (if ``opt_warp``) and cameras 1..'s time
    offsets (if ``opt_time``; only ``time_cameras`` where given; needs ``prob.velocity``). Target poses T_rig_board (V, 4, 4) are
    always optimised. Returns updated (intr, T_cam_rig, T_rig_board, result); the result carries
    the warp and the time offsets.
    """
    C = len(model)
    zeros = lambda n: torch.zeros(n, dtype=torch.float64)  # noqa: E731
    p = Params(
        [x.clone() for x in intr],
        T_cam_rig.clone(),
        T_rig_board.clone(),
        zeros(2) if warp is None else warp.clone().to(torch.float64),
        zeros(C) if time_offsets is None else time_offsets.clone().to(torch.float64),
    )
    free = Free(opt_intr, opt_extr, opt_warp, opt_time and prob.velocity is not None, time_cameras)
    layout = Layout.make([x.numel() for x in intr], free)
    r, Jc, Jp = linearise(prob, model, layout, p)
    cost = huber_cost(prob, r, huber)
    if not math.isfinite(cost):
        return p.intr, p.T_cam_rig, p.T_rig_board, _result(False, cost, r, prob, C, 0, "non-finite initial residuals", math.nan, p)
    converged, reason, it, lam, gamma = False, "max iterations", 0, 1e-3, math.nan
    for it in range(1, iters + 1):
        eqs = Normal.build(prob, huber_weights(prob, r, huber), r, Jc, Jp)
        if it == 1 and opt_intr:
            gamma = _schur_gamma(eqs, layout)
        new, c_new, lam = _lm_step(prob, model, layout, p, eqs, cost, lam, huber)
        if new is None:
            # No decrease possible: at a minimum (converged) or stuck (divergent).
            converged, reason = True, "converged (no further decrease)"
            break
        rel = (cost - c_new) / max(cost, 1e-300)
        p = new
        r, Jc, Jp = linearise(prob, model, layout, p)
        cost = huber_cost(prob, r, huber)
        if rel < 1e-9:
            converged, reason = True, "converged"
            break
    return p.intr, p.T_cam_rig, p.T_rig_board, _result(converged, cost, r, prob, C, it, reason, gamma, p)


def _result(converged, cost, r, prob, C, it, reason, gamma, p: Params) -> SolveResult:
    e = r.norm(dim=-1)
    rms = [float(torch.sqrt((e[prob.cam == c] ** 2).mean())) if bool((prob.cam == c).any()) else float("nan") for c in range(C)]
    return SolveResult(converged, cost, rms, it, reason, e, gamma, p.warp, p.time_offsets)


def _schur_gamma(eqs: Normal, layout: Layout) -> float:
    """gamma = log10 kappa of the diagonally normalised pose-free Schur block of the intrinsics."""
    Ci = torch.linalg.pinv(eqs.Cm)
    S = eqs.A - torch.einsum("vai,vij,vbj->ab", eqs.B, Ci, eqs.B)
    idx = torch.cat([torch.arange(o, o + ni) for o, ni in layout.intr if ni])
    S = S[idx][:, idx]
    d = torch.diagonal(S).clamp_min(1e-300).rsqrt()
    ev = torch.linalg.eigvalsh(d[:, None] * S * d[None, :]).abs()
    return float(torch.log10(ev.max() / ev.min().clamp_min(1e-300)))


# --------------------------------------------------------------------------------------------
# Covariance of a solution
# --------------------------------------------------------------------------------------------
@dataclass
class Covariance:
    """The camera block's covariance at a solution, the target poses marginalised: sigma^2 S^-1,
    with S the pose-free Schur complement of the (Huber-weighted) normal equations and sigma^2
    the measured residual variance per pixel coordinate at weight 1."""

    layout: Layout
    cov: Tensor  # (n, n), in the units of the parameters (px, m, rad, s)
    sigma_px: float  # measured corner noise, px per coordinate
    dof: int  # residuals minus parameters

    def block(self, span: tuple[int, int]) -> Tensor:
        o, n = span
        return self.cov[o : o + n, o : o + n]

    def sigma(self, span: tuple[int, int]) -> Tensor:
        return torch.diagonal(self.block(span)).clamp_min(0).sqrt()


def covariance(
    prob: Problem,
    model: list[str],
    p: Params,
    *,
    free: Free,
    huber: float = 1.0,
    sigma_px: float | None = None,
) -> Covariance:
    """Covariance of the camera block of a converged solve (``free`` as it was solved). ``sigma_px``:
    the corner noise to scale by (default: measured from these residuals, sum w r^2 / dof)."""
    layout = Layout.make([x.numel() for x in p.intr], free)
    r, Jc, Jp = linearise(prob, model, layout, p)
    wr = huber_weights(prob, r, huber)
    eqs = Normal.build(prob, wr, r, Jc, Jp)
    # Poses eliminated with a pseudo-inverse: a view whose corners lie on one line leaves a pose
    # direction unconstrained, which carries nothing to the cameras (an inverse would blow it up).
    Ci = torch.linalg.pinv(eqs.Cm, hermitian=True, rtol=1e-10)
    S = eqs.A - torch.einsum("vai,vij,vbj->ab", eqs.B, Ci, eqs.B)
    dof = int(2 * prob.q.shape[0] - layout.n - 6 * prob.n_views)
    if sigma_px is None:
        sigma_px = math.sqrt(float((wr * (r * r).sum(-1)).sum()) / max(dof, 1))
    # The parameters' units differ by many orders (px, m, s, unitless distortion): invert S scaled
    # to a unit diagonal, or round-off gives negative variances.
    d = torch.diagonal(S).clamp_min(1e-300).rsqrt()
    ev, V = torch.linalg.eigh(d[:, None] * S * d[None, :])
    inv = (V / ev.clamp_min(1e-12 * float(ev.max()))) @ V.T
    cov = sigma_px**2 * d[:, None] * inv * d[None, :]
    return Covariance(layout, cov, sigma_px, dof)
