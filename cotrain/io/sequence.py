"""Calibration sequences: observations of a target by N cameras over time, and their folder layout.

Folder layout (the one CO-Calib's release reads)::

    SEQ/cam0/images/*.png
    SEQ/cam0/timestamps.csv      frame_id,timestamp_ns,filename
    SEQ/cam0/detections.json     the detection JSON of docs/conventions.md, with its target
    SEQ/cam1/...

Cameras are matched in time within a tolerance: every distinct (matched) time is one *view*, with
one unknown target pose; each camera that saw the target at that time contributes an observation.
The sequence carries the target its detections name, so selector and calibrator need no flag.
"""

from __future__ import annotations

import csv
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cotrain.targets import Target, TargetError, same_target, target_from_json


class SequenceError(ValueError):
    """A sequence folder or detection file that cannot be used (one-line message)."""


@dataclass
class Observation:
    """Corners of the target seen by one camera in one view."""

    cam: int  # camera index
    view: int  # view index (one target pose)
    ids: np.ndarray  # (M,) int corner ids
    q: np.ndarray  # (M, 2) pixels (docs/conventions.md)
    weight: np.ndarray  # (M,) observation weights (detector confidence, 1 if unknown)
    frame: str = ""  # image name or frame id, for reports


@dataclass
class CameraInfo:
    name: str  # "cam0", ...
    width: int
    height: int
    mask_radius: float | None = None  # usable fisheye radius about the image centre (px), if known
    topic: str | None = None  # the ROS image topic it was recorded on (a sequence made from a bag)


@dataclass
class Sequence:
    cameras: list[CameraInfo]
    n_views: int
    observations: list[Observation] = field(default_factory=list)
    timestamps_ns: np.ndarray | None = None  # (n_views,) reference time of each view
    target: Target | None = None  # the observed target (corner ids index its points)

    def by_camera(self, cam: int) -> list[Observation]:
        return [o for o in self.observations if o.cam == cam]

    def by_view(self) -> dict[int, list[Observation]]:
        out: dict[int, list[Observation]] = {}
        for o in self.observations:
            out.setdefault(o.view, []).append(o)
        return out

    def subset(self, keep: set[tuple[int, int]]) -> Sequence:
        """The same sequence with only the (cam, view) observations in ``keep``."""
        obs = [o for o in self.observations if (o.cam, o.view) in keep]
        return Sequence(self.cameras, self.n_views, obs, self.timestamps_ns, self.target)


def read_detections(path: Path) -> tuple[dict[str, dict], Target | None]:
    """Detection JSON (docs/conventions.md) -> ({image basename: entry}, its target or None).
    Raises SequenceError."""
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise SequenceError(f"{path}: unreadable detection JSON ({e.__class__.__name__})") from None
    return parse_detections(data, str(path))


def parse_detections(data: dict, where: str) -> tuple[dict[str, dict], Target | None]:
    """A detection JSON already loaded: ({image basename: entry}, its target or None)."""
    if not isinstance(data, dict) or not isinstance(data.get("images"), list):
        raise SequenceError(f"{where}: not a detection JSON (no 'images' list)")
    out = {}
    for entry in data["images"]:
        if not isinstance(entry, dict) or "path" not in entry:
            raise SequenceError(f"{where}: an image entry has no 'path'")
        out[Path(entry["path"]).name] = entry
    target = None
    if data.get("target") is not None:
        try:
            target = target_from_json(data["target"], f"{where}: target")
        except TargetError as e:
            raise SequenceError(str(e)) from None
    return out, target


def _one_target(found: list[tuple[str, Target]], given: Target | None, seq: str) -> Target:
    """The sequence's target: what its detections name (all alike); ``given`` (a --target) must agree."""
    for where, t in found[1:]:
        if not same_target(t, found[0][1]):
            raise SequenceError(f"{where}: target {t} differs from {found[0][0]}'s {found[0][1]}")
    if found and given is not None and not same_target(given, found[0][1]):
        raise SequenceError(f"--target ({given}) contradicts the detections' target ({found[0][1]}, {found[0][0]})")
    if found:
        return found[0][1]
    if given is None:
        raise SequenceError(f"{seq}: the detections name no target; pass --target TARGET.yaml")
    return given


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


