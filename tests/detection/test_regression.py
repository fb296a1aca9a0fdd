"""The set-by-set regression table (calib_eval.detection.regression): rows scored as the sets'
own commands score them, kept and reused under the detector's key, and the comparison that flags
a row whose recall fell or whose wrong corners grew."""

import json

import pytest

from calib_eval.detection import regression as reg


def _row(recall, wrong, empty=0):
    return {"rows": {"FoV rows": {"recall": recall, "hits": 0, "detectable": 0, "wrong": wrong}}, "empty_with_reports": empty}


def test_compare_flags_recall_drops_beyond_the_tolerance_and_any_new_wrong_corner():
    before = {"a": _row(0.90, 0), "b": _row(0.90, 0), "c": _row(0.90, 1), "d": _row(0.90, 0, empty=0)}
    after = {"a": _row(0.8951, 0), "b": _row(0.8949, 0), "c": _row(0.95, 2), "d": _row(0.90, 0, empty=1)}
    text, bad = reg.compare(before, after)
    assert bad == 3  # b (recall down 0.0051), c (a wrong corner more), d (an empty frame with reports)
    lines = {line.split(" | ")[0].strip("| "): line for line in text.splitlines()[2:]}
    assert "regressed" not in lines["a"] and "regressed" in lines["b"] and "regressed" in lines["c"]
    _, bad = reg.compare({"a": _row(0.9, 0), "gone": _row(0.9, 0)}, {"a": _row(0.9, 0)})
    assert bad == 1  # a set no longer scored hides what it measured
    with pytest.raises(ValueError, match="not a regression.json"):
        reg.compare([], {})


def test_overrides_are_fields_of_the_configs_and_bad_ones_are_one_line_errors(capsys):
    from cotrain.detect.tag_config import TagConfig

    grid = reg._overridden("GridConfig", ["half_rim_px=20", "min_margin=.inf"])
    assert grid.half_rim_px == 20 and grid.min_margin == float("inf")
    with pytest.raises(ValueError, match="not FIELD=VALUE with a field of TagConfig"):
        reg._overridden("TagConfig", ["no_such_field=1"])
    # The grid settings the tag pass shares are set through TagConfig.grid.
    tags = reg._overridden("TagConfig", ["grid.lens_fov=0", "max_hamming=1"])
    assert tags.grid.lens_fov == 0 and tags.max_hamming == 1 and tags.grid.agree_radius == 0.3
    with pytest.raises(ValueError, match="is a number"):
        reg._overridden("TagConfig", ["grid.lens_fov=wide"])
    # ... and its completion settings (its candidates' symmetry among them) through TagConfig.complete.
    tags = reg._overridden("TagConfig", ["complete.min_symmetry=0.6", "grid.half_resolution=false"])
    assert tags.complete.min_symmetry == 0.6 and tags.complete.rounds == TagConfig().complete.rounds
    assert tags.grid.half_resolution is False
    with pytest.raises(ValueError, match="not FIELD=VALUE"):
        reg._overridden("GridConfig", ["grid.lens_fov=0"])
    assert reg.main(["--grid", "nonsense", "--out", "unused"]) == 2
    assert capsys.readouterr().err.startswith("regression: ")
    assert reg.main(["--only", "no_such_set"]) == 2


def test_rows_of_a_rendered_set_are_scored_kept_and_reused(tmp_path, monkeypatch):
    """A tiny checkerboard set through the real detector: its rows (the FoV rows and a hard row),
    written under the detector's key and reused by a second run without detecting again; another
    setting of the detector detects again."""
    tiny = reg.KeptSet(
        "tiny", "rendered", tuple(sorted(dict(per_fov=1, n_empty=1, conditions=["glare"], per_condition=1, width=320, height=240).items()))
    )
    monkeypatch.setattr(reg, "KEPT_SETS", (tiny,))
    first = reg.run(tmp_path / "out", sets=tmp_path / "sets")
    row = first["tiny"]
    assert set(row["rows"]) == {"FoV rows", "glare"} and row["empty_frames"] == 1
    for r in row["rows"].values():
        assert 0.0 <= r["recall"] <= 1.0 and r["hits"] <= r["detectable"] and r["wrong"] >= 0
    calls = []
    monkeypatch.setitem(reg.RUNNERS, "rendered", lambda *a: calls.append(a) or {"rows": {}})
    assert reg.run(tmp_path / "out", sets=tmp_path / "sets") == first  # reused: nothing detected
    assert not calls
    reg.run(tmp_path / "other", sets=tmp_path / "sets", grid=reg._overridden("GridConfig", ["half_rim_px=20"]))
    assert len(calls) == 1  # another detector key: detected again, on the same frames
    saved = json.loads((tmp_path / "out" / "regression.json").read_text())
    assert saved == json.loads(json.dumps(first))


def test_each_target_gets_its_own_passs_settings():
    """The regression runs both targets under one pair of settings: the AprilGrid's detector gets
    the tag pass's (the grid settings it would refuse are not passed), the checkerboard's the
    grid pass's."""
    from calib_eval.detection.regression import target_detector
    from cotrain.detect.grid_config import GridConfig
    from cotrain.detect.tag_config import TagConfig
    from cotrain.targets import AprilGrid, Checkerboard, TargetConfig

    grid, tags = GridConfig(min_margin=30.0), TagConfig(max_hamming=1)
    assert target_detector(AprilGrid(), grid, tags).tags.max_hamming == 1
    assert target_detector(Checkerboard(TargetConfig()), grid, tags).grid.min_margin == 30.0


def test_a_row_with_nothing_to_find_says_so():
    """A row without a detectable corner (the FoV rows of a set of hard rows only) reads "no corner
    to find", not a recall of 0."""
    from calib_eval.detection.regression import table

    rows = {
        "s": {
            "rows": {
                "FoV rows": {"recall": 0.0, "hits": 0, "detectable": 0, "wrong": 0},
                "glare": {"recall": 0.5, "hits": 1, "detectable": 2, "wrong": 0},
            }
        }
    }
    out = table(rows)
    assert "| s | FoV rows | no corner to find | 0 / 0 | 0 |" in out and "| s | glare | 0.5000 | 1 / 2 | 0 |" in out
