"""Whether to trust a calibration: its uncertainty, cross-validation, and a verdict with causes.

:func:`assess` takes a finished calibration and its sequence and returns a :class:`TrustReport`:
the covariance-based uncertainty (:mod:`.uncertainty`), the cross-validation between halves of
the views (:mod:`.cross_validation`), the board's estimated warp, the cameras' time offsets, and a
verdict (``trust`` / ``caution`` / ``fail``) whose causes each name a camera and say what to do.

Every statistical check is a tail test on the measured corner noise, at one false-alarm
probability (``TrustConfig.significance``): no threshold comes from a list of sets. The causes:

- ``unsynchronised``: an estimated time offset that is significant and moves the board in the
  image by more than half the corner noise; or, where no offset is estimable, the joint fit
  costing more than the cameras' own fits can explain (a chi-square on the cost the joint solve
  adds per parameter it ties);
- ``board_not_flat``: the estimated warp significant against its covariance (chi-square, 2 dof);
- ``camera_model``: a radial trend in a camera's residuals (binned mean radial residual against
  its standard error); the other models are then calibrated and compared on held-out views;
- ``coverage``: the capture advice of :mod:`.coverage`;
- ``few_views``: the uncertainty over the stated use's limits (projection, extrinsics);
- ``outliers``: many corners rejected or views dropped;
- ``noise_model``: the halves differ by more than the noise model predicts (``spread_ratio``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2, norm

from calib_eval.calibration.calibrator import CalibConfig, CalibrationResult, FinalSolve
from calib_eval.calibration.coverage import coverage
from calib_eval.calibration.cross_validation import CrossValidation, CrossValidationConfig, cross_validate
from calib_eval.calibration.solver import Problem, covariance, residuals, solve
from calib_eval.calibration.uncertainty import Uncertainty, uncertainty_of
from cotrain.geometry import cameras
from cotrain.io.sequence import Sequence

LEVELS = ("trust", "caution", "fail")


@dataclass
class TrustConfig:
    significance: float = 1e-3  # false-alarm probability of each statistical test (a tail of the measured noise)
    max_spread_ratio: float = 1.5  # cross-validation: halves' difference / its predicted sigma. 1.5 is the 3x of the
    # full data's sigma (each half's sigma is sqrt(2) of it, their difference 2x) the verdict must never trust beyond
    min_shift_noise: float = 0.5  # an offset matters where the board moves more than this share of the corner noise over it
    min_tie_excess: float = 2.0  # joint cost per tied parameter (in noise variances) over which cameras disagree (1 = noise).
    # 1.5 named 1 of 10 clean twelve-view rigs (seeds 1000-1009: dof 56, p 0.0008); set there, reported on seeds from 2000
    radial_bins: int = 8  # equal-count radius bins of the radial-trend test
    max_projection_sigma_px: float | None = None  # the stated use: 95th percentile of the projection sigma, px (default:
    # half the measured corner noise: the calibration then adds at most about 12 % to a corner's error in quadrature)
    max_translation_sigma_m: float = 0.001  # the stated use: a pair's translation sigma (1 mm)
    max_rotation_sigma_deg: float = 0.1  # the stated use: a pair's rotation sigma
    max_outlier_share: float = 0.05  # share of a camera's corners rejected or in dropped views
    compare_models: bool = True  # calibrate the other families where the camera model is named
    cv: CrossValidationConfig = field(default_factory=CrossValidationConfig)


@dataclass
class Cause:
    code: str
    camera: str | None
    text: str

    def as_dict(self) -> dict:
        return {"code": self.code, "camera": self.camera, "text": self.text}


@dataclass
class Verdict:
    level: str
    causes: list[Cause] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"level": self.level, "causes": [c.as_dict() for c in self.causes]}

    def line(self) -> str:
        """The CLI's last line."""
        if not self.causes:
            return f"verdict: {self.level}"
        return f"verdict: {self.level}: " + "; ".join(c.text for c in self.causes)


