"""Run project code in a fresh interpreter where some packages cannot be imported, as where they
are not installed (``ModuleNotFoundError`` with the package's name): the base install without the
``[train]`` extra, or a calibration without onnx either."""

import subprocess
import sys

from cotrain.cli import TRAIN_EXTRA  # noqa: F401  (the packages of pyproject's [train] extra)

_BLOCK = """
import importlib.abc, sys
class NotInstalled(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        top = name.split('.')[0]
        if top in {blocked!r}:
            raise ModuleNotFoundError(f"No module named {{top!r}}", name=top)
sys.meta_path.insert(0, NotInstalled())
"""


def run_without(blocked: tuple[str, ...], entry: str, argv: list[str], cwd, check_torch: bool = False) -> subprocess.CompletedProcess:
    """``entry``'s ``run(argv)`` (``cotrain.cli`` or ``calib_eval.cli``) with ``blocked`` not
    importable; ``check_torch``: also fail where torch ended up imported anyway."""
    tail = "\nassert not any(m.split('.')[0] == 'torch' for m in sys.modules), 'torch was imported'" if check_torch else ""
    code = f"{_BLOCK.format(blocked=set(blocked))}\nfrom {entry} import run\nrc = run({argv!r}){tail}\nsys.exit(rc)"
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, timeout=600)
