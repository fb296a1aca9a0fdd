"""Calibration sequences: observations of a target by N cameras over time, and their folder layout.

Folder layout (the one CO-Calib's release reads)::

    SEQ/cam0/images/*.png
    SEQ/cam0/timestamps.csv      frame_id,timestamp_ns,filename
    SEQ/cam0/detections.json     optional: the detection JSON of CONVENTIONS.md
    SEQ/cam1/...

Cameras are matched in time within a tolerance: every distinct (matched) time is one *view*, with
one unknown target pose; each camera that saw the target at that time contributes an observation.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


class SequenceError(ValueError):
    """A sequence folder or detection file that cannot be used (one-line message)."""


@dataclass
class Observation:
    """Corners of the target seen by one camera in one view."""

    cam: int  # camera index
    view: int  # view index (one target pose)
    ids: np.ndarray  # (M,) int corner ids
    q: np.ndarray  # (M, 2) pixels (CONVENTIONS pixel convention)
    weight: np.ndarray  # (M,) observation weights (detector confidence, 1 if unknown)
    frame: str = ""  # image name or frame id, for reports


@dataclass
class CameraInfo:
    name: str  # "cam0", ...
    width: int
    height: int
    mask_radius: float | None = None  # usable fisheye radius about the image centre (px), if known


@dataclass
class Sequence:
    cameras: list[CameraInfo]
    n_views: int
    observations: list[Observation] = field(default_factory=list)
    timestamps_ns: np.ndarray | None = None  # (n_views,) reference time of each view

    def by_camera(self, cam: int) -> list[Observation]:
        return [o for o in self.observations if o.cam == cam]

    def by_view(self) -> dict[int, list[Observation]]:
        out: dict[int, list[Observation]] = {}
        for o in self.observations:
            out.setdefault(o.view, []).append(o)
        return out

    def subset(self, keep: set[tuple[int, int]]) -> Sequence:
        """The same sequence with only the (cam, view) observations in ``keep``."""
        return Sequence(self.cameras, self.n_views, [o for o in self.observations if (o.cam, o.view) in keep], self.timestamps_ns)


def read_detections(path: Path) -> dict[str, dict]:
    """Detection JSON of CONVENTIONS -> {image basename: entry}. Raises SequenceError."""
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise SequenceError(f"{path}: unreadable detection JSON ({e.__class__.__name__})") from None
    if not isinstance(data, dict) or not isinstance(data.get("images"), list):
        raise SequenceError(f"{path}: not a detection JSON (no 'images' list)")
    out = {}
    for entry in data["images"]:
        if not isinstance(entry, dict) or "path" not in entry:
            raise SequenceError(f"{path}: an image entry has no 'path'")
        out[Path(entry["path"]).name] = entry
    return out


def _read_timestamps(path: Path) -> list[tuple[str, int, str]]:
    if not path.is_file():
        raise SequenceError(f"{path}: missing timestamps.csv")
    rows = []
    with path.open() as f:
        reader = csv.reader(f)
        for i, row in enumerate(reader):
            if not row or row[0].startswith("#"):
                continue
            if len(row) < 3:
                raise SequenceError(f"{path}:{i + 1}: expected frame_id,timestamp_ns,filename")
            if i == 0 and not row[1].strip().lstrip("-").isdigit():
                continue  # the header line
            try:
                rows.append((row[0].strip(), int(row[1]), row[2].strip()))
            except ValueError:
                raise SequenceError(f"{path}:{i + 1}: timestamp_ns is not an integer") from None
    return rows


def load_sequence(seq: str | Path, tolerance_ms: float = 10.0, detect=None) -> Sequence:
    """Read a sequence folder. ``detect(image_paths) -> {basename: entry}`` is used for cameras
    without ``detections.json``; without it such a camera is an error."""
    root = Path(seq)
    if not root.is_dir():
        raise SequenceError(f"{seq}: not a folder")
    cam_dirs = sorted(
        (p for p in root.iterdir() if p.is_dir() and p.name.startswith("cam") and p.name[3:].isdigit()), key=lambda p: int(p.name[3:])
    )
    if not cam_dirs:
        raise SequenceError(f"{seq}: no cam0/, cam1/, ... folders")
    per_cam = []
    cameras = []
    for cd in cam_dirs:
        rows = _read_timestamps(cd / "timestamps.csv")
        det_path = cd / "detections.json"
        if det_path.is_file():
            dets = read_detections(det_path)
        elif detect is not None:
            dets = detect([cd / "images" / r[2] for r in rows])
        else:
            raise SequenceError(f"{cd}: no detections.json and no detector available")
        size = None
        for e in dets.values():
            if e.get("width") and e.get("height"):
                size = (int(e["width"]), int(e["height"]))
                break
        if size is None:
            raise SequenceError(f"{cd}: detections give no image size")
        cameras.append(CameraInfo(cd.name, *size))
        per_cam.append((rows, dets))

    # Views from cam0's clock; other cameras join the nearest view within the tolerance.
    tol = int(tolerance_ms * 1e6)
    times: list[int] = sorted({t for rows, _ in per_cam[:1] for _, t, _ in rows})
    obs = []
    for ci, (rows, dets) in enumerate(per_cam):
        for _, t, name in rows:
            arr = np.asarray(times, dtype=np.int64)
            j = int(np.argmin(np.abs(arr - t))) if len(arr) else -1
            if j < 0 or abs(int(arr[j]) - t) > tol:
                times.append(t)
                times.sort()
                arr = np.asarray(times, dtype=np.int64)
                j = int(np.argmin(np.abs(arr - t)))
            e = dets.get(Path(name).name)
            if e is None or e.get("error"):
                continue
            corners = e.get("corners") or []
            if not corners:
                continue
            ids = np.array([c["id"] for c in corners], dtype=np.int64)
            q = np.array([[c["x"], c["y"]] for c in corners], dtype=np.float64)
            w = np.array([float(c.get("confidence", 1.0) or 1.0) for c in corners], dtype=np.float64)
            obs.append(Observation(ci, t, ids, q, np.clip(w, 1e-3, 1.0), name))
    # Re-index views by time.
    arr = np.asarray(sorted(set(times)), dtype=np.int64)
    for o in obs:
        o.view = int(np.argmin(np.abs(arr - o.view)))
    return Sequence(cameras, len(arr), obs, arr)


def write_sequence(seq: Sequence, root: str | Path, target: dict | None = None, model_name: str = "synthetic") -> Path:
    """Write ``seq`` in the folder layout (timestamps.csv and detections.json per camera; no images)."""
    root = Path(root)
    ts = seq.timestamps_ns if seq.timestamps_ns is not None else np.arange(seq.n_views, dtype=np.int64) * 50_000_000
    by_cam_view = {(o.cam, o.view): o for o in seq.observations}
    for c, cam in enumerate(seq.cameras):
        d = root / cam.name
        (d / "images").mkdir(parents=True, exist_ok=True)
        lines = ["frame_id,timestamp_ns,filename"]
        images = []
        for v in range(seq.n_views):
            name = f"{v:06d}.png"
            lines.append(f"{v},{int(ts[v])},{name}")
            o = by_cam_view.get((c, v))
            corners = (
                []
                if o is None
                else [{"id": int(i), "x": float(x), "y": float(y), "confidence": float(w)} for i, (x, y), w in zip(o.ids, o.q, o.weight)]
            )
            images.append(
                {"path": f"{cam.name}/images/{name}", "width": cam.width, "height": cam.height, "corners": corners, "error": None}
            )
        (d / "timestamps.csv").write_text("\n".join(lines) + "\n")
        det = {
            "model": model_name,
            "target": target or {"kind": "checkerboard", "squares_x": 10, "squares_y": 7, "square_size": 0.04},
            "images": images,
        }
        (d / "detections.json").write_text(json.dumps(det))
    return root
