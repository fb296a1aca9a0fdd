"""The exported network as the detector runs it: one loader that checks the ONNX's contract.

    net = OnnxModel(path)                 # raises a one-line ValueError for a file that is no cotrain model
    out = net.run(batch)                  # {name: array} for the names of cotrain.model.outputs
    net.input_size, net.target            # processing size (H, W) and the target it was trained on

The outputs are read by name (:mod:`cotrain.model.outputs`), never by position. ``only`` keeps the
part of the graph that computes the named outputs (the grid pass reads the dense maps; the
per-slot read-out's point heads are then not run at all). A graph with only the dense maps (an
int8 graph from ``cotrain export --int8``) is a model for the grid pass alone.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from cotrain.model.outputs import DENSE_OUTPUTS, INPUT, LOGITS, SLOT_OUTPUTS, SOURCE_KEY, file_sha256
from cotrain.targets import Checkerboard, Target, TargetError, target_from_json


def default_model_path() -> Path:
    """The shipped checkerboard model (``export/default.onnx``, installed with the package)."""
    from importlib.resources import files

    return Path(str(files("export") / "default.onnx"))


def default_grid_model_path(float_path: str | Path | None = None) -> Path:
    """The graph the grid pass runs by default: the shipped model's dense maps with int8
    convolutions (``export/default.int8.onnx``, written by ``python -m export.ship``; the same FoV
    recall and wrong corners as the float graph on the kept sets, its network about twice as fast;
    docs/results/size_curve.md) where it is installed and made from the shipped float graph (its
    :data:`SOURCE_KEY` metadata), else :func:`default_model_path`. ``float_path``: another float
    graph than the shipped one, its int8 graph beside it (``NAME.int8.onnx``)."""
    import onnx

    float_path = Path(float_path) if float_path else default_model_path()
    int8 = float_path.with_suffix(".int8.onnx")
    if not (int8.is_file() and float_path.is_file()):
        return float_path
    try:
        meta = {p.key: p.value for p in onnx.load(str(int8)).metadata_props}
    except Exception:
        return float_path
    return int8 if meta.get(SOURCE_KEY) == file_sha256(float_path) else float_path


class OnnxModel:
    """An onnxruntime session on the CPU over a cotrain ONNX model, with its metadata.

    ``threads``: onnxruntime's intra-op threads; 0: half the cores (at least one), so that the
    grid pass of the previous image and the reading of the next have the other half
    (:func:`cotrain.io.detections.detect_files` runs them side by side; on two cores this is 1.5x
    the throughput of two onnxruntime threads). ``only``: the outputs to compute (default all the
    model has)."""

    def __init__(self, path: str | Path | None = None, threads: int = 0, only: tuple[str, ...] | None = None):
        import onnx

        self.path = Path(path) if path else default_model_path()
        if not self.path.is_file():
            hint = "" if path else " (the shipped default model is missing; pass --model)"
            raise FileNotFoundError(f"{self.path}: model not found{hint}")
        try:
            proto = onnx.load(str(self.path))
        except Exception as e:
            raise ValueError(f"{self.path}: not a loadable ONNX model ({type(e).__name__})") from None
        meta = {p.key: p.value for p in proto.metadata_props}
        if "cotrain.input_size" not in meta:
            raise ValueError(f"{self.path}: not a cotrain model (no cotrain.input_size metadata)")
        self.input_size: tuple[int, int] = tuple(json.loads(meta["cotrain.input_size"]))  # (H, W)
        try:
            trained = json.loads(meta["cotrain.target"]) if "cotrain.target" in meta else Checkerboard().to_json()
            self.target: Target = target_from_json(trained)
        except (TargetError, json.JSONDecodeError) as e:
            raise ValueError(f"{self.path}: bad cotrain.target metadata ({e})") from None
        inputs = [i.name for i in proto.graph.input]
        names = {o.name for o in proto.graph.output}
        if INPUT not in inputs:
            raise ValueError(f"{self.path}: no input named {INPUT!r} (has {', '.join(inputs)})")
        # A model exported before the grid pass has no dense maps (only the per-slot read-out
        # runs); an int8 graph for the grid pass has only the dense maps.
        self.has_dense = all(n in names for n in DENSE_OUTPUTS)
        self.has_slots = all(n in names for n in SLOT_OUTPUTS)
        if not (self.has_dense or self.has_slots):
            missing = [n for n in SLOT_OUTPUTS + DENSE_OUTPUTS if n not in names]
            raise ValueError(f"{self.path}: the model lacks the outputs {', '.join(missing)}")
        self.has_logits = all(n in names for n in LOGITS.values())  # the int8 graph's column / row maps before the log-softmax
        self.outputs = (
            (SLOT_OUTPUTS if self.has_slots else ())
            + (DENSE_OUTPUTS if self.has_dense else ())
            + (tuple(LOGITS.values()) if self.has_logits else ())
        )
        self._proto, self._threads, self._session = proto, threads, None
        if only is not None:
            self.keep(only)

    def keep(self, names: tuple[str, ...]) -> None:
        """Compute only the outputs ``names`` from now on: the graph is cut to what they need."""
        lacking = [n for n in names if n not in self.outputs]
        if lacking:
            raise ValueError(f"{self.path}: the model lacks the outputs {', '.join(lacking)}")
        if set(names) != set(self.outputs):
            import onnx

            self._proto = onnx.utils.Extractor(self._proto).extract_model([INPUT], list(names))
            self._session = None
        self.outputs = tuple(names)

    @property
    def threads(self) -> int:
        """onnxruntime's intra-op threads (0: half the cores); setting it drops the session, which
        is made anew on the next run."""
        return self._threads

    @threads.setter
    def threads(self, n: int) -> None:
        self._threads, self._session = n, None

    def __getstate__(self) -> dict:
        """Pickled (to a worker process) without the onnxruntime session: it is made there anew."""
        return {**self.__dict__, "_session": None}

    @property
    def session(self):
        """The onnxruntime session over the (possibly cut) graph, made on first use."""
        if self._session is None:
            import onnxruntime as ort

            opts = ort.SessionOptions()
            opts.intra_op_num_threads = self._threads or max(1, (os.cpu_count() or 2) // 2)
            try:
                self._session = ort.InferenceSession(self._proto.SerializeToString(), opts, providers=["CPUExecutionProvider"])
            except Exception as e:
                raise ValueError(f"{self.path}: not a loadable ONNX model ({type(e).__name__})") from None
        return self._session

    def run(self, batch: np.ndarray, names: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
        """Outputs by name for (B, 1, H, W) float32 processing-size images (``names``: a subset)."""
        names = tuple(names or self.outputs)
        return dict(zip(names, self.session.run(list(names), {INPUT: batch.astype(np.float32)})))
