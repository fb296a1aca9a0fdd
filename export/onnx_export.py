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
from cotrain.model.outputs import INPUT, OUTPUTS, SOURCE_KEY, file_sha256
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


def export_onnx(
    checkpoint: str | Path, out: str | Path, tol_px: float = 0.01, n_check: int = 8, input_size: tuple[int, int] | None = None
) -> dict:
    """Export ``checkpoint`` to ``out`` and run the parity check; returns the check's figures.

    ``input_size`` (H, W): the processing size of the exported graph, default the one the network
    was trained at. The network is fully convolutional, so a smaller size is a cheaper detector
    whose boards look smaller to the network (``calib_eval.detection.processing_size`` measures
    what that costs in recall); the metadata records the size the graph takes."""
    import onnx
    import onnxruntime as ort

    model, cfg = build_from_checkpoint(load_checkpoint(checkpoint))
    if input_size is not None:
        H, W = (int(v) for v in input_size)
        if H < 32 or W < 32:
            raise ExportError(f"input size {H}x{W} is too small (at least 32 x 32)")
        cfg.model.input_size = (H, W)
        cfg.render.height, cfg.render.width = H, W
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


# Convolutions kept in float: int8 in the heads and the first side output moved column / row votes
# enough to flip a board's identity. (The decoder stage dec2, a third of the network's time in float,
# is int8: with it the detector keeps its FoV recall and wrong corners on every kept set,
# docs/results/size_curve.md.) The second side convolution, 8 -> 8 channels at the full
# processing size, runs faster in float (1.9 ms against 2.7 in int8) but is kept int8: in float
# it moved the maps enough for one lattice at a 240-degree rim to slip by a row (seed 11, fov240_033).
KEEP_FLOAT = ("model.head_", "model.side.0")


def add_logit_outputs(proto) -> None:
    """Give an ONNX graph of the dense maps the inputs of the log-softmax of ``col_logp`` and
    ``row_logp`` as outputs of their own (:data:`cotrain.model.outputs.LOGITS`), in place."""
    from onnx import TensorProto, helper

    from cotrain.model.outputs import LOGITS

    g = proto.graph
    source = {n.output[0]: n for n in g.node if n.op_type == "LogSoftmax"}
    for logp, logits in LOGITS.items():
        node = source.get(logp)
        if node is None:
            raise ExportError(f"the graph computes no {logp} by a LogSoftmax")
        g.node.append(helper.make_node("Identity", [node.input[0]], [logits], name=f"{logits}_output"))
        shape = [d.dim_param or d.dim_value for d in next(o for o in g.output if o.name == logp).type.tensor_type.shape.dim]
        g.output.append(helper.make_tensor_value_info(logits, TensorProto.FLOAT, shape))


def quantize_dense(
    model: str | Path, out: str | Path, n_calib: int = 32, seed: int = 515151, keep_float: tuple[str, ...] = KEEP_FLOAT
) -> dict:
    """An int8 graph of ``model``'s dense maps (the grid pass's inputs) at ``out``.

    The graph is cut to :data:`~cotrain.model.outputs.DENSE_OUTPUTS` (the per-slot point heads
    are not part of it) and its convolutions are quantized statically (QDQ, int8 weights per
    channel, uint8 activations) with ranges calibrated on ``n_calib`` images rendered by the
    model's own training config. The metadata is the model's, so the detector takes either file,
    with :data:`SOURCE_KEY` added: the float graph's sha256, so that a float graph written again
    is not paired with a stale int8 one (:func:`cotrain.detect.onnx_model.default_grid_model_path`).
    Returns the largest differences of the maps against the float graph on other rendered images.
    """
    import tempfile

    import onnx
    import onnxruntime as ort
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    from cotrain.config import from_dict
    from cotrain.model.outputs import DENSE_OUTPUTS, LOGITS, log_softmax_channels

    proto = onnx.load(str(model))
    meta = {p.key: p.value for p in proto.metadata_props}
    if "cotrain.config" not in meta:
        raise ExportError(f"{model}: not a cotrain model (no cotrain.config metadata)")
    cfg = from_dict(TrainConfig, json.loads(meta["cotrain.config"]))
    H, W = json.loads(meta["cotrain.input_size"])
    cfg.render.height, cfg.render.width = H, W
    dense = onnx.utils.Extractor(proto).extract_model([INPUT], list(DENSE_OUTPUTS))
    # Convolutions whose weights are named with a prefix of keep_float stay in float.
    exclude = [n.name for n in dense.graph.node if n.op_type == "Conv" and n.input[1].startswith(keep_float)]
    calib = render_batch(cfg.render, list(range(n_calib)), seed=seed)["image"].numpy().astype(np.float32)

    class Reader(CalibrationDataReader):
        def __init__(self):
            self.it = iter(calib[i : i + 1] for i in range(len(calib)))

        def get_next(self):
            x = next(self.it, None)
            return None if x is None else {INPUT: x}

    out = Path(out)
    with tempfile.TemporaryDirectory() as tmp:
        f32, pre, q = Path(tmp) / "dense.onnx", Path(tmp) / "pre.onnx", Path(tmp) / "int8.onnx"
        onnx.save(dense, str(f32))
        quant_pre_process(str(f32), str(pre), skip_symbolic_shape=True)
        quantize_static(
            str(pre),
            str(q),
            Reader(),
            quant_format=QuantFormat.QDQ,
            op_types_to_quantize=["Conv"],
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
            per_channel=True,
            nodes_to_exclude=exclude,
        )
        qproto = onnx.load(str(q))
        add_logit_outputs(qproto)
        del qproto.metadata_props[:]
        for k, v in {**meta, SOURCE_KEY: file_sha256(model)}.items():
            entry = qproto.metadata_props.add()
            entry.key, entry.value = k, v
        out.parent.mkdir(parents=True, exist_ok=True)
        onnx.save(qproto, str(out))
    check = render_batch(cfg.render, list(range(8)), seed=seed + 1)["image"].numpy().astype(np.float32)
    ref = ort.InferenceSession(dense.SerializeToString(), providers=["CPUExecutionProvider"]).run(list(DENSE_OUTPUTS), {INPUT: check})
    got = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"]).run(list(DENSE_OUTPUTS), {INPUT: check})
    diff = {n: float(np.abs(a - b).max()) for n, a, b in zip(DENSE_OUTPUTS, ref, got)}
    logits = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"]).run(list(LOGITS.values()), {INPUT: check})
    maps = dict(zip(DENSE_OUTPUTS, got))
    for (logp, name), x in zip(LOGITS.items(), logits):
        d = float(np.abs(log_softmax_channels(x) - maps[logp]).max())
        if d > 1e-4:
            raise ExportError(f"{name}: its log-softmax differs from {logp} by {d}")
    return {"out": str(out), "max_diff": diff, "calibration_images": n_calib}
