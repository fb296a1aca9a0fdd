"""Multi-camera fisheye calibration (paper Sec. III-A): staged pipeline over the shared camera models.

1. Intrinsic initialisation per camera: a guess from the rough FoV and image size, per-view target
   poses from bearing vectors (valid beyond 90 degrees off-axis), frames added progressively
   (anchors first when the selector is on) with the intrinsics re-estimated at each step; the
   conditioning score gamma_k is recorded at every step.
2. Intrinsic refinement over all selected views of each camera (with outlier rejection).
3. Full calibration: extrinsics initialised from co-visible views, then intrinsics, extrinsics
   and target poses optimised together.

The solver (:mod:`calib_eval.calibration.solver`) is Levenberg-Marquardt on the block structure:
target poses (6 each) are eliminated with the Schur complement, leaving a small system in the
camera parameters. Robust kernel: Huber. Initial values: :mod:`calib_eval.calibration.initialisation`.
Names follow docs/conventions.md: ``T_cam_rig`` (cam0 is the rig), ``T_rig_board`` per view.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from calib_eval.calibration.initialisation import average_pose, focal_search, initial_guess, view_pose
from calib_eval.calibration.solver import Free, Params, Problem, SolveResult, covariance, residuals, solve, solve_params
from calib_eval.calibration.time_offset import OffsetEstimate, TimeOffsetConfig, board_velocities, estimable_cameras
from cotrain.geometry import cameras
from cotrain.io.sequence import Observation, Sequence
from cotrain.targets import Target, board_points


@dataclass
class CalibConfig:
    model: str = "kb4"  # camera family for every camera (kb4, ucm, eucm, ds, or Kalibr's pinhole-equi, omni-none, ...)
    models: list[str] = field(default_factory=list)  # one family per camera (a mixed rig); empty: ``model`` for all
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
    view_outlier_px: float = 3.0  # after the joint stage, an observation whose median corner error exceeds this ...
    view_outlier_ratio: float = 5.0  # ... and this many times its camera's median over observations drops its view (a wrong board)
    view_outlier_cap_px: float = 10.0  # ... the threshold never exceeds this (a camera whose median is itself off)
    flat_board: bool = False  # True: the board is taken as flat; False: its two-parameter warp is estimated in stage 3
    time_offset: str = "estimate"  # "estimate": report each camera's offset to cam0; "auto": calibrate with it applied; "off"
    time_offsets_s: dict[int, float] = field(default_factory=dict)  # camera -> offset (s) set by hand (applied; not estimated)
    timing: TimeOffsetConfig = field(default_factory=TimeOffsetConfig)


class CalibrationFailed(RuntimeError):
    """Raised inside the pipeline; :func:`calibrate` turns it into a failure report."""


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
    dropped: list[dict] = field(default_factory=list)  # views dropped as a whole: view, frame, cameras, reason
    rejected: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)  # (cam, view) -> corner ids stage 2 dropped (outliers)
    warp_m: np.ndarray = field(default_factory=lambda: np.zeros(2))  # the board's warp (k_x, k_y), m at its centre (0: flat)
    time_offsets_s: np.ndarray | None = None  # (C,) the offsets the result was calibrated with (s; zeros: none applied)
    time_offset_estimates: list[OffsetEstimate] = field(default_factory=list)  # cameras 1..: estimated offsets, or why not
    final: FinalSolve | None = None  # the joint stage's problem and solution (for the uncertainty and cross-validation)
    timed: FinalSolve | None = None  # the solve with the time offsets estimated (where they were), applied or not


@dataclass
class FinalSolve:
    """The joint stage's last problem and its solution: what the trust checks linearise."""

    used: list[Observation]  # the observations of the problem
    views: list[int]  # view ids in the problem's view order
    problem: Problem
    params: Params
    free: Free
    huber: float


def _intrinsic_stage(
    model: str, intr: np.ndarray, obs: list[Observation], board: Target, cfg: CalibConfig, progressive: bool
) -> tuple[np.ndarray, dict[int, np.ndarray], list[float], SolveResult]:
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
                T = view_pose(model, intr, o, board)
                if T is None:
                    continue
                poses_cb[o.view] = T
            active.append(o)
        if len(active) < 2:
            continue
        vi = {o.view: i for i, o in enumerate(active)}
        prob = Problem.build(active, board, vi, single_camera=True)
        Tb = np.stack([poses_cb[o.view] for o in active])
        iters = cfg.init_iters if progressive else cfg.refine_iters
        out_intr, _, Tb, res = solve(prob, [model], [intr], np.eye(4)[None], Tb, iters=iters, huber=cfg.huber_px)
        gammas.append(res.schur_cond)
        if not all(math.isfinite(v) for v in res.rms):
            raise CalibrationFailed(f"intrinsic {'initialisation' if progressive else 'refinement'} diverged at {k} frames")
        intr = out_intr[0]
        for o, T in zip(active, Tb):
            poses_cb[o.view] = T
    if res is None:
        raise CalibrationFailed("too few usable views to initialise the intrinsics")
    return intr, poses_cb, gammas, res


