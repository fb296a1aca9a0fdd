"""Ship a trained model: ``python -m export.ship CHECKPOINT`` writes ``export/default.pt`` (float16
weights and config only, no optimizer state) and ``export/default.onnx`` (with the parity check)."""

from __future__ import annotations

import sys
from pathlib import Path

import torch

from cotrain.model.train import load_checkpoint
from export.onnx_export import export_onnx

HERE = Path(__file__).resolve().parent


def ship(checkpoint: str | Path) -> dict:
    ck = load_checkpoint(checkpoint)
    # Half-precision storage keeps the repository light; loading casts back to float32.
    weights = {k: v.half() if v.is_floating_point() else v for k, v in ck["model"].items()}
    slim = {"model": weights, "config": ck["config"], "step": ck["step"], "best_score": ck["best_score"], "wall_time": ck["wall_time"]}
    torch.save(slim, HERE / "default.pt")
    r = export_onnx(HERE / "default.pt", HERE / "default.onnx")
    sel = ck["config"]["train"].get("select_by", "recall")
    print(f"shipped step {ck['step']} (validation {sel} {ck['best_score']:.3f}) -> {HERE / 'default.pt'}, {HERE / 'default.onnx'}")
    return r


if __name__ == "__main__":
    ship(sys.argv[1])
