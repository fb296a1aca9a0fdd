"""Image folders as sequence folders: one folder per camera, the way OpenCV and ROS users save a rig.

    sequence_from_folders(["left", "right"], "out/sequence", detector)

writes ``out/sequence/camN/timestamps.csv`` and ``camN/detections.json`` (camN is the N-th folder
given) and links ``camN/images`` to the folder (a copy where links are not allowed), so the
sequence loader reads it like one made from a bag.

Pairing and times (:func:`pair_folders`):

- Names that are whole numbers of nanoseconds (16 digits or more, as ``rosbag`` exporters and
  Kalibr's ``bagcreater`` save them) are the capture times; cameras are then matched by time as
  for a bag, and the folders may hold different counts.
- Otherwise images pair across folders by identical file names where every folder has the same
  names, and by sorted order where the names differ (``left-0001.png`` / ``right-0001.png``);
  pairs are then one second apart (snapshots: no board motion to estimate a time offset from).
- A folder without images, or folders with different counts that can only pair by order, is a
  :class:`FolderError` that says what was found.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

from cotrain.detect.images import IMAGE_SUFFIXES, image_folders_below

NS_DIGITS = 16  # a file name of at least this many digits is a time in nanoseconds (1e15 ns = 11.6 days after 1970)
SNAPSHOT_PERIOD_NS = 1_000_000_000  # spacing of views that have no times of their own (one second)


class FolderError(ValueError):
    """Image folders that cannot make a sequence (one-line reason)."""


@dataclass
class FolderPairing:
    """How the images of the folders pair up."""

    files: list[list[Path]]  # per camera, the images in view order
    stamps_ns: list[list[int]]  # per camera, the time of each image
    how: str  # "time" (nanosecond names), "name" (identical names) or "order" (sorted order)


def folder_images(folder: str | Path) -> list[Path]:
    """The images directly in ``folder``, sorted by name; a missing folder, or one without
    images, is a :class:`FolderError` (naming sub-folders that hold images, if any)."""
    d = Path(folder)
    if not d.is_dir():
        raise FolderError(f"{folder}: no such folder (--images takes one folder of images per camera)")
    files = sorted(q for q in d.iterdir() if q.suffix.lower() in IMAGE_SUFFIXES and q.is_file())
    if not files:
        below = image_folders_below(d)
        hint = f"; folders below it hold images: {', '.join(map(str, below[:4]))}" if below else ""
        suffixes = " ".join(sorted(IMAGE_SUFFIXES))
        raise FolderError(f"{folder}: no images ({suffixes}){hint}")
    return files


def _stamp(p: Path) -> int | None:
    return int(p.stem) if p.stem.isdigit() and len(p.stem) >= NS_DIGITS else None


def pair_folders(folders: list[str | Path]) -> FolderPairing:
    """Pair the images of one folder per camera (see the module docstring)."""
    files = [folder_images(f) for f in folders]
    stamps = [[_stamp(p) for p in fs] for fs in files]
    if all(s is not None for ss in stamps for s in ss):
        return FolderPairing(files, stamps, "time")
    names = [[p.name for p in fs] for fs in files]
    if all(n == names[0] for n in names[1:]):
        return FolderPairing(files, [[k * SNAPSHOT_PERIOD_NS for k in range(len(fs))] for fs in files], "name")
    if any(set(n) & set(names[0]) for n in names[1:]):
        # Some names shared, some not: pair the shared names, keep the rest for their own camera.
        order = sorted(set().union(*map(set, names)))
        slot = {n: k for k, n in enumerate(order)}
        return FolderPairing(files, [[slot[p.name] * SNAPSHOT_PERIOD_NS for p in fs] for fs in files], "name")
    counts = [len(fs) for fs in files]
    if len(set(counts)) > 1:
        found = ", ".join(f"{f}: {n} images" for f, n in zip(folders, counts))
        raise FolderError(
            f"the file names differ between folders ({files[0][0].name} / {files[1][0].name}), so images pair by sorted order, "
            f"which needs the same count in every folder ({found}); remove the unpaired images or name them alike"
        )
    return FolderPairing(files, [[k * SNAPSHOT_PERIOD_NS for k in range(n)] for n in counts], "order")


def _link_images(cam: Path, folder: Path) -> None:
    """``cam/images`` pointing at ``folder``: a symbolic link, or a copy where links are not allowed."""
    link = cam / "images"
    if link.is_symlink() or link.is_file():
        link.unlink()
    elif link.is_dir():
        shutil.rmtree(link)
    try:
        link.symlink_to(folder.resolve(), target_is_directory=True)
    except OSError:
        shutil.copytree(folder, link)


def _folder_stamp(files: list[Path]) -> list:
    return [[p.name, p.stat().st_size, p.stat().st_mtime_ns] for p in files]


def sequence_from_folders(
    folders: list[str | Path], out: str | Path, detector, progress: bool = True, workers: int = 1
) -> tuple[Path, dict]:
    """A sequence folder with detections at ``out`` from one image folder per camera (cam0 first),
    with ``detector`` (a :class:`cotrain.detect.detector.Detector`). Cached as for bags: a second
    call for the same files, detector and target detects nothing again. Returns the folder and what
    was read ({"images", "pairing", "cached"})."""
    from cotrain.io.detections import detect_files, write_json_atomic
    from cotrain.io.sequence import write_camera_detections

    pairing = pair_folders(folders)
    out = Path(out)
    key = {
        "format": 1,
        "folders": [str(Path(f).resolve()) for f in folders],
        "files": [_folder_stamp(fs) for fs in pairing.files],
        "detector": detector.cache_key(),
        "target": detector.target.to_json(),
    }
    read = {"images": [len(fs) for fs in pairing.files], "pairing": pairing.how}
    marker = out / "folders.json"
    if marker.is_file():
        try:
            cached = json.loads(marker.read_text())
        except (OSError, json.JSONDecodeError):
            cached = {}  # an unreadable marker is a cache miss
        if cached.get("key") == key and all((out / f"cam{i}" / "detections.json").is_file() for i in range(len(folders))):
            return out, {**read, "cached": True}
    elif out.is_dir() and any(out.iterdir()):
        raise FolderError(f"{out}: not empty and not made from image folders; choose another --out / --cache folder")
    marker.unlink(missing_ok=True)
    for old in out.glob("cam*"):  # a previous run with other folders
        if old.is_dir() and not old.is_symlink() and old.name[3:].isdigit():
            shutil.rmtree(old)
    for i, (folder, files, stamps) in enumerate(zip(folders, pairing.files, pairing.stamps_ns)):
        cam = out / f"cam{i}"
        cam.mkdir(parents=True, exist_ok=True)
        _link_images(cam, Path(folder))
        rows = ["frame_id,timestamp_ns,filename", *(f"{k},{t},{p.name}" for k, (p, t) in enumerate(zip(files, stamps)))]
        (cam / "timestamps.csv").write_text("\n".join(rows) + "\n")
        (cam / "source").write_text(str(Path(folder).resolve()) + "\n")
        write_camera_detections(cam, lambda paths: detect_files(paths, detector, progress=progress, workers=workers))
    write_json_atomic({"key": key, "read": read}, marker)
    return out, {**read, "cached": False}


def check_sequence_folder(out: str | Path, flag: str = "--out") -> Path:
    """``out`` as the name of a sequence folder to write: an existing file, or a name ending in
    ``.json`` (a detections file is what ``detect IMAGES --out`` writes), is a :class:`FolderError`."""
    p = Path(out)
    if p.exists() and not p.is_dir():
        raise FolderError(f"{flag} {out}: an existing file; with --bag or --images {flag} names a sequence folder to write")
    if p.suffix.lower() == ".json":
        raise FolderError(
            f"{flag} {out}: with --bag or --images {flag} names a sequence folder, not a .json file (e.g. {p.with_suffix('')})"
        )
    return p
