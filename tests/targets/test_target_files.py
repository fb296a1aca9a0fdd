"""The Target protocol and the ways a target is described: config section, detection JSON,
Kalibr target yaml, BoofCV target yaml."""

import numpy as np
import pytest
import torch
import yaml

from cotrain.targets import (
    Checkerboard,
    Target,
    TargetConfig,
    TargetError,
    load_target,
    same_target,
    target_from_boofcv,
    target_from_flags,
    target_from_json,
    target_from_kalibr,
)


def test_checkerboard_is_a_target():
    b = Checkerboard(TargetConfig(squares_x=8, squares_y=6, square_size=0.03))
    assert isinstance(b, Target)
    assert b.n_corners == 7 * 5 and b.spacing == 0.03
    assert b.points().shape == (35, 3)


def test_json_round_trip_and_convention():
    b = Checkerboard(TargetConfig(squares_x=8, squares_y=6, square_size=0.03))
    j = b.to_json()
    assert j == {"kind": "checkerboard", "squares_x": 8, "squares_y": 6, "square_size": 0.03}
    back = target_from_json(j)
    assert same_target(back, b)
    assert torch.equal(back.points(), b.points())


def test_kalibr_checkerboard_counts_inner_corners(tmp_path):
    """Kalibr's targetCols / targetRows count inner corners: 9 x 6 corners is our 10 x 7 board."""
    f = tmp_path / "checkerboard.yaml"
    f.write_text("target_type: 'checkerboard'\ntargetCols: 9\ntargetRows: 6\nrowSpacingMeters: 0.04\ncolSpacingMeters: 0.04\n")
    t = load_target(f)
    assert same_target(t, Checkerboard())
    assert t.n_corners == 54
    # Kalibr's corner (col c, row r) has id r * targetCols + c at ((c + 1) s, (r + 1) s) in our board frame.
    np.testing.assert_allclose(t.points()[1 * 9 + 4].numpy(), [5 * 0.04, 2 * 0.04, 0.0])
    assert yaml.safe_load(yaml.safe_dump(t.to_kalibr())) == yaml.safe_load(f.read_text())


def test_our_config_section_both_ways(tmp_path):
    f = tmp_path / "train.yaml"
    f.write_text("target:\n  squares_x: 7\n  squares_y: 5\n  square_size: 0.025\n")
    g = tmp_path / "flat.yaml"
    g.write_text("squares_x: 7\nsquares_y: 5\nsquare_size: 0.025\n")
    assert same_target(load_target(f), load_target(g))
    assert load_target(f).to_json()["squares_x"] == 7


@pytest.mark.parametrize(
    "text, msg",
    [
        ("target_type: aprilgrid_v2\n", "unsupported Kalibr target_type"),
        ("target_type: checkerboard\ntargetCols: 9\n", "missing 'targetRows'"),
        ("target_type: checkerboard\ntargetCols: 9\ntargetRows: 6\nrowSpacingMeters: 0.04\ncolSpacingMeters: 0.05\n", "differ"),
        ("target_type: checkerboard\ntargetCols: 9.5\ntargetRows: 6\nrowSpacingMeters: 0.04\ncolSpacingMeters: 0.04\n", "integer"),
        ("target:\n  squares_x: 1\n  squares_y: 7\n", "at least 2"),
        ("target:\n  colour: red\n", "unknown key"),
        ("cam0:\n  camera_model: pinhole\n  intrinsics: [1, 2, 3, 4]\n", "not a calibration target.*looks like a camchain"),
        ("rows: 6\ncols: 8\n", "not a calibration target: give a Kalibr target yaml"),
        ("[1, 2]\n", "top level must be a mapping"),
        ("", "describes no target"),
    ],
)
def test_bad_target_files_are_one_line(tmp_path, text, msg):
    f = tmp_path / "t.yaml"
    f.write_text(text)
    with pytest.raises(TargetError, match=msg) as e:
        load_target(f)
    assert "\n" not in str(e.value)


def test_missing_file_is_a_target_error(tmp_path):
    with pytest.raises(TargetError, match="not found"):
        load_target(tmp_path / "nope.yaml")


def test_same_target_compares_the_printed_board():
    a = Checkerboard()
    assert same_target(a, target_from_kalibr(a.to_kalibr()))
    assert not same_target(a, Checkerboard(TargetConfig(square_size=0.05)))
    assert not same_target(a, Checkerboard(TargetConfig(squares_x=9)))
    # The white margin is not part of the printed layout the detections describe.
    assert same_target(a, Checkerboard(TargetConfig(margin=0.0)))


