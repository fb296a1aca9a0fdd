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
from scipy import sparse

from cotrain.geometry import cameras, poses
from cotrain.io.sequence import Observation
from cotrain.targets import Target, board_points

Array = np.ndarray  # float64 throughout (int64 for indices); no torch in this package

# Derivatives of the projection by the five-point central difference in float64,
# f' = (f(-2h) - 8 f(-h) + 8 f(h) - f(2h)) / 12h: truncation O(h^4) and round-off O(eps / h) balance
# at h of about eps^(1/5) (1e-3) times each variable's scale, both then near 1e-12 relative (autograd
# agrees to that in tests/calibration/test_jacobians.py), so the LM iterates follow those of exact
# derivatives. Chosen over forward-mode or per-model analytic derivatives because it runs through
# the one shared camera model (:mod:`cotrain.geometry.cameras`) unchanged, batched in one call per
# Jacobian; the plain three-point difference (error near 1e-9) was measurably less faithful on the
# poorly determined distortion terms.
_FD_STEP = 1e-3  # points: times their distance
_FD_STEP_SHAPE = 2e-4  # shape parameters (xi, alpha, ...: strongly curved near the domain's edge): times max(|value|, 1)
_FD_TAPS = np.array([-2.0, -1.0, 1.0, 2.0])  # step multiples ...
_FD_WEIGHTS = np.array([1.0, -8.0, 8.0, -1.0]) / 12.0  # ... and their weights (divided by h)


def _stencil(f_of_steps: Array, h: Array) -> Array:
    """Derivative from the projections at the four taps: ``f_of_steps`` (4, K, ...) -> (K, ...),
    ``h`` broadcasting against (K, ...)."""
    return np.tensordot(_FD_WEIGHTS, f_of_steps, axes=1) / h


# --------------------------------------------------------------------------------------------
# Residuals and Jacobians
# --------------------------------------------------------------------------------------------
def retract(T: Array, d: Array) -> Array:
    """Left increment: (R, t) -> (Exp(w) R, Exp(w) t + v), d = (w, v)."""
    R = poses.rotation_from_axis_angle(d[..., :3])
    return poses.make_pose(R @ T[..., :3, :3], (R @ T[..., :3, 3:])[..., 0] + d[..., 3:])


def _skew(p: Array) -> Array:
    """(O, 3) -> (O, 3, 3) with skew(p) w = p x w."""
    z = np.zeros_like(p[:, 0])
    return np.stack([np.stack([z, -p[:, 2], p[:, 1]], -1), np.stack([p[:, 2], z, -p[:, 0]], -1), np.stack([-p[:, 1], p[:, 0], z], -1)], -2)


def project_with_jacobians(model: str, p: Array, intr: Array) -> tuple[Array, Array, Array, Array]:
    """q (O, 2), valid (O,), d q / d p (O, 2, 3) and d q / d intr (O, 2, P) through the shared
    camera model.

    fx, fy, cx, cy enter every family as q = (fx mx + cx, fy my + cy) with (mx, my) free of them,
    so their columns are exact. The others (d q / d p and the shape parameters) are five-point
    central differences in float64 (see ``_FD_STEP``): each point's step scaled by its distance,
    each shape parameter's by max(|value|, 1) (``_FD_STEP_SHAPE``), all perturbations evaluated in
    one batched call per block."""
    m = cameras.get_model(model)
    p = np.asarray(p, dtype=np.float64)
    intr = np.asarray(intr, dtype=np.float64)
    q, valid = m.project(p, intr)
    n_obs, P = p.shape[0], intr.shape[-1]
    # d q / d p: 3 coordinates at 4 taps, as a leading batch of 12.
    h = _FD_STEP * np.maximum(np.linalg.norm(p, axis=-1), 1e-6)  # (O,)
    dp = np.eye(3)[:, None, :] * h[None, :, None]  # (3, O, 3)
    qp, _ = m.project(p + _FD_TAPS[:, None, None, None] * dp, intr)  # (4, 3, O, 2)
    Jq_p = _stencil(qp, h[None, :, None]).transpose(1, 2, 0)
    Ji = np.zeros((n_obs, 2, P))
    ifx, ify, icx, icy = (m.index(n) for n in ("fx", "fy", "cx", "cy"))
    Ji[:, 0, ifx] = (q[:, 0] - intr[icx]) / intr[ifx]
    Ji[:, 1, ify] = (q[:, 1] - intr[icy]) / intr[ify]
    Ji[:, 0, icx] = 1.0
    Ji[:, 1, icy] = 1.0
    shape = [m.index(n) for n in m.shape_names]
    if shape:
        hs = _FD_STEP_SHAPE * np.maximum(np.abs(intr[shape]), 1.0)  # (S,)
        di = np.zeros((len(shape), P))
        di[np.arange(len(shape)), shape] = hs
        qs, _ = m.project(p, (intr + _FD_TAPS[:, None, None] * di)[:, :, None, :])  # (4, S, O, 2)
        Ji[:, :, shape] = _stencil(qs, hs[:, None, None]).transpose(1, 2, 0)
    return q, valid, Jq_p, Ji


