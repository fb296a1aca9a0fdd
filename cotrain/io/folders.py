"""Image folders as sequence folders: one folder per camera, the way OpenCV and ROS users save a rig.

    sequence_from_folders(["left", "right"], "out/sequence", detector)

writes ``out/sequence/camN/timestamps.csv`` and ``camN/detections.json`` (camN is the N-th folder
given) and links ``camN/images`` to the folder (a copy where links are not allowed), so the
sequence loader reads it like one made from a bag.

Pairing and times (:func:`pair_folders`):

- Names that are whole numbers of nanoseconds (16 digits or more, as ``rosbag`` exporters and
  Kalibr's ``bagcreater`` save them) are the capture times; cameras are then matched by time as
  for a bag, and the folders may hold different counts.
- Otherwise images pair across folders by identical file names (where only some names are shared,
  those pair and the others stay single views of their camera), and by sorted order where no name
  is shared (``left-0001.png`` / ``right-0001.png``); views are then one second apart (snapshots:
  no board motion to estimate a time offset from).
- A folder without images, or folders with different counts that can only pair by order, is a
  :class:`FolderError` that says what was found.
"""

from __future__ import annotations

import csv
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

from cotrain.detect.images import IMAGE_SUFFIXES, expand_inputs, image_folders_below

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
    files = expand_inputs([str(d)])
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
    """``cam/images`` pointing at ``folder``: a symbolic link, or a copy where links are not allowed
    (then ``cam/images.copied`` says so, and only then may :func:`_clear_camera` remove it)."""
    try:
        (cam / "images").symlink_to(folder.resolve(), target_is_directory=True)
    except OSError:
        shutil.copytree(folder, cam / "images")
        (cam / "images.copied").write_text("")


OURS = ("timestamps.csv", "source", "detections.json", "detections.json.tmp")  # the files a camera folder gets here


def _clear_camera(cam: Path) -> None:
    """Remove what :func:`sequence_from_folders` wrote in ``cam`` and nothing else: our files, the
    ``images`` link (never what it points at), an images copy we made, then the folder if empty."""
    if cam.is_symlink() or not cam.is_dir():
        raise FolderError(f"{cam}: not a camera folder this command made (a link or a file); choose another --out / --cache folder")
    for name in OURS:
        (cam / name).unlink(missing_ok=True)
    images = cam / "images"
    if images.is_symlink():
        images.unlink()
    elif (cam / "images.copied").is_file():
        shutil.rmtree(images)
        (cam / "images.copied").unlink()
    if not any(cam.iterdir()):
        cam.rmdir()


def _read_marker(marker: Path) -> dict | None:
    """The marker a previous run left ({"key", "read", "complete"}), or None where it is missing or
    not one of ours (then the folder is not touched)."""
    try:
        data = json.loads(marker.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and isinstance(data.get("key"), dict) and "complete" in data else None


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
    previous = _read_marker(marker) if marker.is_file() else None
    if previous and previous["complete"] and previous["key"] == key:
        if all((out / f"cam{i}" / "detections.json").is_file() for i in range(len(folders))):
            return out, {**read, "cached": True}
    if previous is None and out.is_dir() and any(out.iterdir()):
        raise FolderError(f"{out}: not empty and not made from image folders; choose another --out / --cache folder")
    _check_apart(folders, out)
    for old in sorted(out.glob("cam*")):  # what a previous run (other folders, or interrupted) wrote
        if old.name[3:].isdigit():
            _clear_camera(old)
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic({"key": key, "read": read, "complete": False}, marker)  # ours from now on, even if interrupted
    for i, (folder, files, stamps) in enumerate(zip(folders, pairing.files, pairing.stamps_ns)):
        cam = out / f"cam{i}"
        cam.mkdir(exist_ok=True)  # kept where it holds files of the user's own
        _link_images(cam, Path(folder))
        with (cam / "timestamps.csv").open("w", newline="") as f:
            rows = csv.writer(f, lineterminator="\n")
            rows.writerow(["frame_id", "timestamp_ns", "filename"])
            rows.writerows([k, t, p.name] for k, (p, t) in enumerate(zip(files, stamps)))
        (cam / "source").write_text(str(Path(folder).resolve()) + "\n")
        write_camera_detections(cam, lambda paths: detect_files(paths, detector, progress=progress, workers=workers))
    write_json_atomic({"key": key, "read": read, "complete": True}, marker)
    return out, {**read, "cached": False}


def _check_apart(folders: list[str | Path], out: Path) -> None:
    """The sequence folder must not be, or hold, an image folder (its camN folders are rewritten)."""
    o = out.resolve()
    for f in folders:
        r = Path(f).resolve()
        if r == o or o in r.parents:
            raise FolderError(f"{out}: holds the image folder {f}; the sequence folder must be another one (--out / --cache)")


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
