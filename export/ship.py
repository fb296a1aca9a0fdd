"""Ship a trained model: ``python -m export.ship CHECKPOINT [--name NAME]`` writes ``export/NAME.pt``
(float16 weights and config only, no optimizer state) and ``export/NAME.onnx`` (with the parity
check); NAME is ``default`` (the checkerboard model the detector loads) unless given, e.g.
``aprilgrid`` for the AprilGrid network. A checkerboard model also gets ``export/NAME.int8.onnx``:
its dense maps with int8 convolutions, the graph the grid pass runs by default
(:func:`cotrain.detect.onnx_model.default_grid_model_path`). Check that graph's detections on the
kept sets before shipping it (docs/results/size_curve.md)."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import torch

from cotrain.model.train import load_checkpoint
from export.onnx_export import export_onnx, quantize_dense

HERE = Path(__file__).resolve().parent


def ship(checkpoint: str | Path, name: str = "default") -> dict:
    if not re.fullmatch(r"[A-Za-z0-9_-]+", name):
        raise ValueError(f"--name {name!r}: a plain file stem (letters, digits, _ and -)")
    ck = load_checkpoint(checkpoint)
    kind = ck["config"].get("render", {}).get("target", {}).get("kind", "checkerboard")  # older configs: checkerboard
    if name == "default" and kind != "checkerboard":
        raise ValueError(f"{checkpoint}: trained on a {kind}; export/default is the checkerboard model the detector loads (give --name)")
    # Half-precision storage keeps the repository light; loading casts back to float32.
    weights = {k: v.half() if v.is_floating_point() else v for k, v in ck["model"].items()}
    slim = {"model": weights, "config": ck["config"], "step": ck["step"], "best_score": ck["best_score"], "wall_time": ck["wall_time"]}
    pt, onnx_path = HERE / f"{name}.pt", HERE / f"{name}.onnx"
    torch.save(slim, pt)
    r = export_onnx(pt, onnx_path)
    if kind == "checkerboard":
        q = quantize_dense(onnx_path, onnx_path.with_suffix(".int8.onnx"))
        print(f"wrote {q['out']} (int8 dense maps for the grid pass)")
    sel = ck["config"]["train"].get("select_by", "recall")
    print(f"shipped step {ck['step']} (validation {sel} {ck['best_score']:.3f}) -> {pt}, {onnx_path}")
    return r


if __name__ == "__main__":
    ap = argparse.ArgumentParser(
        description="ship a checkpoint as export/NAME.pt, export/NAME.onnx (and NAME.int8.onnx for a checkerboard model)"
    )
    ap.add_argument("checkpoint")
    ap.add_argument("--name", default="default", help="file stem under export/ (default: the checkerboard model)")
    a = ap.parse_args()
    try:
        ship(a.checkpoint, a.name)
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"error: {e}") from None
