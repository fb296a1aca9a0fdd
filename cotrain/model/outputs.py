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

(h, w) = (H, W) / 4 (:data:`cotrain.geometry.letterbox.CELLS`). The per-slot outputs are the
paper's read-out; the dense maps are what the detector's grid pass reads.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

INPUT = "image"
SLOT_OUTPUTS = ("corners", "visibility", "confidence", "learnability")
DENSE_OUTPUTS = ("corner_prob", "mask_prob", "col_logp", "row_logp")
OUTPUTS = SLOT_OUTPUTS + DENSE_OUTPUTS


# An int8 graph of the dense maps (export.onnx_export.quantize_dense) records in this metadata key
# the sha256 of the float graph it was made from; the detector runs it only beside that graph
# (cotrain.detect.onnx_model.default_grid_model_path).
SOURCE_KEY = "cotrain.source_sha256"


def file_sha256(path: str | Path) -> str:
    """The hex sha256 of a file's bytes (:data:`SOURCE_KEY`)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()
