"""The real fisheye stereo head (``../shared/real/ros_fisheye_stereo``): its verdict, its sigma and
the difference between calibrations from its even and its odd frames.
``python -m calib_eval.benchmark.real_stereo [--out report/real_stereo]``.

46 pairs of 800x503 grey images, ``left-NNNN.png`` / ``right-NNNN.png`` (cam0 / cam1), saved by
the ROS calibrator from two free-running cameras; a checkerboard of 9 x 7 squares whose square
size was not recorded (0.1 here: every length is in that unit, the ratio of two is not). The pairs
are snapshots, not a continuous recording, so no time offset can be measured. Our detector finds
the corners (cached in ``OUT/sequence``); the rig is calibrated as Kalibr's ``pinhole-equi`` (kb4)
with all pairs, with the even and with the odd pairs, each assessed as ``calib-eval calibrate``
does. ``OUT/summary.json`` holds the figures, ``OUT/all/report.html`` the page.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from calib_eval.calibration.calibrator import CalibConfig, calibrate
from calib_eval.calibration.publish import publish
from cotrain.io.sequence import Sequence, load_sequence, write_camera_detections

HERE = Path(__file__).resolve().parents[2]
DATA = HERE.parent / "shared" / "real" / "ros_fisheye_stereo" / "images"
SQUARE = 0.1  # the board's square size is not recorded; lengths are in this unit


def build_sequence(data: Path, out: Path) -> Path:
    """A sequence folder (cam0 = left, cam1 = right, one view per pair, stamps a second apart)
    with our detector's corners; kept and reused."""
    from cotrain.detect.detector import Detector
    from cotrain.io.detections import detect_files
    from cotrain.targets import TargetConfig, make_target

    seq = out / "sequence"
    if all((seq / c / "detections.json").exists() for c in ("cam0", "cam1")):
        return seq
    pairs = sorted(p.name.removeprefix("left-") for p in data.glob("left-*.png"))
    if not pairs:
        raise FileNotFoundError(f"{data}: no left-NNNN.png images")
    for cam, side in (("cam0", "left"), ("cam1", "right")):
        d = seq / cam / "images"
        d.mkdir(parents=True, exist_ok=True)
        rows = ["frame_id,timestamp_ns,filename"]
        for i, name in enumerate(pairs):
            shutil.copyfile(data / f"{side}-{name}", d / f"{side}-{name}")
            rows.append(f"{i},{i * 1_000_000_000},{side}-{name}")
        (seq / cam / "timestamps.csv").write_text("\n".join(rows) + "\n")
    target = make_target(TargetConfig(kind="checkerboard", squares_x=9, squares_y=7, square_size=SQUARE))
    det = Detector(target=target)
    for cam in ("cam0", "cam1"):
        write_camera_detections(seq / cam, lambda paths: detect_files(paths, det, workers=0))
    return seq


def _half(seq: Sequence, parity: int) -> Sequence:
    return seq.subset({(o.cam, o.view) for o in seq.observations if o.view % 2 == parity})


def _figures(res, trust) -> dict:
    T = res.T_cam_rig[1]
    u = trust.uncertainty
    out = {
        "success": res.success,
        "rms_px": res.rms_px,
        "fx": [float(res.intrinsics[c][0]) for c in range(2)],
        "R_cam1_cam0_rotvec_deg": np.degrees(Rotation.from_matrix(T[:3, :3]).as_rotvec()).tolist(),
        "baseline": float(np.linalg.norm(T[:3, 3])),
        "verdict": trust.verdict.as_dict(),
    }
    if u is not None:
        out["fx_sigma"] = [float(u.intrinsics_sigma[c][0]) for c in range(2)]
        pu = u.pairs[(0, 1)]
        out.update({"rotation_sigma_deg": pu.rotation_sigma_deg, "baseline_sigma": pu.baseline_sigma_m, "noise_px": u.sigma_px})
        out["projection_sigma_p95_px"] = [m.p95_px for m in u.projection]
    if trust.cross_validation is not None and trust.cross_validation.ok:
        out["spread_ratio"] = trust.cross_validation.spread_ratio
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m calib_eval.benchmark.real_stereo", description=__doc__.split("\n")[0])
    p.add_argument("--data", default=str(DATA), help="folder of left-NNNN.png / right-NNNN.png")
    p.add_argument("--fov", type=float, default=185.0, help="rough FoV (deg)")
    p.add_argument("--out", default="report/real_stereo")
    a = p.parse_args(argv)
    out = Path(a.out)
    seq_dir = build_sequence(Path(a.data), out)
    seq = load_sequence(seq_dir)
    cfg = CalibConfig(model="kb4", fov=a.fov)
    summary = {}
    for name, s in (("all", seq), ("even", _half(seq, 0)), ("odd", _half(seq, 1))):
        res = calibrate(s, cfg)
        pub = publish(res, s, cfg, out / name)
        summary[name] = _figures(res, pub.trust)
        print(f"{name}: {pub.trust.verdict.line()}", flush=True)
    e, o = summary["even"], summary["odd"]
    if e["success"] and o["success"]:
        Re = Rotation.from_rotvec(np.radians(e["R_cam1_cam0_rotvec_deg"]))
        Ro = Rotation.from_rotvec(np.radians(o["R_cam1_cam0_rotvec_deg"]))
        summary["halves"] = {
            "focal_pct": [100 * abs(e["fx"][c] / o["fx"][c] - 1) for c in range(2)],
            "rotation_deg": math.degrees(float(np.linalg.norm((Re * Ro.inv()).as_rotvec()))),
            "baseline_pct": 100 * abs(e["baseline"] / o["baseline"] - 1),
        }
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps({k: v for k, v in summary.items() if k != "all"} | {"all": summary["all"]}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
