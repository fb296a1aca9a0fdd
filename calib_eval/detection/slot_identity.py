"""Does the network's per-slot read-out learn identity? ``python -m calib_eval.detection.slot_identity``.

The paper's contract is one heatmap channel per corner id. On a checkerboard a slot has to learn
global identity (which corner of a partial view this is), and the checkerboard network's slots
stayed near 0.06 recall after CPU-hours (docs/training.md). On an AprilGrid every tag names itself,
so a slot only has to read the tag under it. This script puts the two side by side:

1. ``--curve LABEL=CSV[@BATCH]`` (repeatable): training curves (``curve.csv`` of ``cotrain train``:
   step, wall time, validation per-slot recall and identity accuracy) plotted against wall time
   and against samples seen (steps x the run's batch: ``@BATCH``, else ``--batch``), to ``--out``
   (png) with a Markdown table of the figures at matching budgets;
2. ``--model M.onnx --set DIR``: the per-slot read-out of an exported model on a rendered AprilGrid
   evaluation set (``calib_eval.detection.tags``: ``labels.json`` and ``images/``) at full
   resolution: a slot's corner counts where its visibility is at least ``--threshold``; recall per
   FoV and wrong ids by the tag evaluation's rules (:func:`calib_eval.detection.tags.score_frame`).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import cv2
import numpy as np

from calib_eval.detection.tags import score_frame
from cotrain.detect.detector import slot_readout
from cotrain.detect.onnx_model import OnnxModel
from cotrain.geometry.letterbox import Letterbox
from cotrain.model.outputs import SLOT_OUTPUTS


def read_curve(path: str | Path) -> dict[str, np.ndarray]:
    """A ``curve.csv`` as columns (step, wall_s, recall, id_acc, ...; floats)."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise ValueError(f"{path}: no rows")
    missing = [k for k in ("step", "wall_s", "recall", "id_acc") if k not in rows[0]]
    if missing:
        raise ValueError(f"{path}: not a training curve (no {', '.join(missing)} column)")

    def value(r: dict, k: str) -> float:
        v = r.get(k)
        return float(v) if v not in (None, "", "nan") else np.nan

    return {k: np.array([value(r, k) for r in rows]) for k in rows[0]}


def at_budget(curve: dict[str, np.ndarray], key: str, budget: float, value: str) -> float:
    """The best ``value`` reached by ``budget`` of ``key`` (wall_s or samples); NaN before the first row."""
    on = curve[key] <= budget
    return float(np.nanmax(curve[value][on])) if on.any() else float("nan")