@dataclass
class TrustReport:
    verdict: Verdict
    uncertainty: Uncertainty | None
    cross_validation: CrossValidation | None
    tie_test: dict  # the joint-against-own-fits cost test
    radial: list[dict]  # per camera: the radial-trend test
    model_comparison: dict = field(default_factory=dict)  # family -> per camera held-out RMS (px), where the model is named


# --------------------------------------------------------------------------------------------
# The checks
# --------------------------------------------------------------------------------------------
def _used_corners(final: FinalSolve, C: int) -> list[np.ndarray]:
    return [np.concatenate([o.q for o in final.used if o.cam == c] or [np.zeros((0, 2))]) for c in range(C)]


def tie_test(final: FinalSolve, models: list[str], cfg: TrustConfig) -> dict:
    """Does tying the cameras together cost more than the noise explains? Each camera is solved
    alone from the joint solution (its intrinsics, its own board poses, the warp); the joint cost
    over theirs, in noise variances (the noise the cameras' own fits measure), is chi-square with
    as many dof as the joint solve has fewer parameters. Per camera, its share of the excess."""
    p, prob, C = final.params, final.problem, len(models)
    r = residuals(prob, models, p)
    joint = [float((prob.w * (r * r).sum(-1))[prob.cam == c].sum()) for c in range(C)]
    own, n_own = [], 0
    for c in range(C):
        sub, views = prob.select(prob.cam == c, one_camera=True)
        sub.velocity = sub.acceleration = None  # alone, each camera's poses are its own
        T_cb = p.T_cam_rig[c] @ p.T_rig_board[views]
        _, _, _, res = solve(sub, [models[c]], [p.intr[c]], np.eye(4)[None], T_cb, opt_warp=final.free.warp, warp=p.warp, iters=20)
        e = res.residuals
        own.append(float((sub.w * e * e).sum()))
        n_own += p.intr[c].size + 6 * len(views) + (2 if final.free.warp else 0)
    n_joint = sum(x.size for x in p.intr) + 6 * (C - 1) * final.free.extr + 6 * prob.n_views + (2 if final.free.warp else 0)
    n_joint += (C - 1) if final.free.time else 0
    dof = max(n_own - n_joint, 1)
    sigma_px = math.sqrt(sum(own) / max(2 * prob.q.shape[0] - n_own, 1))
    excess = (sum(joint) - sum(own)) / sigma_px**2
    pval = float(chi2.sf(excess, dof))
    per_cam = [(j - o) / sigma_px**2 for j, o in zip(joint, own)]
    disagree = pval < cfg.significance and excess / dof > cfg.min_tie_excess
    return {
        "excess_per_dof": excess / dof,
        "sigma_own_px": sigma_px,
        "dof": dof,
        "p_value": pval,
        "disagree": bool(disagree),
        "rms_joint_px": [math.sqrt(j / max(1, int((prob.cam == c).sum()))) for c, j in enumerate(joint)],
        "rms_own_px": [math.sqrt(o / max(1, int((prob.cam == c).sum()))) for c, o in enumerate(own)],
        "share": per_cam,
    }


