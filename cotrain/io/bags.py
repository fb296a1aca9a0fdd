"""ROS bags as sequence folders: ROS1 ``.bag`` and ROS2 (``.db3`` / ``.mcap``) read with ``rosbags``
(pure Python, no ROS install).

    bag_to_sequence("rec.bag", ["/cam0/image_raw", "/cam1/image_raw"], "out/sequence")

writes ``out/sequence/camN/images/<stamp>.png`` and ``timestamps.csv`` (the header stamps, so the
sequence loader matches cameras by them), one camera per topic in the given order. Messages are
streamed: a 10 GB bag is never held in memory. ``sensor_msgs/Image`` (mono8, mono16, rgb8, bgr8,
rgba8, bgra8 and the bayer encodings OpenCV converts) and ``sensor_msgs/CompressedImage`` are
read; a message that cannot be decoded is skipped and counted.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from cotrain.progress import progress_bar

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
_BAYER = {
    "bayer_rggb8": cv2.COLOR_BayerRGGB2GRAY,
    "bayer_bggr8": cv2.COLOR_BayerBGGR2GRAY,
    "bayer_gbrg8": cv2.COLOR_BayerGBRG2GRAY,
    "bayer_grbg8": cv2.COLOR_BayerGRBG2GRAY,
}


class BagError(ValueError):
    """A bag that cannot be used (one-line message)."""


@dataclass
class BagSummary:
    """What :func:`bag_to_sequence` read."""

    images: list[int] = field(default_factory=list)  # images written per camera
    skipped: list[int] = field(default_factory=list)  # undecodable messages per camera
    reasons: dict[str, int] = field(default_factory=dict)  # why messages were skipped, with counts
    clock: list[str] = field(default_factory=list)  # per camera: "header" stamps, or "bag" time where the headers are 0
    thinned: list[int] = field(default_factory=list)  # images per camera left out by the interval


def decode_image(msg, msgtype: str) -> np.ndarray:
    """A deserialised sensor_msgs Image / CompressedImage -> uint8 or uint16 grey (H, W).
    Raises ValueError with the reason."""
    if msgtype.endswith("CompressedImage"):
        img = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ValueError(f"undecodable {msg.format or 'compressed'} image")
        return img if img.ndim == 2 else cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2GRAY)
    enc, h, w = msg.encoding.lower(), int(msg.height), int(msg.width)
    data = np.frombuffer(bytes(msg.data), np.uint8)
    depth = {"mono8": 1, "mono16": 2, "rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, **dict.fromkeys(_BAYER, 1)}.get(enc)
    if depth is None:
        raise ValueError(f"unsupported encoding {msg.encoding!r}")
    step = int(msg.step) or w * depth
    if h == 0 or w == 0 or step < w * depth or len(data) < step * h:
        raise ValueError(f"{w}x{h} {enc} image with {len(data)} bytes")
    rows = data[: step * h].reshape(h, step)[:, : w * depth]
    if enc == "mono16":
        return rows.copy().view(">u2" if msg.is_bigendian else "<u2").reshape(h, w).astype(np.uint16)
    if enc in _BAYER:
        return cv2.cvtColor(np.ascontiguousarray(rows), _BAYER[enc])
    img = rows.reshape(h, w, depth)
    if enc == "mono8":
        return img[..., 0].copy()
    code = cv2.COLOR_RGB2GRAY if enc.startswith("rgb") else cv2.COLOR_BGR2GRAY
    return cv2.cvtColor(np.ascontiguousarray(img[..., :3]), code)


def bag_to_sequence(bag: str | Path, topics: list[str], out: str | Path, progress: bool = True, interval_s: float = 0.0) -> BagSummary:
    """Stream the image topics of ``bag`` into a sequence folder at ``out`` (see the module
    docstring). A missing topic or a bag without images is a :class:`BagError`. ``interval_s`` > 0
    thins the recording before anything is decoded: of the first topic, the first image of each
    slot of ``interval_s`` (a whole number of its frame periods); of every other topic, the image
    within half a frame period of one of those (by the bag's receive time), so that the kept images
    of synchronised cameras stay paired (a 30 Hz recording thinned to 2 Hz with 0.5). Finding the
    first topic's frames reads its messages once more."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(bag)
    if not path.exists():
        raise BagError(f"{bag}: no such bag")
    if len(set(topics)) != len(topics):
        raise BagError(f"--topics names a topic twice: {' '.join(topics)}")
    out = Path(out)
    try:
        # ROS2 bags before Iron carry no message definitions: read them with Humble's types.
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as e:  # rosbags' reader errors are plain Exceptions: a one-line reason, never a traceback
        raise BagError(f"{bag}: not a readable ROS1 / ROS2 bag ({str(e).splitlines()[0] if str(e) else type(e).__name__})") from None
    try:
        image_topics = sorted({c.topic for c in reader.connections if c.msgtype in IMAGE_TYPES})
        missing = [t for t in topics if t not in image_topics]
        if missing:
            have = ", ".join(image_topics) if image_topics else "none"
            raise BagError(f"{bag}: no image topic {', '.join(missing)} (image topics in the bag: {have})")
        conns = [c for c in reader.connections if c.topic in topics]
        cam_of = {t: i for i, t in enumerate(topics)}
        summary = BagSummary([0] * len(topics), [0] * len(topics), {}, [""] * len(topics), [0] * len(topics))
        seen: list[set[int]] = [set() for _ in topics]
        keep0, half = _reference_times(reader, [c for c in conns if c.topic == topics[0]], bag, interval_s) if interval_s > 0 else (None, 0)
        used: list[set[int]] = [set() for _ in topics]
        rows: list[list[str]] = [["frame_id,timestamp_ns,filename"] for _ in topics]
        for i in range(len(topics)):
            (out / f"cam{i}" / "images").mkdir(parents=True, exist_ok=True)
        total = sum(c.msgcount for c in conns)
        stream = progress_bar(_messages(reader, conns, bag), total=total, desc="bag", unit="msg", enabled=progress)
        for conn, t_bag, raw in stream:
            cam = cam_of[conn.topic]
            ref = -1
            if keep0 is not None and len(keep0) == 0:
                summary.thinned[cam] += 1
                continue
            if keep0 is not None:  # thinned before anything is decoded
                k = int(np.clip(np.searchsorted(keep0, t_bag), 1, len(keep0) - 1)) if len(keep0) > 1 else 0
                k = k - 1 if k > 0 and abs(int(keep0[k - 1]) - int(t_bag)) <= abs(int(keep0[k]) - int(t_bag)) else k
                ref = int(keep0[k])
                if abs(ref - int(t_bag)) > (0 if cam == 0 else half) or ref in used[cam]:
                    summary.thinned[cam] += 1
                    continue
            try:
                msg = reader.deserialize(raw, conn.msgtype)
                grey = decode_image(msg, conn.msgtype)
                header = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
                # One clock per camera, chosen on its first image: the header stamps (capture
                # time), or the bag's receive time where a driver leaves them at 0.
                summary.clock[cam] = summary.clock[cam] or ("header" if header else "bag")
                stamp = header if summary.clock[cam] == "header" else int(t_bag)
                if stamp in seen[cam]:
                    raise ValueError("duplicate stamp on its topic")
            except Exception as e:  # a corrupt message is skipped and counted, never the end of the run
                summary.skipped[cam] += 1
                why = str(e).splitlines()[0][:80] if str(e) else type(e).__name__
                summary.reasons[why] = summary.reasons.get(why, 0) + 1
                continue
            seen[cam].add(stamp)
            used[cam].add(ref)
            name = f"{stamp:019d}.png"
            if not cv2.imwrite(str(out / f"cam{cam}" / "images" / name), grey):
                raise OSError(f"{out / f'cam{cam}' / 'images' / name}: cannot write the image")
            rows[cam].append(f"{summary.images[cam]},{stamp},{name}")
            summary.images[cam] += 1
    finally:
        reader.close()
    empty = [t for t, n in zip(topics, summary.images) if n == 0]
    if empty:
        raise BagError(f"{bag}: no decodable image on {', '.join(empty)}")
    for i, r in enumerate(rows):
        (out / f"cam{i}" / "timestamps.csv").write_text("\n".join(r) + "\n")
        (out / f"cam{i}" / "rostopic").write_text(topics[i] + "\n")  # camchain.yaml names it
    return summary


def _reference_times(reader, conns, bag, interval_s: float) -> tuple[np.ndarray, float]:
    """Receive times (ns, sorted) of the first topic's images that ``interval_s`` thinning keeps
    (the first of each slot of a whole number of its frame periods, slot edges half-way between
    frames), and half its frame period (ns)."""
    t = np.array(sorted(int(t_bag) for _, t_bag, _ in _messages(reader, conns, bag)), dtype=np.int64)
    if len(t) < 2:
        return t, 0.0
    period = float(np.median(np.diff(t)))
    slot_ns = max(1, round(interval_s * 1e9 / max(period, 1.0))) * max(period, 1.0)
    slot = np.floor((t - t[0] + 0.5 * period) / slot_ns).astype(np.int64)
    first = np.r_[True, slot[1:] != slot[:-1]]
    return t[first], 0.5 * period


def _messages(reader, conns, bag):
    """The reader's messages; a bag damaged part-way through is a BagError, not a traceback."""
    n = 0
    try:
        for item in reader.messages(connections=conns):
            n += 1
            yield item
    except Exception as e:
        raise BagError(f"{bag}: damaged after {n} messages ({str(e).splitlines()[0] if str(e) else type(e).__name__})") from None


def _bag_stamp(path: Path) -> list:
    """Name, size and modification time of the bag, or of every file of a ROS2 bag folder."""
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    return [[str(p.relative_to(path) if path.is_dir() else p.name), p.stat().st_size, p.stat().st_mtime_ns] for p in files]


def sequence_from_bag(
    bag: str | Path, topics: list[str], out: str | Path, detector, progress: bool = True, interval_s: float = 0.0, workers: int = 1
) -> tuple[Path, dict]:
    """A sequence folder with detections from the image topics of ``bag``, at ``out``: images and
    timestamps from :func:`bag_to_sequence`, ``camN/detections.json`` from ``detector``
    (a :class:`cotrain.detect.detector.Detector`). Both are cached: a second call for the same bag
    (path, size, modification time), topics and target detects nothing again. Returns the folder
    and what was read ({"images", "skipped", "thinned", "reasons", "cached"}). ``interval_s``: see
    :func:`bag_to_sequence`; ``workers``: see :func:`cotrain.io.detections.detect_files`."""
    from cotrain.io.detections import detect_files, write_json_atomic
    from cotrain.io.sequence import write_camera_detections

    path, out = Path(bag), Path(out)
    if not path.exists():
        raise BagError(f"{bag}: no such bag")
    key = {
        "format": 1,
        "bag": str(path.resolve()),
        "files": _bag_stamp(path),
        "topics": list(topics),
        "interval_s": interval_s,
        "detector": detector.cache_key(),
        "target": detector.target.to_json(),
    }
    marker = out / "bag.json"
    try:
        cached = json.loads(marker.read_text()) if marker.is_file() else None
    except (OSError, ValueError):
        cached = None
    ours = isinstance(cached, dict) and isinstance(cached.get("key"), dict)  # else the folder is not touched
    if (
        ours
        and cached["key"] == key
        and cached.get("read")
        and all((out / f"cam{i}" / "detections.json").is_file() for i in range(len(topics)))
    ):
        return out, {**cached["read"], "cached": True}
    if not ours and out.is_dir() and any(out.iterdir()):
        raise BagError(f"{out}: not empty and not made from a bag; choose another --cache / --out folder")
    for old in out.glob("cam*"):  # a previous extraction (other topics, another detector, or interrupted)
        if old.is_symlink() or (old.name[3:].isdigit() and not old.is_dir()):
            raise BagError(f"{old}: not a camera folder this command made (a link or a file); choose another --cache / --out folder")
        if old.name[3:].isdigit():
            shutil.rmtree(old)
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic({"key": key, "read": None}, marker)  # ours from now on, even if interrupted
    summary = bag_to_sequence(path, topics, out, progress, interval_s)
    for i in range(len(topics)):
        write_camera_detections(out / f"cam{i}", lambda paths: detect_files(paths, detector, progress=progress, workers=workers))
    read = {"images": summary.images, "skipped": summary.skipped, "thinned": summary.thinned, "reasons": summary.reasons}
    write_json_atomic({"key": key, "read": read}, marker)
    return out, {**read, "cached": False}


def image_message(ts, stamp: int, img: np.ndarray, encoding: str = "mono8", frame: str = "cam"):
    """A ``sensor_msgs/Image`` (``encoding``) or, for ``encoding="png"``, a ``CompressedImage`` of
    ``img`` stamped ``stamp`` (ns), built with typestore ``ts``; returns (message, its type)."""
    S = ts.types
    Header, Time = S["std_msgs/msg/Header"], S["builtin_interfaces/msg/Time"]
    extra = {"seq": 0} if "seq" in Header.__dataclass_fields__ else {}  # ROS1's header counts messages
    header = Header(stamp=Time(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id=frame, **extra)
    if encoding == "png":
        data = np.frombuffer(cv2.imencode(".png", img)[1].tobytes(), np.uint8)
        return S["sensor_msgs/msg/CompressedImage"](header=header, format="png", data=data), "sensor_msgs/msg/CompressedImage"
    h, w = img.shape[:2]
    step = img.strides[0]
    msg = S["sensor_msgs/msg/Image"](
        header=header, height=h, width=w, encoding=encoding, is_bigendian=0, step=step, data=img.reshape(-1).view(np.uint8)
    )
    return msg, "sensor_msgs/msg/Image"


def write_image_bag(
    path: Path, ros: int, cams: list[list[tuple[int, np.ndarray]]], encoding: str = "mono8", extra=None, delay: int = 0
) -> Path:
    """A ROS1 ``.bag`` (``ros=1``) or ROS2 bag folder (``ros=2``) with one image topic per camera
    (/camN/image_raw) from ``cams[c] = [(stamp_ns, image), ...]``, received ``delay`` ns after the
    header stamps; ``extra(writer, ts, ser)`` adds more. For tests and benchmarks: a bag from a
    sequence folder."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if ros == 1 else Stores.ROS2_HUMBLE)
    writer = Writer1(path) if ros == 1 else Writer2(path, version=9)
    with writer:
        msgtype = "sensor_msgs/msg/CompressedImage" if encoding == "png" else "sensor_msgs/msg/Image"
        conns = [writer.add_connection(f"/cam{c}/image_raw", msgtype, typestore=ts) for c in range(len(cams))]
        ser = ts.serialize_ros1 if ros == 1 else ts.serialize_cdr
        for c, frames in enumerate(cams):
            for stamp, img in frames:
                msg, typ = image_message(ts, stamp, img, encoding, f"cam{c}")
                writer.write(conns[c], stamp + delay, ser(msg, typ))
        if extra:
            extra(writer, ts, ser)
    return path