def observation_jacobians(model: str, intr: Array, T_cam_rig: Array, T_rig_board: Array, X: Array):
    """Per observation (O): predicted q (O, 2), d q / d intr (O, 2, P), d q / d cam increment
    (O, 2, 6) and d q / d pose increment (O, 2, 6). Poses are gathered per observation; the
    increments are the left perturbations of :func:`retract` (rotation first)."""
    q, Ji, Jc, Jp, _ = observation_blocks(model, intr, T_cam_rig, T_rig_board, X)
    return q, Ji, Jc, Jp


def observation_blocks(model: str, intr: Array, T_cam_rig: Array, T_rig_board: Array, X: Array):
    """:func:`observation_jacobians` plus d q / d z (O, 2): the corner moved along the board's z
    axis (the board's out-of-plane warp)."""
    p_r = (T_rig_board[:, :3, :3] @ X[:, :, None])[..., 0] + T_rig_board[:, :3, 3]
    R_c = T_cam_rig[:, :3, :3]
    p_c = (R_c @ p_r[:, :, None])[..., 0] + T_cam_rig[:, :3, 3]
    q, _, Jq_p, Ji = project_with_jacobians(model, p_c, intr)
    eye = np.broadcast_to(np.eye(3, dtype=X.dtype), (X.shape[0], 3, 3))
    d_cam = np.concatenate([-_skew(p_c), eye], -1)  # d p_c / d (w_c, v_c)
    d_pose = R_c @ np.concatenate([-_skew(p_r), eye], -1)  # d p_c / d (w_p, v_p)
    d_z = R_c @ T_rig_board[:, :3, 2:3]  # d p_c / d z_board
    return q, Ji, Jq_p @ d_cam, Jq_p @ d_pose, (Jq_p @ d_z)[..., 0]


# --------------------------------------------------------------------------------------------
# The problem, its parameters and their column layout
# --------------------------------------------------------------------------------------------
def warp_basis(X: Array, points: Array) -> Array:
    """mrcal's two-parameter board warp: the out-of-plane offset of a corner at board point X
    (O, 3) is ``k_x (1 - x^2) + k_y (1 - y^2)``, x and y running from -1 to 1 over the extent of
    the target's corner grid ``points`` (N, 3). Returns the basis (O, 2), 1 at the grid's centre."""
    lo, hi = points[:, :2].min(0), points[:, :2].max(0)
    u = (2 * X[:, :2] - (lo + hi)) / np.maximum(hi - lo, 1e-12)
    return 1 - u * u


