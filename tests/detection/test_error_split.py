"""calib_eval.detection.error_split: a detector's corner error split into frames whose corners are
all off by one common shift (labels of one-sided motion blur) and the rest."""

import numpy as np
import pytest

from calib_eval.detection.error_split import countable, main, split_errors


def test_split_errors_known_values():
    rng = np.random.default_rng(0)
    e = rng.normal(0, 0.02, (10, 2))
    offsets = {
        "shifted": np.array([0.7, 0.0]) + e,  # every corner 0.7 px to the right
        "clean": np.array([[0.1, 0.0], [-0.1, 0.0], [0.0, 0.1], [0.0, -0.1]] * 3, float),  # mean 0, each 0.1 px
        "few": np.full((3, 2), 0.5),  # a common shift, but too few corners to measure it
        "none": np.zeros((0, 2)),  # no corner matched: not a frame of any group
    }
    r = split_errors(offsets, min_corners=8, shift_px=0.25)
    assert (r["shifted"]["frames"], r["shifted"]["corners"]) == (1, 10)
    assert (r["other"]["frames"], r["other"]["corners"]) == (2, 15)
    assert (r["all"]["frames"], r["all"]["corners"]) == (3, 25)
    assert r["shifted"]["mean"] == pytest.approx(0.7, abs=0.02)
    assert r["other"]["mean"] == pytest.approx((12 * 0.1 + 3 * np.hypot(0.5, 0.5)) / 15)
    # with the shifted frame's own mean offset taken out only its noise is left (the 'few' frame stays as it is)
    resid = np.concatenate([np.hypot(*(e - e.mean(0)).T), np.full(12, 0.1), np.full(3, np.hypot(0.5, 0.5))])
    assert r["residual_mean"] == pytest.approx(resid.mean())
    assert r["residual_median"] == pytest.approx(np.median(resid))


def test_countable_corners_of_either_set():
    assert countable({"detectable": [True, False], "visible": [True, True]}).tolist() == [True, False]
    assert countable({"visible": [True, True, False], "tag_px": [9.0, 5.0, 20.0]}).tolist() == [True, False, False]


def test_bad_set_is_one_line_error(tmp_path, capsys):
    assert main(["--set", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip().startswith("error: no labels.json")
    (tmp_path / "labels.json").write_text('{"labels": []}')
    assert main(["--set", str(tmp_path)]) == 2
    assert "names no target" in capsys.readouterr().err
