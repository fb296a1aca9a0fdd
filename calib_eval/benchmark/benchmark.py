"""Synthetic calibration benchmark (paper Tables IV-V): ``calib-eval benchmark [--configs ...] [--trials N] [--out DIR]``.

Per configuration and trial, one synthetic sequence (480 frames, f-theta cameras, 1280x720, 5 cm
baseline) is calibrated four ways on the same observations:

- ``all``: every frame, the staged pipeline (Kalibr-style);
- ``selector``: CO-Calib, the selector's frames with anchors first;
- ``random``: a random subset of views of the selector's size;
- ``ba_only``: every frame, without intrinsic initialisation (the BA-only two-stage ablation);
- ``mrcal``: mrcal 2.2's ``mrcal-calibrate-cameras`` (a peer, where installed) on the selector's
  frames, the same detections as ``selector``
  (:mod:`calib_eval.calibration.mrcal_peer`); where it fails, its own message is kept per trial.

Success: the pipeline ends normally with every camera's RMS <= 2 px (the pipeline's own verdict).
Strict success: success, every calibrated camera within 2 px RMS of the true one over 95 % of the FoV
(model-independent: the calibrated family may differ from the true f-theta), and every extrinsic
within 5 mm and 0.5 deg of the ground truth, and the mean target-pose error under 50 mm. ATE and
extrinsic errors are averaged over strict successes. The
same criteria apply to every variant.

Trials run in parallel processes; under ``torchrun`` (RANK / WORLD_SIZE in the environment)
each rank takes the trials ``i % WORLD_SIZE == RANK``, writes a shard, and rank 0 merges.
"""

from __future__ import annotations

import json
import math
import os
import re
import time
import zlib
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from calib_eval.benchmark.rigs import SynthSpec, make_sequence, paper_config
from calib_eval.calibration.calibrator import CalibConfig, calibrate
from calib_eval.calibration.compare import MAX_RMS_PX, error_rays, mrcal_valid, pixel_difference, pose_difference, project_rays
from calib_eval.calibration.mrcal_peer import MrcalConfig, calibrate_mrcal
from calib_eval.calibration.selector import SelectorConfig, select
from cotrain.io.detections import json_safe
from cotrain.progress import progress_bar

PAPER_CONFIGS = [f"FoV{f}_{y}" for f in (180, 200, 220, 240) for y in (0, 60, 90, 120)]
ALL_CONFIGS = PAPER_CONFIGS + ["FoV220_hex"]
VARIANTS = ["all", "selector", "random", "ba_only"]  # ours; "mrcal" runs where asked for
ALL_VARIANTS = [*VARIANTS, "mrcal"]
VARIANT_NAMES = {
    "all": "All frames (Kalibr-style)",
    "selector": "CO-Calib (selector)",
    "random": "Random subset",
    "ba_only": "BA-only two-stage",
    "mrcal": "mrcal 2.2 (selector's frames)",
}
STRICT = {"intr_px": 2.0, "ext_mm": 5.0, "ext_deg": 0.5, "ate_mm": 50.0}
# Paper Table IV/V: SR (%), ATE t/r (mm/deg), Ext t/r (mm/deg); Kalibr is the all-frames row.
PAPER_OVERALL = {
    "all": (68.1, 3.27, 0.079, 0.54, 0.029),
    "selector": (99.3, 3.69, 0.111, 0.18, 0.021),
    "random": (30.9, 4.43, 0.160, 0.26, 0.029),
    "ba_only": (13.5, 4.74, 0.178, 0.31, 0.033),
}
PAPER_SR = {  # per configuration: Kalibr, CO-Calib, random, BA-only success rates (%)
    "FoV180_0": (97, 100, 39, 29),
    "FoV180_60": (100, 100, 42, 28),
    "FoV180_90": (100, 99, 35, 17),
    "FoV180_120": (100, 100, 24, 12),
    "FoV200_0": (97, 100, 59, 22),
    "FoV200_60": (98, 99, 52, 26),
    "FoV200_90": (97, 100, 54, 19),
    "FoV200_120": (92, 100, 50, 20),
    "FoV220_0": (33, 100, 13, 3),
    "FoV220_60": (64, 100, 33, 10),
    "FoV220_90": (56, 99, 21, 9),
    "FoV220_120": (54, 97, 20, 8),
    "FoV240_0": (12, 98, 12, 1),
    "FoV240_60": (41, 98, 22, 6),
    "FoV240_90": (25, 98, 13, 5),
    "FoV240_120": (23, 100, 5, 1),
}