@dataclass
class Problem:
    """Observations flattened: per corner o, its camera, view, board point and pixel."""

    cam: Array  # (O,) int64
    view: Array  # (O,) int64, index into the active views
    X: Array  # (O, 3) board coordinates (m)
    q: Array  # (O, 2) pixels
    w: Array  # (O,) observation weights
    n_views: int
    warp_basis: Array | None = None  # (O, 2) :func:`warp_basis` of each corner
    velocity: Array | None = None  # (V, 6) at each view: the board's angular velocity (rad/s, rig frame) and its origin's velocity (m/s)
    acceleration: Array | None = None  # (V, 6) their rates of change (per second); None: constant velocity

    @staticmethod
    def build(obs: list[Observation], board: Target, view_index: dict[int, int], single_camera: bool = False) -> Problem:
        """Flatten ``obs``; ``single_camera`` maps every observation to camera 0 (per-camera stages)."""
        P = board_points(board)
        cam, view, X, q, w = [], [], [], [], []
        for o in obs:
            cam.append(np.full(len(o.ids), 0 if single_camera else o.cam))
            view.append(np.full(len(o.ids), view_index[o.view]))
            X.append(P[o.ids])
            q.append(o.q)
            w.append(o.weight)
        t = lambda a, dt=np.float64: np.concatenate(a).astype(dt)  # noqa: E731
        Xt = t(X)
        return Problem(t(cam, np.int64), t(view, np.int64), Xt, t(q), t(w), len(view_index), warp_basis(Xt, P))

    def select(self, keep: Array, one_camera: bool = False) -> tuple[Problem, Array]:
        """The corners ``keep`` (O,) bool, their views renumbered in order; ``one_camera`` maps them
        to camera 0. Returns the sub-problem and its views' indices in this one (V',)."""
        views = np.unique(self.view[keep])  # sorted
        index = np.full((self.n_views,), -1, dtype=np.int64)
        index[views] = np.arange(len(views))
        rows = lambda a: a[views] if a is not None else None  # noqa: E731
        cam = np.zeros(int(keep.sum()), dtype=np.int64) if one_camera else self.cam[keep]
        basis = self.warp_basis[keep] if self.warp_basis is not None else None
        sub = Problem(cam, index[self.view[keep]], self.X[keep], self.q[keep], self.w[keep], len(views), basis)
        sub.velocity, sub.acceleration = rows(self.velocity), rows(self.acceleration)
        return sub, views


