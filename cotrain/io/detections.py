"""The detection JSON (docs/conventions.md): written by ``cotrain detect``, read by every evaluator.

Work over many files goes on past a bad one: an unreadable image becomes an entry with an
``error`` and no corners.
"""

from __future__ import annotations

import json
import math
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from cotrain.detect.detector import Detector, draw_detection
from cotrain.detect.images import ImageError, load_image

LOOKAHEAD = 2  # images read and through the network ahead of the one the grid pass works on


def detect_files(paths: list[Path], detector: Detector, draw_dir: Path | None = None, progress: bool = True) -> dict:
    """Run the detector over files; returns the detection JSON of docs/conventions.md (as a dict).

    Two images are in flight: while the grid pass works on one image, a second thread reads the
    next one and runs it through the network (decoding and onnxruntime release the GIL), so on
    two cores the work per image is about the longer of the two halves, not their sum."""
    from tqdm import tqdm

    entries = []
    if draw_dir is not None:
        draw_dir.mkdir(parents=True, exist_ok=True)

    def front(p: Path):
        return detector.network(load_image(p))

    with ThreadPoolExecutor(max_workers=1) as pool:
        ahead = [pool.submit(front, p) for p in paths[:LOOKAHEAD]]
        for k, p in enumerate(tqdm(paths, desc="detect", unit="img", disable=not progress or len(paths) < 2)):
            if k + LOOKAHEAD < len(paths):
                ahead.append(pool.submit(front, paths[k + LOOKAHEAD]))
            entry = {"path": str(p), "width": 0, "height": 0, "corners": [], "error": None}
            try:
                pending = ahead[k].result()
                ahead[k] = None  # the image is not kept once it is done
                entry["height"], entry["width"] = pending.grey.shape
                det = detector.finish(pending)
                entry["corners"] = [
                    {"id": int(i), "x": round(float(x), 3), "y": round(float(y), 3), "confidence": round(float(c), 4)}
                    for i, (x, y), c in zip(det.ids, det.xy, det.confidence)
                ]
                if draw_dir is not None:
                    cv2.imwrite(str(draw_dir / (p.stem + "_det.png")), draw_detection(pending.grey, det))
            except ImageError as e:
                entry["error"] = str(e)
            entries.append(entry)
    return {"model": str(detector.path), "target": detector.target.to_json(), "images": entries}


def json_safe(obj):
    """``obj`` with NaN and infinities as None (JSON has no such numbers) and numpy scalars and
    arrays as plain Python values, for ``json.dumps``."""
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def write_json_atomic(data: dict, out: Path) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, out)