def test_symmetries_of_the_board():
    assert Checkerboard().symmetries() == ()  # 10 x 7: every corner has one identity
    (half,) = Checkerboard(TargetConfig(squares_x=7, squares_y=5)).symmetries()  # 6 x 4 inner corners
    assert half[0] == 23 and half[23] == 0 and sorted(half) == list(range(24))


def test_grid_coordinates():
    b = Checkerboard()
    uv, inside = b.grid_coordinates(torch.tensor([[0.04, 0.04], [0.08, 0.12], [-0.01, 0.1]], dtype=torch.float64))
    np.testing.assert_allclose(uv.numpy(), [[0, 0], [1, 2], [-1.25, 1.5]])
    assert inside.tolist() == [True, True, False]


def test_board_from_command_line_flags(tmp_path):
    f = tmp_path / "k.yaml"
    f.write_text("target_type: checkerboard\ntargetCols: 6\ntargetRows: 4\nrowSpacingMeters: 0.03\ncolSpacingMeters: 0.03\n")
    assert target_from_flags(None, None, None, None) is None
    assert same_target(target_from_flags(str(f), None, None, None), Checkerboard(TargetConfig(squares_x=7, squares_y=5, square_size=0.03)))
    assert target_from_flags(None, 7, 5, 0.03).to_json() == {"kind": "checkerboard", "squares_x": 7, "squares_y": 5, "square_size": 0.03}
    # The base board's square size is kept for another layout, and --square-size alone resizes the base.
    base = Checkerboard(TargetConfig(square_size=0.05))
    assert target_from_flags(None, 7, 5, None, base).spacing == 0.05
    assert same_target(target_from_flags(None, None, None, 0.02, base), Checkerboard(TargetConfig(square_size=0.02)))
    for args, msg in [
        ((str(f), 7, 5, None), "either"),
        ((None, 7, None, None), "both"),
        ((None, 7, 5, -1.0), "positive"),
        ((None, None, None, 0.02), "name the board"),
    ]:
        with pytest.raises(TargetError, match=msg):
            target_from_flags(*args)


BOOFCV_YAML = """# Serialized boofcv.alg.fiducial.calib.ConfigCalibrationTarget
BoofCV.GIT_SHA: a9ab9041d1703a9c09c31999043382e870554729
boofcv.alg.fiducial.calib.ConfigCalibrationTarget:
  grid:
    numRows: 7
    shapeSize: 0.03
    numCols: 5
BoofCV.Version: 0.39-SNAPSHOT
"""


def test_boofcv_chessboard_counts_squares(tmp_path):
    """BoofCV's serialised ConfigCalibrationTarget (as BoofCV writes it, the chessboard its default
    type): numCols x numRows squares, columns along x, shapeSize the square's side."""
    f = tmp_path / "calibration_target.yaml"
    f.write_text(BOOFCV_YAML)
    b = load_target(f)
    assert isinstance(b, Checkerboard)
    assert same_target(b, Checkerboard(TargetConfig(squares_x=5, squares_y=7, square_size=0.03)))
    typed = yaml.safe_load(BOOFCV_YAML)
    typed["boofcv.alg.fiducial.calib.ConfigCalibrationTarget"]["type"] = "CHESSBOARD"
    assert same_target(target_from_boofcv(typed), b)


@pytest.mark.parametrize(
    "section, message",
    [
        ({"type": "SQUARE_GRID", "grid": {"numRows": 7, "numCols": 5, "shapeSize": 1.0}}, "unsupported BoofCV target type SQUARE_GRID"),
        ({"type": "CHESSBOARD"}, "no 'grid' mapping"),
        ({"grid": {"numRows": 7.5, "numCols": 5, "shapeSize": 1.0}}, "numRows must be an integer"),
        ({"grid": {"numRows": 7, "numCols": 5}}, "missing 'shapeSize'"),
    ],
)
def test_boofcv_target_errors_name_the_problem(tmp_path, section, message):
    f = tmp_path / "bad.yaml"
    f.write_text(yaml.safe_dump({"boofcv.alg.fiducial.calib.ConfigCalibrationTarget": section}))
    with pytest.raises(TargetError, match=message):
        load_target(f)