@dataclass
class Params:
    """Everything the solver estimates."""

    intr: list[Array]  # per camera, Kalibr order
    T_cam_rig: Array  # (C, 4, 4); cam0 is the gauge
    T_rig_board: Array  # (V, 4, 4), the board at each view's time (cam0's stamp)
    warp: Array  # (2,) m: the board's out-of-plane offset at its centre along x and y (z into the board)
    time_offsets: Array  # (C,) s: camera c sees the board of view v as it was at t_v + time_offsets[c]

    def clone(self) -> Params:
        return Params(
            [x.copy() for x in self.intr], self.T_cam_rig.copy(), self.T_rig_board.copy(), self.warp.copy(), self.time_offsets.copy()
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


def _effective(prob: Problem, p: Params, sel: Array, c: int) -> tuple[Array, Array, Array]:
    """For camera c's corners ``sel``: the board pose it saw, the warped board points, and the
    pose's rate of change with the time offset as a left increment (O, 6).

    The board seen dt after the view's stamp, to second order: R = Exp(dt w + dt^2 alpha / 2) R_v,
    t = t_v + dt u + dt^2 a / 2 (``Problem.velocity`` = (w, u), ``Problem.acceleration`` =
    (alpha, a)). Its rate as a left increment: (w + dt alpha, u + dt a - (w + dt alpha) x t)."""
    T_rb = p.T_rig_board[prob.view[sel]]
    zero = np.zeros((len(sel), 6))
    vel = prob.velocity[prob.view[sel]] if prob.velocity is not None else zero
    acc = prob.acceleration[prob.view[sel]] if prob.acceleration is not None else zero
    dt = p.time_offsets[c]
    if float(dt) != 0.0:
        d = dt * vel + 0.5 * dt * dt * acc
        R = poses.rotation_from_axis_angle(d[:, :3]) @ T_rb[:, :3, :3]
        T_rb = poses.make_pose(R, T_rb[:, :3, 3] + d[:, 3:])
    rate = vel + dt * acc
    rate = np.concatenate([rate[:, :3], rate[:, 3:] - np.cross(rate[:, :3], T_rb[:, :3, 3])], -1)
    X = prob.X[sel]
    if prob.warp_basis is not None and bool((p.warp != 0).any()):
        X = X.copy()
        X[:, 2] = X[:, 2] + prob.warp_basis[sel] @ p.warp
    return T_rb, X, rate


def residuals(prob: Problem, model: list[str], p: Params) -> Array:
    """Observed minus predicted pixels (O, 2)."""
    r = np.zeros((prob.q.shape[0], 2))
    for c in range(len(model)):
        sel = np.flatnonzero(prob.cam == c)
        if not len(sel):
            continue
        T_rb, X, _ = _effective(prob, p, sel, c)
        T = p.T_cam_rig[c] @ T_rb
        pc = (T[:, :3, :3] @ X[:, :, None])[..., 0] + T[:, :3, 3]
        r[sel] = prob.q[sel] - cameras.project(model[c], pc, p.intr[c])[0]
    return r


def linearise(prob: Problem, model: list[str], layout: Layout, p: Params) -> tuple[Array, Array, Array]:
    """Residuals (O, 2), d q / d camera block (O, 2, n) and d q / d pose increment (O, 2, 6)."""
    n_obs = prob.q.shape[0]
    r = np.zeros((n_obs, 2))
    Jc = np.zeros((n_obs, 2, max(1, layout.n)))
    Jp = np.zeros((n_obs, 2, 6))
    for c in range(len(model)):
        sel = np.flatnonzero(prob.cam == c)
        if not len(sel):
            continue
        T_rb, X, vel = _effective(prob, p, sel, c)
        qh, Ji, Jx, Jpose, Jz = observation_blocks(model[c], p.intr[c], np.broadcast_to(p.T_cam_rig[c], (len(sel), 4, 4)), T_rb, X)
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


def huber_weights(prob: Problem, r: Array, huber: float) -> Array:
    """IRLS weights (O,): the observation weight times the Huber kernel's weight of each corner."""
    e = np.linalg.norm(r, axis=-1)
    return prob.w * np.where(e < huber, 1.0, huber / np.maximum(e, 1e-12))


def huber_cost(prob: Problem, r: Array, huber: float) -> float:
    e = np.linalg.norm(r, axis=-1)
    rho = np.where(e < huber, 0.5 * e * e, huber * (e - 0.5 * huber))
    return float((prob.w * rho).sum())


@dataclass
class Normal:
    """The normal equations in blocks: camera block A (n, n) and gradient g_c (n,), per view the
    coupling B (V, n, 6), the pose block Cm (V, 6, 6) and gradient g_p (V, 6)."""

    A: Array
    g_c: Array
    B: Array
    Cm: Array
    g_p: Array

    @staticmethod
    def build(prob: Problem, wr: Array, r: Array, Jc: Array, Jp: Array) -> Normal:
        V, n, n_obs = prob.n_views, Jc.shape[-1], Jc.shape[0]
        # The residual is q - q_hat, so J of the residual is -J of q_hat: the signs cancel in g.
        wJc, wJp = wr[:, None, None] * Jc, wr[:, None, None] * Jp
        A = wJc.reshape(2 * n_obs, n).T @ Jc.reshape(2 * n_obs, n)
        g_c = wJc.reshape(2 * n_obs, n).T @ r.reshape(2 * n_obs)
        # Per-view sums of per-corner blocks (torch's index_add_): one sparse (V, O) incidence product.
        by_view = sparse.csr_matrix((np.ones(n_obs), (prob.view, np.arange(n_obs))), shape=(V, n_obs))
        wJp_t = wJp.transpose(0, 2, 1)
        per = [(wJc.transpose(0, 2, 1) @ Jp).reshape(n_obs, -1), (wJp_t @ Jp).reshape(n_obs, 36), (wJp_t @ r[:, :, None])[..., 0]]
        sums = np.asarray(by_view @ np.concatenate(per, 1))
        B, Cm, g_p = sums[:, : n * 6].reshape(V, n, 6), sums[:, n * 6 : n * 6 + 36].reshape(V, 6, 6), sums[:, n * 6 + 36 :]
        return Normal(A, g_c, B, Cm, g_p)

    def schur(self, lam: float = 0.0) -> tuple[Array, Array, Array]:
        """Poses eliminated at Levenberg-Marquardt damping ``lam``: S (n, n), its right-hand side
        (n,) and the damped pose blocks' inverses (V, 6, 6)."""
        Ad = self.A + lam * np.diag(np.maximum(np.diagonal(self.A), 1e-9))
        cd = np.maximum(np.diagonal(self.Cm, axis1=-2, axis2=-1), 1e-9)  # (V, 6)
        Cd = self.Cm + lam * cd[:, :, None] * np.eye(6)
        Ci = np.linalg.inv(Cd + 1e-12 * np.eye(6))
        S = Ad - _sandwich(self.B, Ci)
        rhs = self.g_c - np.einsum("vai,vi->a", self.B, (Ci @ self.g_p[:, :, None])[..., 0])
        return S, rhs, Ci


def _sandwich(B: Array, Ci: Array) -> Array:
    """sum over views of B_v Ci_v B_v^T (n, n), for B (V, n, 6) and Ci (V, 6, 6)."""
    V, n = B.shape[0], B.shape[1]
    BC = B @ Ci  # (V, n, 6)
    return BC.transpose(1, 0, 2).reshape(n, V * 6) @ B.transpose(1, 0, 2).reshape(n, V * 6).T


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
    residuals: Array  # (O,) per-corner error norm (px)
    schur_cond: float  # gamma: log10 condition of the normalised pose-free intrinsic Schur block
    warp: Array | None = None  # (2,) m, the board warp at the end (zeros unless estimated)
    time_offsets: Array | None = None  # (C,) s, the cameras' time offsets at the end


def _apply(p: Params, dc: Array, dp: Array, layout: Layout, model: list[str]) -> Params:
    """The parameters moved by camera-block increment dc (n,) and pose increments dp (V, 6)."""
    new = Params(list(p.intr), p.T_cam_rig.copy(), retract(p.T_rig_board, dp), p.warp.copy(), p.time_offsets.copy())
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
            dc = np.linalg.solve(S, rhs) if layout.n else np.zeros(0)
        except np.linalg.LinAlgError:
            lam *= 10
            continue
        dp = (Ci @ (eqs.g_p - np.einsum("vai,a->vi", eqs.B, dc))[:, :, None])[..., 0]
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
    intr: list[Array],
    T_cam_rig: Array,
    T_rig_board: Array,
    *,
    opt_intr: bool = True,
    opt_extr: bool = False,
    opt_warp: bool = False,
    opt_time: bool = False,
    time_cameras: frozenset[int] | None = None,
    warp: Array | None = None,
    time_offsets: Array | None = None,
    iters: int = 30,
    huber: float = 1.0,
) -> tuple[list[Array], Array, Array, SolveResult]:
    """Levenberg-Marquardt with the target poses eliminated by the Schur complement.

    Camera parameters: intrinsics of every camera (if ``opt_intr``), extrinsics of cameras 1..
    (if ``opt_extr``; cam0 is the gauge), the board warp (if ``opt_warp``) and cameras 1..'s time
    offsets (if ``opt_time``; only ``time_cameras`` where given; needs ``prob.velocity``). Target poses T_rig_board (V, 4, 4) are
    always optimised. Returns updated (intr, T_cam_rig, T_rig_board, result); the result carries
    the warp and the time offsets.
    """
    C = len(model)
    f64 = lambda x: np.array(x, dtype=np.float64)  # noqa: E731  (copies)
    p = Params(
        [f64(x) for x in intr],
        f64(T_cam_rig),
        f64(T_rig_board),
        np.zeros(2) if warp is None else f64(warp),
        np.zeros(C) if time_offsets is None else f64(time_offsets),
    )
    free = Free(opt_intr, opt_extr, opt_warp, opt_time and prob.velocity is not None, time_cameras)
    layout = Layout.make([np.size(x) for x in intr], free)
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


