"""The per-slot identity comparison: curves read, figures at a budget, bad input refused."""

import pytest

from calib_eval.detection.slot_identity import at_budget, curve_table, evaluate_slots, main, read_curve
from tests.paths import ROOT


def _curve(tmp_path, rows):
    p = tmp_path / "curve.csv"
    p.write_text("step,wall_s,recall,error_px,id_acc,outlier_rate\n" + "\n".join(",".join(map(str, r)) for r in rows) + "\n")
    return p


def test_best_figure_reached_by_a_budget(tmp_path):
    rows = [(250, 600, 0.01, 2.0, 0.02, 0.9), (500, 1500, 0.05, 1.5, 0.04, 0.8), (750, 2400, 0.03, 1.4, 0.06, 0.8)]
    c = read_curve(_curve(tmp_path, rows))
    c["samples"] = c["step"] * 8
    assert at_budget(c, "wall_s", 900, "recall") == pytest.approx(0.01)
    assert at_budget(c, "wall_s", 1800, "recall") == pytest.approx(0.05)
    assert at_budget(c, "wall_s", 3600, "recall") == pytest.approx(0.05)  # the best so far, not the last
    assert at_budget(c, "samples", 6000, "id_acc") == pytest.approx(0.06)
    assert at_budget(c, "wall_s", 100, "recall") != at_budget(c, "wall_s", 100, "recall")  # NaN before the first row
    table = curve_table({"run": c})
    # by 5 / 15 / 30 / 60 / 90 min, by 15,000 / 30,000 samples, end
    cells = ["-", "0.010 / 0.020", "0.050 / 0.040", "0.050 / 0.060", "0.050 / 0.060", "0.050 / 0.060", "0.050 / 0.060"]
    assert "| run | " + " | ".join(cells) + " | 0.050 / 0.060 (40, 6000) |" in table


def test_each_curve_counts_samples_with_its_own_batch(tmp_path):
    rows = [(100, 60, 0.01, 2.0, 0.02, 0.9), (200, 120, 0.03, 1.5, 0.04, 0.8), (300, 180, 0.05, 1.5, 0.06, 0.8)]
    p = _curve(tmp_path, rows)
    out = tmp_path / "plot.png"
    assert main(["--curve", f"gpu={p}@64", "--curve", f"cpu={p}", "--batch", "8", "--out", str(out)]) == 0
    table = out.with_suffix(".md").read_text()
    # 300 steps of 64 = 19,200 samples: by 15,000 samples only the first two rows count
    best, early = "0.050 / 0.060", "0.030 / 0.040"
    assert "| gpu | " + " | ".join([best] * 5 + [early, best]) + " | 0.050 / 0.060 (3, 19200) |" in table
    # 300 steps of --batch 8 = 2,400 samples
    assert "| cpu | " + " | ".join([best] * 7) + " | 0.050 / 0.060 (3, 2400) |" in table
    # a path with an @ of its own (no batch after it) is a path
    (tmp_path / "u@host").mkdir()
    at = _curve(tmp_path / "u@host", rows)
    assert main(["--curve", f"home={at}", "--batch", "8", "--out", str(out)]) == 0
    assert "| home | " in out.with_suffix(".md").read_text()


def test_bad_input_is_one_line_and_nonzero(tmp_path, capsys):
    assert main(["--curve", "no-equals-sign"]) == 1
    assert main(["--curve", f"x={tmp_path / 'missing.csv'}"]) == 1
    assert main(["--curve", f"x={_curve(tmp_path, [(1, 1, 0.0, 1.0, 0.0, 1.0)])}@0"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(e.startswith("error: ") for e in err)
    with pytest.raises(ValueError, match="not an aprilgrid"):
        evaluate_slots(ROOT / "export" / "default.onnx", tmp_path)  # the checkerboard model