def calibrate(seq: Sequence, cfg: CalibConfig, order: dict[int, list[int]] | None = None) -> CalibrationResult:
    """Run the staged pipeline on ``seq``.

    ``order``: per camera, the views in the order stage 1 should add them (the selector's anchors
    first); default: sequence order. Never raises for a bad sequence: the result says why.
    """
    t0 = time.time()
    board = seq.target
    C = len(seq.cameras)
    models = list(cfg.models or [cfg.model] * C)  # as given; our names once resolved below
    frames: dict[str, list[int]] = {}
    gammas: list[list[float]] = [[] for _ in range(C)]
    stages: list[dict] = []

    def fail(reason: str, intr=None, T_cr=None) -> CalibrationResult:
        return _failure(reason, models, C, frames, gammas, time.time() - t0, stages, intr, T_cr)

    if len(models) != C:
        return fail(f"{len(models)} camera models given for {C} cameras")
    try:
        models[:] = [cameras.model_from_name(n) for n in models]
    except ValueError as e:
        return fail(str(e))
    if board is None:
        return fail("the sequence names no target (its detections carry none)")
    obs_by_cam = _usable_observations(seq, cfg, order)
    if isinstance(obs_by_cam, str):
        return fail(obs_by_cam)

    # Stages 1 and 2, per camera.
    intr: list[np.ndarray] = []
    cam_poses: list[dict[int, np.ndarray]] = []
    rejected: dict[tuple[int, int], np.ndarray] = {}
    try:
        for c in range(C):
            fit = _camera_stages(seq, c, models[c], obs_by_cam[c], cfg)
            gammas[c] = fit.gamma
            stages.extend(fit.stages)
            rejected.update(fit.rejected)
            obs_by_cam[c] = fit.obs
            for stage, n in fit.frames.items():
                frames.setdefault(stage, []).append(n)
            intr.append(fit.intr)
            cam_poses.append(fit.poses)
    except CalibrationFailed as e:
        return fail(str(e), intr)

    # Stage 3: extrinsics from co-visible views (spanning tree from cam0), then everything jointly.
    if cfg.no_init:
        for c in range(C):
            cam_poses[c] = {o.view: T for o in obs_by_cam[c] if (T := view_pose(models[c], intr[c], o, board)) is not None}
    T_cam_rig, missing = _initial_extrinsics(cam_poses)
    if missing:
        names = ", ".join(seq.cameras[c].name for c in missing)
        return fail(f"no co-visible views link {names} to cam0: extrinsics cannot be initialised", intr, T_cam_rig)
    T_rig_board = _initial_board_poses(cam_poses, T_cam_rig)
    joint = _JointStage(seq, models, cfg, board)
    dropped: list[dict] = []
    no_poses = np.zeros((0, 4, 4))  # set per round from T_rig_board
    start = Params(intr, T_cam_rig.copy(), no_poses, np.zeros(2), joint.fixed_offsets)
    obs_before = obs_by_cam
    out = joint.run(obs_by_cam, T_rig_board, start, dropped, stages)
    if isinstance(out, str):
        return fail(out, intr, T_cam_rig)
    final, res = out
    obs_by_cam = [[o for o in final.used if o.cam == c] for c in range(C)]
    frames["full"] = [len(obs_by_cam[c]) for c in range(C)]
    estimates: list[OffsetEstimate] = []
    timed = None
    if cfg.time_offset in ("estimate", "auto") and C > 1 and not cfg.time_offsets_s:
        estimates, timed, dropped = _time_offset_stage(joint, final, obs_before, T_rig_board, start, dropped, stages)
        if timed is not None and cfg.time_offset == "auto":
            final, res = timed
        stages.append({"stage": "time offsets", "rms_px": res.rms, "iterations": res.iterations, "reason": res.reason})
    stages.append({"stage": "full", "rms_px": res.rms, "iterations": res.iterations, "reason": res.reason})
    return _finish(final, res, models, cfg, time.time() - t0, frames, gammas, stages, dropped, rejected, estimates, timed)