def solve_params(prob: Problem, models: list[str], p: Params, free: Free, iters: int, huber: float) -> tuple[Params, SolveResult]:
    """:func:`solve` from the named parameters ``p``, freeing the groups ``free`` names (the board
    poses always); returns the solved parameters and the result."""
    intr, Tcr, Tb, res = solve(
        prob,
        models,
        p.intr,
        p.T_cam_rig,
        p.T_rig_board,
        opt_intr=free.intr,
        opt_extr=free.extr,
        opt_warp=free.warp,
        opt_time=free.time,
        time_cameras=free.time_cameras,
        warp=p.warp,
        time_offsets=p.time_offsets,
        iters=iters,
        huber=huber,
    )
    return Params(list(intr), Tcr, Tb, res.warp, res.time_offsets), res


def _result(converged, cost, r, prob, C, it, reason, gamma, p: Params) -> SolveResult:
    e = np.linalg.norm(r, axis=-1)
    rms = [float(np.sqrt((e[prob.cam == c] ** 2).mean())) if bool((prob.cam == c).any()) else float("nan") for c in range(C)]
    return SolveResult(converged, cost, rms, it, reason, e, gamma, p.warp, p.time_offsets)


def _schur_gamma(eqs: Normal, layout: Layout) -> float:
    """gamma = log10 kappa of the diagonally normalised pose-free Schur block of the intrinsics."""
    Ci = np.linalg.pinv(eqs.Cm, rcond=6 * np.finfo(np.float64).eps)  # torch's default rtol, max(m, n) eps
    S = eqs.A - _sandwich(eqs.B, Ci)
    idx = np.concatenate([np.arange(o, o + ni) for o, ni in layout.intr if ni])
    S = S[idx][:, idx]
    d = 1 / np.sqrt(np.maximum(np.diagonal(S), 1e-300))
    ev = np.abs(np.linalg.eigvalsh(d[:, None] * S * d[None, :]))
    return float(np.log10(ev.max() / max(ev.min(), 1e-300)))


