"""ROS bags as input: images streamed out of ROS1 and ROS2 bags (raw and compressed) give the
same calibration as the folder they were written from; bad bags give one-line errors."""

import cv2
import numpy as np
import pytest
import yaml
from rosbags.typesys import Stores, get_typestore

from calib_eval.benchmark.rendered import render_rig_sequence
from calib_eval.benchmark.rigs import paper_config
from calib_eval.cli import run as calib_cli
from cotrain.io.bags import BagError, bag_to_sequence, decode_image, image_message, write_image_bag

T0 = 1_700_000_000_000_000_000  # header stamps of the bags: the folder's times plus this


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    """A rendered FoV 200 stereo rig (32 frames) as a sequence folder, calibrated from the folder."""
    root = tmp_path_factory.mktemp("rig")
    seq_dir = root / "seq"
    render_rig_sequence(paper_config("FoV200_90"), 32, seq_dir, seed=11, progress=False)
    cams = []
    for c in range(2):
        rows = (seq_dir / f"cam{c}" / "timestamps.csv").read_text().splitlines()[1:]
        cams.append(
            [
                (T0 + int(r.split(",")[1]), cv2.imread(str(seq_dir / f"cam{c}" / "images" / r.split(",")[2]), cv2.IMREAD_GRAYSCALE))
                for r in rows
            ]
        )
    from cotrain.detect.detector import Detector
    from cotrain.io.detections import detect_files
    from cotrain.io.sequence import write_camera_detections

    det = Detector(threads=1)
    for c in range(2):
        write_camera_detections(seq_dir / f"cam{c}", lambda paths: detect_files(paths, det, progress=False))
    out = root / "folder_calib"
    assert (
        calib_cli(["calibrate", str(seq_dir), "--fov", "200", "--models", "pinhole-equi", "pinhole-equi", "--select", "--out", str(out)])
        == 0
    )
    return cams, yaml.safe_load((out / "camchain.yaml").read_text())


@pytest.mark.parametrize("ros, encoding", [(1, "mono8"), (2, "png")])
def test_bag_calibration_matches_the_folder(rig, tmp_path, ros, encoding, capsys):
    cams, folder_chain = rig
    bag = write_image_bag(tmp_path / ("rec.bag" if ros == 1 else "rec"), ros, cams, encoding)
    out = tmp_path / "calib"
    args = ["calibrate", "--bag", str(bag), "--topics", "/cam0/image_raw", "/cam1/image_raw", "--fov", "200"]
    args += ["--models", "pinhole-equi", "pinhole-equi", "--select", "--out", str(out)]
    assert calib_cli(args) == 0
    assert yaml.safe_load((out / "camchain.yaml").read_text()) == folder_chain
    assert "detected" in capsys.readouterr().out
    # A second run reuses the cached images and detections.
    assert calib_cli(args) == 0
    assert "cached detections" in capsys.readouterr().out
    assert yaml.safe_load((out / "camchain.yaml").read_text()) == folder_chain


