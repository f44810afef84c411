"""Layering rules of docs/design.md §6.1, checked statically with ``ast``.

* The core (all of ``spgeo/`` except ``spgeo/cli/`` and ``spgeo/apps/``, plus ``factors/``)
  never imports ``spgeo.evaluation``: not at module level, not inside functions, not through
  a relative import that resolves to it.
* Modules of ``spgeo/``, ``factors/`` and ``evaluation/`` stay at 500 lines or less unless
  their docstring opens with a reason (a line starting ``Longer than 500 lines because``).
"""
from __future__ import annotations

import ast
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]
APPLICATION_DIRS = ("spgeo/cli", "spgeo/apps")
# installed package name of each top-level source folder
PACKAGE_OF_DIR = {"spgeo": "spgeo", "factors": "spgeo.factors", "evaluation": "spgeo.evaluation"}
FORBIDDEN = "spgeo.evaluation"
MAX_LINES = 500
LONG_REASON = "Longer than 500 lines because"


def _python_files(folder: str) -> list[Path]:
    return sorted(p for p in (ROOT / folder).rglob("*.py") if "__pycache__" not in p.parts)


def core_files() -> list[Path]:
    """Every ``.py`` file of the core, as paths under the repository root."""
    skip = tuple(ROOT / d for d in APPLICATION_DIRS)
    files = [p for p in _python_files("spgeo") if not any(p.is_relative_to(s) for s in skip)]
    return files + _python_files("factors")


def module_package(path: Path) -> str:
    """Dotted package that holds ``path`` once installed (``factors/x.py`` -> ``spgeo.factors``)."""
    rel = path.relative_to(ROOT)
    parts = [PACKAGE_OF_DIR[rel.parts[0]], *rel.parts[1:-1]]
    return ".".join(parts)


def imported_modules(source: str, package: str) -> list[tuple[int, str]]:
    """``(line, absolute module name)`` for every import statement anywhere in ``source``.

    ``from X import a, b`` yields ``X``, ``X.a`` and ``X.b`` (a name may be a sub-module);
    relative imports are resolved against ``package``, the package holding the module.
    """
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                parts = parts[: len(parts) - (node.level - 1)]
                base = ".".join(parts + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            found.append((node.lineno, base))
            found.extend((node.lineno, f"{base}.{alias.name}") for alias in node.names)
    return found


def is_forbidden(module: str) -> bool:
    return module == FORBIDDEN or module.startswith(FORBIDDEN + ".")


def forbidden_import_lines(path: Path) -> list[int]:
    """Sorted line numbers of ``path`` that import ``spgeo.evaluation`` or a part of it."""
    source = path.read_text(encoding="utf-8")
    return sorted({line for line, module in imported_modules(source, module_package(path))
                   if is_forbidden(module)})


def test_core_file_list_is_sane():
    files = {p.relative_to(ROOT).as_posix() for p in core_files()}
    assert "spgeo/__init__.py" in files and "factors/__init__.py" in files
    assert not any(f.startswith(tuple(d + "/" for d in APPLICATION_DIRS)) for f in files)


def test_import_scanner_resolves_relative_and_nested_imports():
    assert module_package(ROOT / "spgeo" / "frontend" / "base.py") == "spgeo.frontend"
    assert module_package(ROOT / "factors" / "photometric.py") == "spgeo.factors"
    source = ("def f():\n    from ..evaluation import metrics\n"   # line 2, nested + relative
              "import spgeo.evaluation.trajectory as t\n"           # line 3
              "from spgeo import evaluation\n"                      # line 4
              "from . import base\n"                                # line 5, allowed
              "from ..factors.photometric import X\n")              # line 6, allowed
    hits = sorted({line for line, module in imported_modules(source, "spgeo.frontend")
                   if is_forbidden(module)})
    assert hits == [2, 3, 4]
    # factors/ installs as spgeo.factors: its ``..evaluation`` is spgeo.evaluation
    assert [is_forbidden(m) for _, m in imported_modules("from ..evaluation import x\n",
                                                         "spgeo.factors")] == [True, True]


def test_core_never_imports_evaluation():
    offenders = [f"{path.relative_to(ROOT).as_posix()}:{line}"
                 for path in core_files() for line in forbidden_import_lines(path)]
    assert not offenders, ("the core must not import spgeo.evaluation (docs/design.md §6.1):\n"
                           + "\n".join(offenders))


def _opens_with_reason(path: Path) -> bool:
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    return any(line.strip().startswith(LONG_REASON) for line in doc.splitlines()[:5])


def test_modules_at_most_500_lines_or_say_why():
    too_long = []
    for folder in PACKAGE_OF_DIR:
        for path in _python_files(folder):
            n = len(path.read_text(encoding="utf-8").splitlines())
            if n > MAX_LINES and not _opens_with_reason(path):
                too_long.append(f"{path.relative_to(ROOT).as_posix()}: {n} lines")
    assert not too_long, (f"modules over {MAX_LINES} lines without a "
                          f"'{LONG_REASON} ...' line in their docstring:\n" + "\n".join(too_long))