def _failure(reason, models, C, frames, gammas, runtime, stages, intr=None, T_cr=None) -> CalibrationResult:
    return CalibrationResult(
        False,
        reason,
        list(models),
        [np.asarray(x) for x in (intr or [])],
        T_cr if T_cr is not None else np.tile(np.eye(4), (C, 1, 1)),
        {},
        [float("nan")] * C,
        frames,
        gammas,
        runtime,
        stages,
    )


def _initial_board_poses(cam_poses: list[dict[int, np.ndarray]], T_cam_rig: np.ndarray) -> dict[int, np.ndarray]:
    """T_rig_board per view: the average of what the cameras that saw it imply."""
    out = {}
    for v in sorted({v for poses in cam_poses for v in poses}):
        cands = [np.linalg.inv(T_cam_rig[c]) @ poses[v] for c, poses in enumerate(cam_poses) if v in poses]
        out[v] = cands[0] if len(cands) == 1 else average_pose(cands)
    return out


def _usable_observations(seq: Sequence, cfg: CalibConfig, order: dict[int, list[int]] | None) -> list[list[Observation]] | str:
    """Per camera, its observations with enough corners, in the order stage 1 adds them; or why
    a camera has too few."""
    out = []
    for c in range(len(seq.cameras)):
        ob = [o for o in seq.by_camera(c) if len(o.ids) >= cfg.min_corners]
        if order and c in order:
            rank = {v: i for i, v in enumerate(order[c])}
            ob.sort(key=lambda o: rank.get(o.view, len(rank) + o.view))
        else:
            ob.sort(key=lambda o: o.view)
        if len(ob) < cfg.min_views:
            return f"{seq.cameras[c].name}: only {len(ob)} usable views of the target (need {cfg.min_views})"
        out.append(ob)
    return out


def _finish(final, res, models, cfg, runtime, frames, gammas, stages, dropped, rejected, estimates, timed) -> CalibrationResult:
    """The result of the final joint solve: success where every camera's RMS is within bounds."""
    p = final.params
    intr_np = [np.asarray(x) for x in p.intr]
    T_cr = np.asarray(p.T_cam_rig)
    ok_finite = all(np.isfinite(x).all() for x in intr_np) and np.isfinite(T_cr).all()
    worst = max(res.rms) if res.rms and all(math.isfinite(x) for x in res.rms) else float("nan")
    success = ok_finite and math.isfinite(worst) and worst <= cfg.max_rms_px
    reason = "ok" if success else (f"final RMS {worst:.2f} px exceeds {cfg.max_rms_px} px" if ok_finite else "non-finite parameters")
    T_rb = {v: p.T_rig_board[i] for i, v in enumerate(final.views)}
    return CalibrationResult(
        success,
        reason,
        models,
        intr_np,
        T_cr,
        T_rb,
        res.rms,
        frames,
        gammas,
        runtime,
        stages,
        dropped,
        rejected,
        p.warp.copy(),
        p.time_offsets.copy(),
        estimates,
        final,
        timed[0] if timed is not None else None,
    )


@dataclass
class _CameraFit:
    """Stages 1 and 2 of one camera."""

    intr: np.ndarray
    poses: dict[int, np.ndarray]  # view -> T_cam_board
    obs: list[Observation]  # the observations kept (outlier corners removed)
    rejected: dict[tuple[int, int], np.ndarray]  # (cam, view) -> corner ids dropped as outliers
    gamma: list[float]
    stages: list[dict]
    frames: dict[str, int]  # stage -> observations