def plot_curves(curves: dict[str, dict[str, np.ndarray]], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for label, c in curves.items():
        for ax, key, scale, unit in (
            (axes[0], "wall_s", 60.0, "training wall time (min, log scale)"),
            (axes[1], "samples", 1.0, "samples seen"),
        ):
            (line,) = ax.plot(c[key] / scale, c["recall"], label=f"{label}: recall")
            ax.plot(c[key] / scale, c["id_acc"], "--", color=line.get_color(), label=f"{label}: slot on its corner")
            ax.set_xlabel(unit)
    axes[0].set_ylabel("validation, per-slot read-out")
    axes[0].set_xscale("log")  # minutes of a GPU beside hours of a CPU
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.set_ylim(bottom=0)
    axes[1].legend(fontsize=8)
    fig.suptitle("Per-slot identity against training budget (validation at the processing size)")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def curve_table(curves: dict[str, dict[str, np.ndarray]]) -> str:
    """Markdown: per curve, the best validation recall and identity accuracy by 5, 15, 30, 60, 90
    min, by 15,000 and 30,000 samples and at the end, with the samples seen."""
    marks = [("wall_s", 60 * m, f"by {m} min") for m in (5, 15, 30, 60, 90)]
    marks += [("samples", n, f"by {n:,} samples") for n in (15_000, 30_000)]
    head = "| run | " + " | ".join(name for _, _, name in marks) + " | end (min, samples) |"
    lines = [head, "|" + " --- |" * (len(marks) + 2)]
    for label, c in curves.items():
        cells = []
        for key, budget, _ in marks:
            r, a = at_budget(c, key, budget, "recall"), at_budget(c, key, budget, "id_acc")
            cells.append("-" if np.isnan(r) else f"{r:.3f} / {a:.3f}")
        end = f"{np.nanmax(c['recall']):.3f} / {np.nanmax(c['id_acc']):.3f} ({c['wall_s'][-1] / 60:.0f}, {int(c['samples'][-1])})"
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {end} |")
    return "\n".join(lines) + "\n\nCells: best validation recall / share of slots on their corner so far.\n"


def slots_in_image(model: OnnxModel, grey: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Ids (K,) and input pixels (K, 2) of the slots the model reports in ``grey`` (H, W) (see
    :func:`cotrain.detect.detector.slot_readout`)."""
    h, w = grey.shape
    box = Letterbox(w, h, model.input_size)
    keep, xy = slot_readout(model.run(box.apply(grey)[None, None], SLOT_OUTPUTS), box, threshold)
    ids = np.nonzero(keep)[0]
    return ids, xy[ids]


def evaluate_slots(model_path: str | Path, set_dir: Path, threshold: float = 0.5, min_tag_px: float = 8.0) -> dict:
    """Per-slot read-out of an AprilGrid model on a rendered set: recall overall and per FoV, wrong ids."""
    model = OnnxModel(model_path, only=SLOT_OUTPUTS)
    if model.target.kind != "aprilgrid":
        raise ValueError(f"{model_path}: trained on a {model.target.kind}, not an aprilgrid")
    labels = json.loads((set_dir / "labels.json").read_text())["labels"]
    per_fov: dict[str, list[int]] = {}
    wrong = empty_reports = reported = 0
    for lab in labels:
        grey = cv2.imread(str(set_dir / "images" / lab["image"]), cv2.IMREAD_GRAYSCALE)
        if grey is None:
            print(f"{lab['image']}: unreadable, skipped", file=sys.stderr)
            continue
        ids, xy = slots_in_image(model, grey.astype(np.float32) / 255, threshold)
        if lab["fov"] is None:
            empty_reports += len(ids) > 0
            continue
        s = score_frame(ids.tolist(), list(xy), lab, min_tag_px)
        reported += len(ids)
        tot = per_fov.setdefault(str(lab["fov"]), [0, 0])
        tot[0] += int(s["det"].sum())
        tot[1] += int(s["hit"].sum())
        wrong += s["wrong"]
    det = sum(v[0] for v in per_fov.values())
    hit = sum(v[1] for v in per_fov.values())
    return {
        "recall": hit / max(det, 1),
        "per_fov": {k: v[1] / max(v[0], 1) for k, v in sorted(per_fov.items())},
        "wrong": wrong,
        "reported": reported,
        "frames_without_target_with_reports": empty_reports,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--curve", action="append", default=[], metavar="LABEL=CSV[@BATCH]", help="a training curve and its run's batch size (repeatable)"
    )
    ap.add_argument("--batch", type=int, default=8, help="batch size of the runs whose --curve names none (samples = steps x batch)")
    ap.add_argument("--out", default="docs/results/slot_identity.png", help="plot of the curves (a .md table beside it)")
    ap.add_argument("--model", help="an exported AprilGrid model (ONNX) to read out on --set")
    ap.add_argument("--set", default="runs/tags_eval50", help="rendered AprilGrid set (calib_eval.detection.tags --out)")
    ap.add_argument("--threshold", type=float, default=0.5, help="a slot reports its corner at this visibility")
    a = ap.parse_args(argv)
    if not a.curve and not a.model:
        ap.error("give --curve LABEL=CSV and / or --model M.onnx")
    try:
        if a.curve:
            curves = {}
            for spec in a.curve:
                label, sep, path = spec.partition("=")
                if not sep:
                    raise ValueError(f"--curve {spec!r}: expected LABEL=CSV[@BATCH]")
                head, _, tail = path.rpartition("@")
                batch = a.batch
                if head and tail.isdigit():  # CSV@BATCH (a path may hold an @ of its own)
                    path, batch = head, int(tail)
                    if batch < 1:
                        raise ValueError(f"--curve {spec!r}: the batch after @ must be a positive integer")
                c = read_curve(path)
                c["samples"] = c["step"] * batch
                curves[label] = c
            out = Path(a.out)
            out.parent.mkdir(parents=True, exist_ok=True)
            plot_curves(curves, out)
            table = curve_table(curves)
            out.with_suffix(".md").write_text(table)
            print(table)
            print(f"plot: {out}")
        if a.model:
            r = evaluate_slots(a.model, Path(a.set), a.threshold)
            print(json.dumps(r, indent=1))
    except (OSError, ValueError, KeyError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