def projection_difference(model: str, params: np.ndarray, gt_model: str, gt_params: np.ndarray, fov: float, n: int = 400) -> float:
    """RMS pixel difference between two cameras over rays up to 95 % of the half FoV: a
    model-independent intrinsic error (the calibrated family may differ from the true one)."""
    v = error_rays(fov, n)
    return pixel_difference(*project_rays(model, params, v), *project_rays(gt_model, gt_params, v))


def evaluate_result(res, gt, fov: float) -> dict:
    """Errors of a calibration result against ground truth."""
    out = {"success": bool(res.success), "reason": res.reason, "runtime_s": res.runtime_s, "gamma": res.gamma}
    if not res.success:
        out["strict"] = False
        return out
    intr_px = max(projection_difference(res.model[c], res.intrinsics[c], gt.model[c], gt.params[c], fov) for c in range(len(gt.params)))
    out.update({"intr_px": float(intr_px), **pose_errors(np.asarray(res.T_cam_rig), res.T_rig_board, gt), "rms_px": res.rms_px})
    out["strict"] = is_strict(out)
    return out


def pose_errors(T_cam_rig: np.ndarray, T_rig_board: dict[int, np.ndarray], gt) -> dict:
    """Mean extrinsic (cameras after cam0) and target-pose (ATE) errors against the ground truth, mm and deg."""
    ext_t, ext_r = pose_difference(T_cam_rig[1:], gt.T_cam_rig[1:])
    views = sorted(T_rig_board)
    ate_t, ate_r = pose_difference(np.stack([T_rig_board[v] for v in views]), gt.T_rig_board[views])
    return {
        "ext_mm": float(np.mean(ext_t)),
        "ext_deg": float(np.mean(ext_r)),
        "ate_mm": float(np.mean(ate_t)),
        "ate_deg": float(np.mean(ate_r)),
    }


MRCAL_TIMEOUT_S = 120.0  # mrcal's tool is stopped after this long in the benchmark (ours takes seconds)


def evaluate_mrcal(seq, gt, fov: float, timeout_s: float = MRCAL_TIMEOUT_S) -> dict:
    """mrcal's tool on ``seq``, scored by the same criteria as ours (success also needs its RMS <= 2 px)."""
    v = error_rays(fov)
    m = calibrate_mrcal(seq, fov, MrcalConfig(timeout_s=timeout_s), rays=v)
    out = {"available": m.available, "success": False, "reason": m.reason, "stage": m.stage, "runtime_s": m.runtime_s}
    out.update({"rms_px": max(m.rms_cam, default=m.rms_px), "outliers": m.outliers})
    if m.success and not out["rms_px"] <= MAX_RMS_PX:
        out["reason"] = f"final RMS {out['rms_px']:.2f} px > {MAX_RMS_PX} px"
    if not m.success or out["reason"]:
        out["strict"] = False
        return out
    out["success"] = True
    intr_px = max(pixel_difference(q, mrcal_valid(q), *project_rays(gt.model[c], gt.params[c], v)) for c, q in enumerate(m.q_rays))
    out.update({"intr_px": float(intr_px), **pose_errors(m.T_cam_rig, m.T_rig_board, gt)})
    out["strict"] = is_strict(out)
    return out


def is_strict(r: dict) -> bool:
    """Strict success: success, intrinsics, extrinsics and target poses near the ground truth."""
    return bool(
        r.get("success")
        and r.get("intr_px", math.inf) < STRICT["intr_px"]
        and r.get("ext_mm", math.inf) < STRICT["ext_mm"]
        and r.get("ext_deg", math.inf) < STRICT["ext_deg"]
        and r.get("ate_mm", math.inf) < STRICT["ate_mm"]
    )


