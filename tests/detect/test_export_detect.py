"""ONNX export (checker + parity) and the onnxruntime detector on rendered and broken inputs."""

import json

import cv2
import numpy as np
import onnx
import pytest

from cotrain.cli import run as cotrain_cli
from cotrain.config import load_config
from cotrain.detect.detector import Detector
from cotrain.detect.images import expand_inputs, load_image
from cotrain.detect.onnx_model import OnnxModel
from cotrain.io.detections import detect_files
from cotrain.model.outputs import DENSE_OUTPUTS, GRID_OUTPUTS, dense_maps
from cotrain.model.train import TrainConfig, finalize_config, train
from cotrain.render.renderer import render_batch
from cotrain.targets import Checkerboard, TargetConfig
from tests.paths import TINY


@pytest.fixture(scope="module")
def tiny_onnx(tmp_path_factory):
    d = tmp_path_factory.mktemp("tiny")
    train(finalize_config(load_config(TrainConfig, TINY, [f"train.out_dir={d}", "train.steps=2"])))
    out = d / "tiny.onnx"
    assert cotrain_cli(["export", "--checkpoint", str(d / "last.pt"), "--out", str(out)]) == 0
    return out


def test_export_checker_metadata_dynamic_batch(tiny_onnx):
    m = onnx.load(str(tiny_onnx))
    onnx.checker.check_model(m)
    assert max(o.version for o in m.opset_import if o.domain in ("", "ai.onnx")) >= 17
    meta = {p.key: p.value for p in m.metadata_props}
    assert json.loads(meta["cotrain.input_size"]) == [64, 96]
    assert json.loads(meta["cotrain.target"])["squares_x"] == 10
    net = OnnxModel(tiny_onnx)
    for b in (1, 3):
        outs = net.run(np.zeros((b, 1, 64, 96), np.float32))
        assert outs["corners"].shape == (b, 54, 2) and outs["visibility"].shape == (b, 54)
        assert outs["col_logp"].shape == (b, 11, 16, 24) and outs["row_logp"].shape == (b, 8, 16, 24)


def test_grid_mode_cuts_the_graph_to_the_dense_maps(tiny_onnx):
    """The grid pass's detector runs only the part of the graph its dense maps need, and those
    maps are the full graph's, value for value."""
    full, det = OnnxModel(tiny_onnx), Detector(tiny_onnx)
    assert det.net.outputs == DENSE_OUTPUTS
    cut = {n.op_type for n in det.net._proto.graph.node}
    assert "GridSample" in {n.op_type for n in full._proto.graph.node} and "GridSample" not in cut  # the point heads' sampling
    x = np.random.default_rng(1).random((2, 1, 64, 96)).astype(np.float32)
    a, b = full.run(x), det.net.run(x)
    for n in DENSE_OUTPUTS:
        np.testing.assert_allclose(b[n], a[n], rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="lacks the outputs"):
        det.net.keep(("corners",))


def test_export_at_another_processing_size(tiny_onnx, tmp_path):
    """--input-size exports the same weights at another processing size: the metadata says it, the
    detector letterboxes into it, and the maps are a quarter of it."""
    ck = tiny_onnx.parent / "last.pt"
    out = tmp_path / "small.onnx"
    assert cotrain_cli(["export", "--checkpoint", str(ck), "--out", str(out), "--input-size", "64x32"]) == 0
    det = Detector(out)
    assert det.input_size == (32, 64)
    assert det.letterbox(np.zeros((120, 200), np.float32)).scale == pytest.approx(min(64 / 200, 32 / 120))
    assert det.net.run(np.zeros((1, 1, 32, 64), np.float32))["corner_prob"].shape == (1, 1, 8, 16)
    assert cotrain_cli(["export", "--checkpoint", str(ck), "--out", str(out), "--input-size", "64by32"]) == 2


