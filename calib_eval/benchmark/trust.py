"""Is the verdict right, and is the stated sigma honest? ``python -m calib_eval.benchmark.trust``.

Synthetic stereo rigs (FoV220_90, 0.3 px corner noise) with ground truth, one case per cause the
verdict must name (:mod:`calib_eval.calibration.trust`), calibrated and assessed as
``calib-eval calibrate`` does:

- ``clean``: independent random views; sigma coverage (share of focal, principal point,
  baseline and rotation components within 2 sigma of the truth) and no cause;
- ``offset_5/15/30``: a continuous recording, cam1 exposed 5 / 15 / 30 ms after its stamp;
  ``unsynchronised`` named (default settings), then ``--time-offset auto``: the offset recovered
  within 1 ms, the clean tolerances met, and sigma coverage;
- ``bent_1..5``: the board bent by 1-5 mm at its centre (a cylinder); the bend recovered within
  0.5 mm, the clean tolerances met, ``board_not_flat`` named;
- ``model``: an EUCM lens (alpha 0.7, beta 1.5) calibrated as kb4: ``camera_model`` named;
- ``ds_as_kb4``: a double-sphere lens (the default shape) calibrated as kb4, which fits it;
- ``few_views``: 12 frames: ``few_views`` named.

The checks' thresholds come from noise statistics; they were looked at on seeds 0-5 while being
built, and ``min_tie_excess`` was raised from 1.5 to 2 after a run on seeds 1000-1009 (1 of 10
twelve-view rigs named unsynchronised): the reported figures are on seeds from 2000
(``--seed0 2000``). Every trial is written to
``OUT/trials.jsonl`` as it finishes (a rerun skips finished trials); ``results.md`` and
``results.json`` summarise them.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation

SEED0 = 1000
CLEAN = {"focal_pct": 0.5, "pp_px": 1.0, "ext_mm": 1.0, "ext_deg": 0.1}  # the clean tolerances
CASES: dict[str, dict] = {
    "clean": {"synth": {"n_frames": 160}, "expect": None, "coverage": True},
    **{
        f"offset_{ms}": {
            "synth": {"n_frames": 240, "motion": "continuous", "time_offsets_s": (0.0, ms / 1000)},
            "expect": "unsynchronised",
            "auto": True,
            "coverage": True,
            "offset_s": ms / 1000,
        }
        for ms in (5, 15, 30)
    },
    **{
        f"bent_{mm}": {"synth": {"n_frames": 160, "bend_m": mm / 1000}, "expect": "board_not_flat", "bend_m": mm / 1000} for mm in (1, 3, 5)
    },
    "model": {"synth": {"n_frames": 160}, "rig": {"model": "eucm", "shape": {"alpha": 0.7, "beta": 1.5}}, "expect": "camera_model"},
    "ds_as_kb4": {"synth": {"n_frames": 160}, "rig": {"model": "ds"}, "expect": None},
    "few_views": {"synth": {"n_frames": 12}, "expect": "few_views"},
}


def _z_scores(res, trust, gt) -> list[float]:
    """(error / sigma) of fx, fy, cx, cy per camera, the baseline and the 3 rotation components."""
    u = trust.uncertainty
    z = []
    for c in range(len(res.model)):
        z += list((np.asarray(res.intrinsics[c][:4]) - gt.params[c][:4]) / u.intrinsics_sigma[c][:4])
    pu = u.pairs[(0, 1)]
    T_est, T_true = res.T_cam_rig[1], gt.T_cam_rig[1]
    w = Rotation.from_matrix(T_true[:3, :3] @ T_est[:3, :3].T).as_rotvec()
    z.append((np.linalg.norm(T_est[:3, 3]) - np.linalg.norm(T_true[:3, 3])) / pu.baseline_sigma_m)
    z += list(-w / np.radians(pu.rotation_sigma_xyz_deg))
    return [float(x) for x in z]


def _errors(res, gt) -> dict:
    focal = max(abs(res.intrinsics[c][k] / gt.params[c][k] - 1) * 100 for c in range(2) for k in (0, 1))
    pp = max(float(np.linalg.norm(np.asarray(res.intrinsics[c][2:4]) - gt.params[c][2:4])) for c in range(2))
    D = res.T_cam_rig[1] @ np.linalg.inv(gt.T_cam_rig[1])
    ext_mm = 1000 * float(np.linalg.norm(res.T_cam_rig[1][:3, 3] - gt.T_cam_rig[1][:3, 3]))
    ext_deg = math.degrees(float(np.linalg.norm(Rotation.from_matrix(D[:3, :3]).as_rotvec())))
    out = {"focal_pct": float(focal), "pp_px": pp, "ext_mm": ext_mm, "ext_deg": ext_deg}
    out["clean_tolerances"] = all(out[k] < v for k, v in CLEAN.items())
    return out


def run_trial(case: str, trial: int, seed0: int = SEED0) -> dict:
    """Calibrate and assess one synthetic rig of ``case``; score it against its ground truth."""
    from calib_eval.benchmark.rigs import SynthSpec, make_sequence, paper_config
    from calib_eval.calibration.calibrator import CalibConfig, calibrate
    from calib_eval.calibration.trust import assess

    torch.set_num_threads(1)
    spec = CASES[case]
    rig = paper_config("FoV220_90")
    for k, v in spec.get("rig", {}).items():
        setattr(rig, k, v)
    seq, gt = make_sequence(rig, SynthSpec(**spec["synth"]), seed=seed0 + trial)
    out: dict = {"case": case, "trial": trial, "seed": seed0 + trial}
    for mode in ("default", "auto") if spec.get("auto") else ("default",):
        cfg = CalibConfig(model="kb4", fov=rig.fov, time_offset="auto" if mode == "auto" else "estimate")
        t0 = time.time()
        res = calibrate(seq, cfg)
        t1 = time.time()
        trust = assess(res, seq, cfg)
        row = {"success": res.success, "calibrate_s": t1 - t0, "assess_s": time.time() - t1, "level": trust.verdict.level}
        row["causes"] = sorted({c.code for c in trust.verdict.causes})
        row["texts"] = [c.text for c in trust.verdict.causes]
        if res.success:
            row.update(_errors(res, gt))
            row["z"] = _z_scores(res, trust, gt) if spec.get("coverage") else []
            row["warp_mm"] = (res.warp_m * 1000).tolist()
            est = [e for e in res.time_offset_estimates if e.value_s is not None]
            row["offset_s"] = est[0].value_s if est else None
            cv = trust.cross_validation
            row["spread_ratio"] = cv.spread_ratio if cv is not None and cv.ok else None
        out[mode] = row
    return out


def _share(rows, pred) -> str:
    n = sum(1 for r in rows if pred(r))
    return f"{n} / {len(rows)}"


def summarise(trials: list[dict]) -> tuple[str, dict]:
    """The results table (markdown) and its figures."""
    lines = [
        "| case | trials | expected cause named | no cause | other causes seen | check | result |",
        "|---|---|---|---|---|---|---|",
    ]
    figures: dict = {}
    for case, spec in CASES.items():
        rows = [t for t in trials if t["case"] == case]
        if not rows:
            continue
        d = [t["default"] for t in rows]
        exp = spec["expect"]
        named = _share(d, lambda r, exp=exp: exp in r["causes"]) if exp else "-"
        none = _share(d, lambda r: not r["causes"])
        others = sorted({c for r in d for c in r["causes"] if c != exp})
        check, result = _case_check(case, spec, rows)
        figures[case] = {"named": named, "no_cause": none, "others": others, "check": check, "result": result}
        lines.append(f"| {case} | {len(rows)} | {named} | {none} | {', '.join(others) or '-'} | {check} | {result} |")
    z = [x for t in trials for m in (("auto",) if CASES[t["case"]].get("auto") else ("default",)) if m in t for x in t[m].get("z", [])]
    if z:
        za = np.abs(np.asarray(z))
        figures["coverage"] = {"within_2_sigma": float((za < 2).mean()), "within_1_sigma": float((za < 1).mean()), "n": len(z)}
        figures["coverage"]["rms_z"] = float(np.sqrt((np.asarray(z) ** 2).mean()))
        lines += [
            "",
            f"Sigma coverage over {len(z)} parameters (fx, fy, cx, cy of both cameras, baseline, 3 rotation components; clean and "
            f"corrected offset rigs): {100 * figures['coverage']['within_2_sigma']:.1f} % within 2 sigma "
            f"(Gaussian: 95.4 %), {100 * figures['coverage']['within_1_sigma']:.1f} % within 1 sigma (68.3 %), RMS z "
            f"{figures['coverage']['rms_z']:.2f}.",
        ]
    times = [t["default"]["calibrate_s"] for t in trials if t["case"] == "clean"]
    ass = [t["default"]["assess_s"] for t in trials if t["case"] == "clean"]
    if times:
        lines.append(f"\nClean 160-frame rigs: calibration median {np.median(times):.1f} s, trust checks median {np.median(ass):.1f} s.")
    return "\n".join(lines) + "\n", figures


def _case_check(case: str, spec: dict, rows: list[dict]) -> tuple[str, str]:
    """The case's own check over its trials (failed calibrations count against it)."""
    try:
        return _case_check_rows(case, spec, rows)
    except (KeyError, ValueError, TypeError) as e:  # a failed trial lacks the figures
        return "-", f"not computed: {type(e).__name__} {e} (a trial without the figures)"