def coverage_grid(seq, cells: int = 16) -> list[list[int]]:
    """Per camera, observation counts on a cells x cells image grid (for D_qty / D_sp)."""
    out = []
    for c, cam in enumerate(seq.cameras):
        g = np.zeros((cells, cells), dtype=int)
        for o in seq.by_camera(c):
            ix = np.clip((o.q[:, 0] / cam.width * cells).astype(int), 0, cells - 1)
            iy = np.clip((o.q[:, 1] / cam.height * cells).astype(int), 0, cells - 1)
            np.add.at(g, (iy, ix), 1)
        out.append(g.tolist())
    return out


def run_trial(
    config: str,
    trial: int,
    frames: int = 480,
    noise_px: float = 0.3,
    variants: list[str] | None = None,
    model: str = "ds",
    mrcal_timeout_s: float = MRCAL_TIMEOUT_S,
) -> dict:
    """One sequence, calibrated by every variant. Deterministic in (config, trial)."""
    import torch

    torch.set_num_threads(1)

    rig = paper_config(config)
    seed = zlib.crc32(f"{config}/{trial}".encode())
    seq, gt = make_sequence(rig, SynthSpec(n_frames=frames, noise_px=noise_px), seed=seed)
    out = {"config": config, "trial": trial, "seed": seed, "model": model, "n_obs": len(seq.observations), "grid": coverage_grid(seq)}
    variants = variants or VARIANTS
    sel = select(seq, SelectorConfig(fov=rig.fov))
    for v in variants:
        t0 = time.time()
        if v == "all":
            res = calibrate(seq, CalibConfig(model=model, fov=rig.fov))
        elif v == "selector":
            res = calibrate(seq.subset(sel.keep), CalibConfig(model=model, fov=rig.fov), order=sel.order)
        elif v == "mrcal":
            r = evaluate_mrcal(seq.subset(sel.keep), gt, rig.fov, mrcal_timeout_s)
            r["wall_s"] = time.time() - t0
            out[v] = r
            continue
        elif v == "random":
            rng = np.random.default_rng(seed)
            n_views = len({view for _, view in sel.keep})
            views = rng.choice(seq.n_views, size=min(n_views, seq.n_views), replace=False)
            keep = {(o.cam, o.view) for o in seq.observations if o.view in set(views.tolist())}
            res = calibrate(seq.subset(keep), CalibConfig(model=model, fov=rig.fov))
        else:
            res = calibrate(seq, CalibConfig(model=model, fov=rig.fov, no_init=True))
        r = evaluate_result(res, gt, rig.fov)
        r["wall_s"] = time.time() - t0
        out[v] = r
    return out


def _summarise(trials: list[dict], variants: list[str]) -> dict:
    by_cfg: dict[str, dict] = {}
    for t in trials:
        by_cfg.setdefault(t["config"], {v: [] for v in variants})
        for v in variants:
            if v in t:
                by_cfg[t["config"]][v].append(t[v])

    def agg(rs: list[dict]) -> dict:
        for r in rs:
            r["strict"] = is_strict(r)  # recomputed, so that merged shards follow the current criteria
        strict = [r for r in rs if r["strict"]]
        f = lambda k: float(np.mean([r[k] for r in strict])) if strict else float("nan")  # noqa: E731
        return {
            "n": len(rs),
            "available": all(r.get("available", True) for r in rs),
            "sr": 100 * np.mean([r["success"] for r in rs]) if rs else float("nan"),
            "strict_sr": 100 * np.mean([r.get("strict", False) for r in rs]) if rs else float("nan"),
            "ate_mm": f("ate_mm"),
            "ate_deg": f("ate_deg"),
            "ext_mm": f("ext_mm"),
            "ext_deg": f("ext_deg"),
            "runtime_s": float(np.median([r["runtime_s"] for r in rs])) if rs else float("nan"),
        }

    summary = {cfg: {v: agg(rs) for v, rs in d.items()} for cfg, d in by_cfg.items()}
    summary["overall"] = {v: agg([t[v] for t in trials if v in t and t["config"] in PAPER_CONFIGS]) for v in variants}
    return summary


