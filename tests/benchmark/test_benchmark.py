"""Benchmark end to end (small), and the paper's coupling finding as a property test."""

import json

import numpy as np
import pytest

from calib_eval.benchmark.analysis import PROFILES, coupling_index, distribution_metrics
from calib_eval.cli import run as calib_cli


def test_two_trial_benchmark_two_configs(tmp_path):
    out = tmp_path / "bench"
    rc = calib_cli(
        ["benchmark", "--configs", "FoV200_0", "FoV220_90", "--trials", "2", "--frames", "80", "--workers", "1", "--out", str(out)]
    )
    assert rc == 0
    res = json.loads((out / "results.json").read_text())["summary"]
    assert set(res) == {"FoV200_0", "FoV220_90", "overall"}
    for v in ("all", "selector", "random", "ba_only"):
        assert res["overall"][v]["n"] == 4
        assert 0 <= res["overall"][v]["sr"] <= 100
    assert res["overall"]["selector"]["sr"] > 0
    table = (out / "results.md").read_text()
    assert "CO-Calib (selector)" in table and "Strict success" in table and "paper SR" in table
    assert calib_cli(["analysis", "--benchmark", str(out), "--out", str(tmp_path / "an")]) == 0
    assert (tmp_path / "an" / "coupling_index.png").is_file() and (tmp_path / "an" / "gamma_trajectories.png").is_file()


@pytest.mark.parametrize("family", ["ucm", "eucm", "ds"])
@pytest.mark.parametrize("fov", [180, 220, 240])
def test_radial_cover_decouples_focal_and_shape(family, fov):
    radial = coupling_index(family, fov, PROFILES["R"])
    for band in ("C", "M", "E"):
        assert radial < coupling_index(family, fov, PROFILES[band])


def test_distribution_metrics_known_values():
    a = np.array([[2.0, 0.0], [0.0, 0.0]])
    b = np.array([[0.0, 0.0], [0.0, 2.0]])
    m = distribution_metrics([a, a], [b, b], permutations=50)
    assert m["D_qty"] == pytest.approx(0.0) and m["D_sp"] == pytest.approx(1.0)
    m2 = distribution_metrics([a], [2 * a], permutations=10)
    assert m2["D_qty"] == pytest.approx(1 / 3) and m2["D_sp"] == pytest.approx(0.0)