def _camera_stages(seq: Sequence, c: int, model: str, obs: list[Observation], cfg: CalibConfig) -> _CameraFit:
    """Intrinsic initialisation (stage 1, progressive, gamma recorded) and refinement with outlier
    rejection (stage 2) of camera c. Raises :class:`CalibrationFailed`."""
    board, info = seq.target, seq.cameras[c]
    guess = initial_guess(model, cfg.fov, info.width, info.height, cfg.shared_intrinsics_guess_radius)
    guess = focal_search(model, guess, obs, board)
    if cfg.no_init:
        return _CameraFit(guess, {}, obs, {}, [], [], {"init": 0})
    x, pc_, gamma, res = _intrinsic_stage(model, guess, obs, board, cfg, progressive=True)
    stages = [{"stage": "init", "camera": c, "rms_px": res.rms[0], "iterations": res.iterations, "reason": res.reason}]
    # Stage 2: refinement over all views, then outlier rejection and a final pass.
    x, pc_, _, res = _intrinsic_stage(model, x, obs, board, cfg, progressive=False)
    keep = _reject_outliers(obs, pc_, model, x, board, cfg)
    if _whole_views_lost(obs, keep):
        # A view's pose is initialised with the intrinsics it starts from; a view at the rim posed
        # with stage 1's can stay in a wrong minimum and lose all its corners. Pose every view
        # again with the refined intrinsics before judging corners.
        x, pc_, _, res = _intrinsic_stage(model, x, obs, board, cfg, progressive=False)
        keep = _reject_outliers(obs, pc_, model, x, board, cfg)
    kept_ids = {o.view: o.ids for o in keep}
    rejected = {}
    for o in obs:
        gone = np.setdiff1d(o.ids, kept_ids.get(o.view, []))
        if len(gone):
            rejected[(c, o.view)] = gone
    if rejected:
        x, pc_, _, res = _intrinsic_stage(model, x, keep, board, cfg, progressive=False)
    stages.append({"stage": "refine", "camera": c, "rms_px": res.rms[0], "iterations": res.iterations, "reason": res.reason})
    if res.rms[0] > cfg.max_rms_px * 3:
        raise CalibrationFailed(f"{info.name}: intrinsic refinement ended at RMS {res.rms[0]:.2f} px")
    return _CameraFit(x, pc_, keep, rejected, gamma, stages, {"init": len(obs), "refine": len(keep)})


def _time_offset_stage(joint, final, obs_before, T_rig_board, start: Params, dropped: list[dict], stages: list[dict]):
    """Estimate the cameras' time offsets from ``final``. With ``time_offset="auto"`` where the
    solve without offsets dropped views (they may only have been out of time), solve again from
    every view with the estimated offsets, then estimate them once more. Returns the estimates,
    the timed solve (or None) and the dropped views."""
    cfg, C = joint.cfg, len(joint.models)
    estimates, timed = joint.estimate_time_offsets(final)
    if timed is None or cfg.time_offset != "auto" or not dropped:
        return estimates, timed, dropped
    offsets = {c: float(timed[0].params.time_offsets[c]) for c in range(1, C)}
    again = _JointStage(joint.seq, joint.models, replace(cfg, time_offsets_s=offsets), joint.board)
    redropped: list[dict] = []
    start.time_offsets = again.fixed_offsets
    out = again.run(obs_before, T_rig_board, start, redropped, stages)
    if isinstance(out, str):
        return estimates, timed, dropped
    estimates, timed = joint.estimate_time_offsets(out[0])
    return estimates, timed, redropped


def _initial_extrinsics(cam_poses: list[dict[int, np.ndarray]]) -> tuple[np.ndarray, list[int]]:
    """T_cam_rig (C, 4, 4) from co-visible views along a spanning tree from cam0, and the cameras
    no co-visible view links to cam0."""
    C = len(cam_poses)
    T_cam_rig = np.tile(np.eye(4), (C, 1, 1))
    known = {0}
    while len(known) < C:
        added = False
        for c in sorted(set(range(C)) - known):
            for k in sorted(known):
                shared = set(cam_poses[c]) & set(cam_poses[k])
                if shared:
                    # T_c_rig = T_c_board T_board_k T_k_rig
                    cands = [cam_poses[c][v] @ np.linalg.inv(cam_poses[k][v]) @ T_cam_rig[k] for v in shared]
                    T_cam_rig[c] = average_pose(cands)
                    known.add(c)
                    added = True
                    break
        if not added:
            return T_cam_rig, sorted(set(range(C)) - known)
    return T_cam_rig, []