def _case_check_rows(case: str, spec: dict, rows: list[dict]) -> tuple[str, str]:
    if case.startswith("offset"):
        a = [t["auto"] for t in rows]
        err = [abs(r["offset_s"] - spec["offset_s"]) * 1000 for r in a if r.get("offset_s") is not None]
        ok = _share(a, lambda r: r.get("clean_tolerances"))
        return (
            "auto: offset error < 1 ms; clean tolerances",
            f"max {max(err):.2f} ms (median {np.median(err):.2f}); {ok} within tolerances; "
            f"worst {max(r['ext_mm'] for r in a):.2f} mm / {max(r['ext_deg'] for r in a):.3f} deg / {max(r['focal_pct'] for r in a):.3f} %",
        )
    if case.startswith("bent"):
        d = [t["default"] for t in rows]
        err = [abs(r["warp_mm"][0] - spec["bend_m"] * 1000) for r in d if r.get("warp_mm")]
        ok = _share(d, lambda r: r.get("clean_tolerances"))
        return "bend error < 0.5 mm; clean tolerances", f"max {max(err):.2f} mm; {ok} within tolerances"
    if case == "clean":
        d = [t["default"] for t in rows]
        sr = [r["spread_ratio"] for r in d if r.get("spread_ratio") is not None]
        return "cross-validation spread ratio", f"median {np.median(sr):.2f}, max {max(sr):.2f}"
    return "-", "-"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m calib_eval.benchmark.trust", description=__doc__.split("\n")[0])
    p.add_argument("--trials", type=int, default=10, help="trials per case (the clean case gets 5x this)")
    p.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    p.add_argument("--seed0", type=int, default=SEED0, help="the first trial's seed (trial k: seed0 + k)")
    p.add_argument("--out", default="report/trust")
    a = p.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    log = out / "trials.jsonl"
    done = [json.loads(x) for x in log.read_text().splitlines()] if log.exists() else []
    done = [t for t in done if t.get("seed", a.seed0 + t["trial"]) == a.seed0 + t["trial"]]  # another --seed0's trials are not these
    have = {(t["case"], t["trial"]) for t in done}
    todo = [(c, k) for c in a.cases for k in range(a.trials * (5 if c == "clean" else 1)) if (c, k) not in have]
    print(f"{len(todo)} trials to run ({len(have)} done) with {a.workers} workers -> {out}", flush=True)
    with ProcessPoolExecutor(a.workers) as ex:
        cases, trials = zip(*todo) if todo else ((), ())
        for i, t in enumerate(ex.map(run_trial, cases, trials, [a.seed0] * len(todo))):
            done.append(t)
            with log.open("a") as f:
                f.write(json.dumps(t) + "\n")
            d = t["default"]
            print(f"[{i + 1}/{len(todo)}] {t['case']} #{t['trial']}: {d['level']} {d['causes']} ({d['calibrate_s']:.1f} s)", flush=True)
    table, figures = summarise([t for t in done if t["case"] in a.cases])
    (out / "results.md").write_text(table)
    (out / "results.json").write_text(json.dumps(figures, indent=1))
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