def test_int8_graph_for_the_grid_pass(tiny_onnx, tmp_path):
    """--int8: a dense-maps-only graph with quantized convolutions; the grid pass takes it, the
    per-slot read-out refuses it in one line, and its maps stay near the float graph's."""
    from export.onnx_export import quantize_dense

    out = tmp_path / "int8.onnx"
    r = quantize_dense(tiny_onnx, out, n_calib=4)
    ops = {n.op_type for n in onnx.load(str(out)).graph.node}
    assert "QuantizeLinear" in ops and "DequantizeLinear" in ops
    net = OnnxModel(out)
    assert net.outputs == DENSE_OUTPUTS + ("col_logits", "row_logits") and not net.has_slots and net.input_size == (64, 96)
    assert r["max_diff"]["corner_prob"] < 0.25 and r["max_diff"]["mask_prob"] < 0.25
    # The grid pass runs the logits, without the graph's log-softmax, and takes it itself: the same maps.
    det = Detector(out)
    assert det.net.outputs == GRID_OUTPUTS
    assert "LogSoftmax" not in {n.op_type for n in det.net._proto.graph.node}
    x = np.random.default_rng(2).random((1, 1, 64, 96)).astype(np.float32)
    given, taken = net.run(x), dense_maps(det.net.run(x))
    for n in DENSE_OUTPUTS:
        np.testing.assert_allclose(taken[n], given[n], atol=1e-5)
    det.detect(np.random.default_rng(0).random((120, 200)).astype(np.float32))
    with pytest.raises(ValueError, match="no per-slot outputs"):
        Detector(out, mode="slots")


