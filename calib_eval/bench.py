"""Calibration run-time benchmark: a 480-frame stereo sequence, all frames and the selected subset."""

from __future__ import annotations

import statistics
import time

from calib_eval.calibrator import CalibConfig, calibrate
from calib_eval.selector import SelectorConfig, select
from calib_eval.synth import SynthSpec, make_sequence, paper_config


def bench_calibration(config: str = "FoV220_90", frames: int = 480, repeats: int = 3) -> dict:
    rig = paper_config(config)
    seq, _ = make_sequence(rig, SynthSpec(n_frames=frames), seed=0)
    t_all, t_sel, t_select = [], [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        r_all = calibrate(seq, CalibConfig(fov=rig.fov))
        t_all.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        sel = select(seq, SelectorConfig(fov=rig.fov))
        t1 = time.perf_counter()
        r_sel = calibrate(seq.subset(sel.keep), CalibConfig(fov=rig.fov), order=sel.order)
        t_select.append(t1 - t0)
        t_sel.append(time.perf_counter() - t0)
    out = {
        "config": config,
        "frames": frames,
        "all_frames_s": statistics.median(t_all),
        "selected_s": statistics.median(t_sel),
        "select_only_s": statistics.median(t_select),
        "n_selected_obs": len(sel.keep),
        "n_obs": len(seq.observations),
        "success_all": r_all.success,
        "success_selected": r_sel.success,
    }
    print(
        f"calibration {config}, {frames} frames ({out['n_obs']} observations): all frames {out['all_frames_s']:.2f} s, "
        f"selector + selected ({out['n_selected_obs']} observations) {out['selected_s']:.2f} s "
        f"(selector alone {out['select_only_s']:.2f} s); median of {repeats}"
    )
    return out


if __name__ == "__main__":
    bench_calibration()
