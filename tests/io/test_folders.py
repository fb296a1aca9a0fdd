"""Image folders as input (one folder per camera): pairing by name, order or nanosecond names,
the cached sequence folder, and the one-line errors a newcomer meets."""

import shutil

import pytest

from calib_eval.cli import run as calib_cli
from cotrain.cli import run as cotrain_cli
from cotrain.io.folders import SNAPSHOT_PERIOD_NS, FolderError, check_sequence_folder, pair_folders, sequence_from_folders
from cotrain.io.sequence import load_sequence
from tests.paths import SHARED

STEREO = SHARED / "real" / "ros_fisheye_stereo" / "images"
KALIBR_CHECKERBOARD = "target_type: checkerboard\ntargetCols: 8\ntargetRows: 6\nrowSpacingMeters: 0.1\ncolSpacingMeters: 0.1\n"


def _files(folder, names):
    folder.mkdir(parents=True, exist_ok=True)
    for n in names:
        (folder / n).write_bytes(b"x")
    return folder


def test_identical_names_pair_by_name_and_keep_unpaired_images(tmp_path):
    a = _files(tmp_path / "a", ["0001.png", "0002.png", "0003.png"])
    b = _files(tmp_path / "b", ["0001.png", "0003.png"])
    p = pair_folders([a, b])
    assert p.how == "name"
    # 0003 is the same view in both folders; 0002 only in a's.
    assert p.stamps_ns[0][2] == p.stamps_ns[1][1] and p.stamps_ns[0][1] not in p.stamps_ns[1]
    same = pair_folders([a, a])
    assert same.stamps_ns[0] == [0, SNAPSHOT_PERIOD_NS, 2 * SNAPSHOT_PERIOD_NS]


def test_different_names_pair_by_sorted_order(tmp_path):
    a = _files(tmp_path / "left", ["left-0002.png", "left-0001.png"])
    b = _files(tmp_path / "right", ["right-0001.png", "right-0002.png"])
    p = pair_folders([a, b])
    assert p.how == "order"
    assert [f.name for f in p.files[0]] == ["left-0001.png", "left-0002.png"]
    assert p.stamps_ns[0] == p.stamps_ns[1]


def test_nanosecond_names_are_times_and_counts_may_differ(tmp_path):
    t = 1_700_000_000_000_000_000
    a = _files(tmp_path / "a", [f"{t}.png", f"{t + 50_000_000}.png"])
    b = _files(tmp_path / "b", [f"{t + 2_000_000}.png"])
    p = pair_folders([a, b])
    assert p.how == "time" and p.stamps_ns == [[t, t + 50_000_000], [t + 2_000_000]]
    # Short numbers are frame numbers, not times.
    assert pair_folders([_files(tmp_path / "c", ["0001.png"]), _files(tmp_path / "d", ["0001.png"])]).how == "name"


def test_count_mismatch_and_empty_folder_say_what_was_found(tmp_path):
    a = _files(tmp_path / "left", ["left-1.png", "left-2.png", "left-3.png"])
    b = _files(tmp_path / "right", ["right-1.png"])
    with pytest.raises(FolderError, match=r"left: 3 images, .*right: 1 images") as e:
        pair_folders([a, b])
    assert "\n" not in str(e.value)
    empty = tmp_path / "empty"
    (empty / "cam0").mkdir(parents=True)
    (empty / "cam0" / "x.png").write_bytes(b"x")
    with pytest.raises(FolderError, match="no images .*folders below it hold images: .*cam0"):
        pair_folders([a, empty])
    with pytest.raises(FolderError, match="no such folder"):
        pair_folders([a, tmp_path / "missing"])