def test_export_bad_checkpoint_is_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    assert cotrain_cli(["export", "--checkpoint", str(bad), "--out", str(tmp_path / "x.onnx")]) == 2
    assert cotrain_cli(["export", "--checkpoint", str(tmp_path / "missing.pt"), "--out", str(tmp_path / "x.onnx")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 2


def test_detect_rendered_and_broken_inputs(tiny_onnx, tmp_path):
    cfg = finalize_config(load_config(TrainConfig, TINY))
    cfg.render.height, cfg.render.width = 120, 200
    batch = render_batch(cfg.render, [0, 1], seed=5)
    folder = tmp_path / "imgs"
    folder.mkdir()
    for i in range(2):
        cv2.imwrite(str(folder / f"r{i}.png"), (batch["image"][i, 0].numpy() * 255).astype(np.uint8))
    cv2.imwrite(str(folder / "deep.png"), (batch["image"][0, 0].numpy() * 65535).astype(np.uint16))
    cv2.imwrite(str(folder / "colour.jpg"), cv2.cvtColor((batch["image"][1, 0].numpy() * 255).astype(np.uint8), cv2.COLOR_GRAY2BGR))
    (folder / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\nbroken")
    (folder / "empty.png").write_bytes(b"")
    cv2.imwrite(str(folder / "tiny.png"), np.zeros((1, 1), np.uint8))
    out = tmp_path / "det.json"
    rc = cotrain_cli(
        [
            "detect",
            "--model",
            str(tiny_onnx),
            str(folder),
            str(tmp_path / "missing.png"),
            "--out",
            str(out),
            "--threshold",
            "0.0",
            "--no-consistency",
            "--slots",
            "--draw",
            str(tmp_path / "draw"),
        ]
    )
    assert rc == 0
    data = json.loads(out.read_text())
    assert set(data) == {"model", "target", "images"}
    by = {e["path"].split("/")[-1]: e for e in data["images"]}
    assert len(by) == 8
    for name in ("r0.png", "r1.png", "deep.png", "colour.jpg"):
        e = by[name]
        assert e["error"] is None and (e["width"], e["height"]) == (200, 120)
        # Threshold 0: every slot whose corner lands inside the image is reported.
        full = Detector(tiny_onnx, threshold=0.0, consistency=False, mode="slots").detect(load_image(folder / name))
        inside = ((full.all_xy[:, 0] > -0.5) & (full.all_xy[:, 0] < 199.5) & (full.all_xy[:, 1] > -0.5) & (full.all_xy[:, 1] < 119.5)).sum()
        assert len(e["corners"]) == inside > 0
        for c in e["corners"]:
            assert set(c) == {"id", "x", "y", "confidence"} and 0 <= c["id"] < 54 and 0 <= c["confidence"] <= 1
            assert -0.5 <= c["x"] < 199.5 and -0.5 <= c["y"] < 119.5
    # 16-bit and 8-bit versions of the same image give the same corners.
    a = np.array([[c["x"], c["y"]] for c in by["r0.png"]["corners"]])
    b = np.array([[c["x"], c["y"]] for c in by["deep.png"]["corners"]])
    assert np.abs(a - b).max() < 0.5
    for name, why in [
        ("corrupt.png", "not a readable image"),
        ("empty.png", "empty file"),
        ("tiny.png", "too small"),
        ("missing.png", "not found"),
    ]:
        assert why in by[name]["error"] and by[name]["corners"] == []
    assert (tmp_path / "draw" / "r0_det.png").is_file()


def test_detect_maps_back_to_input_resolution(tiny_onnx):
    """A corner the model puts at processing pixel x maps to (x + 0.5) / s - 0.5 in the input."""
    det = Detector(tiny_onnx, threshold=0.0, consistency=False, mode="slots")
    img = np.random.default_rng(0).random((240, 400)).astype(np.float32)  # 2.5x the 96x64 size in x, 3.75 in y
    d = det.detect(img)
    box = det.letterbox(img)
    s = box.scale
    raw = det.net.run(box.apply(img)[None, None])["corners"][0]
    assert s == pytest.approx(min(96 / 400, 64 / 240))
    np.testing.assert_allclose(d.all_xy, (raw + 0.5) / s - 0.5, rtol=1e-6)


def test_detect_missing_model_is_clear(tmp_path):
    assert cotrain_cli(["detect", "--model", str(tmp_path / "none.onnx"), str(tmp_path)]) == 2


def test_expand_inputs_sorted(tmp_path):
    for n in ("b.png", "a.jpg", "notes.txt"):
        (tmp_path / n).write_bytes(b"x")
    assert [p.name for p in expand_inputs([str(tmp_path)])] == ["a.jpg", "b.png"]


def test_detect_files_finds_rendered_corners_and_records_errors(tmp_path, monkeypatch, worker_pools):
    """detect_files with the shipped model on clean renders at twice the processing size (known
    corners): nearly every visible corner found under its own id, sub-pixel at input resolution,
    nothing reported where the board is not; bad files become entries with an error. Two worker
    processes (the threshold of files per process lowered to these few files) give the same JSON."""
    from cotrain.render.renderer import RenderConfig

    cfg = RenderConfig(
        height=432,
        width=768,
        p_occluder=0.0,
        p_no_target=0.0,
        p_blur=0.0,
        p_motion=0.0,
        p_jpeg=0.0,
        distance_range=(0.15, 0.4),
        max_tilt_deg=40.0,
        offaxis_margin_deg=-30.0,
    )
    out = render_batch(cfg, [0, 1, 2, 3], seed=3)  # sample 0: the board almost out of view (3 corners)
    paths = []
    for i in range(4):
        paths.append(tmp_path / f"r{i}.png")
        cv2.imwrite(str(paths[i]), (out["image"][i, 0].numpy() * 255).round().astype(np.uint8))
    (tmp_path / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\nbroken")
    # A bad file between good ones: the files after it (read ahead while it failed) are still done.
    files = [*paths[:2], tmp_path / "corrupt.png", *paths[2:], tmp_path / "missing.png"]
    data = detect_files(files, Detector(threads=1), progress=False)
    assert [e["path"] for e in data["images"]] == [str(p) for p in files]
    assert data["target"] is not None
    good = [e for e in data["images"] if e["path"] in {str(p) for p in paths}]
    # Two images in flight (network ahead, grid pass behind) give what one image at a time gives.
    det = Detector(threads=1)
    for p, e in zip(paths, good):
        d = det.detect(load_image(p))
        assert [c["id"] for c in e["corners"]] == d.ids.tolist()
        np.testing.assert_allclose(np.array([[c["x"], c["y"]] for c in e["corners"]]).reshape(-1, 2), d.xy.reshape(-1, 2), atol=1e-3)
    n_found = 0
    for i, e in enumerate(good):
        assert e["error"] is None and (e["width"], e["height"]) == (768, 432)
        vis, gt = out["visible"][i].numpy(), out["corners_raw"][i].numpy()
        ids = np.array([c["id"] for c in e["corners"]], dtype=int)
        xy = np.array([[c["x"], c["y"]] for c in e["corners"]]).reshape(-1, 2)
        assert len(set(ids.tolist())) == len(ids) and vis[ids].all()  # no corner twice, none off the board
        if vis.sum() >= 20:
            assert len(ids) >= 0.95 * vis.sum(), (i, len(ids), vis.sum())
            err = np.linalg.norm(xy - gt[ids], axis=1)
            assert np.median(err) < 0.3 and err.max() < 1.0, (i, np.median(err), err.max())  # measured 0.03-0.06 / 0.16
            assert all(0 < c["confidence"] <= 1 for c in e["corners"])
            n_found += 1
    assert n_found == 3
    for e, why in zip([data["images"][2], data["images"][5]], ("not a readable image", "not found")):
        assert why in e["error"] and e["corners"] == [] and (e["width"], e["height"]) == (0, 0)
    monkeypatch.setattr(Detector, "files_per_worker", 3)
    assert detect_files(files, Detector(threads=1), progress=False, workers=2) == data
    assert worker_pools == [2]  # the files went to two worker processes


def test_grid_consistency_drops_wrong_ids():
    from cotrain.detect.detector import grid_consistent

    nx, ny = 9, 6
    ids = np.arange(nx * ny)
    jj, ii = np.divmod(ids, nx)
    # A smoothly distorted grid (quadratic warp, like a fisheye patch).
    xy = np.stack([100 + 20 * ii + 0.3 * ii**2, 80 + 18 * jj + 0.2 * ii * jj], -1).astype(float)
    assert grid_consistent(ids, xy, nx).all()
    bad = xy.copy()
    bad[[10, 40]] = bad[[40, 10]]  # two corners with swapped ids
    keep = grid_consistent(ids, bad, nx)
    assert not keep[10] and not keep[40] and keep.sum() >= len(ids) - 8
    # An isolated corner (no neighbours reported) is not trusted.
    assert not grid_consistent(np.array([5]), np.array([[3.0, 4.0]]), nx).any()


def test_polish_moves_noisy_corners_to_the_saddle():
    from cotrain.detect.detector import polish_corners
    from cotrain.render.renderer import RenderConfig

    cfg = RenderConfig(height=480, width=640, p_occluder=0.0, p_no_target=0.0, p_blur=0.0, p_motion=0.0, p_jpeg=0.0)
    out = render_batch(cfg, list(range(6)), seed=8)
    rng = np.random.default_rng(0)
    before, after = [], []
    for b in range(6):
        sel = out["visible"][b].numpy() & (out["square_px"][b].numpy() >= 10)
        if not sel.any():
            continue
        gt = out["corners_raw"][b].numpy()[sel].astype(float)
        q = gt + rng.normal(scale=0.7, size=gt.shape)
        p = polish_corners(out["image"][b, 0].numpy(), q, out["square_px"][b].numpy()[sel])
        before.append(np.linalg.norm(q - gt, axis=1))
        after.append(np.linalg.norm(p - gt, axis=1))
    before, after = np.concatenate(before), np.concatenate(after)
    assert len(before) > 50
    assert np.median(after) < 0.2 < np.median(before)


def test_detect_another_board(tmp_path, tiny_onnx, capsys):
    """--squares-x / --squares-y name another checkerboard: the JSON's target says it, the
    network's column / row votes are not used, slot mode (the model's own ids) is refused, and
    half a board size or a bad square size is a one-line error."""
    img = tmp_path / "a.png"
    cv2.imwrite(str(img), np.full((120, 200), 128, np.uint8))
    out = tmp_path / "d.json"
    args = ["detect", "--model", str(tiny_onnx), str(img), "--out", str(out)]
    assert cotrain_cli([*args, "--squares-x", "7", "--squares-y", "5", "--square-size", "0.03"]) == 0
    assert json.loads(out.read_text())["target"].items() >= {"squares_x": 7, "squares_y": 5, "square_size": 0.03}.items()
    det = Detector(tiny_onnx, target=Checkerboard(TargetConfig(squares_x=7, squares_y=5)))
    assert (det.nx, det.ny, det.board_votes) == (6, 4, False)
    assert Detector(tiny_onnx).board_votes
    capsys.readouterr()
    assert cotrain_cli([*args, "--squares-x", "7"]) == 2
    assert cotrain_cli([*args, "--squares-x", "7", "--squares-y", "5", "--slots"]) == 2
    assert cotrain_cli([*args, "--squares-x", "2", "--squares-y", "5"]) == 2
    assert cotrain_cli([*args, "--square-size", "-1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and all(line.startswith("cotrain detect: error:") for line in err)


def test_detect_target_from_a_kalibr_yaml(tmp_path, tiny_onnx, capsys):
    """--target takes a Kalibr target yaml (inner corners counted): the JSON names the board, the
    detector finds 6 x 4 inner corners; a missing or contradictory target is a one-line error."""
    img = tmp_path / "a.png"
    cv2.imwrite(str(img), np.full((120, 200), 128, np.uint8))
    kalibr = tmp_path / "checkerboard.yaml"
    kalibr.write_text("target_type: checkerboard\ntargetCols: 6\ntargetRows: 4\nrowSpacingMeters: 0.03\ncolSpacingMeters: 0.03\n")
    out = tmp_path / "d.json"
    args = ["detect", "--model", str(tiny_onnx), str(img), "--out", str(out)]
    assert cotrain_cli([*args, "--target", str(kalibr)]) == 0
    assert json.loads(out.read_text())["target"] == {"kind": "checkerboard", "squares_x": 7, "squares_y": 5, "square_size": 0.03}
    capsys.readouterr()
    assert cotrain_cli([*args, "--target", str(tmp_path / "missing.yaml")]) == 2
    assert cotrain_cli([*args, "--target", str(kalibr), "--squares-x", "7", "--squares-y", "5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "not found" in err[0] and "either" in err[1]


def test_detect_on_a_recording_folder_names_the_image_folders_below(tmp_path, capsys):
    """A recording's top folder (images one or two levels down) is an error that names those
    folders; a folder without any images anywhere says only that none were found."""
    top = tmp_path / "recording"
    for sub in ("cam0/images", "cam1/images"):
        (top / sub).mkdir(parents=True)
        cv2.imwrite(str(top / sub / "000.png"), np.zeros((32, 32), np.uint8))
    (top / "notes").mkdir()
    (top / "notes" / "readme.txt").write_text("not an image")
    assert cotrain_cli(["detect", str(top), "--out", str(tmp_path / "d.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert f"{top / 'cam0' / 'images'}, {top / 'cam1' / 'images'}" in err
    assert cotrain_cli(["detect", str(top / "notes"), "--out", str(tmp_path / "d.json")]) == 2
    assert capsys.readouterr().err.strip().endswith("no images found in the given paths")
    assert not (tmp_path / "d.json").exists()