def _table(summary: dict, variants: list[str], trials: int) -> str:
    lines = [
        "| configuration | method | SR | strict SR | ATE t/r (mm/deg) | Ext. t/r (mm/deg) | paper SR |",
        "|---|---|---|---|---|---|---|",
    ]
    idx = {v: i for i, v in enumerate(VARIANTS)}
    for cfg in [c for c in ALL_CONFIGS if c in summary] + ["overall"]:
        for v in variants:
            s = summary[cfg][v]
            if not s["available"]:
                lines.append(f"| {cfg} | {VARIANT_NAMES[v]} | not installed | | | | |")
                continue
            if v not in idx:
                p = ""
            elif cfg == "overall":
                p = f"{PAPER_OVERALL[v][0]:.1f}%"
            else:
                p = f"{PAPER_SR[cfg][idx[v]]}%" if cfg in PAPER_SR else ""
            lines.append(
                f"| {cfg} | {VARIANT_NAMES[v]} | {s['sr']:.0f}% | {s['strict_sr']:.0f}% | {s['ate_mm']:.2f}/{s['ate_deg']:.3f} | "
                f"{s['ext_mm']:.2f}/{s['ext_deg']:.3f} | {p} |"
            )
    lines += [
        "",
        f"{trials} trial(s) per configuration. Paper overall (SR, ATE, Ext.): "
        + "; ".join(
            f"{VARIANT_NAMES[v]} {PAPER_OVERALL[v][0]}%, {PAPER_OVERALL[v][1]}/{PAPER_OVERALL[v][2]}, "
            f"{PAPER_OVERALL[v][3]}/{PAPER_OVERALL[v][4]}"
            for v in variants
            if v in PAPER_OVERALL
        ),
        "",
        "Success: the pipeline ends normally with every camera's RMS <= 2 px. Strict success: success, projections within "
        f"{STRICT['intr_px']} px RMS of the true camera over 95 % of the FoV, extrinsics within {STRICT['ext_mm']} mm and "
        f"{STRICT['ext_deg']} deg of the ground truth, mean target-pose error (ATE) below {STRICT['ate_mm']} mm. "
        "ATE and Ext. are means over strict successes; the criteria are the same for every method. The overall row covers the 16 "
        "paper configurations (not the hex rig).",
    ]
    return "\n".join(lines)


def failure_table(trials: list[dict], variant: str) -> str:
    """Per configuration, how often ``variant`` failed, at which stage, with which message, and the
    median RMS the tool had reached when it stopped."""
    rows: dict[tuple[str, str, str], list[float]] = {}
    n: dict[str, int] = {}
    for t in trials:
        r = t.get(variant)
        if r is None or not r.get("available", True):
            continue
        n[t["config"]] = n.get(t["config"], 0) + 1
        if r.get("success"):
            continue
        reason = re.sub(r"final RMS [0-9.]+ px > ", "final RMS over ", (r.get("reason") or "?").replace("|", "/"))  # one row, RMS beside
        reason = re.sub(r"observation \d+ \(camera \d+\)", "an observation", re.sub(r"^(?:[\w<>]+\.)+(?=\w+: )", "", reason))
        key = (t["config"], r.get("stage", "") or "-", reason[:160])
        rows.setdefault(key, []).append(r.get("rms_px", math.nan))
    if not rows:
        return ""
    lines = [
        f"### Where {VARIANT_NAMES[variant]} fails",
        "",
        "| configuration | failed | last stage | message | median RMS reached (px) |",
        "|---|---|---|---|---|",
    ]
    order = lambda k: (ALL_CONFIGS.index(k[0]) if k[0] in ALL_CONFIGS else 99, -len(rows[k]))  # noqa: E731
    for k in sorted(rows, key=order):
        rms = [x for x in rows[k] if x is not None and math.isfinite(x)]
        lines.append(f"| {k[0]} | {len(rows[k])}/{n[k[0]]} | {k[1]} | `{k[2]}` | {np.median(rms) if rms else math.nan:.2f} |")
    return "\n".join(lines)