class _JointStage:
    """Stage 3: intrinsics, extrinsics, target poses (and the board's warp, and time offsets where
    set or estimated) solved together over every camera's observations."""

    def __init__(self, seq: Sequence, models: list[str], cfg: CalibConfig, board: Target):
        self.seq, self.models, self.cfg, self.board = seq, models, cfg, board
        C = len(models)
        self.fixed_offsets = np.array([float(cfg.time_offsets_s.get(c, 0.0)) for c in range(C)], dtype=np.float64)
        self.free = Free(intr=True, extr=C > 1, warp=not cfg.flat_board, time=False)

    def _problem(
        self, used: list[Observation], T_rig_board: dict[int, np.ndarray], views: list[int], timed: frozenset[int] = frozenset()
    ) -> tuple[Problem, list[Observation]]:
        """The joint problem over ``used`` (and the observations it kept). Where cameras are timed
        (``timed``: their offsets are estimated; or set by hand), the board's motion at each view;
        in a view where it is unknown (no smooth neighbours), a timed camera saw the board at
        another time than the pose: its observation is kept only where no untimed camera saw the
        view (and then only the first such camera's)."""
        hand = {c for c in range(len(self.models)) if float(self.fixed_offsets[c]) != 0.0}
        timed = frozenset(timed) | frozenset(hand)
        if not timed or self.seq.timestamps_ns is None:
            return Problem.build(used, self.board, {v: i for i, v in enumerate(views)}), used
        motion = board_velocities(T_rig_board, self.seq.timestamps_ns, self.cfg.timing, with_acceleration=True)
        cams: dict[int, set[int]] = {}
        for o in used:
            cams.setdefault(o.view, set()).add(o.cam)

        def keep(o: Observation) -> bool:
            if o.view in motion or o.cam not in timed:
                return True
            return not (cams[o.view] - timed) and o.cam == min(cams[o.view])

        used = [o for o in used if keep(o)]
        prob = Problem.build(used, self.board, {v: i for i, v in enumerate(views)})
        both = np.stack([motion.get(v, np.zeros(12)) for v in views])
        prob.velocity, prob.acceleration = np.ascontiguousarray(both[:, :6]), np.ascontiguousarray(both[:, 6:])
        return prob, used

    def solve(self, prob: Problem, p: Params, free: Free) -> tuple[Params, SolveResult]:
        iters = self.cfg.refine_iters * (2 if self.cfg.no_init else 1)
        return solve_params(prob, self.models, p, free, iters, self.cfg.huber_px)

    def run(self, obs_by_cam, T_rig_board, start: Params, dropped: list[dict], stages: list[dict]):
        """Solve, drop the views a board placed with the wrong identity spoils, solve again.
        Returns (FinalSolve, SolveResult), or the reason of a failure."""
        cfg, C, p = self.cfg, len(self.models), start
        rounds = 6
        for it in range(rounds + 1):
            # Observations that disagree with the rig as a whole (a board placed with the wrong
            # identity: consistent within itself, so per-camera stages absorb it into its pose)
            # are dropped and the stage is run again.
            views = sorted(T_rig_board)
            used = [o for c in range(C) for o in obs_by_cam[c] if o.view in T_rig_board]
            prob, used = self._problem(used, T_rig_board, views)
            p.T_rig_board = np.stack([T_rig_board[v] for v in views])
            p, res = self.solve(prob, p, self.free)
            bad = _inconsistent_views(used, res.residuals, cfg) if it < rounds else []  # the last solve is final
            if not bad:
                return FinalSolve(used, views, prob, p, self.free, cfg.huber_px), res
            # A wrong board pulls its view's pose, and with it the other cameras' boards of that
            # view: which of them is wrong cannot be told from one view, so the whole view goes.
            worst = {}
            for o, med in bad:
                worst[o.view] = max(worst.get(o.view, 0.0), med)
            for v, med in sorted(worst.items()):
                cams = [self.seq.cameras[o.cam].name for o in used if o.view == v]
                frame = next(o.frame for o in used if o.view == v)
                dropped.append(
                    {"view": v, "frame": frame, "cameras": cams, "reason": f"board off the rig by {med:.1f} px (median corner error)"}
                )
            obs_by_cam = [[o for o in ob if o.view not in worst] for ob in obs_by_cam]
            short = [self.seq.cameras[c].name for c in range(C) if len(obs_by_cam[c]) < cfg.min_views]
            if short:
                return f"{', '.join(short)}: fewer than {cfg.min_views} views agree with the rig ({len(dropped)} views dropped)"
            seen = {o.view for ob in obs_by_cam for o in ob}
            T_rig_board = {v: p.T_rig_board[i] for i, v in enumerate(views) if v in seen}
            stages.append({"stage": "full", "rms_px": res.rms, "iterations": res.iterations, "reason": f"dropped {len(worst)} views"})
        raise AssertionError("unreachable")

    def estimate_time_offsets(self, final: FinalSolve) -> tuple[list[OffsetEstimate], tuple[FinalSolve, SolveResult] | None]:
        """Each camera's offset to cam0, estimated with everything else from the board's
        velocities (rounds: velocities from the poses, solve, again). Returns the estimates and
        the timed solve (None where no camera's offset is estimable)."""
        C, names, tcfg = len(self.models), [c.name for c in self.seq.cameras], self.cfg.timing
        if self.seq.timestamps_ns is None:
            return [OffsetEstimate(names[c], None, None, 0, "the sequence has no timestamps") for c in range(1, C)], None
        poses = {v: final.params.T_rig_board[i] for i, v in enumerate(final.views)}
        vel = board_velocities(poses, self.seq.timestamps_ns, tcfg)
        cams_by_view: dict[int, set[int]] = {}
        for o in final.used:
            cams_by_view.setdefault(o.view, set()).add(o.cam)
        counts = estimable_cameras(cams_by_view, vel, C, tcfg)
        if all(n < tcfg.min_views for n in counts.values()):
            why = f"the recording is not continuous (fewer than {tcfg.min_views} co-visible views between smooth neighbours)"
            return [OffsetEstimate(names[c], None, None, counts[c], why) for c in range(1, C)], None
        timed = frozenset(c for c, n in counts.items() if n >= tcfg.min_views)
        free = Free(intr=True, extr=C > 1, warp=self.free.warp, time=True, time_cameras=timed)
        p, res, used = final.params.clone(), None, final.used
        for _ in range(tcfg.rounds):
            prob, used = self._problem(final.used, poses, final.views, timed=timed)
            p, res = self.solve(prob, p, free)
            poses = {v: p.T_rig_board[i] for i, v in enumerate(final.views)}
        cov = covariance(prob, self.models, p, free=free, huber=self.cfg.huber_px)
        out = []
        for c in range(1, C):
            if counts[c] < tcfg.min_views:
                out.append(OffsetEstimate(names[c], None, None, counts[c], f"only {counts[c]} co-visible views in continuous motion"))
                continue
            sigma = float(cov.sigma(cov.layout.time[c])[0])
            shift = _offset_shift_px(prob, self.models, p, c)
            out.append(OffsetEstimate(names[c], float(p.time_offsets[c]), sigma, counts[c], "estimated", shift))
        return out, (FinalSolve(used, final.views, prob, p, free, self.cfg.huber_px), res)


