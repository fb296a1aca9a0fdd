"""Our calibration and mrcal's side by side on the same detections (``calib-eval compare``).

Both calibrate the same observations (the selector's frames, or every frame). Intrinsics of
different families are compared through their projections: the RMS pixel distance between the
two cameras' images of the same rays, spread over the image circle up to 95 % of the half FoV.
Extrinsics are compared as the translation (mm) and rotation (deg) between the two ``T_cam_rig``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib_eval.calibration.calibrator import CalibConfig, CalibrationResult, calibrate
from calib_eval.calibration.mrcal_peer import MrcalConfig, MrcalResult, calibrate_mrcal
from cotrain.geometry import cameras, rotation_angle_deg
from cotrain.io.detections import json_safe
from cotrain.io.sequence import Sequence

MAX_RMS_PX = CalibConfig().max_rms_px  # a final RMS above this is no calibration, for either


def error_rays(fov: float, n: int = 400) -> np.ndarray:
    """(n, 3) unit rays spread evenly over the image circle up to 95 % of the half FoV."""
    rng = np.random.default_rng(0)
    th = np.sqrt(rng.random(n)) * math.radians(fov) / 2 * 0.95
    ph = rng.random(n) * 2 * math.pi
    return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)


def project_rays(model: str, params, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Projections (R, 2) of rays ``v`` (R, 3) by one of our cameras, and (R,) which are valid."""
    return cameras.project(model, np.asarray(v, dtype=np.float64), np.asarray(params, dtype=np.float64))


def pixel_difference(q1: np.ndarray, ok1: np.ndarray, q2: np.ndarray, ok2: np.ndarray) -> float:
    """RMS pixel distance between two cameras' projections of the same rays (inf where one fails)."""
    if not bool((np.asarray(ok1) & np.asarray(ok2)).all()):
        return math.inf
    return float(np.sqrt(np.mean(np.sum((q1 - q2) ** 2, axis=-1))))


def mrcal_valid(q: np.ndarray) -> np.ndarray:
    """Which of mrcal's projections are real (the reader writes -1e9 for none)."""
    return np.isfinite(q).all(-1) & (q > -1e8).all(-1)


def pose_difference(T1: np.ndarray, T2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation (mm) and rotation (deg) between poses (K, 4, 4)."""
    dR = T1[:, :3, :3] @ np.swapaxes(T2[:, :3, :3], -1, -2)
    return 1000 * np.linalg.norm(T1[:, :3, 3] - T2[:, :3, 3], axis=-1), rotation_angle_deg(dR)


@dataclass
class Comparison:
    ours: CalibrationResult
    mrcal: MrcalResult
    rows: list[dict]  # per camera: name, our RMS, mrcal's RMS, projection difference (px), extrinsic difference

    def table(self) -> str:
        m = self.mrcal
        worst = max(m.rms_cam, default=math.nan)
        reached = f", RMS {m.rms_px:.2f} px (mrcal's own figure)" if math.isfinite(m.rms_px) else ""
        head = f"mrcal: {m.lensmodel}; " + (
            f"{m.runtime_s:.1f} s, {m.outliers} corners thrown out"
            + (f"; it ended at {worst:.1f} px RMS, which is not a calibration" if worst > MAX_RMS_PX else "")
            if m.success
            else f"failed ({m.reason})" + (f" after stage '{m.stage}'{reached}" if m.stage else "")
        )
        ours = f"ours: {', '.join(self.ours.model)}; {self.ours.runtime_s:.1f} s" + (
            "" if self.ours.success else f"; failed ({self.ours.reason})"
        )
        lines = [
            ours,
            head,
            "",
            "| camera | ours RMS (px) | mrcal RMS (px) | projection difference (px RMS) | extrinsics difference (mm / deg) |",
            "|---|---|---|---|---|",
        ]
        for r in self.rows:
            f = lambda x, p=3: "-" if x is None or not math.isfinite(x) else f"{x:.{p}f}"  # noqa: E731
            ext = "-" if r["ext_mm"] is None else f"{r['ext_mm']:.2f} / {r['ext_deg']:.3f}"
            lines.append(f"| {r['camera']} | {f(r['ours_rms'])} | {f(r['mrcal_rms'])} | {f(r['proj_px'])} | {ext} |")
        return "\n".join(lines)


def compare(
    seq: Sequence, fov: float, cfg: CalibConfig, order=None, mrcal_cfg: MrcalConfig | None = None, workdir: Path | None = None
) -> Comparison:
    """Calibrate ``seq`` with ours and with mrcal, and compare the two results camera by camera."""
    ours = calibrate(seq, cfg, order)
    v = error_rays(fov)
    m = calibrate_mrcal(seq, fov, mrcal_cfg, rays=v, workdir=workdir)
    rows = []
    for c, cam in enumerate(seq.cameras):
        row = {"camera": cam.name, "ours_rms": ours.rms_px[c] if ours.success else None, "mrcal_rms": None, "proj_px": None}
        row.update({"ext_mm": None, "ext_deg": None})
        if m.success:
            row["mrcal_rms"] = m.rms_cam[c]  # over the corners mrcal kept, per corner as ours
            if ours.success:
                q, ok = project_rays(ours.model[c], ours.intrinsics[c], v)
                row["proj_px"] = pixel_difference(q, ok, m.q_rays[c], mrcal_valid(m.q_rays[c]))
                if c > 0:
                    t, r = pose_difference(np.asarray(ours.T_cam_rig)[c : c + 1], m.T_cam_rig[c : c + 1])
                    row["ext_mm"], row["ext_deg"] = float(t[0]), float(r[0])
        rows.append(row)
    return Comparison(ours, m, rows)


def write_comparison(cmp: Comparison, out: Path) -> tuple[Path, Path]:
    """compare.md (the table) and compare.json (the table's rows and both runs' status)."""
    out.mkdir(parents=True, exist_ok=True)
    md, js = out / "compare.md", out / "compare.json"
    md.write_text("# Ours and mrcal on the same detections\n\n" + cmp.table() + "\n")
    m = cmp.mrcal
    keys = ("available", "success", "reason", "stage", "runtime_s", "lensmodel", "rms_px", "rms_cam", "outliers")
    mrcal = {k: getattr(m, k) for k in keys}
    ours = {"success": cmp.ours.success, "reason": cmp.ours.reason, "model": cmp.ours.model, "runtime_s": cmp.ours.runtime_s}
    js.write_text(json.dumps(json_safe({"ours": ours, "mrcal": mrcal, "cameras": cmp.rows}), indent=1))
    return md, js