def radial_trend(final: FinalSolve, models: list[str], sigma_px: float, cfg: TrustConfig) -> list[dict]:
    """Per camera: the mean radial residual in equal-count radius bins against its standard error
    (sigma / sqrt(n)); chi-square over the bins."""
    p, prob = final.params, final.problem
    r = residuals(prob, models, p)
    out = []
    for c, m in enumerate(models):
        sel = prob.cam == c
        mdl = cameras.get_model(m)
        centre = np.stack([p.intr[c][mdl.index("cx")], p.intr[c][mdl.index("cy")]])
        d = prob.q[sel] - centre
        rad = np.linalg.norm(d, axis=-1)
        rr = (r[sel] * d).sum(-1) / np.maximum(rad, 1e-9)
        keep = np.linalg.norm(r[sel], axis=-1) < 5 * sigma_px
        rad, rr = rad[keep], rr[keep]
        if len(rad) < 10 * cfg.radial_bins:
            out.append({"chi2": math.nan, "p_value": 1.0, "trend": False, "bins": []})
            continue
        edges = np.quantile(rad, np.linspace(0, 1, cfg.radial_bins + 1))
        idx = np.clip(np.searchsorted(edges, rad, side="right") - 1, 0, cfg.radial_bins - 1)
        bins = []
        stat = 0.0
        for b in range(cfg.radial_bins):
            v = rr[idx == b]
            if not len(v):  # repeated radii can leave a bin empty
                continue
            mean, se = float(v.mean()), sigma_px / math.sqrt(len(v))
            stat += (mean / se) ** 2
            bins.append({"radius_px": float(np.median(rad[idx == b])), "mean_radial_px": mean, "se_px": se})
        pval = float(chi2.sf(stat, cfg.radial_bins))
        out.append({"chi2": stat, "p_value": pval, "trend": pval < cfg.significance, "bins": bins})
    return out


def held_out_rms(res: CalibrationResult, seq: Sequence, cfg: CrossValidationConfig) -> list[float]:
    """Per camera: the RMS (px) on each half's views of the other half's calibration (board poses
    fitted with the cameras fixed), over both directions."""
    from calib_eval.calibration.cross_validation import fit_half, split_views

    final = res.final
    A, B = split_views(final.views, np.random.default_rng(cfg.seed))
    C = len(res.model)
    err2, n = np.zeros(C), np.zeros(C)
    for fit, test in ((A, B), (B, A)):
        half = fit_half(final, res.model, fit, cfg)
        if half is None:
            return [math.nan] * C
        p = half[0]
        views = sorted(test)
        used = [o for o in final.used if o.view in test]
        prob = Problem.build(used, seq.target, {v: i for i, v in enumerate(views)})
        Tb = np.stack([res.T_rig_board[v] for v in views])
        _, _, _, out = solve(prob, res.model, p.intr, p.T_cam_rig, Tb, opt_intr=False, warp=p.warp, iters=10)
        e = out.residuals
        for c in range(C):
            sel = prob.cam == c
            err2[c] += float((e[sel] ** 2).sum())
            n[c] += int(sel.sum())
    return list(np.sqrt(err2 / np.maximum(n, 1)))


# --------------------------------------------------------------------------------------------
# The verdict
# --------------------------------------------------------------------------------------------
def _offset_causes(res: CalibrationResult, sigma_px: float, cfg: TrustConfig) -> list[Cause]:
    """Cameras whose estimated offset is significant and moves the board by more than
    ``min_shift_noise`` of the corner noise (not named where the offsets were applied)."""
    z = float(norm.isf(cfg.significance / 2))
    out = []
    applied = res.time_offsets_s is not None and bool(np.any(res.time_offsets_s != 0))
    for e in res.time_offset_estimates:
        if e.value_s is None or applied:
            continue
        if abs(e.value_s) > z * e.sigma_s and e.shift_px > cfg.min_shift_noise * sigma_px:
            when = "after" if e.value_s > 0 else "before"
            out.append(
                Cause(
                    "unsynchronised",
                    e.camera,
                    f"{e.camera}'s images are exposed about {abs(e.value_s) * 1000:.1f} ms {when} their stamps (the board moves "
                    f"{e.shift_px:.2f} px in that time): calibrate with --time-offset auto or synchronise the cameras",
                )
            )
    return out


