"""Calibrator and selector against synthetic ground truth (projected corners + Gaussian noise;
no renderer involved). Tolerances from issue 7: focal < 0.5 %, principal point < 1 px,
extrinsics < 1 mm and 0.1 deg."""

import json
import math

import numpy as np
import pytest
import torch
import yaml

from calib_eval.benchmark.rigs import SynthSpec, make_sequence, paper_config
from calib_eval.calibration.calibrator import CalibConfig, calibrate
from calib_eval.calibration.selector import SelectorConfig, isotropy_score, radial_span_score, select
from calib_eval.cli import run as calib_cli
from cotrain.geometry import cameras
from cotrain.io.sequence import write_sequence


def _errors(res, gt, model):
    m = cameras.get_model(model)
    out = []
    for c in range(2):
        est, ref = res.intrinsics[c], gt.params[c]
        f_err = max(abs(est[m.index(k)] / ref[m.index(k)] - 1) for k in ("fx", "fy"))
        pp_err = math.hypot(est[m.index("cx")] - ref[m.index("cx")], est[m.index("cy")] - ref[m.index("cy")])
        out.append((f_err, pp_err))
    T, Tg = res.T_cam_rig[1], gt.T_cam_rig[1]
    t_err = np.linalg.norm(T[:3, 3] - Tg[:3, 3])
    dR = T[:3, :3] @ Tg[:3, :3].T
    r_err = math.degrees(math.acos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
    return out, t_err, r_err


@pytest.mark.parametrize("model", ["kb4", "ucm", "eucm", "ds"])
def test_stereo_fov220_yaw90_recovers_ground_truth(model):
    rig = paper_config("FoV220_90")
    rig.model = model
    seq, gt = make_sequence(rig, SynthSpec(n_frames=480, noise_px=0.3), seed=7)
    sel = select(seq, SelectorConfig(fov=220))
    res = calibrate(seq.subset(sel.keep), CalibConfig(model=model, fov=220), order=sel.order)
    assert res.success, res.reason
    intr, t_err, r_err = _errors(res, gt, model)
    for f_err, pp_err in intr:
        assert f_err < 0.005 and pp_err < 1.0
    assert t_err < 1e-3 and r_err < 0.1
    assert all(len(g) > 3 and all(np.isfinite(g)) for g in res.gamma)


def test_gross_outliers_still_succeed():
    rig = paper_config("FoV220_90")
    seq, gt = make_sequence(rig, SynthSpec(n_frames=120, noise_px=0.3, outlier_rate=0.05), seed=3)
    res = calibrate(seq, CalibConfig(model="kb4", fov=220))
    assert res.success, res.reason
    intr, t_err, r_err = _errors(res, gt, "kb4")
    assert all(f < 0.005 and p < 1.0 for f, p in intr)
    assert t_err < 1e-3 and r_err < 0.1


def test_camera_never_sees_target_fails_clearly():
    seq, _ = make_sequence(paper_config("FoV200_60"), SynthSpec(n_frames=40), seed=1)
    blind = seq.subset({(o.cam, o.view) for o in seq.observations if o.cam == 0})
    res = calibrate(blind, CalibConfig(fov=200))
    assert not res.success and "cam1" in res.reason and "views" in res.reason


def test_three_frames_fail_clearly():
    seq, _ = make_sequence(paper_config("FoV200_0"), SynthSpec(n_frames=3), seed=1)
    res = calibrate(seq, CalibConfig(fov=200))
    assert not res.success and "views" in res.reason


def test_selector_scores_hand_computed():
    X = np.stack(np.meshgrid(np.arange(1, 10) * 0.04, np.arange(1, 7) * 0.04), -1).reshape(-1, 2)
    centre = X.mean(0)
    # Fronto-parallel: image = 500 X + offset -> isotropic, s_iso = 1.
    assert isotropy_score(X, 500 * X + [300, 200], centre) == pytest.approx(1.0, abs=1e-6)
    # Grazing: y foreshortened by 5 -> s_iso = 0.2.
    q = np.c_[500 * X[:, 0], 100 * X[:, 1]] + [300, 200]
    assert isotropy_score(X, q, centre) == pytest.approx(0.2, abs=1e-6)
    # Directed radial span: corners from radius 100 to 300 along +x, R = 400 -> (0.75 - 0.25) / 2.
    o = np.array([640.0, 360.0])
    q = o + np.c_[np.linspace(100, 300, 5), np.zeros(5)]
    assert radial_span_score(q, o, 400.0) == pytest.approx(0.25)
    # A board across the centre, from -200 to +300 px: the mean is at +50 px -> a = +x.
    q = o + np.c_[np.linspace(-200, 300, 6), np.zeros(6)]
    assert radial_span_score(q, o, 400.0) == pytest.approx(500 / 400 / 2)


def test_selector_stages_and_reasons():
    seq, _ = make_sequence(paper_config("FoV220_60"), SynthSpec(n_frames=120), seed=2)
    sel = select(seq, SelectorConfig(fov=220))
    stages = sel.summary()
    assert stages.get("anchor", 0) > 0 and stages.get("covisible", 0) > 0
    assert all(s.reason for s in sel.scores)
    for c, views in sel.order.items():
        first = [s for s in sel.scores if s.cam == c and s.view == views[0]][0]
        assert first.stage == "anchor"


def test_cli_synth_select_calibrate(tmp_path):
    seq_dir = tmp_path / "seq"
    assert calib_cli(["synth", "--config", "FoV200_90", "--frames", "80", "--out", str(seq_dir)]) == 0
    assert calib_cli(["select", str(seq_dir), "--fov", "200"]) == 0
    sel = json.loads((seq_dir / "selection.json").read_text())
    assert {"stage", "s_iso", "s_drs", "reason"} <= set(sel["frames"][0])
    assert calib_cli(["calibrate", str(seq_dir), "--fov", "200", "--select", "--out", str(tmp_path / "out")]) == 0
    import yaml

    chain = yaml.safe_load((tmp_path / "out" / "camchain.yaml").read_text())
    assert chain["cam0"]["camera_model"] == "pinhole" and chain["cam0"]["distortion_model"] == "equidistant"
    assert len(chain["cam0"]["distortion_coeffs"]) == 4 and chain["cam0"]["resolution"] == [1280, 720]
    assert np.asarray(chain["cam1"]["T_cn_cnm1"]).shape == (4, 4) and "T_cn_cnm1" not in chain["cam0"]
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["success"] and set(report["rms_px"]) == {"cam0", "cam1"}
    # Bad input: one line, exit 2.
    assert calib_cli(["calibrate", str(tmp_path / "missing"), "--fov", "200", "--out", str(tmp_path / "o2")]) == 2


def test_bad_sequence_folders_are_one_line_errors(tmp_path, capsys):
    seq = tmp_path / "seq"
    assert calib_cli(["select", str(seq), "--fov", "200"]) == 2  # missing folder
    (seq / "cam0" / "images").mkdir(parents=True)
    assert calib_cli(["select", str(seq), "--fov", "200"]) == 2  # no timestamps.csv
    (seq / "cam0" / "timestamps.csv").write_text("frame_id\n")
    assert calib_cli(["select", str(seq), "--fov", "200"]) == 2  # malformed header
    (seq / "cam0" / "timestamps.csv").write_text("frame_id,timestamp_ns,filename\n0,abc,0.png\n")
    assert calib_cli(["select", str(seq), "--fov", "200"]) == 2  # bad timestamp
    (seq / "cam0" / "timestamps.csv").write_text("frame_id,timestamp_ns,filename\n0,0,0.png\n")
    (seq / "cam0" / "detections.json").write_text("{not json")
    assert calib_cli(["select", str(seq), "--fov", "200"]) == 2  # corrupt detections
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 5 and all(line.startswith("calib-eval select: error:") for line in err)


def test_mixed_rig_with_kalibr_model_names(tmp_path, capsys):
    """A stereo rig of a Kannala-Brandt and a UCM camera, calibrated with Kalibr's model strings
    (pinhole-equi, omni-none): each camera gets its own family, camchain.yaml says them in Kalibr's
    terms, and the rig comes back. Unsupported or miscounted models are one-line errors."""
    rig = paper_config("FoV200_60")
    seq, gt = make_sequence(rig, SynthSpec(n_frames=120), seed=5)
    # Re-project the second camera's observations with a UCM camera of the same FoV.
    ucm = cameras.make_camera("ucm", rig.fov, rig.width, rig.height, xi=1.1)
    for o in seq.observations:
        if o.cam == 1:
            T = gt.T_cam_rig[1] @ gt.T_rig_board[o.view]
            pc = seq.target.points().numpy()[o.ids] @ T[:3, :3].T + T[:3, 3]
            q, _ = cameras.project("ucm", torch.from_numpy(pc), ucm)
            o.q = q.numpy() + np.random.default_rng(o.view).normal(scale=0.3, size=q.shape)
    root = write_sequence(seq, tmp_path / "seq")
    out = tmp_path / "out"
    assert calib_cli(["calibrate", str(root), "--fov", "200", "--models", "pinhole-equi", "omni-none", "--out", str(out)]) == 0
    chain = yaml.safe_load((out / "camchain.yaml").read_text())
    assert (chain["cam0"]["camera_model"], chain["cam0"]["distortion_model"]) == ("pinhole", "equidistant")
    assert (chain["cam1"]["camera_model"], chain["cam1"]["distortion_model"]) == ("omni", "none")
    assert len(chain["cam0"]["intrinsics"]) == 4 and len(chain["cam0"]["distortion_coeffs"]) == 4
    xi, fx = chain["cam1"]["intrinsics"][:2]
    assert abs(xi - 1.1) < 0.05 and abs(fx / float(ucm[1]) - 1) < 0.01
    T10 = np.array(chain["cam1"]["T_cn_cnm1"])
    assert np.linalg.norm(T10[:3, 3] - gt.T_cam_rig[1][:3, 3]) < 1e-3
    capsys.readouterr()
    base = ["calibrate", str(root), "--fov", "200", "--out", str(tmp_path / "x")]
    assert calib_cli([*base, "--models", "pinhole-radtan", "ds-none"]) == 2
    assert calib_cli([*base, "--models", "ds-none"]) == 2
    assert calib_cli([*base, "--model", "ds", "--models", "ds-none", "ds-none"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and "pinhole-equi" in err[0] and "2 cameras" in err[1] and "not both" in err[2]
