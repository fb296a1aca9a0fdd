"""Per-FoV detection evaluation: ``calib-eval detection [--model M.onnx] [--fov ...] [--per-fov N] [--seed N] [--size WxH] [--out DIR]``.

1. Render a fixed, versioned benchmark set (seeded; 1280x720 unless ``--size``) per FoV: half with the
   paper's f-theta model, half with the other families (ucm, eucm, ds), plus images without a target,
   plus one row per hard condition (:data:`CONDITIONS`: large squares at the rim, over- and
   under-exposure, a low-contrast print, motion blur, strong vignetting, glare; FoV 180-240).
2. Run the learned detector and the geometry-based detectors (OpenCV ``findChessboardCornersSB``
   and ``findChessboardCorners`` + ``cornerSubPix``) on the same images; save their predictions.
3. Score in a second pass from the saved predictions.

Metrics (printed with the table):
- recall: detectable ground-truth corners (visible, local square >= ``min_square_px`` at full
  resolution, learnability > 0) found within 3 px; the learned detector must give the right id,
  geometry-based detectors (no identity) are matched by position (each prediction used once).
- error: mean and median pixel error of the recalled corners.
- outlier rate: reported corners with a wrong id or more than 3 px from their ground truth
  (for position-matched detectors: more than 3 px from every visible corner).
- false images: images without a target on which anything was reported.
- ms/image: wall time per image of each detector, including decoding the PNG.
"""

from __future__ import annotations

import dataclasses
import json
import math
import statistics
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from calib_eval.detection import DEFAULT_DETECTORS, DETECTORS
from calib_eval.detection.conditions import CONDITIONS
from calib_eval.detection.opencv_baseline import find_chessboard
from calib_eval.detection.sets import cache_key, describe, set_seed
from cotrain.detect.buffers import keep_image_buffers
from cotrain.detect.detector import Detector
from cotrain.detect.images import ImageError, load_image
from cotrain.geometry import cameras
from cotrain.progress import progress_bar
from cotrain.render.renderer import LABEL_VERSION, RenderConfig, render_batch
from cotrain.targets import Target, TargetConfig, TargetError, load_target, make_target, target_from_json

BENCH_VERSION = 1  # bump when the benchmark set changes: results are only comparable within a version
PAPER = {  # Table: detection recall / mean error (px) of the paper
    180: {"learned": (0.9330, 0.7841), "geometry": (0.7085, 0.8377)},
    200: {"learned": (0.9344, 0.7944), "geometry": (0.7049, 0.8380)},
    220: {"learned": (0.9255, 0.7941), "geometry": (0.7077, 0.8304)},
    240: {"learned": (0.9263, 0.8277), "geometry": (0.6838, 0.8553)},
}
TOL_PX = 3.0
EXPERIMENTAL = ("learned_slots", "learned_slots_polish")  # the network's per-slot read-out: reported apart from the detectors


@dataclass
class EvalConfig:
    fovs: list[int] = field(default_factory=lambda: [180, 200, 220, 240])  # FoVs (deg)
    per_fov: int = 50  # images per FoV
    n_empty: int = 20  # images without a target
    seed: int = 2026  # benchmark seed (with BENCH_VERSION: the set)
    min_square_px: float = 10.0  # detectable: local square at least this many pixels in the rendered frame
    width: int = 1280
    height: int = 720
    target: TargetConfig = field(default_factory=TargetConfig)  # the board rendered and looked for
    conditions: list[str] = field(default_factory=lambda: list(CONDITIONS))  # rows of hard frames (CONDITIONS)
    per_condition: int = 24  # images per condition


def parse_size(text: str) -> tuple[int, int]:
    """``"1280x720"`` -> (1280, 720); a clear ValueError otherwise."""
    w, sep, h = text.lower().partition("x")
    if not (sep and w.isdigit() and h.isdigit() and int(w) >= 64 and int(h) >= 64):
        raise ValueError(f"--size wants WIDTHxHEIGHT (at least 64x64), not {text!r}")
    return int(w), int(h)


