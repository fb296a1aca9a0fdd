"""The exported model's outputs, by name: the contract between ``export/`` and the detector.

The ONNX graph takes ``image`` (B, 1, H, W) float32 grey in [0, 1] at the processing size
(:class:`cotrain.geometry.letterbox.Letterbox`) and returns, in this order:

==============  =====================  ======================================================
name            shape                  meaning
==============  =====================  ======================================================
corners         (B, N, 2)              per-slot refined corners, processing pixels
visibility      (B, N)                 per-slot visibility probability
confidence      (B, N)                 per-slot probability that the corner is within ~0.5 px
learnability    (B, N)                 per-slot learnability in [0, 1]
corner_prob     (B, 1, h, w)           class-agnostic corner probability per 1/4 cell
mask_prob       (B, 1, h, w)           probability that the cell is on the checker squares
col_logp        (B, nx + 2, h, w)      log-probability of the nearest corner column -1 .. nx
row_logp        (B, ny + 2, h, w)      log-probability of the nearest corner row -1 .. ny
==============  =====================  ======================================================

The int8 graph of the dense maps (``export.onnx_export.quantize_dense``) also returns
``col_logits`` and ``row_logits``: the column / row maps before their log-softmax over the channel
axis. The detector runs it for those in place of ``col_logp`` / ``row_logp`` and takes the
log-softmax itself (:func:`dense_maps`) in the thread of the grid pass, not in the one that runs
the network: there onnxruntime's log-softmax over the channels took 1 ms of the network's 14.

(h, w) = (H, W) / 4 (:data:`cotrain.geometry.letterbox.CELLS`). The per-slot outputs are the
paper's read-out; the dense maps are what the detector's grid pass reads.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

INPUT = "image"
SLOT_OUTPUTS = ("corners", "visibility", "confidence", "learnability")
DENSE_OUTPUTS = ("corner_prob", "mask_prob", "col_logp", "row_logp")
OUTPUTS = SLOT_OUTPUTS + DENSE_OUTPUTS
LOGITS = {"col_logp": "col_logits", "row_logp": "row_logits"}  # a log-probability map -> its maps before the log-softmax
GRID_OUTPUTS = ("corner_prob", "mask_prob", *LOGITS.values())  # what the grid pass runs where a graph has the logits


def log_softmax_channels(logits: np.ndarray) -> np.ndarray:
    """Log-softmax over the channel axis of maps (..., C, h, w) -> (..., C, h, w) float32 (as the
    graph's LogSoftmax: the largest value subtracted first)."""
    z = logits - logits.max(axis=-3, keepdims=True)
    return (z - np.log(np.exp(z).sum(axis=-3, keepdims=True))).astype(np.float32)


def dense_maps(out: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The dense maps of :data:`DENSE_OUTPUTS` by name from a graph's outputs ``out``: each
    log-probability map as given, or from its logits (:data:`LOGITS`) where ``out`` has those."""
    return {name: out[name] if name in out else log_softmax_channels(out[LOGITS[name]]) for name in DENSE_OUTPUTS}


# An int8 graph of the dense maps (export.onnx_export.quantize_dense) records in this metadata key
# the sha256 of the float graph it was made from; the detector runs it only beside that graph
# (cotrain.detect.onnx_model.default_grid_model_path).
SOURCE_KEY = "cotrain.source_sha256"


def file_sha256(path: str | Path) -> str:
    """The hex sha256 of a file's bytes (:data:`SOURCE_KEY`)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()
