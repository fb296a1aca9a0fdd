"""The detector's shape, measured: ``python -m calib_eval.benchmark.detector_shape [--root cotrain/detect]
[--doc docs/detector.md] [--json OUT.json]``.

Reads every ``*.py`` file under ``--root`` (recursively, sorted) with :mod:`ast` (source text is
never matched with regular expressions), prints a markdown table to stdout and, with ``--json``,
writes the same figures as JSON (to a temporary file first, then :func:`os.replace`). A missing
root or doc is a one-line error on stderr (``detector_shape: ...``) and exit code 2; so is a file
that does not parse.

What is counted, exactly:

* **Numeric literal.** An ``int`` or ``float`` constant in the expression tree (``bool`` constants,
  ``True`` / ``False``, are not; strings, ``None`` and complex numbers are not). A sign is part of
  its literal: ``-1.0`` is one number. ``float(<string literal>)`` (``float("inf")``,
  ``float("-inf")``) is one number, and so is an attribute ``inf`` of ``math``, ``np`` or ``numpy``
  (``math.inf``, ``-np.inf``). Every other expression counts the numeric literals anywhere inside
  it: ``(0.1, 0.2)`` counts 2, ``np.arange(0.3, 2.0, 0.05)`` counts 3, ``np.array([[1, 0], [0, 1]])``
  counts 4. No literal is judged "not a tuning number"; the rule counts them all.
* **Dataclass fields.** A class (at any depth: module level, nested in a class or a function)
  decorated with ``@dataclass`` or ``@dataclasses.dataclass``, with or without arguments. Its
  fields are the annotated assignments with a value directly in its body (annotation
  ``ClassVar[...]`` excluded: that is no field; plain assignments without annotation are no fields
  either). A field's default counts its numeric literals as above, except for a call to
  ``field(...)`` / ``dataclasses.field(...)``: only its ``default=`` and ``default_factory=``
  arguments are counted (``field(default_factory=lambda: (1, 2))`` counts 2;
  ``field(default_factory=GridConfig)`` counts 0). Function parameters' defaults, and attributes
  of classes that are not dataclasses, are not counted.
* **Constants.** An assignment (``A = ...``, ``A: T = ...``, ``A = B = ...``, ``A, B = ...``) at
  module level (directly in the module's body, or inside a module-level ``if`` / ``try`` /
  ``with`` block, never inside a ``def`` or ``class``) with at least one target name matching
  ``^[A-Z][A-Z0-9_]*$`` (so ``_PRIVATE`` and ``lowercase`` are not constants). Its value counts its
  numeric literals as above, once per statement (``A = B = 3`` counts 1); a value without numeric
  literals counts 0.
* **Lines.** Physical lines of a file: ``len(text.splitlines())`` (a last line without a newline
  counts; ``wc -l`` would not count it). The doc file's lines the same way.
* **Functions.** Every ``def`` / ``async def`` at any depth (methods, nested functions), its length
  ``end_lineno - lineno + 1`` of the ``def`` node: from the ``def`` line to its last line, decorators
  excluded. Named ``file:Outer.inner`` (dotted through the enclosing classes and functions).

The targets beside the figures (:data:`TARGETS`): at most 80 tuned numbers, no file over 700 lines,
no function over 80 lines, the doc at most 400 lines. The check is strictly "over": a file of 700
lines or a function of 80 lines is within target.
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import re
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

TARGETS = {"tuned_numbers": 80, "file_lines": 700, "function_lines": 80, "doc_lines": 400}
CONSTANT_NAME = re.compile(r"^[A-Z][A-Z0-9_]*$")  # matched against names, never against source text
INF_MODULES = ("math", "np", "numpy")  # <module>.inf is one number


class ShapeError(Exception):
    """A path that is missing or a file that does not parse: the CLI's one-line error, exit 2."""


def numbers_in(node: ast.AST | None) -> int:
    """Numeric literals in the expression ``node`` (module docstring: "Numeric literal")."""
    if node is None:
        return 0
    if isinstance(node, ast.Constant):
        return int(isinstance(node.value, (int, float)) and not isinstance(node.value, bool))
    if _is_float_of_string(node) or _is_module_inf(node):
        return 1
    return sum(numbers_in(child) for child in ast.iter_child_nodes(node))


def _is_float_of_string(node: ast.AST) -> bool:
    """``float("...")``: a call to the name ``float`` with one string literal."""
    return (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id == "float"
        and len(node.args) == 1
        and not node.keywords
        and isinstance(node.args[0], ast.Constant)
        and isinstance(node.args[0].value, str)
    )


def _is_module_inf(node: ast.AST) -> bool:
    """``math.inf``, ``np.inf`` or ``numpy.inf``."""
    return isinstance(node, ast.Attribute) and node.attr == "inf" and isinstance(node.value, ast.Name) and node.value.id in INF_MODULES


