"""Detections of a folder of images in the JSON of CONVENTIONS (``calib-eval opencv-detect``), so
real sequences can be calibrated with OpenCV's geometry-based detector or with ours (``--learned``).

OpenCV orders a symmetric board's corners arbitrarily up to a 180-degree turn; for a board that is
symmetric under that turn (both square counts odd) the geometry is identical either way, so
calibration is unaffected. For asymmetric boards the ids are only as reliable as OpenCV's order.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from cotrain.detect.detector import ImageError, load_image
from cotrain.targets import TargetConfig


def opencv_detect(paths: list[Path], target: TargetConfig, sb: bool = False, progress: bool = True) -> dict:
    from tqdm import tqdm

    pattern = (target.squares_x - 1, target.squares_y - 1)
    images = []
    for p in tqdm(paths, desc="opencv", disable=not progress):
        e = {"path": str(p), "width": 0, "height": 0, "corners": [], "error": None}
        try:
            g = (load_image(p) * 255).round().astype(np.uint8)
            e["height"], e["width"] = g.shape
            if sb:
                ok, c = cv2.findChessboardCornersSB(g, pattern, flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
            else:
                ok, c = cv2.findChessboardCorners(g, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
                if ok:
                    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 0.01)
                    c = cv2.cornerSubPix(g, c, (5, 5), (-1, -1), crit)
            if ok:
                e["corners"] = [{"id": i, "x": float(x), "y": float(y), "confidence": 1.0} for i, (x, y) in enumerate(c.reshape(-1, 2))]
        except ImageError as err:
            e["error"] = str(err)
        images.append(e)
    t = {"kind": target.kind, "squares_x": target.squares_x, "squares_y": target.squares_y, "square_size": target.square_size}
    return {"model": "opencv_sb" if sb else "opencv_classic", "target": t, "images": images}


def learned_detect(paths: list[Path], target: TargetConfig, model: str | None = None, progress: bool = True) -> dict:
    """Our detector (network + grid pass) on another board than the model's if need be: the
    lattice is then placed from the geometry alone (see :class:`cotrain.detect.detector.Detector`)."""
    from cotrain.detect.detector import Detector, detect_files

    det = Detector(model, target={"squares_x": target.squares_x, "squares_y": target.squares_y, "square_size": target.square_size})
    return detect_files(paths, det, progress=progress)


def folder_to_sequence(
    images_dir: Path, seq_dir: Path, target: TargetConfig, sb: bool = False, learned: bool = False, model: str | None = None
) -> Path:
    """Make a one-camera sequence folder (cam0) from a folder of images, with OpenCV detections
    (``sb``: findChessboardCornersSB) or ours (``learned``, ``model``: default the shipped one)."""
    import json

    from cotrain.detect.detector import expand_inputs

    paths = expand_inputs([str(images_dir)])
    if not paths:
        raise FileNotFoundError(f"{images_dir}: no images")
    cam = seq_dir / "cam0"
    (cam / "images").mkdir(parents=True, exist_ok=True)
    lines = ["frame_id,timestamp_ns,filename"]
    for k, p in enumerate(paths):
        dst = cam / "images" / p.name
        if not dst.exists():
            dst.write_bytes(p.read_bytes())
        lines.append(f"{k},{k * 100_000_000},{p.name}")
    (cam / "timestamps.csv").write_text("\n".join(lines) + "\n")
    files = [cam / "images" / p.name for p in paths]
    det = learned_detect(files, target, model) if learned else opencv_detect(files, target, sb)
    for e in det["images"]:
        e["path"] = f"cam0/images/{Path(e['path']).name}"
    (cam / "detections.json").write_text(json.dumps(det))
    return seq_dir
