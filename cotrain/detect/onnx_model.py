"""The exported network as the detector runs it: one loader that checks the ONNX's contract.

    net = OnnxModel(path)                 # raises a one-line ValueError for a file that is no cotrain model
    out = net.run(batch)                  # {name: array} for the names of cotrain.model.outputs
    net.input_size, net.target            # processing size (H, W) and the target it was trained on

The outputs are read by name (:mod:`cotrain.model.outputs`), never by position.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from cotrain.model.outputs import DENSE_OUTPUTS, INPUT, SLOT_OUTPUTS
from cotrain.targets import Checkerboard, Target, TargetError, target_from_json


def default_model_path() -> Path:
    """The shipped checkerboard model (``export/default.onnx``, installed with the package)."""
    from importlib.resources import files

    return Path(str(files("export") / "default.onnx"))


class OnnxModel:
    """An onnxruntime session on the CPU over a cotrain ONNX model, with its metadata."""

    def __init__(self, path: str | Path | None = None, threads: int = 0):
        import onnxruntime as ort

        self.path = Path(path) if path else default_model_path()
        if not self.path.is_file():
            hint = "" if path else " (the shipped default model is missing; pass --model)"
            raise FileNotFoundError(f"{self.path}: model not found{hint}")
        opts = ort.SessionOptions()
        if threads:
            opts.intra_op_num_threads = threads
        try:
            self.session = ort.InferenceSession(str(self.path), opts, providers=["CPUExecutionProvider"])
        except Exception as e:
            raise ValueError(f"{self.path}: not a loadable ONNX model ({type(e).__name__})") from None
        meta = self.session.get_modelmeta().custom_metadata_map
        if "cotrain.input_size" not in meta:
            raise ValueError(f"{self.path}: not a cotrain model (no cotrain.input_size metadata)")
        self.input_size: tuple[int, int] = tuple(json.loads(meta["cotrain.input_size"]))  # (H, W)
        try:
            trained = json.loads(meta["cotrain.target"]) if "cotrain.target" in meta else Checkerboard().to_json()
            self.target: Target = target_from_json(trained)
        except (TargetError, json.JSONDecodeError) as e:
            raise ValueError(f"{self.path}: bad cotrain.target metadata ({e})") from None
        inputs = [i.name for i in self.session.get_inputs()]
        names = {o.name for o in self.session.get_outputs()}
        if INPUT not in inputs:
            raise ValueError(f"{self.path}: no input named {INPUT!r} (has {', '.join(inputs)})")
        missing = [n for n in SLOT_OUTPUTS if n not in names]
        if missing:
            raise ValueError(f"{self.path}: the model lacks the outputs {', '.join(missing)}")
        # A model exported before the grid pass has no dense maps: only the per-slot read-out runs.
        self.has_dense = all(n in names for n in DENSE_OUTPUTS)
        self.outputs = SLOT_OUTPUTS + (DENSE_OUTPUTS if self.has_dense else ())

    def run(self, batch: np.ndarray, names: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
        """Outputs by name for (B, 1, H, W) float32 processing-size images (``names``: a subset)."""
        names = tuple(names or self.outputs)
        return dict(zip(names, self.session.run(list(names), {INPUT: batch.astype(np.float32)})))
