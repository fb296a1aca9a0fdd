"""What the network's processing size and int8 cost the detector: ``python -m calib_eval.detection.processing_size``.

The shipped checkpoint (``export/default.pt``) is exported at several processing sizes
(``cotrain export --input-size``) and as the int8 graph (``cotrain export --int8``); each runs the
detector on the detection evaluation's FoV set (``calib-eval detection``'s frames, rendered once
into ``--set``). Per variant: recall per FoV, wrong ids, and the network's time alone (one
onnxruntime thread, as in ``cotrain detect`` over files on two cores; median of repeated runs).
Writes ``size_curve.md`` / ``.json`` into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from calib_eval.detection.evaluation import EvalConfig, load_or_render, run_learned, score
from cotrain.detect.onnx_model import OnnxModel
from cotrain.model.outputs import DENSE_OUTPUTS
from cotrain.targets import make_target
from export.onnx_export import export_onnx, quantize_dense

SIZES = ((216, 384), (180, 320), (144, 256), (108, 192))  # (H, W); 216x384 is the size the network was trained at


def network_ms(model: Path, runs: int = 30) -> float:
    """Median ms of one onnxruntime run (1 thread) of the dense maps on one processing-size image."""
    net = OnnxModel(model, threads=1, only=DENSE_OUTPUTS)
    x = np.random.default_rng(0).random((1, 1, *net.input_size)).astype(np.float32)
    for _ in range(3):
        net.run(x)
    t = []
    for _ in range(runs):
        t0 = time.perf_counter()
        net.run(x)
        t.append(time.perf_counter() - t0)
    return 1000 * statistics.median(t)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", default="export/default.pt")
    ap.add_argument("--set", default="report/detection_fov_set", help="folder of the rendered FoV set (rendered if missing)")
    ap.add_argument("--per-fov", type=int, default=50)
    ap.add_argument("--out", default="report/size_curve")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = EvalConfig(per_fov=a.per_fov, conditions=[])
    meta = load_or_render(cfg, Path(a.set))
    images = [Path(a.set) / "images" / lab["image"] for lab in meta["labels"]]
    board = make_target(cfg.target)
    variants: list[tuple[str, Path]] = []
    for h, w in SIZES:
        path = out / f"model_{w}x{h}.onnx"
        export_onnx(a.checkpoint, path, input_size=(h, w))
        variants.append((f"{w}x{h}", path))
    int8 = out / "model_384x216.int8.onnx"
    quantize_dense(out / "model_384x216.onnx", int8)
    variants.append(("384x216 int8", int8))
    rows = {}
    for name, path in variants:
        r = score(run_learned(str(path), images, board, progress=False), meta["labels"])
        per = r["per_fov"]
        hit = sum(v["recall"] * v["n_detectable"] for v in per.values())
        det = sum(v["n_detectable"] for v in per.values())
        wrong = sum(round(v["outlier_rate"] * v["n_reported"]) for v in per.values())
        rows[name] = {
            "recall_per_fov": {k: v["recall"] for k, v in per.items()},
            "recall": hit / max(det, 1),
            "wrong": wrong,
            "false_images": r["false_images"],
            "network_ms_1_thread": network_ms(path),
        }
        print(f"{name}: recall {rows[name]['recall']:.3f}, wrong {wrong}, network {rows[name]['network_ms_1_thread']:.1f} ms")
    fovs = [str(f) for f in cfg.fovs]
    md = [
        "# Processing size and int8: the detector's recall against the network's time",
        "",
        f"`python -m calib_eval.detection.processing_size`: the shipped checkpoint exported at each size, the detector "
        f"(grid pass) on the evaluation's FoV set ({a.per_fov} frames per FoV, 1280x720, seed {cfg.seed}); network time: "
        "dense maps only, one onnxruntime thread, median of 30 runs.",
        "",
        "| processing size | recall " + " / ".join(fovs) + " | overall | wrong ids | network ms |",
        "| --- | --- | --- | --- | --- |",
    ]
    for name, r in rows.items():
        per = " / ".join(f"{r['recall_per_fov'].get(f, float('nan')):.3f}" for f in fovs)
        md.append(f"| {name} | {per} | {r['recall']:.3f} | {r['wrong']} | {r['network_ms_1_thread']:.1f} |")
    (out / "size_curve.md").write_text("\n".join(md) + "\n")
    (out / "size_curve.json").write_text(json.dumps(rows, indent=1))
    print("\n".join(md[4:]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