# --------------------------------------------------------------------------------------------
# Covariance of a solution
# --------------------------------------------------------------------------------------------
@dataclass
class Covariance:
    """The camera block's covariance at a solution, the target poses marginalised: sigma^2 S^-1,
    with S the pose-free Schur complement of the (Huber-weighted) normal equations and sigma^2
    the measured residual variance per pixel coordinate at weight 1."""

    layout: Layout
    cov: Array  # (n, n), in the units of the parameters (px, m, rad, s)
    sigma_px: float  # measured corner noise, px per coordinate
    dof: int  # residuals minus parameters

    def block(self, span: tuple[int, int]) -> Array:
        o, n = span
        return self.cov[o : o + n, o : o + n]

    def sigma(self, span: tuple[int, int]) -> Array:
        return np.sqrt(np.maximum(np.diagonal(self.block(span)), 0))


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
    layout = Layout.make([np.size(x) for x in p.intr], free)
    r, Jc, Jp = linearise(prob, model, layout, p)
    wr = huber_weights(prob, r, huber)
    eqs = Normal.build(prob, wr, r, Jc, Jp)
    # Poses eliminated with a pseudo-inverse: a view whose corners lie on one line leaves a pose
    # direction unconstrained, which carries nothing to the cameras (an inverse would blow it up).
    Ci = np.linalg.pinv(eqs.Cm, rcond=1e-10, hermitian=True)  # relative to the largest singular value, as torch's rtol
    S = eqs.A - _sandwich(eqs.B, Ci)
    dof = int(2 * prob.q.shape[0] - layout.n - 6 * prob.n_views)
    if sigma_px is None:
        sigma_px = math.sqrt(float((wr * (r * r).sum(-1)).sum()) / max(dof, 1))
    # The parameters' units differ by many orders (px, m, s, unitless distortion): invert S scaled
    # to a unit diagonal, or round-off gives negative variances.
    d = 1 / np.sqrt(np.maximum(np.diagonal(S), 1e-300))
    ev, V = np.linalg.eigh(d[:, None] * S * d[None, :])
    inv = (V / np.maximum(ev, 1e-12 * float(ev.max()))) @ V.T
    cov = sigma_px**2 * d[:, None] * inv * d[None, :]
    return Covariance(layout, cov, sigma_px, dof)