def _render_cfg(
    fov: float | tuple[float, float], cfg: EvalConfig, models: list[str], no_target: bool = False, condition: str | None = None
):
    rc = RenderConfig(
        height=cfg.height,
        width=cfg.width,
        models=models,
        model_weights=[1.0] * len(models),
        fov_range=fov if isinstance(fov, tuple) else (fov, fov),
        kb4_k_scale=0.0,
        p_no_target=1.0 if no_target else 0.0,
        distance_range=(0.15, 1.2),
        target=cfg.target,
    )
    return dataclasses.replace(rc, **CONDITIONS[condition]) if condition else rc


def render_benchmark(cfg: EvalConfig, out: Path, progress: bool = True) -> dict:
    """Render the benchmark set into ``out/images`` and its labels into ``out/labels.json``."""
    img_dir = out / "images"
    img_dir.mkdir(parents=True, exist_ok=True)
    jobs = []
    for fov in cfg.fovs:
        half = cfg.per_fov // 2
        jobs += [(fov, "kb4", i) for i in range(half)] + [(fov, "other", i) for i in range(half, cfg.per_fov)]
    jobs += [(0, "empty", i) for i in range(cfg.n_empty)]
    for c in cfg.conditions:
        if c not in CONDITIONS:
            raise ValueError(f"unknown condition {c!r} (known: {', '.join(CONDITIONS)})")
        jobs += [(c, "cond", i) for i in range(cfg.per_condition)]
    labels = []
    base = set_seed(cfg.seed, cfg.width, cfg.height)  # the seed at 1280x720; mixed with the size elsewhere (sets.py)
    for fov, kind, i in progress_bar(jobs, desc="render benchmark", unit="img", enabled=progress):
        condition = fov if kind == "cond" else None
        if kind == "empty":
            rc = _render_cfg(200, cfg, list(cameras.MODELS), no_target=True)
            seed = base * 1000 + BENCH_VERSION * 100
        elif condition:
            models = ["kb4"] if i % 2 == 0 else [m for m in cameras.MODELS if m != "kb4"]
            rc = _render_cfg((180.0, 240.0), cfg, models, condition=condition)
            seed = base * 1000 + BENCH_VERSION * 100 + 50 + list(CONDITIONS).index(condition)
        else:
            rc = _render_cfg(fov, cfg, ["kb4"] if kind == "kb4" else [m for m in cameras.MODELS if m != "kb4"])
            seed = base * 1000 + BENCH_VERSION * 100 + (fov // 10)
        b = render_batch(rc, [i], seed=seed)
        if kind == "empty":
            name = f"empty_{i:03d}.png"
        elif condition:
            name = f"{condition.replace(' ', '_').replace('-', '_')}_{i:03d}.png"
        else:
            name = f"fov{fov}_{i:03d}.png"
        cv2.imwrite(str(img_dir / name), (b["image"][0, 0].numpy() * 255).round().astype(np.uint8))
        p = b["params"][0]
        model = rc.models[int(b["model_index"][0])]
        m = cameras.get_model(model)
        centre = [float(p[m.index("cx")]), float(p[m.index("cy")])]
        det = (b["visible"][0] & (b["square_px"][0] >= cfg.min_square_px) & (b["learnability"][0] > 0)).tolist()
        labels.append(
            {
                "image": name,
                "fov": (round(float(b["fov"][0]), 1) if condition else fov) if kind != "empty" else None,
                "condition": condition,
                "model": model,
                "has_target": kind != "empty",
                "corners": b["corners_raw"][0].tolist(),
                "visible": b["visible"][0].tolist(),
                "detectable": det,
                "centre": centre,
                "radius": float(b["radius"][0]),
            }
        )
    meta = {
        "version": BENCH_VERSION,
        "label_version": LABEL_VERSION,
        **cache_key(cfg.width, cfg.height),  # the seed scheme, off 1280x720 (sets.py)
        "config": dataclasses.asdict(cfg),
        "conditions": _condition_settings(cfg),
        "target": make_target(cfg.target).to_json(),
        "labels": labels,
    }
    (out / "labels.json").write_text(json.dumps(meta))
    return meta


# --------------------------------------------------------------------------------------------
# Detectors
# --------------------------------------------------------------------------------------------
def run_learned(
    model: str | None, images: list[Path], target: Target, progress: bool = True, mode: str = "grid", polish: bool = False
) -> dict:
    det = Detector(model, polish=polish, mode=mode, target=target)
    out = {}
    for p in progress_bar(images, desc=f"learned ({det.mode}{' + polish' if polish else ''})", unit="img", enabled=progress):
        t0 = time.perf_counter()
        try:
            d = det.detect(load_image(p))
            corners = [[int(i), float(x), float(y)] for i, (x, y) in zip(d.ids, d.xy)]
            err = None
        except ImageError as e:
            corners, err = [], str(e)
        out[p.name] = {"corners": corners, "ms": 1000 * (time.perf_counter() - t0), "error": err, "has_id": True}
    return out


def run_geometry(kind: str, images: list[Path], target: Target, progress: bool = True) -> dict:
    """OpenCV detectors (``opencv_sb``, ``opencv_classic``) looking for ``target``; corners carry no
    identity we trust (id -1). A file that cannot be read as an image gets no corners and its
    ``error`` (as :func:`run_learned`), and the run goes on."""
    method = kind.removeprefix("opencv_")
    out = {}
    for p in progress_bar(images, desc=kind, unit="img", enabled=progress):
        t0 = time.perf_counter()
        grey = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        c = find_chessboard(grey, (target.nx, target.ny), method) if grey is not None else None
        corners = [[-1, float(x), float(y)] for x, y in c] if c is not None else []
        err = None if grey is not None else f"{p}: not readable as an image"
        out[p.name] = {"corners": corners, "ms": 1000 * (time.perf_counter() - t0), "error": err, "has_id": False}
    return out


# --------------------------------------------------------------------------------------------
# Scoring
# --------------------------------------------------------------------------------------------
def score_image(
    pred: list[list[float]],
    has_id: bool,
    gt: np.ndarray,
    visible: np.ndarray,
    detectable: np.ndarray,
    tol: float = TOL_PX,
    symmetries: tuple[np.ndarray, ...] = (),
) -> dict:
    """Match one image's predictions to ground truth.

    pred: [[id, x, y], ...] (id -1 when the detector gives none); gt (N, 2); visible, detectable (N,).
    ``symmetries``: the target's id permutations under which it looks the same (``Target.symmetries()``;
    a checkerboard with both square counts odd or both even, under a half turn). On such a board
    one view's ids are defined up to them (the detector reports one of the equivalent sets, as
    OpenCV does), so the predictions are scored under each and the one with the most hits counts.
    A corner reported with its own id within ``tol`` of a corner the labels call hidden (an
    occluder within 2 px of it, a glare spot that washes it out, the image circle's edge) is
    neither a hit nor an outlier: it is counted in ``n_hidden`` (its id is right, and its position
    too, to the tolerance; the labels' visibility is conservative).
    Returns hits (list of (gt id, error)), n_detectable, n_reported, n_outliers, n_hidden.
    """
    if has_id and symmetries:
        options = [score_image(pred, True, gt, visible, detectable, tol)]
        for perm in symmetries:
            moved = [[int(perm[int(i)]) if 0 <= int(i) < len(perm) else int(i), x, y] for i, x, y in pred]
            options.append(score_image(moved, True, gt, visible, detectable, tol))
        return max(options, key=lambda s: (len(s["hits"]), -s["n_outliers"]))
    hits: list[tuple[int, float]] = []
    outliers = hidden = 0
    if has_id:
        for i, x, y in pred:
            i = int(i)
            e = math.hypot(x - gt[i, 0], y - gt[i, 1]) if 0 <= i < len(gt) else math.inf
            if not e <= tol:  # (NaN: a label behind the camera)
                outliers += 1
            elif not visible[i]:
                hidden += 1
            elif detectable[i]:
                hits.append((i, e))
    else:
        vis_idx = np.nonzero(visible)[0]
        used: set[int] = set()
        pairs = []
        for k, (_, x, y) in enumerate(pred):
            if len(vis_idx):
                d = np.hypot(gt[vis_idx, 0] - x, gt[vis_idx, 1] - y)
                for j in np.argsort(d):
                    if d[j] > tol:
                        break
                    pairs.append((float(d[j]), k, int(vis_idx[j])))
        pairs.sort()
        matched_pred: set[int] = set()
        for e, k, i in pairs:
            if k in matched_pred or i in used:
                continue
            matched_pred.add(k)
            used.add(i)
            if detectable[i]:
                hits.append((i, e))
        hidden_q = gt[~np.asarray(visible, bool)]
        for k, (_, x, y) in enumerate(pred):
            if k in matched_pred:
                continue
            if len(hidden_q) and np.hypot(hidden_q[:, 0] - x, hidden_q[:, 1] - y).min() <= tol:
                hidden += 1  # at a corner labelled hidden (no id to check: the position alone)
            else:
                outliers += 1
    return {"hits": hits, "n_detectable": int(np.sum(detectable)), "n_reported": len(pred), "n_outliers": outliers, "n_hidden": hidden}


def score(preds: dict[str, dict], labels: list[dict], symmetries: tuple[np.ndarray, ...] = ()) -> dict:
    """Per-FoV and overall metrics of one detector from its saved predictions (``symmetries``: the
    target's, see :func:`score_image`)."""
    groups: dict[str, dict] = {}
    errors_by_fov: dict[str, list[float]] = {}
    radial: dict[str, list[tuple[float, bool]]] = {}
    empty_flagged, n_empty = 0, 0
    ms = []
    for lab in labels:
        p = preds.get(lab["image"])
        if p is None:
            continue
        ms.append(p["ms"])
        if not lab["has_target"]:
            n_empty += 1
            empty_flagged += int(len(p["corners"]) > 0)
            continue
        gt = np.asarray(lab["corners"])
        s = score_image(p["corners"], p["has_id"], gt, np.asarray(lab["visible"]), np.asarray(lab["detectable"]), symmetries=symmetries)
        key = lab.get("condition") or str(lab["fov"])
        g = groups.setdefault(key, {"det": 0, "hit": 0, "rep": 0, "out": 0, "hid": 0})
        g["det"] += s["n_detectable"]
        g["hit"] += len(s["hits"])
        g["rep"] += s["n_reported"]
        g["out"] += s["n_outliers"]
        g["hid"] += s["n_hidden"]
        errors_by_fov.setdefault(key, []).extend(e for _, e in s["hits"])
        hit_ids = {i for i, _ in s["hits"]}
        c = np.asarray(lab["centre"])
        for i in np.nonzero(lab["detectable"])[0]:
            radial.setdefault(key, []).append((float(np.hypot(*(gt[i] - c)) / lab["radius"]), i in hit_ids))
    rows, by_condition = {}, {}
    for key, g in groups.items():
        e = errors_by_fov[key]
        (by_condition if key in CONDITIONS else rows)[key] = {
            "recall": g["hit"] / max(1, g["det"]),
            "mean_error_px": float(np.mean(e)) if e else float("nan"),
            "median_error_px": float(np.median(e)) if e else float("nan"),
            "outlier_rate": g["out"] / max(1, g["rep"]),
            "n_detectable": g["det"],
            "n_reported": g["rep"],
            "n_hidden": g["hid"],  # reported with the right id within 3 px of a corner labelled hidden (score_image)
        }
    return {
        "per_fov": rows,
        "per_condition": by_condition,
        "false_images": empty_flagged,
        "n_empty": n_empty,
        "ms_per_image": statistics.median(ms) if ms else float("nan"),
        "errors": errors_by_fov,
        "radial": radial,
    }


# --------------------------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------------------------
def _table(results: dict[str, dict], fovs: list[int]) -> str:
    lines = [
        "| FoV | detector | recall | mean err px | median err px | outliers | labelled hidden | paper recall / err |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for fov in fovs:
        for name, r in results.items():
            row = r["per_fov"].get(str(fov))
            if row is None:
                continue
            paper = PAPER.get(fov, {}).get("learned" if name.startswith("learned") else "geometry")
            ptxt = f"{paper[0]:.3f} / {paper[1]:.3f}" if paper and name in ("learned", "opencv_sb") else ""
            lines.append(
                f"| {fov} | {name} | {row['recall']:.3f} | {row['mean_error_px']:.3f} | {row['median_error_px']:.3f} | "
                f"{100 * row['outlier_rate']:.2f}% | {row.get('n_hidden', 0)} | {ptxt} |"
            )
    conditions = [c for c in CONDITIONS if any(c in r.get("per_condition", {}) for r in results.values())]
    if conditions:
        lines += [
            "",
            "| condition (FoV 180-240) | detector | recall | mean err px | median err px | outliers | labelled hidden |",
            "|---|---|---|---|---|---|---|",
        ]
        for c in conditions:
            for name, r in results.items():
                row = r.get("per_condition", {}).get(c)
                if row is not None:
                    lines.append(
                        f"| {c} | {name} | {row['recall']:.3f} | {row['mean_error_px']:.3f} | {row['median_error_px']:.3f} | "
                        f"{100 * row['outlier_rate']:.2f}% | {row.get('n_hidden', 0)} |"
                    )
    lines.append("")
    lines.append("| detector | images without target with reports | ms / image (median) |")
    lines.append("|---|---|---|")
    for name, r in results.items():
        lines.append(f"| {name} | {r['false_images']} / {r['n_empty']} | {r['ms_per_image']:.1f} |")
    return "\n".join(lines)


def _plots(results: dict[str, dict], fovs: list[int], out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    fig, axes = plt.subplots(1, len(fovs), figsize=(4 * len(fovs), 3.4), sharey=True, squeeze=False)
    bins = np.linspace(0, 1.0, 11)
    for ax, fov in zip(axes[0], fovs):
        for name, r in results.items():
            pts = r["radial"].get(str(fov), [])
            if not pts:
                continue
            rr = np.array([p[0] for p in pts])
            hit = np.array([p[1] for p in pts], dtype=float)
            idx = np.clip(np.digitize(rr, bins) - 1, 0, len(bins) - 2)
            rec = [hit[idx == b].mean() if np.any(idx == b) else np.nan for b in range(len(bins) - 1)]
            ax.plot((bins[:-1] + bins[1:]) / 2, rec, marker="o", label=name)
        ax.set_title(f"FoV {fov}")
        ax.set_xlabel("radius / image-circle radius")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("recall")
    if axes[0][-1].get_legend_handles_labels()[0]:
        axes[0][-1].legend(fontsize=8)
    fig.tight_layout()
    p = out / "recall_vs_radius.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)
    fig, ax = plt.subplots(figsize=(5, 3.4))
    for name, r in results.items():
        e = [x for v in r["errors"].values() for x in v]
        if e:
            ax.hist(e, bins=np.linspace(0, TOL_PX, 31), histtype="step", density=True, label=f"{name} (median {np.median(e):.2f})")
    ax.set_xlabel("error of recalled corners (px)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    p = out / "error_distribution.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)
    return paths


def _condition_settings(cfg: EvalConfig) -> dict:
    """The render settings of the set's conditions as labels.json stores them (a set rendered with
    other settings for a condition of the same name is rendered again)."""
    return json.loads(json.dumps({c: CONDITIONS[c] for c in cfg.conditions}))


def read_set(set_dir: str | Path, target: str | None = None, default: Target | None = None) -> tuple[dict, Target]:
    """A rendered set's ``labels.json`` (checkerboard or AprilGrid set) and its target: ``target``
    (a target file) where given, else the one the set names, else ``default``. Raises TargetError
    with a one-line message where there is no labels.json or no target."""
    path = Path(set_dir) / "labels.json"
    if not path.is_file():
        raise TargetError(f"no labels.json in {set_dir} (render a set first)")
    meta = json.loads(path.read_text())
    stored = meta.get("target") or meta.get("key", {}).get("target")
    board = load_target(target) if target else target_from_json(stored) if stored else default
    if board is None:
        raise TargetError(f"{path} names no target; give --target")
    return meta, board


def load_or_render(cfg: EvalConfig, out: Path, progress: bool = True) -> dict:
    """The set's labels from ``out/labels.json`` when they were rendered with this version,
    config and (off 1280x720) seed scheme (:func:`calib_eval.detection.sets.cache_key`); otherwise
    the set is rendered again and predictions saved for another set are removed."""
    out.mkdir(parents=True, exist_ok=True)
    labels_path = out / "labels.json"
    if labels_path.is_file():
        meta = json.loads(labels_path.read_text())
        same = meta.get("version") == BENCH_VERSION and meta.get("config") == dataclasses.asdict(cfg)
        same &= meta.get("label_version", 1) == LABEL_VERSION
        same &= all(meta.get(k) == v for k, v in cache_key(cfg.width, cfg.height).items())
        if same and meta.get("conditions", {}) == _condition_settings(cfg):
            return meta
    for stale in out.glob("predictions_*.json"):
        stale.unlink()  # from another set
    return render_benchmark(cfg, out, progress)


def evaluate_detection(model: str | None, cfg: EvalConfig, out: Path, progress: bool = True, detectors: list[str] | None = None) -> dict:
    """The whole evaluation; writes results.md, results.json and the plots into ``out``."""
    t0 = time.time()
    meta = load_or_render(cfg, out, progress)
    images = [out / "images" / lab["image"] for lab in meta["labels"]]
    detectors = detectors or DEFAULT_DETECTORS
    board = make_target(cfg.target)
    keep_image_buffers()  # as cotrain detect runs (cotrain.detect.buffers), for every detector timed here
    # Detectors not run this time keep their saved predictions on this set in the table.
    kept = [n for n in DETECTORS if n not in detectors and (out / f"predictions_{n}.json").is_file()]
    preds = {}
    for name in detectors:
        if name.startswith("learned"):
            mode = "grid" if name == "learned" else "slots"
            preds[name] = run_learned(model, images, board, progress, mode=mode, polish=name.endswith("polish"))
        else:
            preds[name] = run_geometry(name, images, board, progress=progress)
        (out / f"predictions_{name}.json").write_text(json.dumps(preds[name]))
    # Second pass: scores from the saved predictions.
    order = [n for n in DETECTORS if n in detectors or n in kept]
    results = {
        name: score(json.loads((out / f"predictions_{name}.json").read_text()), meta["labels"], board.symmetries()) for name in order
    }
    # The per-slot read-out is the network's own experimental output, not a detector a user
    # would pick: it gets a section of its own, below the detectors.
    found = {k: v for k, v in results.items() if k not in EXPERIMENTAL}
    slots = {k: v for k, v in results.items() if k in EXPERIMENTAL}
    table = _table(found, cfg.fovs)
    elapsed = time.time() - t0
    plots = _plots(found, cfg.fovs, out)
    kind = describe("checkerboard", cfg.seed, cfg.width, cfg.height)
    md = [
        f"# Detection evaluation (benchmark v{BENCH_VERSION}, seed {cfg.seed})",
        "",
        f"The set: {kind}.",
        "",
        f"{cfg.per_fov} images per FoV at {cfg.width}x{cfg.height} (half f-theta, half ucm/eucm/ds), {cfg.n_empty} without a target. "
        f"Model: {model or 'shipped default'}. Run this time: {', '.join(detectors)} ({elapsed:.0f} s)"
        + (f"; {', '.join(kept)}: saved predictions of an earlier run on the same set." if kept else "."),
        "",
        table,
        "",
        "Recall: detectable ground-truth corners found within 3 px (learned: right id; OpenCV: matched by position). "
        "Outliers: reported corners with a wrong id or over 3 px off. Labelled hidden: reported within 3 px of a corner the labels "
        "call hidden (an occluder within 2 px of it, glare that washes it out), with its id (OpenCV: at its position); "
        "neither hits nor outliers. Paper numbers: learned / geometry-based rows of its table.",
        "",
        *[f"![{p.stem}]({p.name})" for p in plots],
    ]
    if slots:
        md += [
            "",
            "## Experimental: the network's per-slot read-out (`cotrain detect --slots`)",
            "",
            "One heatmap channel per corner id, read out by the network itself (the paper's contract). It is not a "
            "detector to use: its ids are right for few corners, and most of what it reports is an outlier. The "
            "figures show how far the network has learned global identity.",
            "",
            _table(slots, cfg.fovs),
        ]
    (out / "results.md").write_text("\n".join(md) + "\n")
    slim = {k: {kk: vv for kk, vv in v.items() if kk not in ("errors", "radial")} for k, v in results.items()}
    (out / "results.json").write_text(
        json.dumps(
            {
                "version": BENCH_VERSION,
                "elapsed_s": elapsed,
                "model": model,
                "set": kind,
                "results": slim,
                "paper": {str(k): v for k, v in PAPER.items()},
            },
            indent=1,
        )
    )
    print(kind)
    print(table)
    print(f"evaluation took {elapsed:.0f} s -> {out}/results.md")
    return {"results": slim, "elapsed_s": elapsed, "table": table}