def test_missing_topic_and_empty_bag_are_one_line(tmp_path, capsys):
    img = np.full((40, 60), 128, np.uint8)
    bag = write_image_bag(tmp_path / "two.bag", 1, [[(T0, img)], [(T0, img)]])
    base = ["calibrate", "--fov", "200", "--out", str(tmp_path / "o")]
    assert calib_cli([*base, "--bag", str(bag), "--topics", "/cam0/image_raw", "/left/image"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "/left/image" in err[0] and "/cam0/image_raw, /cam1/image_raw" in err[0]
    empty = write_image_bag(tmp_path / "empty", 2, [])
    assert calib_cli([*base, "--bag", str(empty), "--topics", "/cam0/image_raw"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "image topics in the bag: none" in err[0]
    assert calib_cli([*base, "--bag", str(tmp_path / "nope.bag"), "--topics", "/cam0/image_raw"]) == 2
    assert calib_cli([*base, str(tmp_path), "--bag", str(bag), "--topics", "/cam0/image_raw"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "no such bag" in err[0] and "one of them" in err[1]


def test_corrupt_message_is_skipped_and_counted(tmp_path):
    img = np.tile(np.arange(60, dtype=np.uint8), (40, 1))

    def broken(writer, ts, ser):
        conn = [c for c in writer.connections if c.topic == "/cam0/image_raw"][0]
        msg, typ = image_message(ts, T0 + 3, img)
        msg.height = 400  # more rows than the data holds
        writer.write(conn, T0 + 3, ser(msg, typ))

    bag = write_image_bag(tmp_path / "r.bag", 1, [[(T0, img), (T0 + 1, img)]], extra=broken)
    out = tmp_path / "seq"
    summary = bag_to_sequence(bag, ["/cam0/image_raw"], out, progress=False)
    assert summary.images == [2] and summary.skipped == [1] and sum(summary.reasons.values()) == 1
    rows = (out / "cam0" / "timestamps.csv").read_text().splitlines()
    assert [int(r.split(",")[1]) for r in rows[1:]] == [T0, T0 + 1]
    assert np.array_equal(cv2.imread(str(out / "cam0" / "images" / rows[1].split(",")[2]), cv2.IMREAD_UNCHANGED), img)
    with pytest.raises(BagError, match="twice"):
        bag_to_sequence(bag, ["/cam0/image_raw", "/cam0/image_raw"], tmp_path / "x", progress=False)


def test_decode_encodings():
    ts = get_typestore(Stores.ROS2_HUMBLE)
    rng = np.random.default_rng(0)
    grey = rng.integers(0, 255, (6, 8), dtype=np.uint8)
    bgr = np.dstack([grey, grey, grey])
    for enc, img in [("mono8", grey), ("bgr8", bgr), ("rgb8", bgr[..., ::-1].copy()), ("bgra8", np.dstack([bgr, grey]))]:
        msg, typ = image_message(ts, T0, img, enc)
        np.testing.assert_array_equal(decode_image(msg, typ), grey)
    deep = rng.integers(0, 65535, (6, 8), dtype=np.uint16)
    msg, typ = image_message(ts, T0, deep, "mono16")
    got = decode_image(msg, typ)
    assert got.dtype == np.uint16 and np.array_equal(got, deep)
    # A flat colour (B, G, R) = (40, 120, 220) as an RGGB mosaic decodes to its grey value.
    mosaic = np.zeros((8, 8), np.uint8)
    mosaic[0::2, 0::2], mosaic[0::2, 1::2], mosaic[1::2, 0::2], mosaic[1::2, 1::2] = 220, 120, 120, 40
    msg, typ = image_message(ts, T0, mosaic, "bayer_rggb8")
    want = cv2.cvtColor(np.full((1, 1, 3), (40, 120, 220), np.uint8), cv2.COLOR_BGR2GRAY)[0, 0]
    assert abs(int(decode_image(msg, typ)[4, 4]) - int(want)) <= 2
    msg, typ = image_message(ts, T0, grey, "png")
    np.testing.assert_array_equal(decode_image(msg, typ), grey)
    msg, typ = image_message(ts, T0, grey, "yuv422")
    with pytest.raises(ValueError, match="unsupported encoding"):
        decode_image(msg, typ)


def test_cotrain_detect_from_a_bag(rig, tmp_path, capsys):
    """``cotrain detect --bag --topics`` writes the sequence folder the calibrator reads."""
    from cotrain.cli import run as cotrain_cli
    from cotrain.io.sequence import load_sequence

    cams, _ = rig
    bag = write_image_bag(tmp_path / "rec.bag", 1, [frames[:4] for frames in cams])
    out = tmp_path / "seq"
    assert cotrain_cli(["detect", "--bag", str(bag), "--topics", "/cam0/image_raw", "/cam1/image_raw", "--out", str(out)]) == 0
    seq = load_sequence(out)
    assert len(seq.cameras) == 2 and seq.n_views == 4 and len(seq.observations) >= 4
    capsys.readouterr()
    assert cotrain_cli(["detect", "--bag", str(bag)]) == 2
    assert cotrain_cli(["detect", str(tmp_path), "--bag", str(bag), "--topics", "/cam0/image_raw"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "together" in err[0] and "one of them" in err[1]


def test_cache_follows_topics_and_refuses_foreign_folders(tmp_path):
    """Another set of topics re-extracts (no stale camera folder survives); a folder whose marker is
    unreadable (markers are written atomically: not ours), or that was not made from a bag, is
    refused and nothing in it removed; an interrupted extraction is made again."""
    from cotrain.detect.detector import Detector
    from cotrain.io.bags import sequence_from_bag

    img = np.full((40, 60), 128, np.uint8)
    bag = write_image_bag(tmp_path / "r.bag", 1, [[(T0, img)], [(T0, img)], [(T0, img)]])
    det = Detector(threads=1)
    out = tmp_path / "seq"
    three = ["/cam0/image_raw", "/cam1/image_raw", "/cam2/image_raw"]
    assert not sequence_from_bag(bag, three, out, det, progress=False)[1]["cached"]
    assert sequence_from_bag(bag, three, out, det, progress=False)[1]["cached"]
    assert not sequence_from_bag(bag, three[:2], out, det, progress=False)[1]["cached"]
    assert sorted(p.name for p in out.glob("cam*")) == ["cam0", "cam1"]
    (out / "bag.json").write_text("{not json")
    with pytest.raises(BagError, match="not made from a bag"):
        sequence_from_bag(bag, three[:2], out, det, progress=False)
    assert sorted(p.name for p in out.glob("cam*")) == ["cam0", "cam1"]
    (out / "bag.json").write_text('{"key": {"format": 1}, "read": null}')  # what an interrupted extraction leaves
    assert not sequence_from_bag(bag, three[:2], out, det, progress=False)[1]["cached"]
    assert sequence_from_bag(bag, three[:2], out, det, progress=False)[1]["cached"]
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    with pytest.raises(BagError, match="not made from a bag"):
        sequence_from_bag(bag, three[:2], mine, det, progress=False)


def test_damaged_and_old_bags(tmp_path):
    img = np.full((40, 60), 128, np.uint8)
    frames = [(T0 + k, img) for k in range(50)]
    bag = write_image_bag(tmp_path / "r.bag", 1, [frames])
    data = bytearray(bag.read_bytes())
    damaged = tmp_path / "d.bag"
    damaged.write_bytes(bytes(data[: len(data) * 2 // 3]))  # cut part-way: the index is gone
    with pytest.raises(BagError):
        bag_to_sequence(damaged, ["/cam0/image_raw"], tmp_path / "x", progress=False)
    # A ROS2 bag without message definitions (recorded before Iron) is read with Humble's types.
    old = write_image_bag(tmp_path / "old", 2, [frames[:3]])
    meta = old / "metadata.yaml"
    m = yaml.safe_load(meta.read_text())
    for t in m["rosbag2_bagfile_information"]["topics_with_message_count"]:
        t["topic_metadata"].pop("message_definition", None)
        t["topic_metadata"].pop("type_description_hash", None)
    meta.write_text(yaml.safe_dump(m))
    import sqlite3

    db = next(old.glob("*.db3"))
    with sqlite3.connect(db) as con:
        if "message_definitions" in {r[0] for r in con.execute("select name from sqlite_master")}:
            con.execute("delete from message_definitions")
    assert bag_to_sequence(old, ["/cam0/image_raw"], tmp_path / "o", progress=False).images == [3]


def test_header_stamps_their_fallback_and_duplicates(tmp_path):
    """The header stamps are the clock (not the receive time); a topic whose headers are 0 falls
    back to the bag's time as a whole; a repeated stamp is skipped and counted; camchain's
    rostopic comes from the bag."""
    img = np.full((40, 60), 128, np.uint8)
    cams = [[(T0, img), (T0 + 50_000_000, img), (T0 + 50_000_000, img)], [(0, img), (0, img)]]
    bag = write_image_bag(tmp_path / "r.bag", 1, cams, delay=7_000_000)
    out = tmp_path / "seq"
    summary = bag_to_sequence(bag, ["/cam0/image_raw", "/cam1/image_raw"], out, progress=False)
    assert summary.clock == ["header", "bag"] and summary.images == [2, 1] and summary.skipped == [1, 1]
    assert "duplicate stamp on its topic" in summary.reasons
    t0 = [int(r.split(",")[1]) for r in (out / "cam0" / "timestamps.csv").read_text().splitlines()[1:]]
    t1 = [int(r.split(",")[1]) for r in (out / "cam1" / "timestamps.csv").read_text().splitlines()[1:]]
    assert t0 == [T0, T0 + 50_000_000] and t1 == [7_000_000]
    assert (out / "cam1" / "rostopic").read_text().strip() == "/cam1/image_raw"


def test_every_thins_by_time_slots_and_keeps_cameras_paired(tmp_path):
    """A 30 Hz stereo recording thinned to one image per 0.5 s: cam0 keeps the first frame of each
    slot, cam1 (2 ms later) the frame within half a period of it; where cam1 dropped that frame its
    slot stays unpaired rather than taking a frame 35 ms off. An IMU topic in the bag changes
    nothing."""
    img = np.full((40, 60), 128, np.uint8)
    period = 33_333_333
    cam0 = [(T0 + k * period, img) for k in range(60)]
    cam1 = [(T0 + k * period + 2_000_000, img) for k in range(60) if k != 15]  # frame 15 dropped

    def imu(writer, ts, ser):  # a longer, faster topic that starts earlier
        S = ts.types
        conn = writer.add_connection("/imu", "std_msgs/msg/Header", typestore=ts)
        for k in range(500):
            stamp = T0 - 10**9 + k * 5_000_000
            time = S["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9)
            h = S["std_msgs/msg/Header"](stamp=time, frame_id="imu", seq=0)
            writer.write(conn, stamp, ser(h, "std_msgs/msg/Header"))

    bag = write_image_bag(tmp_path / "r.bag", 1, [cam0, cam1], extra=imu)
    s = bag_to_sequence(bag, ["/cam0/image_raw", "/cam1/image_raw"], tmp_path / "seq", progress=False, interval_s=0.5)
    t = [[int(r.split(",")[1]) for r in (tmp_path / "seq" / f"cam{c}" / "timestamps.csv").read_text().splitlines()[1:]] for c in (0, 1)]
    assert [round((x - T0) / period) for x in t[0]] == [0, 15, 30, 45]
    assert [round((x - T0 - 2_000_000) / period) for x in t[1]] == [0, 30, 45]
    assert s.images == [4, 3] and s.thinned == [56, 56]
    assert all(min(abs(b - a) for a in t[0]) <= 2_000_000 for b in t[1])  # each kept cam1 image has its cam0 partner
