"""``cotrain export --checkpoint C --out model.onnx``: ONNX (opset 18) with self-describing metadata.

The graph's input and outputs are named in :mod:`cotrain.model.outputs` (the contract the detector
reads them by, :mod:`cotrain.detect.onnx_model`). Resizing (the letterbox, top-left) happens
outside the graph in the detector, as the metadata says. After export, onnxruntime is compared
with PyTorch on rendered images; the export fails if any corner differs by more than ``tol_px``.
"""

from __future__ import annotations

import json
import logging
import os
import warnings
from pathlib import Path

import numpy as np
import torch

from cotrain.config import to_dict
from cotrain.model.network import CornerNet
from cotrain.model.outputs import INPUT, OUTPUTS
from cotrain.model.train import TrainConfig, build_from_checkpoint, load_checkpoint
from cotrain.render.renderer import render_batch
from cotrain.targets import make_target

OPSET = 18  # the dynamo exporter's native opset (>= 17 as required; down-conversion to 17 fails)


class ExportWrapper(torch.nn.Module):
    """The network with probabilities instead of logits, as the detector consumes it."""

    def __init__(self, model: CornerNet):
        super().__init__()
        self.model = model

    def named(self, image: torch.Tensor) -> dict[str, torch.Tensor]:
        """The outputs of :mod:`cotrain.model.outputs`, by name."""
        o = self.model(image)
        cfg = self.model.cfg
        if o["board_col_logits"].shape[1] > 0:
            lc, lr = torch.log_softmax(o["board_col_logits"], 1), torch.log_softmax(o["board_row_logits"], 1)
        else:  # uv regression: classes from the distance of uv to every column / row (0.5 grid units wide)
            cols = torch.arange(-1, cfg.grid_nx + 1, dtype=image.dtype, device=image.device)[None, :, None, None]
            rows = torch.arange(-1, cfg.grid_ny + 1, dtype=image.dtype, device=image.device)[None, :, None, None]
            lc = torch.log_softmax(-((o["board_uv"][:, :1] - cols) ** 2) / 0.5, 1)
            lr = torch.log_softmax(-((o["board_uv"][:, 1:] - rows) ** 2) / 0.5, 1)
        return {
            "corners": o["corners"],
            "visibility": torch.sigmoid(o["visibility_logit"]),
            "confidence": torch.sigmoid(o["confidence_logit"]),
            "learnability": o["learnability"],
            "corner_prob": torch.sigmoid(o["corner_logit"]),
            "mask_prob": torch.sigmoid(o["board_mask_logit"]),
            "col_logp": lc,
            "row_logp": lr,
        }

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """The named outputs as the graph returns them: in the order of :data:`OUTPUTS`."""
        out = self.named(image)
        return tuple(out[n] for n in OUTPUTS)


class ExportError(ValueError):
    """Export or parity check failed (one-line message)."""


def metadata(cfg: TrainConfig, name: str) -> dict[str, str]:
    return {
        "cotrain.name": name,
        "cotrain.target": json.dumps(make_target(cfg.render.target).to_json()),
        "cotrain.input_size": json.dumps(list(cfg.model.input_size)),  # [H, W]
        "cotrain.normalisation": "grey float32 in [0, 1] (8-bit / 255, 16-bit / 65535, colour -> grey); the image is scaled by "
        "s = min(W / w, H / h) with cv2.INTER_AREA and placed top-left on a black H x W canvas; corner pixels map back as "
        "x_in = (x + 0.5) / s - 0.5",
        "cotrain.outputs": json.dumps(OUTPUTS),
        "cotrain.config": json.dumps(to_dict(cfg)),
    }


def export_onnx(checkpoint: str | Path, out: str | Path, tol_px: float = 0.01, n_check: int = 8) -> dict:
    """Export ``checkpoint`` to ``out`` and run the parity check; returns the check's figures."""
    import onnx
    import onnxruntime as ort

    model, cfg = build_from_checkpoint(load_checkpoint(checkpoint))
    H, W = cfg.model.input_size
    wrapper = ExportWrapper(model).eval()
    example = torch.rand(2, 1, H, W)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp.onnx")
    logging.getLogger("torch.onnx").setLevel(logging.ERROR)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            prog = torch.onnx.export(
                wrapper,
                (example,),
                input_names=[INPUT],
                output_names=OUTPUTS,
                opset_version=OPSET,
                dynamic_shapes=({0: torch.export.Dim("batch", min=1, max=256)},),
                dynamo=True,
                verbose=False,
            )
        except Exception as e:  # the exporter's errors are long; keep the first line
            raise ExportError(f"torch.onnx.export failed: {str(e).splitlines()[0][:300]}") from None
    proto = prog.model_proto
    got_opset = max(o.version for o in proto.opset_import if o.domain in ("", "ai.onnx"))
    for k, v in metadata(cfg, Path(checkpoint).stem).items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = k, v
    onnx.save(proto, str(tmp))
    onnx.checker.check_model(str(tmp))
    # Parity on rendered images at the processing size.
    batch = render_batch(cfg.render, list(range(n_check)), seed=424242)
    sess = ort.InferenceSession(str(tmp), providers=["CPUExecutionProvider"])
    got = dict(zip(OUTPUTS, sess.run(list(OUTPUTS), {INPUT: batch["image"].numpy().astype(np.float32)})))
    with torch.no_grad():
        ref = {k: v.numpy() for k, v in wrapper.named(batch["image"]).items()}
    dq = float(np.abs(got["corners"] - ref["corners"]).max())
    dp = float(max(np.abs(got[n] - ref[n]).max() for n in OUTPUTS if n != "corners"))
    if not dq <= tol_px:
        tmp.unlink(missing_ok=True)
        raise ExportError(f"parity check failed: onnxruntime corners differ from PyTorch by {dq:.4f} px (> {tol_px} px)")
    os.replace(tmp, out)
    return {"out": str(out), "max_corner_diff_px": dq, "max_prob_diff": dp, "opset": got_opset, "images": n_check}
