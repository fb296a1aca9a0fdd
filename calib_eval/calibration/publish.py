"""A finished calibration written out: its trust assessment, camchain.yaml, report.json and report.html.

``calib-eval calibrate`` and the main job (:mod:`calib_eval.pipeline`) both end here, so the
verdict they print and the pages they write are the same.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from calib_eval.calibration.calibrator import CalibConfig, CalibrationResult
from calib_eval.calibration.camchain import write_outputs
from calib_eval.calibration.report_html import write_report_html
from calib_eval.calibration.trust import TrustConfig, TrustReport, assess, report_dict
from cotrain.io.sequence import Sequence


@dataclass
class Published:
    chain: Path  # camchain.yaml (written only on success)
    report: Path  # report.json
    page: Path  # report.html
    trust: TrustReport


def publish(
    res: CalibrationResult,
    seq: Sequence,
    cfg: CalibConfig,
    out_dir: str | Path,
    extra: dict | None = None,
    anchors: dict[int, list[int]] | None = None,
    order: dict[int, list[int]] | None = None,
    trust_cfg: TrustConfig | None = None,
) -> Published:
    """Assess ``res`` (:func:`calib_eval.calibration.trust.assess`) and write the three files."""
    trust = assess(res, seq, cfg, trust_cfg, order)
    names = [c.name for c in seq.cameras]
    chain, report = write_outputs(res, seq, out_dir, {**report_dict(trust, res, names), **(extra or {})})
    page = write_report_html(res, seq, out_dir, anchors, trust)
    return Published(chain, report, page, trust)