def _tie_causes(res: CalibrationResult, names: list[str], tie: dict) -> list[Cause]:
    """The joint fit costing more than the cameras' own fits explain (asked only where no offset
    and no camera model were named: cameras that each fit badly also disagree together)."""
    if not tie.get("disagree"):
        return []
    worst = int(np.argmax(tie["share"][1:])) + 1
    rj, ro = tie["rms_joint_px"], tie["rms_own_px"]
    fits = ", ".join(f"{names[c]} {ro[c]:.2f} px alone, {rj[c]:.2f} px together" for c in range(len(names)))
    if res.time_offsets_s is not None and bool(np.any(res.time_offsets_s != 0)):
        text = (
            f"the cameras still disagree on the views they share with the time offsets applied ({fits}): the board moved "
            "too fast for the offsets' correction, or the cameras' clocks drift; synchronise the cameras or move the board slower"
        )
        return [Cause("unsynchronised", names[worst], text)]
    timed = [e for e in res.time_offset_estimates if e.value_s is not None]
    hint = "" if timed else "; the recording is not continuous, so no time offset can be measured"
    return [
        Cause(
            "unsynchronised",
            names[worst],
            f"the cameras disagree on the views they share ({fits}): they were probably not exposed together"
            f"{hint}; synchronise the cameras, or record a continuous motion and calibrate with --time-offset auto",
        )
    ]


def _board_causes(final: FinalSolve, models: list[str], cfg: TrustConfig, timed: bool = False) -> list[Cause]:
    """The warp of ``final`` against its covariance (chi-square, 2 dof); ``timed``: ``final`` is
    the solve with the time offsets (the sentence says so: report.json's warp is the result's)."""
    if not final.free.warp:
        return []
    cov = covariance(final.problem, models, final.params, free=final.free, huber=final.huber)
    S = cov.block(cov.layout.warp)
    w = final.params.warp
    stat = float(w @ np.linalg.lstsq(S, w, rcond=1e-12)[0])
    if stat <= chi2.isf(cfg.significance, 2):
        return []
    mm = w * 1000
    return [
        Cause(
            "board_not_flat",
            None,
            f"the board is bent by {mm[0]:+.2f} mm along x and {mm[1]:+.2f} mm along y at its centre (sigma "
            f"{math.sqrt(S[0, 0]) * 1000:.2f} mm{', estimated with the time offsets' if timed else ''}): the calibration "
            "estimated the bend, but use a stiffer, flatter board",
        )
    ]


def _model_causes(res, seq, radial: list[dict], names: list[str], cfg: TrustConfig, calib_cfg, order) -> tuple[list[Cause], dict]:
    named = [c for c, t in enumerate(radial) if t["trend"]]
    if not named:
        return [], {}
    comparison = compare_models(res, seq, calib_cfg, order, cfg) if cfg.compare_models else {}
    out = []
    for c in named:
        worst = max(radial[c]["bins"], key=lambda b: abs(b["mean_radial_px"]))
        text = (
            f"{names[c]}'s residuals follow the radius (mean radial residual {worst['mean_radial_px']:+.3f} px at "
            f"{worst['radius_px']:.0f} px from the centre): the {res.model[c]} model does not fit this lens well"
        )
        scores = {m: v[c] for m, v in comparison.items() if math.isfinite(v[c])}
        if scores:
            best = min(scores, key=scores.get)
            listed = ", ".join(f"{m} {v:.3f} px" for m, v in sorted(scores.items(), key=lambda kv: kv[1]))
            text += f"; on held-out views {best} fits best ({listed})"
            if best != res.model[c]:
                text += f": calibrate it with --models {best}"
        out.append(Cause("camera_model", names[c], text))
    return out, comparison


def compare_models(res: CalibrationResult, seq: Sequence, calib_cfg: CalibConfig, order, cfg: TrustConfig) -> dict:
    """family -> per camera held-out RMS (px): every family calibrated on the same observations."""
    from dataclasses import replace

    from calib_eval.calibration.calibrator import calibrate

    out = {res.model[0]: held_out_rms(res, seq, cfg.cv)} if len(set(res.model)) == 1 else {}
    for fam in ("kb4", "ds", "eucm", "ucm"):
        if fam in out:
            continue
        other = calibrate(seq, replace(calib_cfg, model=fam, models=[], time_offset="off"), order)
        out[fam] = held_out_rms(other, seq, cfg.cv) if other.success and other.final is not None else [math.nan] * len(res.model)
    return out