def run_benchmark(
    configs: list[str],
    trials: int,
    out: Path,
    workers: int = 0,
    frames: int = 480,
    variants: list[str] | None = None,
    progress: bool = True,
    model: str = "ds",
    mrcal_timeout_s: float = MRCAL_TIMEOUT_S,
) -> dict:
    """Run (this rank's share of) the benchmark, write its shard, and on rank 0 merge all shards."""
    for c in configs:
        paper_config(c)  # validates the names early
    variants = variants or VARIANTS
    rank, world = int(os.environ.get("RANK", "0")), int(os.environ.get("WORLD_SIZE", "1"))
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(c, t) for c in configs for t in range(trials)]
    mine = [j for i, j in enumerate(jobs) if i % world == rank]
    workers = workers or max(1, (os.cpu_count() or 1))
    t0 = time.time()
    results = []
    if workers == 1:
        for c, t in progress_bar(mine, desc=f"benchmark rank {rank}", enabled=progress):
            results.append(run_trial(c, t, frames, variants=variants, model=model, mrcal_timeout_s=mrcal_timeout_s))
    else:
        with ProcessPoolExecutor(workers) as ex:
            futs = [ex.submit(run_trial, c, t, frames, 0.3, variants, model, mrcal_timeout_s) for c, t in mine]
            for f in progress_bar(futs, desc=f"benchmark rank {rank}", enabled=progress):
                results.append(f.result())
    shard = out / f"shard_{rank}_of_{world}.json"
    tmp = shard.with_suffix(".tmp")
    tmp.write_text(json.dumps({"trials": results, "elapsed_s": time.time() - t0}))
    os.replace(tmp, shard)
    if rank != 0:
        return {}
    deadline = time.time() + 24 * 3600
    while time.time() < deadline:
        shards = [out / f"shard_{r}_of_{world}.json" for r in range(world)]
        if all(s.is_file() for s in shards):
            break
        time.sleep(2)
    return merge(out, world, trials, variants, model)


def combine(dirs: list[Path], out: Path, trials: int, model: str = "ds") -> dict:
    """One table from benchmark runs over the same configurations and trials with different
    variants (``trials.json`` of each): a trial's variants are joined by (configuration, trial)."""
    joined: dict[tuple[str, int], dict] = {}
    variants: list[str] = []
    elapsed = 0.0
    for d in dirs:
        for t in json.loads((d / "trials.json").read_text()):
            joined.setdefault((t["config"], t["trial"]), {}).update(t)
            variants += [v for v in ALL_VARIANTS if v in t and v not in variants]
        elapsed += json.loads((d / "results.json").read_text()).get("elapsed_s", 0.0)
    out.mkdir(parents=True, exist_ok=True)
    (out / "shard_0_of_1.json").write_text(json.dumps({"trials": list(joined.values()), "elapsed_s": elapsed}))
    return merge(out, 1, trials, [v for v in ALL_VARIANTS if v in variants], model)


def merge(out: Path, world: int, trials: int, variants: list[str], model: str = "ds") -> dict:
    all_trials, elapsed = [], 0.0
    for r in range(world):
        d = json.loads((out / f"shard_{r}_of_{world}.json").read_text())
        all_trials += d["trials"]
        elapsed = max(elapsed, d["elapsed_s"])
    all_trials.sort(key=lambda t: (ALL_CONFIGS.index(t["config"]) if t["config"] in ALL_CONFIGS else 99, t["trial"]))
    summary = _summarise(all_trials, variants)
    table = _table(summary, variants, trials)
    if "mrcal" in variants:
        table += "\n\n" + (failure_table(all_trials, "mrcal") or "mrcal succeeded in every trial.")
    (out / "trials.json").write_text(json.dumps(all_trials))
    (out / "results.json").write_text(
        json.dumps(
            json_safe({"summary": summary, "elapsed_s": elapsed, "trials": trials, "strict": STRICT, "calibration_model": model}), indent=1
        )
    )
    (out / "results.md").write_text(
        f"# Synthetic calibration benchmark\n\nf-theta cameras calibrated with the `{model}` model; wall time {elapsed:.0f} s.\n\n{table}\n"
    )
    print(table)
    print(f"benchmark took {elapsed:.0f} s -> {out}/results.md")
    return {"summary": summary, "table": table, "elapsed_s": elapsed}