def _offset_shift_px(prob: Problem, models: list[str], p: Params, c: int) -> float:
    """Median image motion (px) of camera c's corners between its stamp and its estimated exposure."""
    zero = p.clone()
    zero.time_offsets[c] = 0.0
    sel = prob.cam == c
    d = np.linalg.norm((residuals(prob, models, zero) - residuals(prob, models, p))[sel], axis=-1)
    return float(np.median(d)) if len(d) else math.nan


def _inconsistent_views(used: list[Observation], err: np.ndarray, cfg: CalibConfig) -> list[tuple[Observation, float]]:
    """Observations of the joint problem (in ``used`` order, ``err`` (O,) per-corner errors, px)
    whose median corner error is above ``cfg.view_outlier_px`` and ``cfg.view_outlier_ratio``
    times the median over the same camera's observations (capped at ``cfg.view_outlier_cap_px``):
    the whole board is off, not a few corners."""
    meds, k = [], 0
    for o in used:
        meds.append(float(np.median(err[k : k + len(o.ids)])))
        k += len(o.ids)
    if not meds:
        return []
    cam_median = {c: float(np.median([m for o, m in zip(used, meds) if o.cam == c])) for c in {o.cam for o in used}}
    thr = {c: max(cfg.view_outlier_px, min(cfg.view_outlier_cap_px, cfg.view_outlier_ratio * m)) for c, m in cam_median.items()}
    return [(o, m) for o, m in zip(used, meds) if m > thr[o.cam]]


def _whole_views_lost(obs: list[Observation], keep: list[Observation]) -> bool:
    """Did outlier rejection take most corners of some observation (a view, not a corner, is off)?"""
    kept = {o.view: len(o.ids) for o in keep}
    return any(kept.get(o.view, 0) < len(o.ids) / 2 for o in obs)


def _reject_outliers(
    obs: list[Observation], poses_cb: dict[int, np.ndarray], model: str, intr: np.ndarray, board: Target, cfg: CalibConfig
) -> list[Observation]:
    errs = []
    per = []
    for o in obs:
        if o.view not in poses_cb:
            per.append(None)
            continue
        T = poses_cb[o.view]
        pc = board_points(board)[o.ids] @ T[:3, :3].T + T[:3, 3]
        q, ok = cameras.project(model, pc, intr)
        e = np.where(ok, np.linalg.norm(q - o.q, axis=1), np.inf)
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
