"""mrcal as a peer: the corners file it reads, its result read back into our frames, and its
column where it is not installed."""

import math

import numpy as np
import pytest
import torch

from calib_eval.benchmark import benchmark
from calib_eval.benchmark.rigs import RigSpec, SynthSpec, make_sequence, paper_config
from calib_eval.calibration import mrcal_peer
from calib_eval.calibration.compare import error_rays, pose_difference, project_rays
from calib_eval.calibration.mrcal_peer import NOT_INSTALLED, MrcalConfig, calibrate_mrcal, mrcal_tool, write_corners


def test_corners_file_is_mrcals_vnlog(tmp_path):
    seq, _ = make_sequence(paper_config("FoV200_60"), SynthSpec(n_frames=12), seed=1)
    views = write_corners(seq, tmp_path / "corners.vnl")
    lines = (tmp_path / "corners.vnl").read_text().splitlines()
    assert lines[0] == "# filename x y level"
    rows: dict[str, list[list[str]]] = {}
    for line in lines[1:]:
        name, *rest = line.split()
        rows.setdefault(name, []).append(rest)
    board = seq.target
    assert len(rows) == len(seq.observations) and views == sorted({o.view for o in seq.observations})
    for o in seq.observations:
        block = rows[f"cam{o.cam}/frame{o.view:06d}.png"]
        assert len(block) == board.n_corners  # a full grid per observation, row-major
        found = [i for i, r in enumerate(block) if r != ["-", "-", "-"]]
        assert found == sorted(o.ids.tolist())
        xy = np.array([[float(block[i][0]), float(block[i][1])] for i in found])
        np.testing.assert_allclose(xy, o.q[np.argsort(o.ids)], atol=1e-4)
        assert all(block[i][2] == "0" for i in found)
    # mrcal's board point (i, j) is our corner j * nx + i: one step along a row is one square along x.
    P = board.points().numpy()
    np.testing.assert_allclose(P[1] - P[0], [board.spacing, 0, 0])
    np.testing.assert_allclose(P[board.nx] - P[0], [0, board.spacing, 0])


def test_not_installed_says_so_and_the_rest_runs(monkeypatch):
    monkeypatch.setattr(mrcal_peer, "mrcal_tool", lambda: None)
    seq, _ = make_sequence(paper_config("FoV200_60"), SynthSpec(n_frames=12), seed=1)
    r = calibrate_mrcal(seq, 200.0)
    assert not r.available and not r.success and r.reason == NOT_INSTALLED
    torch.set_num_threads(1)
    trial = benchmark.run_trial("FoV200_60", 0, frames=40, variants=["selector", "mrcal"], model="kb4")
    assert trial["mrcal"]["available"] is False and trial["selector"]["success"]
    summary = benchmark._summarise([trial], ["selector", "mrcal"])
    table = benchmark._table(summary, ["selector", "mrcal"], 1)
    assert "| FoV200_60 | mrcal 2.2 (selector's frames) | not installed |" in table
    assert "| FoV200_60 | CO-Calib (selector) | 100% |" in table


needs_mrcal = pytest.mark.skipif(mrcal_tool() is None, reason=NOT_INSTALLED)


@needs_mrcal
def test_mrcal_result_in_our_frames(tmp_path):
    """A stereographic rig (UCM with xi = 1 is mrcal's LENSMODEL_STEREOGRAPHIC, with twice its focal
    length), whole boards only: mrcal recovers it, and we read its intrinsics, extrinsics and board
    poses back into our frames correctly."""
    rig = RigSpec(fov=180.0, yaws_deg=[0.0, 60.0], model="ucm")
    seq, gt = make_sequence(rig, SynthSpec(n_frames=120, noise_px=0.2), seed=5)
    whole = {(o.cam, o.view) for o in seq.observations if len(o.ids) == seq.target.n_corners}
    seq = seq.subset(whole)
    assert len(seq.observations) > 40
    v = error_rays(150.0)
    r = calibrate_mrcal(seq, 180.0, MrcalConfig(lensmodel="LENSMODEL_STEREOGRAPHIC"), rays=v, workdir=tmp_path)
    assert r.success, r.reason
    assert max(r.rms_cam) < 0.35 and r.rms_px < 0.3 and (tmp_path / "corners.vnl").is_file() and (tmp_path / "mrcal.log").is_file()
    assert f"Noutliers: {r.outliers} out of" in r.log and len(r.rms_cam) == 2 and r.stage == "final, full optimization"
    for c in range(2):
        xi, fx, fy, cx, cy = gt.params[c]  # Kalibr's omni order
        assert xi == 1.0
        f, g, u, w = r.intrinsics[c]
        assert abs(2 * f - fx) / fx < 2e-3 and abs(2 * g - fy) / fy < 2e-3 and abs(u - cx) < 0.5 and abs(w - cy) < 0.5
        q_gt, ok = project_rays(gt.model[c], gt.params[c], v)
        assert ok.all() and np.sqrt(np.mean(np.sum((r.q_rays[c] - q_gt) ** 2, -1))) < 0.3
    t, a = pose_difference(r.T_cam_rig[1:], gt.T_cam_rig[1:])
    assert t[0] < 1.0 and a[0] < 0.05
    views = sorted(r.T_rig_board)
    assert views == sorted({o.view for o in seq.observations})
    t, a = pose_difference(np.stack([r.T_rig_board[k] for k in views]), gt.T_rig_board[views])
    assert np.median(t) < 2.0 and np.median(a) < 0.2  # a wrong origin would be 57 mm off (corner 0 at one square in x and y)


@needs_mrcal
def test_mrcal_failure_is_one_line_with_its_stage():
    """Beyond 180 degrees, on the selector's frames (partial views at the rim), mrcal's
    stereographic seed goes wrong: the tool stops with an error, kept in its own words with the
    stage it reached, or ends far from a calibration."""
    from calib_eval.calibration.selector import SelectorConfig, select

    rig = paper_config("FoV220_90")
    seq, gt = make_sequence(rig, SynthSpec(n_frames=480), seed=1)
    sub = seq.subset(select(seq, SelectorConfig(fov=rig.fov)).keep)
    r = calibrate_mrcal(sub, rig.fov)
    assert r.available and r.stage
    if r.success:
        assert max(r.rms_cam) > 2.0
    else:
        assert r.reason and "\n" not in r.reason and r.reason in r.log  # mrcal's own message
    scored = benchmark.evaluate_mrcal(sub, gt, rig.fov)
    assert not scored["success"] and not scored["strict"] and math.isfinite(scored["runtime_s"])


def test_compare_command_without_mrcal(tmp_path, monkeypatch, capsys):
    """``calib-eval compare`` runs ours and says where mrcal is missing; its files are written."""
    import json

    from calib_eval.cli import run

    monkeypatch.setattr(mrcal_peer, "mrcal_tool", lambda: None)
    torch.set_num_threads(1)
    assert run(["synth", "--config", "FoV200_60", "--frames", "40", "--seed", "3", "--out", str(tmp_path / "seq")]) == 0
    assert run(["compare", str(tmp_path / "seq"), "--fov", "200", "--out", str(tmp_path / "cmp")]) == 0
    out = capsys.readouterr().out
    assert NOT_INSTALLED in out and "| cam0 |" in out and "| cam1 |" in out
    d = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert d["ours"]["success"] and not d["mrcal"]["available"] and d["cameras"][0]["ours_rms"] < 1.0
    assert (tmp_path / "cmp" / "compare.md").read_text().startswith("# Ours and mrcal")