def _is_dotted(node: ast.AST, name: str, module: str) -> bool:
    """``node`` is the name ``name`` or the attribute ``module.name``."""
    if isinstance(node, ast.Name):
        return node.id == name
    return isinstance(node, ast.Attribute) and node.attr == name and isinstance(node.value, ast.Name) and node.value.id == module


def is_dataclass(cls: ast.ClassDef) -> bool:
    """``cls`` is decorated with ``@dataclass`` / ``@dataclasses.dataclass``, called or not."""
    for dec in cls.decorator_list:
        target = dec.func if isinstance(dec, ast.Call) else dec
        if _is_dotted(target, "dataclass", "dataclasses"):
            return True
    return False


def default_numbers(value: ast.expr) -> int:
    """Numeric literals of a dataclass field's default: of ``default=`` / ``default_factory=``
    where the default is a ``field(...)`` call, else of the whole expression."""
    if isinstance(value, ast.Call) and _is_dotted(value.func, "field", "dataclasses"):
        return sum(numbers_in(kw.value) for kw in value.keywords if kw.arg in ("default", "default_factory"))
    return numbers_in(value)


def _is_classvar(annotation: ast.expr) -> bool:
    """The annotation is ``ClassVar`` / ``ClassVar[...]`` (also as ``typing.ClassVar``)."""
    target = annotation.value if isinstance(annotation, ast.Subscript) else annotation
    return _is_dotted(target, "ClassVar", "typing")


def dataclass_fields(cls: ast.ClassDef) -> dict[str, int]:
    """Numeric literals per field with a default (0 for bool, str, None, ...) of one dataclass."""
    out = {}
    for stmt in cls.body:
        if isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name) and stmt.value is not None:
            if not _is_classvar(stmt.annotation):
                out[stmt.target.id] = default_numbers(stmt.value)
    return out