def _use_causes(unc: Uncertainty | None, names: list[str], cfg: TrustConfig) -> list[Cause]:
    if unc is None:
        return []
    limit = cfg.max_projection_sigma_px if cfg.max_projection_sigma_px is not None else 0.5 * unc.sigma_px
    out = []
    for c, m in enumerate(unc.projection):
        if m.p95_px > limit:
            out.append(
                Cause(
                    "few_views",
                    names[c],
                    f"{names[c]}'s projection is uncertain by up to {m.p95_px:.2f} px (95th percentile; the corner noise is "
                    f"{unc.sigma_px:.2f} px): add views that cover the image",
                )
            )
    for (a, b), pu in unc.pairs.items():
        if pu.translation_sigma_m > cfg.max_translation_sigma_m or pu.rotation_sigma_deg > cfg.max_rotation_sigma_deg:
            out.append(
                Cause(
                    "few_views",
                    names[b],
                    f"{names[a]}-{names[b]} extrinsics are uncertain by {pu.translation_sigma_m * 1000:.2f} mm / "
                    f"{pu.rotation_sigma_deg:.3f} deg: add views that both cameras see",
                )
            )
    return out


def _outlier_causes(res: CalibrationResult, seq: Sequence, names: list[str], cfg: TrustConfig) -> list[Cause]:
    dropped_views = {d["view"] for d in res.dropped}
    out = []
    for c in range(len(names)):
        total = sum(len(o.ids) for o in seq.by_camera(c))
        gone = sum(len(ids) for (cam, _), ids in res.rejected.items() if cam == c)
        gone += sum(len(o.ids) for o in seq.by_camera(c) if o.view in dropped_views)
        if total and gone / total > cfg.max_outlier_share:
            out.append(
                Cause(
                    "outliers",
                    names[c],
                    f"{gone} of {names[c]}'s {total} corners were rejected or dropped with their views ({100 * gone / total:.0f} %): "
                    "check the detections (report.json lists the dropped views)",
                )
            )
    return out


def _coverage_causes(seq: Sequence) -> list[Cause]:
    """The capture advice on radial reach, radial span of single views, view counts and shared
    views. Advice only on where to hold the board (rim sectors, the middle) stays advice: what it
    costs is in the projection uncertainty (``few_views``)."""
    cov = coverage(seq)
    out = []
    for cc in cov.cameras:
        out += [Cause("coverage", cc.name, a) for a in cc.advice if a not in cc.placement]
    minor = {a for cc in cov.cameras for a in cc.placement}
    out += [Cause("coverage", None, a) for a in cov.advice if a not in minor and not any(a == c.text for c in out)]
    return out


def _cv_causes(cv: CrossValidation | None, cfg: TrustConfig) -> list[Cause]:
    if cv is None or not cv.ok:
        return []
    limit = min(cfg.max_spread_ratio, math.sqrt(chi2.isf(cfg.significance, cv.n_params) / cv.n_params))
    if cv.spread_ratio <= limit:
        return []
    return [
        Cause(
            "noise_model",
            None,
            f"calibrations from two halves of the views differ {cv.spread_ratio:.1f} times more than their uncertainty predicts: "
            "the stated sigma is too small; an error the corner noise does not explain is in the data",
        )
    ]


