"""The calibration solver: Levenberg-Marquardt over camera intrinsics, camera poses in the rig and
target poses, with the target poses eliminated by the Schur complement and a Huber kernel.

Each camera model owns its parameters and their bounds (:class:`cotrain.geometry.cameras.CameraModel`):
the solver clamps an increment with ``model.clamp`` and never knows parameter positions. Pose
increments are left perturbations (:func:`retract`, rotation first).
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
            qh, Ji, Jc, Jp = observation_jacobians(
                model[c], intr[c], T_cam_rig[c].expand(len(sel), 4, 4), T_rig_board[prob.view[sel]], prob.X[sel]
            )
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
                    new_T[c] = retract(T_cam_rig[c], dc[o + ni : o + ni + ne])
            new_P = retract(T_rig_board, dp)
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