def load_sequence(seq: str | Path, tolerance_ms: float = 10.0, detect=None, target: Target | None = None) -> Sequence:
    """Read a sequence folder. ``detect(image_paths) -> detection JSON dict`` is used for cameras
    without ``detections.json``; without it such a camera is an error. The target comes from the
    detections; ``target`` is used where they name none, and must agree with them otherwise."""
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
    targets: list[tuple[str, Target]] = []
    for cd in cam_dirs:
        rows = _read_timestamps(cd / "timestamps.csv")
        det_path = cd / "detections.json"
        if det_path.is_file():
            source = str(det_path)
            dets, t = read_detections(det_path)
        elif detect is not None:
            source = f"{cd.name} (detector)"
            dets, t = parse_detections(detect([cd / "images" / r[2] for r in rows]), source)
        else:
            raise SequenceError(f"{cd}: no detections.json and no detector available")
        if t is not None:
            targets.append((source, t))
        size = None
        for e in dets.values():
            if e.get("width") and e.get("height"):
                size = (int(e["width"]), int(e["height"]))
                break
        if size is None:
            raise SequenceError(f"{cd}: detections give no image size")
        topic = (cd / "rostopic").read_text().strip() if (cd / "rostopic").is_file() else None
        cameras.append(CameraInfo(cd.name, *size, topic=topic))
        per_cam.append((rows, dets, source))

    # Views from cam0's clock; other cameras join the nearest view within the tolerance.
    tol = int(tolerance_ms * 1e6)
    times: list[int] = sorted({t for rows, _, _ in per_cam[:1] for _, t, _ in rows})
    board = _one_target(targets, target, str(seq))
    obs = []
    for ci, (rows, dets, source) in enumerate(per_cam):
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
            if ids.min() < 0 or ids.max() >= board.n_corners:
                bad = int(ids.max() if ids.max() >= board.n_corners else ids.min())
                raise SequenceError(f"{source}: {name} has corner id {bad}, not one of the {board.n_corners} of the {board}")
            q = np.array([[c["x"], c["y"]] for c in corners], dtype=np.float64)
            w = np.array([float(c.get("confidence", 1.0) or 1.0) for c in corners], dtype=np.float64)
            obs.append(Observation(ci, t, ids, q, np.clip(w, 1e-3, 1.0), name))
    # Re-index views by time.
    arr = np.asarray(sorted(set(times)), dtype=np.int64)
    for o in obs:
        o.view = int(np.argmin(np.abs(arr - o.view)))
    return Sequence(cameras, len(arr), obs, arr, board)


def write_sequence(seq: Sequence, root: str | Path, model_name: str = "synthetic") -> Path:
    """Write ``seq`` in the folder layout (timestamps.csv and detections.json per camera, with the
    sequence's target; no images)."""
    if seq.target is None:
        raise SequenceError("the sequence has no target to write")
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
            "target": seq.target.to_json(),
            "images": images,
        }
        (d / "detections.json").write_text(json.dumps(det))
    return root


def images_to_sequence(paths: list[Path], seq_dir: str | Path, detect) -> Path:
    """A one-camera sequence folder (``cam0``) from image files: the images copied, timestamps
    0.1 s apart in file order, and ``detect(image_paths) -> detection JSON dict`` written as its
    detections.json (paths relative to the sequence)."""
    if not paths:
        raise SequenceError("no images to make a sequence of")
    cam = Path(seq_dir) / "cam0"
    (cam / "images").mkdir(parents=True, exist_ok=True)
    lines = ["frame_id,timestamp_ns,filename"]
    for k, p in enumerate(paths):
        dst = cam / "images" / p.name
        if not dst.exists():
            dst.write_bytes(p.read_bytes())
        lines.append(f"{k},{k * 100_000_000},{p.name}")
    (cam / "timestamps.csv").write_text("\n".join(lines) + "\n")
    write_camera_detections(cam, detect)
    return Path(seq_dir)


def write_camera_detections(cam: Path, detect) -> Path:
    """``cam/detections.json`` from ``detect(image_paths) -> detection JSON dict`` over the images
    that ``cam/timestamps.csv`` lists, with paths relative to the sequence (written atomically)."""
    names = [r[2] for r in _read_timestamps(cam / "timestamps.csv")]
    det = detect([cam / "images" / n for n in names])
    for e in det["images"]:
        e["path"] = f"{cam.name}/images/{Path(e['path']).name}"
    out = cam / "detections.json"
    tmp = out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(det))
    os.replace(tmp, out)
    return out