def walk_defs(node: ast.AST, prefix: str = "") -> Iterator[tuple[str, ast.AST]]:
    """Every class and function definition inside ``node`` at any depth, with its dotted name
    (``Outer.inner``), outer ones first."""
    for child in ast.iter_child_nodes(node):
        if isinstance(child, (ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            yield f"{prefix}{child.name}", child
            yield from walk_defs(child, f"{prefix}{child.name}.")
        else:
            yield from walk_defs(child, prefix)


def module_level_statements(body: list[ast.stmt]) -> Iterator[ast.stmt]:
    """The module's statements, with those of module-level ``if`` / ``try`` / ``with`` blocks
    (never those inside a ``def`` or ``class``)."""
    for stmt in body:
        yield stmt
        if isinstance(stmt, ast.If):
            yield from module_level_statements(stmt.body + stmt.orelse)
        elif isinstance(stmt, ast.With):
            yield from module_level_statements(stmt.body)
        elif isinstance(stmt, ast.Try):
            blocks = stmt.body + stmt.orelse + stmt.finalbody + [s for h in stmt.handlers for s in h.body]
            yield from module_level_statements(blocks)


def _target_names(target: ast.expr) -> list[str]:
    """Names bound by an assignment target (tuple / list targets unpacked; attributes and
    subscripts bind none)."""
    if isinstance(target, ast.Name):
        return [target.id]
    if isinstance(target, (ast.Tuple, ast.List)):
        return [name for elt in target.elts for name in _target_names(elt)]
    return []


def module_constants(tree: ast.Module) -> dict[str, int]:
    """Numeric literals per module-level UPPER_CASE assignment, keyed by its target names
    (joined with ``", "`` where one statement binds several)."""
    out = {}
    for stmt in module_level_statements(tree.body):
        if isinstance(stmt, ast.Assign):
            targets, value = stmt.targets, stmt.value
        elif isinstance(stmt, ast.AnnAssign) and stmt.value is not None:
            targets, value = [stmt.target], stmt.value
        else:
            continue
        names = [name for target in targets for name in _target_names(target)]
        if any(CONSTANT_NAME.match(name) for name in names):
            out[", ".join(names)] = out.get(", ".join(names), 0) + numbers_in(value)
    return out


def measure_file(path: Path) -> dict:
    """One file's figures: lines, tuned numbers by dataclass and by constant, long functions."""
    text = path.read_text(encoding="utf-8")
    try:
        tree = ast.parse(text, filename=str(path))
    except SyntaxError as err:
        raise ShapeError(f"cannot parse {path}: {err.msg} (line {err.lineno})") from None
    classes, functions = {}, []
    for name, node in walk_defs(tree):
        if isinstance(node, ast.ClassDef) and is_dataclass(node):
            classes[name] = sum(dataclass_fields(node).values())
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            functions.append((name, node.end_lineno - node.lineno + 1))
    constants = module_constants(tree)
    return {"lines": len(text.splitlines()), "classes": classes, "constants": constants, "functions": functions}


def measure(root: Path, doc: Path | None) -> dict:
    """The figures for every ``*.py`` under ``root`` and the doc's lines (None without a doc),
    as a plain dict (see the module docstring for the rules; keys as in the JSON)."""
    root, doc = Path(root), None if doc is None else Path(doc)
    if not root.is_dir():
        raise ShapeError(f"no such directory: {root}")
    if doc is not None and not doc.is_file():
        raise ShapeError(f"no such file: {doc}")
    files, by_file, long_functions, longest = {}, {}, [], {"where": None, "lines": 0}
    for path in sorted(p for p in root.rglob("*.py") if p.is_file()):
        key = path.as_posix()
        fig = measure_file(path)
        files[key] = fig["lines"]
        dc, const = sum(fig["classes"].values()), sum(fig["constants"].values())
        by_file[key] = {
            "total": dc + const,
            "dataclass_fields": dc,
            "constants": const,
            "classes": fig["classes"],
            "constant_names": fig["constants"],
        }
        long_functions += [{"where": f"{key}:{name}", "lines": n} for name, n in fig["functions"] if n > TARGETS["function_lines"]]
        for name, n in fig["functions"]:
            if n > longest["lines"]:
                longest = {"where": f"{key}:{name}", "lines": n}
    dataclass_total = sum(f["dataclass_fields"] for f in by_file.values())
    constant_total = sum(f["constants"] for f in by_file.values())
    return {
        "root": root.as_posix(),
        "doc": None if doc is None else doc.as_posix(),
        "targets": dict(TARGETS),
        "tuned_numbers": {
            "total": dataclass_total + constant_total,
            "dataclass_fields": dataclass_total,
            "constants": constant_total,
            "by_file": by_file,
        },
        "files": files,
        "files_over_700": [{"path": p, "lines": n} for p, n in files.items() if n > TARGETS["file_lines"]],
        "functions_over_80": long_functions,
        "longest_function": longest,
        "doc_lines": None if doc is None else len(doc.read_text(encoding="utf-8").splitlines()),
    }


def _verdict(value: int | None, target: int) -> str:
    """``yes`` / ``no`` for a figure against its target (at most), ``-`` without a figure."""
    return "-" if value is None else ("yes" if value <= target else "no")


def markdown(fig: dict) -> str:
    """The figures as a short markdown page: the summary against the targets, tuned numbers by
    file and by dataclass, the long files and functions."""
    t, tn = fig["targets"], fig["tuned_numbers"]
    longest_fn = f"{fig['longest_function']['lines']}, {fig['longest_function']['where']}"
    rows = [
        ("tuned numbers", tn["total"], t["tuned_numbers"]),
        ("files over 700 lines", len(fig["files_over_700"]), 0),
        ("functions over 80 lines", len(fig["functions_over_80"]), 0),
        (f"lines of {fig['doc']}", fig["doc_lines"], t["doc_lines"]),
    ]
    out = [f"Detector shape of `{fig['root']}`", "", "| figure | measured | target | within |", "|---|---:|---:|:---:|"]
    out += [f"| {name} | {'-' if v is None else v} | {target} | {_verdict(v, target)} |" for name, v, target in rows]
    out += ["", f"Tuned numbers: {tn['total']} = {tn['dataclass_fields']} in dataclass fields + {tn['constants']} in module constants.", ""]
    out += ["| file | lines | tuned | dataclass fields | constants |", "|---|---:|---:|---:|---:|"]
    for path, f in tn["by_file"].items():
        out.append(f"| {path} | {fig['files'][path]} | {f['total']} | {f['dataclass_fields']} | {f['constants']} |")
    out += ["", "| dataclass | tuned numbers |", "|---|---:|"]
    out += [f"| {path}:{cls} | {n} |" for path, f in tn["by_file"].items() for cls, n in f["classes"].items()]
    out += [
        "",
        f"Files over {t['file_lines']} lines: " + (", ".join(f"{f['path']} ({f['lines']})" for f in fig["files_over_700"]) or "none"),
    ]
    out += [f"Functions over {t['function_lines']} lines: {len(fig['functions_over_80'])} (longest {longest_fn})"]
    out += [f"- {f['where']}: {f['lines']}" for f in fig["functions_over_80"]]
    return "\n".join(out) + "\n"


def write_json_atomic(path: Path, data: dict) -> None:
    """``data`` as indented JSON at ``path``: written to a temporary file beside it, then moved
    over it with :func:`os.replace` (a reader never sees half a file)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(data, fh, indent=2)
            fh.write("\n")
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


def main(argv: list[str] | None = None) -> int:
    """The CLI: the markdown table to stdout, ``--json`` the figures; 2 on a missing path."""
    ap = argparse.ArgumentParser(prog="python -m calib_eval.benchmark.detector_shape", description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", type=Path, default=Path("cotrain/detect"), help="package to measure (default cotrain/detect)")
    ap.add_argument("--doc", type=Path, default=Path("docs/detector.md"), help="doc whose lines are counted (default docs/detector.md)")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here as JSON")
    args = ap.parse_args(argv)
    try:
        fig = measure(args.root, args.doc)
        sys.stdout.write(markdown(fig))
        if args.json is not None:
            write_json_atomic(args.json, fig)
    except (ShapeError, OSError, UnicodeDecodeError) as err:
        print(f"detector_shape: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