def test_out_names_a_folder(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(FolderError, match="an existing file"):
        check_sequence_folder(tmp_path / "file")
    with pytest.raises(FolderError, match="not a .json file"):
        check_sequence_folder(tmp_path / "det.json")
    assert check_sequence_folder(tmp_path / "seq") == tmp_path / "seq"


@pytest.fixture(scope="module")
def stereo_folders(tmp_path_factory):
    """Eight pairs of the real stereo head, split into left/ and right/ as OpenCV users save them."""
    if not STEREO.is_dir():
        pytest.skip(f"{STEREO} is not beside the clone")
    root = tmp_path_factory.mktemp("stereo")
    for side in ("left", "right"):
        (root / side).mkdir()
        for f in sorted(STEREO.glob(f"{side}-*.png"))[:8]:
            shutil.copyfile(f, root / side / f.name)
    (root / "board.yaml").write_text(KALIBR_CHECKERBOARD)
    return root


def test_folders_make_a_cached_sequence(stereo_folders):
    from cotrain.detect.detector import make_detector
    from cotrain.targets import load_target

    root = stereo_folders
    det = make_detector(load_target(root / "board.yaml"), None)
    out, read = sequence_from_folders([root / "left", root / "right"], root / "seq", det, progress=False)
    assert read == {"images": [8, 8], "pairing": "order", "cached": False}
    seq = load_sequence(out)
    assert [c.name for c in seq.cameras] == ["cam0", "cam1"] and seq.n_views == 8
    both = {o.view for o in seq.observations if o.cam == 0} & {o.view for o in seq.observations if o.cam == 1}
    assert len(both) >= 7  # the board is found in nearly every image of the head
    assert (out / "cam0" / "images" / "left-0000.png").is_file()
    _, again = sequence_from_folders([root / "left", root / "right"], root / "seq", det, progress=False)
    assert again["cached"]
    with pytest.raises(FolderError, match="not made from image folders"):
        (root / "other").mkdir()
        (root / "other" / "x").write_text("x")
        sequence_from_folders([root / "left", root / "right"], root / "other", det, progress=False)


def test_detect_and_coverage_take_image_folders(stereo_folders, capsys):
    root = stereo_folders
    out = root / "detected"
    args = ["--images", str(root / "left"), str(root / "right"), "--target", str(root / "board.yaml")]
    assert cotrain_cli(["detect", *args, "--out", str(out), "--workers", "1"]) == 0
    assert (out / "cam1" / "detections.json").is_file()
    assert calib_cli(["coverage", *args, "--cache", str(out)]) == 0
    text = capsys.readouterr().out
    assert "cached detections" in text and "cam0 + cam1:" in text


def test_newcomer_errors_are_one_line(stereo_folders, tmp_path, capsys):
    root = stereo_folders
    images = ["--images", str(root / "left"), str(root / "right")]
    camchain = tmp_path / "camchain.yaml"
    camchain.write_text("cam0:\n  camera_model: pinhole\n  intrinsics: [400, 400, 320, 240]\n")
    (tmp_path / "empty").mkdir()
    cases = [
        (["calibrate", *images, "--models", "pinhole-equi", "--out", str(tmp_path / "o")], "give one per camera"),
        (["calibrate", *images, "--target", str(camchain), "--out", str(tmp_path / "o")], "not a calibration target"),
        (["calibrate", "--images", str(root / "left"), str(tmp_path / "empty"), "--out", str(tmp_path / "o")], "empty: no images"),
        (["calibrate", *images, "--out", str(camchain)], "an existing file"),
        (["select", *images, "--fov", "5"], "--fov 5: give the lens's rough field of view"),
    ]
    for argv, msg in cases:
        assert calib_cli(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and msg in err[0], (argv, err)
    assert cotrain_cli(["detect", *images, "--out", str(tmp_path / "det.json")]) == 2
    assert "not a .json file" in capsys.readouterr().err
    assert cotrain_cli(["detect", *images, "--draw", str(tmp_path / "overlays")]) == 2
    assert "--draw goes with images or folders" in capsys.readouterr().err
    assert calib_cli(["coverage", *images, "--every", "0.5"]) == 2
    assert "--every goes with --bag" in capsys.readouterr().err


def test_fov_is_estimated_where_not_given(stereo_folders, capsys):
    """Across the circle touching the shorter side (251.5 px from the centre of 800 x 503), the ROS
    reference calibration (kb4, reference/left.yaml) sees 103 deg."""
    root = stereo_folders
    argv = ["select", "--images", str(root / "left"), str(root / "right"), "--target", str(root / "board.yaml")]
    assert calib_cli([*argv, "--cache", str(root / "sel_seq")]) == 0
    assert (root / "sel_seq" / "selection.json").is_file()  # in the sequence folder, not the working folder
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("no --fov given"))
    est = float(line.split("estimated ")[1].split(" deg")[0])
    assert 85 < est < 125, line


def _detector(root):
    from cotrain.detect.detector import make_detector
    from cotrain.targets import load_target

    return make_detector(load_target(root / "board.yaml"), None)


def test_a_users_image_folders_are_never_removed(stereo_folders, tmp_path):
    """Image folders laid out as rig/cam0, rig/cam1 with --cache rig: refused, every image kept,
    whether rig holds a stray folders.json or a marker that looks like ours."""
    det = _detector(stereo_folders)
    rig = tmp_path / "rig"
    for c, side in enumerate(("left", "right")):
        shutil.copytree(stereo_folders / side, rig / f"cam{c}")
    before = sorted(p.relative_to(rig) for p in rig.rglob("*"))
    for marker in ("not json", '{"key": {}, "complete": true}'):
        (rig / "folders.json").write_text(marker)
        with pytest.raises(FolderError):
            sequence_from_folders([rig / "cam0", rig / "cam1"], rig, det, progress=False)
        (rig / "folders.json").unlink()
        assert sorted(p.relative_to(rig) for p in rig.rglob("*")) == before
    # A camera folder that is a link to the user's folder: refused, the folder untouched.
    seq = tmp_path / "seq"
    seq.mkdir()
    (seq / "folders.json").write_text('{"key": {}, "complete": false}')
    (seq / "cam0").symlink_to(rig / "cam0", target_is_directory=True)
    with pytest.raises(FolderError, match="a link or a file"):
        sequence_from_folders([stereo_folders / "left"], seq, det, progress=False)
    assert sorted(p.relative_to(rig) for p in rig.rglob("*")) == before


def test_an_interrupted_run_is_made_again_and_names_with_commas_survive(stereo_folders, tmp_path):
    det = _detector(stereo_folders)
    left = tmp_path / "left"
    left.mkdir()
    for k, f in enumerate(sorted((stereo_folders / "left").glob("*.png"))[:3]):
        shutil.copyfile(f, left / f"shot,{k}.png")
    seq = tmp_path / "seq"
    (seq / "cam0").mkdir(parents=True)
    (seq / "cam0" / "timestamps.csv").write_text("frame_id,timestamp_ns,filename\n")  # what an interrupted run left
    (seq / "folders.json").write_text('{"key": {"format": 1}, "read": null, "complete": false}')
    out, read = sequence_from_folders([left], seq, det, progress=False)
    assert not read["cached"]
    loaded = load_sequence(out)
    assert sorted({o.frame for o in loaded.observations}) == ["shot,0.png", "shot,1.png", "shot,2.png"]
    assert sequence_from_folders([left], seq, det, progress=False)[1]["cached"]
