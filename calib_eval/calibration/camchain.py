"""Calibration outputs of docs/conventions.md: Kalibr's camchain.yaml and the JSON report beside it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from calib_eval.calibration.calibrator import CalibrationResult
from cotrain.geometry import cameras
from cotrain.io.detections import json_safe
from cotrain.io.sequence import Sequence


def camchain_dict(res: CalibrationResult, seq: Sequence) -> dict:
    """Kalibr camchain: camera_model, intrinsics (Kalibr order), distortion, resolution,
    cam_overlaps and T_cn_cnm1 (T_cam_n_cam_{n-1}) on every camera after cam0."""
    views = seq.by_view()
    C = len(seq.cameras)
    overlaps = {c: set() for c in range(C)}
    for obs in views.values():
        cams = {o.cam for o in obs}
        for c in cams:
            overlaps[c] |= cams - {c}
    out = {}
    for c, info in enumerate(seq.cameras):
        m = cameras.get_model(res.model[c])
        x = dict(zip(m.param_names, (float(v) for v in res.intrinsics[c])))
        intr = [v for n, v in x.items() if n not in m.distortion_names]
        dist = [x[n] for n in m.distortion_names]
        entry = {
            "camera_model": m.kalibr_model,
            "intrinsics": intr,
            "distortion_model": m.kalibr_distortion,
            "distortion_coeffs": dist,
            "resolution": [int(info.width), int(info.height)],
            "cam_overlaps": sorted(overlaps[c]),
            "rostopic": info.topic or f"/{info.name}/image_raw",
        }
        if c > 0:
            T = res.T_cam_rig[c] @ np.linalg.inv(res.T_cam_rig[c - 1])
            entry["T_cn_cnm1"] = [[float(v) for v in row] for row in T]
        out[info.name] = entry
    return out


def write_outputs(res: CalibrationResult, seq: Sequence, out_dir: str | Path, extra: dict | None = None) -> tuple[Path, Path]:
    """Write camchain.yaml (only on success) and report.json; returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    chain = out / "camchain.yaml"
    if res.success:
        chain.write_text(yaml.safe_dump(camchain_dict(res, seq), default_flow_style=None, sort_keys=False))
    elif chain.exists():
        chain.unlink()
    report = {
        "success": res.success,
        "reason": res.reason,
        "camera_model": res.model,
        "rms_px": {seq.cameras[c].name: res.rms_px[c] for c in range(len(seq.cameras))},
        "frames_per_stage": res.frames_per_stage,
        "conditioning_gamma": {seq.cameras[c].name: res.gamma[c] for c in range(len(seq.cameras))},
        "stages": res.stages,
        "dropped_views": res.dropped,
        "rejected_corners": {
            seq.cameras[c].name: int(sum(len(ids) for (cam, _), ids in res.rejected.items() if cam == c)) for c in range(len(seq.cameras))
        },
        "runtime_s": res.runtime_s,
        **(extra or {}),
    }
    rp = out / "report.json"
    rp.write_text(json.dumps(json_safe(report), indent=2, default=_json_default, allow_nan=False))  # NaN -> null
    return chain, rp


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