def assess(res: CalibrationResult, seq: Sequence, calib_cfg: CalibConfig, cfg: TrustConfig | None = None, order=None) -> TrustReport:
    """Uncertainty, cross-validation, the causes and the verdict of a finished calibration."""
    cfg = cfg or TrustConfig()
    names = [c.name for c in seq.cameras]
    if not res.success or res.final is None:
        causes = [Cause("failed", None, f"calibration failed: {res.reason}")]
        finite = res.final is not None and all(bool(np.isfinite(x).all()) for x in res.final.params.intr)
        if finite and any(e.value_s is not None for e in res.time_offset_estimates):
            # It got as far as the joint stage: an offset it measured may say why.
            f = res.final
            noise = covariance(f.problem, res.model, f.params, free=f.free, huber=f.huber).sigma_px
            causes += _offset_causes(res, noise, cfg)
        return TrustReport(Verdict("fail", causes), None, None, {}, [])
    final, C = res.final, len(names)
    sizes = [(c.width, c.height) for c in seq.cameras]
    corners = _used_corners(final, C)
    unc = uncertainty_of(final.problem, res.model, final.params, final.free, final.huber, sizes, corners)
    cv = cross_validate(final, res.model, sizes, corners, cfg.cv)
    tie = tie_test(final, res.model, cfg) if C > 1 else {}
    causes = _offset_causes(res, unc.sigma_px, cfg)
    # An offset left in the data bends the board's and the lens's estimates too: where one was
    # found, the board and the model are judged on the solve that estimated it.
    ref = res.timed if causes and res.timed is not None else final
    radial = radial_trend(ref, res.model, unc.sigma_px, cfg)
    model_causes, comparison = _model_causes(res, seq, radial, names, cfg, calib_cfg, order)
    if not causes and not model_causes:
        causes += _tie_causes(res, names, tie)
    causes += _board_causes(ref, res.model, cfg, timed=ref is not final)
    causes += model_causes + _coverage_causes(seq) + _use_causes(unc, names, cfg) + _outlier_causes(res, seq, names, cfg)
    causes += _cv_causes(cv, cfg)
    return TrustReport(Verdict("caution" if causes else "trust", causes), unc, cv, tie, radial, comparison)


def report_dict(rep: TrustReport, res: CalibrationResult, names: list[str]) -> dict:
    """The trust sections of report.json (docs/conventions.md)."""
    out: dict = {"verdict": rep.verdict.as_dict()}
    u = rep.uncertainty
    if u is not None:
        out["uncertainty"] = {
            "sigma_px": u.sigma_px,
            "cameras": {
                names[c]: {
                    "intrinsics_sigma": u.intrinsics_sigma[c].tolist(),
                    "projection_sigma_px": {"median": m.median_px, "p95": m.p95_px, "max": m.max_px, "range": "infinite"},
                }
                for c, m in enumerate(u.projection)
            },
            "pairs": {f"{names[a]}-{names[b]}": pu.as_dict() for (a, b), pu in u.pairs.items()},
        }
    out["cross_validation"] = rep.cross_validation.as_dict(names) if rep.cross_validation is not None else None
    sigma = (u.warp_sigma_m * 1000).tolist() if u is not None and u.warp_sigma_m is not None else None
    est = res.final is not None and res.final.free.warp
    out["board"] = {
        "deformation_mm": {"x": float(res.warp_m[0] * 1000), "y": float(res.warp_m[1] * 1000)} if est else None,
        "deformation_sigma_mm": {"x": sigma[0], "y": sigma[1]} if sigma else None,
    }
    estimates = {e.camera: e for e in res.time_offset_estimates}
    out["time_offsets_s"] = {n: estimates[n].value_s if n in estimates else None for n in names[1:]}
    out["time_offsets"] = {
        "applied_s": {names[c]: float(res.time_offsets_s[c]) for c in range(1, len(names))} if res.time_offsets_s is not None else {},
        "estimates": {
            n: estimates[n].as_dict() if n in estimates else {"value_s": None, "reason": "not estimated (--time-offset off or set by hand)"}
            for n in names[1:]
        },
    }
    out["checks"] = {"tie_test": rep.tie_test, "radial_trend": {names[c]: t for c, t in enumerate(rep.radial)}}
    if rep.model_comparison:
        out["checks"]["held_out_rms_px"] = {m: {names[c]: v[c] for c in range(len(names))} for m, v in rep.model_comparison.items()}
    return out
