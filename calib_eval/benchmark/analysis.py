"""The paper's failure analysis (Sec. III): ``calib-eval analysis [--benchmark DIR] --out DIR``.

- conditioning trajectories gamma_k of successful against failed trials (from a benchmark run);
- the focal-projection coupling index C_f-eta (Eq. 13) for UCM, EUCM and Double Sphere under
  central, middle, edge and radially covering ray profiles (as Fig. 6);
- D_qty, D_sp and D_rand of the appendix for success against failure groups.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch

from cotrain.geometry import cameras

PROFILES = {"C": (0.0, 0.3), "M": (0.35, 0.65), "E": (0.7, 1.0), "R": (0.0, 1.0)}  # fractions of the half FoV
FAMILIES = ["ucm", "eucm", "ds"]


def coupling_index(model: str, fov: float, profile: tuple[float, float], n: int = 200, seed: int = 0) -> float:
    """C_f-eta = log10 kappa(G), G = J^T J of the column-normalised Jacobian of the stacked
    responses y = f phi(r; eta) with respect to [f, eta], for rays whose off-axis angle lies in
    ``profile`` (fractions of the half FoV). Computed with the shared camera model (fx = fy = f,
    principal point 0)."""
    m = cameras.get_model(model)
    rng = np.random.default_rng(seed)
    half = math.radians(fov) / 2
    th = half * (profile[0] + (profile[1] - profile[0]) * rng.random(n))
    ph = 2 * math.pi * rng.random(n)
    rays = torch.from_numpy(np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1))
    base = cameras.make_camera(model, fov, 1000, 1000, 500.0, principal=(0.0, 0.0))
    shape_idx = [m.index(s) for s in m.shape_names]
    f0 = float(base[m.index("fx")])
    x0 = torch.tensor([f0] + [float(base[i]) for i in shape_idx], dtype=torch.float64)

    def y(x: torch.Tensor) -> torch.Tensor:
        p = base.clone()
        p[m.index("fx")] = x[0]
        p[m.index("fy")] = x[0]
        for k, i in enumerate(shape_idx):
            p[i] = x[1 + k]
        return cameras.project(model, rays, p)[0].reshape(-1)

    J = torch.autograd.functional.jacobian(y, x0)
    J = J / J.norm(dim=0, keepdim=True).clamp_min(1e-300)
    ev = torch.linalg.eigvalsh(J.T @ J).abs()
    return float(torch.log10(ev.max() / ev.min().clamp_min(1e-300)))


def coupling_table(fov: float = 220.0) -> dict[str, dict[str, float]]:
    return {fam: {name: coupling_index(fam, fov, rng) for name, rng in PROFILES.items()} for fam in FAMILIES}


def distribution_metrics(success_grids: list[np.ndarray], failure_grids: list[np.ndarray], permutations: int = 200, seed: int = 0) -> dict:
    """D_qty, D_sp, D_rand (median over label permutations) and Delta_sp, appendix A."""

    def dist(S: list[np.ndarray], F: list[np.ndarray]) -> tuple[float, float]:
        Si = np.mean(S, axis=0)
        Fi = np.mean(F, axis=0)
        NS, NF = Si.sum(), Fi.sum()
        d_qty = abs(NS - NF) / max(NS + NF, 1e-12)
        d_sp = 0.5 * np.abs(Si / max(NS, 1e-12) - Fi / max(NF, 1e-12)).sum()
        return float(d_qty), float(d_sp)

    if not success_grids or not failure_grids:
        return {
            "D_qty": float("nan"),
            "D_sp": float("nan"),
            "D_rand": float("nan"),
            "Delta_sp": float("nan"),
            "n_success": len(success_grids),
            "n_failure": len(failure_grids),
        }
    d_qty, d_sp = dist(success_grids, failure_grids)
    allg = success_grids + failure_grids
    rng = np.random.default_rng(seed)
    rand = []
    for _ in range(permutations):
        perm = rng.permutation(len(allg))
        S = [allg[i] for i in perm[: len(success_grids)]]
        F = [allg[i] for i in perm[len(success_grids) :]]
        rand.append(dist(S, F)[1])
    d_rand = float(np.median(rand))
    return {
        "D_qty": d_qty,
        "D_sp": d_sp,
        "D_rand": d_rand,
        "Delta_sp": abs(d_sp - d_rand),
        "n_success": len(success_grids),
        "n_failure": len(failure_grids),
    }


def run_analysis(benchmark_dir: Path | None, out: Path, fov: float = 220.0) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    result: dict = {}
    # Coupling index (Fig. 6).
    table = coupling_table(fov)
    result["coupling"] = table
    fig, ax = plt.subplots(figsize=(5.5, 3.4))
    w = 0.2
    for k, name in enumerate(PROFILES):
        ax.bar(np.arange(len(FAMILIES)) + (k - 1.5) * w, [table[f][name] for f in FAMILIES], w, label=name)
    ax.set_xticks(range(len(FAMILIES)), [f.upper() for f in FAMILIES])
    ax.set_ylabel("C_f-eta = log10 kappa")
    ax.set_title(f"focal-projection coupling, FoV {fov:.0f}")
    ax.legend(title="profile", fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "coupling_index.png", dpi=110)
    plt.close(fig)
    lines = ["| family | " + " | ".join(PROFILES) + " |", "|---|" + "---|" * len(PROFILES)]
    lines += [f"| {f} | " + " | ".join(f"{table[f][p]:.2f}" for p in PROFILES) + " |" for f in FAMILIES]
    md = [
        "# Failure analysis",
        "",
        f"## Focal-projection coupling C_f-eta (FoV {fov:.0f}; C/M/E: central/middle/edge bands, R: radial cover)",
        "",
        *lines,
        "",
        "![coupling](coupling_index.png)",
        "",
    ]

    if benchmark_dir is not None:
        trials = json.loads((benchmark_dir / "trials.json").read_text())
        # Conditioning trajectories of the all-frames pipeline, success against failure.
        fig, ax = plt.subplots(figsize=(5.5, 3.4))
        groups = {"success": [], "failure": []}
        for t in trials:
            r = t.get("all")
            if not r:
                continue
            for g in r.get("gamma", []):
                if g:
                    groups["success" if r["success"] else "failure"].append(g)
        for name, colour in (("success", "tab:blue"), ("failure", "tab:red")):
            for g in groups[name]:
                ax.plot(range(1, len(g) + 1), g, color=colour, alpha=0.25, lw=1)
            if groups[name]:
                ax.plot([], [], color=colour, label=f"{name} ({len(groups[name])} camera runs)")
        ax.set_xlabel("initialisation step k")
        ax.set_ylabel("gamma_k = log10 kappa(S_c)")
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out / "gamma_trajectories.png", dpi=110)
        plt.close(fig)
        med = {k: float(np.median([np.median(g) for g in v])) if v else float("nan") for k, v in groups.items()}
        result["gamma_median"] = med
        md += [
            "## Conditioning trajectories (all-frames pipeline)",
            "",
            f"Median gamma: success {med['success']:.2f}, failure {med['failure']:.2f}.",
            "",
            "![gamma](gamma_trajectories.png)",
            "",
        ]
        # Spatial distribution metrics per configuration.
        per_cfg = {}
        for t in trials:
            r = t.get("all")
            if not r:
                continue
            d = per_cfg.setdefault(t["config"], {"S": [], "F": []})
            for g in t["grid"]:
                d["S" if r["success"] else "F"].append(np.asarray(g, dtype=float))
        rows = ["| setting | D_qty | D_sp | D_rand | Delta_sp | success / failure camera runs |", "|---|---|---|---|---|---|"]
        result["distribution"] = {}
        for cfg, d in per_cfg.items():
            m = distribution_metrics(d["S"], d["F"])
            result["distribution"][cfg] = m
            rows.append(
                f"| {cfg} | {100 * m['D_qty']:.2f}% | {100 * m['D_sp']:.2f}% | {100 * m['D_rand']:.2f}% | "
                f"{100 * m['Delta_sp']:.2f} pp | {m['n_success']} / {m['n_failure']} |"
            )
        md += [
            "## Success/failure distribution comparison (all-frames pipeline)",
            "",
            *rows,
            "",
            "Settings without failures (or without successes) have no comparison (nan).",
            "",
        ]
    (out / "analysis.md").write_text("\n".join(md) + "\n")
    (out / "analysis.json").write_text(json.dumps(result, indent=1))
    print("\n".join(lines))
    print(f"-> {out}/analysis.md")
    return result
