"""Dependencies go one way along the data path: a module imports nothing of a later stage.

geometry -> targets -> render -> model -> export -> detect -> io -> calibration -> detection
evaluation -> benchmark -> the main job (the pipeline and the command lines). Checked twice: on
every import statement in the source (function-local ones included), and by importing a stage in
a fresh interpreter and looking at what it loaded.
"""

from __future__ import annotations

import ast
import subprocess
import sys

import pytest

from tests.paths import ROOT

STAGES = [
    ("config and progress", ("cotrain.config", "cotrain.progress")),
    ("geometry", ("cotrain.geometry",)),
    ("targets", ("cotrain.targets",)),
    ("render", ("cotrain.render",)),
    ("model", ("cotrain.model",)),
    ("export", ("export",)),
    ("detect", ("cotrain.detect",)),
    ("io", ("cotrain.io",)),
    ("calibration", ("calib_eval.calibration",)),
    ("detection evaluation", ("calib_eval.detection",)),
    ("benchmark", ("calib_eval.benchmark",)),
    ("main job", ("calib_eval.pipeline", "calib_eval.report_index", "calib_eval.cli", "cotrain.cli", "cotrain.main_job")),
]
PACKAGES = ("cotrain", "calib_eval", "export")


def stage_of(module: str) -> int | None:
    """Index of the stage a dotted module name belongs to (None: a package's bare __init__)."""
    for i, (_, prefixes) in enumerate(STAGES):
        if any(module == p or module.startswith(p + ".") for p in prefixes):
            return i
    return None


def project_modules() -> dict[str, object]:
    """{dotted module name: path} of every source file of the three packages."""
    out = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def imports_of(module: str, path) -> set[str]:
    """Every project module ``module``'s source imports, at any depth of the file."""
    tree = ast.parse(path.read_text())
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            found.add(base)
            found.update(f"{base}.{a.name}" for a in node.names)  # `from pkg import module`
    return {m for m in found if m.split(".")[0] in PACKAGES}


def test_every_module_has_a_stage():
    missing = [m for m in project_modules() if stage_of(m) is None and m not in PACKAGES]
    assert not missing, f"modules outside every stage: {missing}"


def test_no_import_of_a_later_stage():
    mods = project_modules()
    bad = []
    for mod, path in mods.items():
        s = stage_of(mod)
        if s is None:
            continue
        for imp in imports_of(mod, path):
            t = stage_of(imp)
            if t is not None and t > s:
                bad.append(f"{mod} ({STAGES[s][0]}) imports {imp} ({STAGES[t][0]})")
    assert not bad, "\n".join(sorted(bad))


def test_checker_sees_a_backward_import(tmp_path):
    """The check itself: a source line importing a later stage is found."""
    f = tmp_path / "fake.py"
    f.write_text("def f():\n    from calib_eval.benchmark.rigs import make_sequence\n")
    imps = imports_of("cotrain.detect.fake", f)
    assert "calib_eval.benchmark.rigs" in imps
    assert stage_of("calib_eval.benchmark.rigs") > stage_of("cotrain.detect.fake")


def _loaded_after(imports: list[str]) -> set[str]:
    code = "import sys\n" + "".join(f"import {m}\n" for m in imports) + "print('\\n'.join(sorted(sys.modules)))"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert r.returncode == 0, r.stderr
    return {m for m in r.stdout.split() if m.split(".")[0] in PACKAGES}


@pytest.mark.parametrize(
    "stage, later",
    [
        ("detect", "calibration"),  # import cotrain.detect loads nothing of calib_eval
        ("io", "calibration"),
        ("calibration", "detection evaluation"),
        ("detection evaluation", "benchmark"),  # nothing but the main job imports the benchmark
    ],
)
def test_importing_a_stage_loads_no_later_stage(stage, later):
    mods = [m for m in project_modules() if stage_of(m) == [n for n, _ in STAGES].index(stage)]
    loaded = _loaded_after(mods)
    first_later = [n for n, _ in STAGES].index(later)
    late = sorted(m for m in loaded if (stage_of(m) or -1) >= first_later)
    assert not late, f"importing the {stage} stage loaded {late}"
