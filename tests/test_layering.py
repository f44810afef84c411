"""Layering and size rules of docs/design.md §6.1, checked statically with ``ast``.

Modules are named as installed: setup.py's ``package_dir`` (read from setup.py) maps the
folders ``factors/`` and ``evaluation/`` to ``spgeo.factors`` and ``spgeo.evaluation``, so
``from ..evaluation.metrics import x`` in ``spgeo/apps/`` is ``spgeo.evaluation.metrics``
and ``from ...apps import x`` in ``evaluation/completion/`` is ``spgeo.apps``.

* Nothing in ``spgeo/`` (the core, and the applications ``spgeo/apps/`` and ``spgeo/cli/``
  too) nor in ``factors/`` imports ``spgeo.evaluation``: not at module level, not inside
  functions, not through a relative import that resolves to it.  (``spgeo eval`` finds a
  protocol with ``importlib`` by a name in a string: no import statement, nothing to see.)
* Nothing below the command line imports ``spgeo.cli``: no module of ``spgeo/`` outside
  ``spgeo/cli/``, of ``factors/`` or of ``evaluation/`` (anywhere in the module), except
  ``spgeo/__main__.py``, the entry of ``python -m spgeo``.
* The modules of ``spgeo/`` and ``factors/`` import each other without a cycle (imports run
  when a module loads: module level and class bodies, not function bodies nor
  ``if TYPE_CHECKING:`` blocks; importing ``a.b.c`` also loads the packages ``a.b`` and
  ``a`` unless the importer lies inside them).  A failure lists every cycle found.  Imports
  deferred into function bodies make no exception: counted too, they form no cycle either
  (only a module ``__getattr__``, the lazy re-export of an optional piece, is left out).
* No import circle among the modules of ``spgeo/``, ``factors/`` and ``evaluation/`` when every
  import statement counts (``TYPE_CHECKING`` blocks and a module ``__getattr__`` included),
  nor among the layers they make: the core (``spgeo/`` but its applications, and
  ``factors/``), ``spgeo.apps``, ``spgeo.cli`` (with ``spgeo/__main__.py``, its entry) and
  ``spgeo.evaluation``; e.g. ``spgeo.evaluation`` uses ``spgeo.apps``, so no module of
  ``spgeo/apps/`` may import one of ``evaluation/``, even where no two modules import each
  other.
* Every function of ``spgeo/``, ``factors/`` and ``evaluation/`` (methods and nested functions included; a
  nested function counts within its parent and on its own) has at most 60 lines of code:
  lines that are neither blank nor comments, its docstring excluded.  A compiled kernel
  (decorated with numba's ``njit`` / ``jit`` / ...) may be longer when its docstring has a
  line starting ``Longer than 60 lines because`` that gives the reason.
* Sizes: no module of ``spgeo/``, ``factors/`` or ``evaluation/`` has more than 600 lines,
  ``spgeo/vo/odometry.py`` (the per-frame state machine) at most 375 (350 until issue 53
  added the entry into a saved map).
* One mapping port: the odometry (``spgeo/vo/odometry.py`` and its read side
  ``spgeo/vo/readout.py``) names the mapping mode at most twice in code (an attribute
  ``mode`` / ``in_worker`` / ``schedule`` (of ``OdometryConfig.mapping``), or the strings
  ``"live"`` / ``"inline"``; docstrings do not count): live and inline differ in the port only.
* One key scheme: no module of ``spgeo/`` or ``factors/`` but ``spgeo/graph/keys.py`` makes a
  gtsam key (``gtsam.symbol`` / ``gtsam.Symbol`` / ``gtsam.symbol_shorthand``, also when
  imported by name); every graph takes its keys from :mod:`spgeo.graph.keys`.
* One rotation projection: no module of ``spgeo/`` or ``factors/`` but ``spgeo/geometry.py``
  projects a matrix onto a rotation by SVD; all use :func:`spgeo.geometry.nearest_rotation`.
  A projection is an SVD ``U, _, Vt = ...svd(M)`` whose singular values go unused and whose
  ``U`` and ``Vt`` (or their transposes) are multiplied together in the same function
  (``U @ Vt``, ``U @ D @ Vt``, ``np.dot`` / ``np.matmul`` too).  Other SVD uses pass: a
  null vector (triangulation, ``_, _, vt = ...``), a fit that uses the singular values
  (Umeyama's scale in :mod:`spgeo.similarity`).
* One tracking decision: no module of ``spgeo/`` or ``factors/`` but
  ``spgeo/vo/frame_tracker.py`` calls ``track_frame`` (the photometric tracker), except
  ``spgeo/vo/scale_check.py``, whose reverse scale check tracks the previous keyframe's
  image against a new keyframe (a measurement of its scale, not a frame of the run).
* One keyframe policy: the thresholds of ``KeyframeDecisionConfig`` are read (``<x>.keyframe.
  <threshold>``) only in ``spgeo/vo/keyframe_policy.py``.
* No private reads across objects: in ``spgeo/``, ``factors/`` and ``evaluation/`` an
  attribute ``_name`` (not a dunder) is read only from ``self`` or ``cls``: an object hands
  what another needs (the odometry's read side is given its parts, not reading them).
* ``OdometryConfig`` has at most 22 top-level fields (groups for the rest).
* One triangulator: in ``spgeo/`` and ``factors/`` nothing calls OpenCV's
  ``triangulatePoints``, and a function named ``triangulate*`` outside
  ``spgeo/triangulation.py`` is an adapter that calls its ``triangulate`` or ``dlt_points``.
"""
from __future__ import annotations

import ast
from pathlib import Path
from typing import Dict, Iterator, List, Optional, Set

import pytest


ROOT = Path(__file__).resolve().parents[1]
APPLICATION_DIRS = ("spgeo/cli", "spgeo/apps")


def setup_package_dirs(setup_source: str) -> Dict[str, str]:
    """setup.py's ``package_dir`` (installed package -> source folder), read with ``ast``."""
    for node in ast.walk(ast.parse(setup_source)):
        if isinstance(node, ast.keyword) and node.arg == "package_dir":
            return ast.literal_eval(node.value)
    raise AssertionError("setup.py passes no package_dir")


# installed package name of each top-level source folder (setup.py's package_dir, inverted)
PACKAGE_OF_DIR = {folder: package for package, folder in
                  setup_package_dirs((ROOT / "setup.py").read_text(encoding="utf-8")).items()}
FORBIDDEN = "spgeo.evaluation"
CLI = "spgeo.cli"
CLI_ENTRY = "spgeo/__main__.py"  # the one module outside spgeo/cli/ that may import spgeo.cli
# the layers above the core (every other module of spgeo/ and factors/ is "core"), and the
# module outside its folder that belongs to one (the entry of ``python -m spgeo``)
LAYERS = ("spgeo.apps", "spgeo.cli", "spgeo.evaluation")
LAYER_OF_MODULE = {"spgeo.__main__": "spgeo.cli"}
MAX_FUNCTION_LINES = 60
LONG_REASON = "Longer than 60 lines because"
KERNEL_DECORATORS = {"njit", "jit", "vectorize", "guvectorize", "stencil", "cfunc"}
KEY_MODULE = "spgeo/graph/keys.py"   # the one module that makes gtsam keys
KEY_MAKERS = {"symbol", "Symbol", "symbol_shorthand"}
ROTATION_MODULE = "spgeo/geometry.py"   # the one module that projects onto SO(3) by SVD


def _python_files(folder: str) -> list[Path]:
    # rglob does not descend into the symlinked folders of a development checkout
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


def module_name(path: Path) -> str:
    """Dotted name of the module in ``path`` once installed (a package for ``__init__.py``)."""
    package = module_package(path)
    return package if path.name == "__init__.py" else f"{package}.{path.stem}"


# ------------------------------------------------------------------ import scanner
def _is_type_checking(test: ast.expr) -> bool:
    return ((isinstance(test, ast.Name) and test.id == "TYPE_CHECKING")
            or (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"))


def _import_nodes(tree: ast.AST, module_level: bool, lazy: bool = False) -> Iterator[ast.stmt]:
    """Import statements of ``tree``; with ``module_level`` only those that run when the
    module loads (not in function bodies nor under ``if TYPE_CHECKING:``); with ``lazy``
    also those in function bodies, except a module ``__getattr__`` (the lazy re-export of
    an optional piece)."""
    if not (module_level or lazy):
        yield from (n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom)))
        return
    todo = [tree]
    while todo:
        node = todo.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)) and (
                not lazy or getattr(node, "name", "") == "__getattr__"):
            continue
        elif isinstance(node, ast.If) and _is_type_checking(node.test):
            todo.extend(node.orelse)
        else:
            todo.extend(ast.iter_child_nodes(node))


def import_statements(source: str, package: str, module_level: bool = False,
                      lazy: bool = False) -> list[tuple[int, str, Optional[list[str]]]]:
    """``(line, absolute module, names)`` per import statement of ``source``.

    ``names`` is the list of names of ``from X import a, b`` and ``None`` for
    ``import X``; relative imports are resolved against ``package``, the package
    holding the module.  With ``module_level`` only the imports that run when the
    module loads are listed, with ``lazy`` those too that run inside functions (see
    :func:`_import_nodes`).
    """
    found: list[tuple[int, str, Optional[list[str]]]] = []
    for node in _import_nodes(ast.parse(source), module_level, lazy):
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name, None) for alias in node.names)
            continue
        if node.level:
            parts = package.split(".")
            parts = parts[: len(parts) - (node.level - 1)]
            base = ".".join(parts + ([node.module] if node.module else []))
        else:
            base = node.module or ""
        found.append((node.lineno, base, [alias.name for alias in node.names]))
    return sorted(found)


def imported_modules(source: str, package: str) -> list[tuple[int, str]]:
    """``(line, absolute module name)`` for every import statement anywhere in ``source``.

    ``from X import a, b`` yields ``X``, ``X.a`` and ``X.b`` (a name may be a sub-module);
    relative imports are resolved against ``package``, the package holding the module.
    """
    found: list[tuple[int, str]] = []
    for line, base, names in import_statements(source, package):
        found.append((line, base))
        found.extend((line, f"{base}.{name}") for name in names or ())
    return found


def is_forbidden(module: str) -> bool:
    return module == FORBIDDEN or module.startswith(FORBIDDEN + ".")


def is_cli(module: str) -> bool:
    return module == CLI or module.startswith(CLI + ".")


def import_lines(path: Path, predicate) -> list[int]:
    """Sorted line numbers of ``path`` that import a module for which ``predicate`` holds."""
    source = path.read_text(encoding="utf-8")
    return sorted({line for line, module in imported_modules(source, module_package(path))
                   if predicate(module)})


def forbidden_import_lines(path: Path) -> list[int]:
    """Sorted line numbers of ``path`` that import ``spgeo.evaluation`` or a part of it."""
    return import_lines(path, is_forbidden)


# ------------------------------------------------------------------ import graph
def _packages_loaded(module: str, importer: str) -> list[str]:
    """The packages above ``module`` that importing it loads: all but those holding
    ``importer`` (already loading when ``importer`` runs)."""
    parts = module.split(".")
    prefixes = [".".join(parts[:i]) for i in range(1, len(parts))]
    return [p for p in prefixes if not (importer == p or importer.startswith(p + "."))]


def module_dependencies(source: str, importer: str, package: str, modules: Set[str],
                        known: Optional[Set[str]] = None, lazy: bool = False,
                        everywhere: bool = False) -> Set[str]:
    """The modules of ``modules`` that loading ``importer`` (held by ``package``) runs.

    ``from X import a`` needs ``X.a`` when that is a module (of ``known``, default
    ``modules``), else ``X`` itself (even when ``X`` is a package holding ``importer``:
    ``a`` must already be defined there).  With ``lazy`` the imports inside functions
    count too (:func:`_import_nodes`); with ``everywhere`` every import statement of
    the module counts (``if TYPE_CHECKING:`` blocks and a module ``__getattr__`` too).
    """
    known = modules if known is None else known
    deps: Set[str] = set()
    statements = (import_statements(source, package) if everywhere
                  else import_statements(source, package, module_level=True, lazy=lazy))
    for _, base, names in statements:
        if names is None:
            needed = [base]
        else:
            needed = [f"{base}.{n}" if f"{base}.{n}" in known else base for n in names]
        for module in needed:
            deps.update(p for p in _packages_loaded(module, importer) if p in modules)
            if module in modules:
                deps.add(module)
    deps.discard(importer)
    return deps


def import_graph(files: List[Path], known: Set[str], lazy: bool = False,
                 everywhere: bool = False) -> Dict[str, Set[str]]:
    """Module name -> the modules (among ``files``) it imports when it loads (with
    ``lazy``: or when its functions run; with ``everywhere``: anywhere in its source,
    ``TYPE_CHECKING`` blocks included); ``known``: every module name, to tell
    ``from X import module`` from ``from X import name``."""
    names = {module_name(p): p for p in files}
    return {name: module_dependencies(path.read_text(encoding="utf-8"), name,
                                      module_package(path), set(names), known, lazy,
                                      everywhere)
            for name, path in names.items()}


def import_cycles(graph: Dict[str, Set[str]]) -> List[List[str]]:
    """One cycle ``[a, b, ..., a]`` per strongly connected group of ``graph`` (Tarjan)."""
    index: Dict[str, int] = {}
    low: Dict[str, int] = {}
    stack: List[str] = []
    groups: List[List[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(_cycle_in(group, graph) for group in groups)


def _cycle_in(group: List[str], graph: Dict[str, Set[str]]) -> List[str]:
    """A shortest cycle through the first module of a strongly connected ``group``."""
    start, members = group[0], set(group)
    paths = {start: [start]}
    todo = [start]
    while todo:
        v = todo.pop(0)
        for w in sorted(graph[v] & members):
            if w == start:
                return paths[v] + [start]
            if w not in paths:
                paths[w] = paths[v] + [w]
                todo.append(w)
    raise AssertionError(f"no cycle through {start}")


def layer_of(module: str) -> str:
    """The layer of ``module``: one of :data:`LAYERS`, else ``"core"``."""
    if module in LAYER_OF_MODULE:
        return LAYER_OF_MODULE[module]
    return next((layer for layer in LAYERS
                 if module == layer or module.startswith(layer + ".")), "core")


def layer_edges(graph: Dict[str, Set[str]]) -> Dict[tuple, List[str]]:
    """``(layer, layer it imports) -> ["importer -> imported", ...]`` for the imports of
    ``graph`` (module -> modules it imports) that cross from one layer into another."""
    edges: Dict[tuple, List[str]] = {}
    for importer in sorted(graph):
        for imported in sorted(graph[importer]):
            pair = (layer_of(importer), layer_of(imported))
            if pair[0] != pair[1]:
                edges.setdefault(pair, []).append(f"{importer} -> {imported}")
    return edges


def layer_circles(graph: Dict[str, Set[str]]) -> List[str]:
    """One line per import circle among the layers of ``graph``'s modules, each step
    with the module imports that make it (at most three shown)."""
    edges = layer_edges(graph)
    layers: Dict[str, Set[str]] = {}
    for a, b in edges:
        layers.setdefault(a, set()).add(b)
        layers.setdefault(b, set())
    found = []
    for cycle in import_cycles(layers):
        steps = [f"{a} -> {b} ({', '.join(edges[a, b][:3])})" for a, b in zip(cycle, cycle[1:])]
        found.append("; ".join(steps))
    return found


# ------------------------------------------------------------------ function length
def code_lines(lines: List[str], node: ast.AST) -> int:
    """Lines of ``node`` that are neither blank nor comments, its docstring excluded."""
    doc: Set[int] = set()
    body = node.body
    if (body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
            and isinstance(body[0].value.value, str)):
        doc = set(range(body[0].lineno, body[0].end_lineno + 1))
    count = 0
    for i in range(node.lineno, node.end_lineno + 1):
        text = lines[i - 1].strip()
        if i not in doc and text and not text.startswith("#"):
            count += 1
    return count


def _decorator_name(node: ast.expr) -> str:
    if isinstance(node, ast.Call):
        node = node.func
    if isinstance(node, ast.Attribute):
        return node.attr
    return node.id if isinstance(node, ast.Name) else ""


def says_why_longer(node: ast.AST) -> bool:
    """A compiled kernel whose docstring has a ``Longer than 60 lines because`` line."""
    kernel = any(_decorator_name(d) in KERNEL_DECORATORS for d in node.decorator_list)
    doc = ast.get_docstring(node) or ""
    return kernel and any(line.strip().startswith(LONG_REASON) for line in doc.splitlines())


def long_functions(path: Path) -> List[str]:
    """``path:line name: N lines`` for each function of ``path`` over the limit."""
    source = path.read_text(encoding="utf-8")
    lines = source.splitlines()
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            n = code_lines(lines, node)
            if n > MAX_FUNCTION_LINES and not says_why_longer(node):
                found.append(f"{path.relative_to(ROOT).as_posix()}:{node.lineno} "
                             f"{node.name}: {n} lines")
    return found


# ------------------------------------------------------------------ key scheme
def key_making_lines(source: str) -> List[int]:
    """Lines of ``source`` that make a gtsam key: ``gtsam.symbol`` / ``Symbol`` /
    ``symbol_shorthand`` used, or imported from ``gtsam`` (any sub-module)."""
    lines = set()
    for node in ast.walk(ast.parse(source)):
        if (isinstance(node, ast.Attribute) and node.attr in KEY_MAKERS
                and isinstance(node.value, ast.Name) and node.value.id == "gtsam"):
            lines.add(node.lineno)
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "gtsam":
            if "symbol_shorthand" in (node.module or "") or any(
                    a.name in KEY_MAKERS for a in node.names):
                lines.add(node.lineno)
        elif isinstance(node, ast.Import) and any("symbol_shorthand" in a.name
                                                   for a in node.names):
            lines.add(node.lineno)
    return sorted(lines)


# ------------------------------------------------------------------ rotation projection
def _scope_nodes(scope: ast.AST) -> Iterator[ast.AST]:
    """The nodes of a function (or module) body, not those of the functions it holds."""
    todo = list(ast.iter_child_nodes(scope))
    while todo:
        node = todo.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            continue
        yield node
        todo.extend(ast.iter_child_nodes(node))


def _is_svd_call(node: ast.AST) -> bool:
    if not isinstance(node, ast.Call):
        return False
    f = node.func
    return ((isinstance(f, ast.Attribute) and f.attr == "svd")
            or (isinstance(f, ast.Name) and f.id == "svd"))


def _matmul_factors(node: ast.AST) -> List[ast.expr]:
    """The factors of a matrix product ``a @ b @ c`` / ``np.dot(a, b)`` / ``np.matmul(a, b)``
    (nested products flattened); ``[]`` for anything else."""
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.MatMult):
        parts = [node.left, node.right]
    elif (isinstance(node, ast.Call) and len(node.args) == 2 and _decorator_name(node)
          in ("dot", "matmul")):
        parts = list(node.args)
    else:
        return []
    return [f for p in parts for f in (_matmul_factors(p) or [p])]


def _factor_name(node: ast.expr) -> Optional[str]:
    """``U`` for ``U`` or ``U.T``; None for other factors."""
    if isinstance(node, ast.Attribute) and node.attr == "T":
        node = node.value
    return node.id if isinstance(node, ast.Name) else None


def rotation_projection_lines(source: str) -> List[int]:
    """Lines of ``source`` whose SVD projects onto a rotation: ``U, S, Vt = ...svd(M)``
    with ``S`` unused (``_`` or never read) and ``U``, ``Vt`` (or their ``.T``) factors of
    one matrix product in the same function (module docstring)."""
    tree = ast.parse(source)
    lines = set()
    for scope in [tree] + [n for n in ast.walk(tree)
                           if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]:
        nodes = list(_scope_nodes(scope))
        read = {n.id for n in nodes if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Load)}
        products = [{_factor_name(f) for f in _matmul_factors(n)} for n in nodes]
        for node in nodes:
            if not (isinstance(node, ast.Assign) and _is_svd_call(node.value)
                    and len(node.targets) == 1 and isinstance(node.targets[0], ast.Tuple)
                    and len(node.targets[0].elts) == 3
                    and all(isinstance(e, ast.Name) for e in node.targets[0].elts)):
                continue
            u, s, vt = (e.id for e in node.targets[0].elts)
            if (s == "_" or s not in read) and any({u, vt} <= p for p in products):
                lines.add(node.lineno)
    return sorted(lines)


# ------------------------------------------------------------------ tests
def test_core_file_list_is_sane():
    files = {p.relative_to(ROOT).as_posix() for p in core_files()}
    assert "spgeo/__init__.py" in files and "factors/__init__.py" in files
    assert not any(f.startswith(tuple(d + "/" for d in APPLICATION_DIRS)) for f in files)
    assert not any(f.startswith(("spgeo/factors/", "spgeo/evaluation/")) for f in files)


def test_import_scanner_resolves_relative_and_nested_imports():
    assert module_package(ROOT / "spgeo" / "frontend" / "base.py") == "spgeo.frontend"
    assert module_package(ROOT / "factors" / "photometric.py") == "spgeo.factors"
    assert module_name(ROOT / "factors" / "__init__.py") == "spgeo.factors"
    assert module_name(ROOT / "spgeo" / "io" / "tum.py") == "spgeo.io.tum"
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
    assert [is_cli(m) for _, m in imported_modules("from .cli.args import x\n", "spgeo")] \
        == [True, True]
    assert not is_cli("spgeo.client") and not is_cli("spgeo.clipping")


def test_module_level_imports_skip_functions_and_type_checking():
    source = ("from typing import TYPE_CHECKING\n"
              "from . import b\n"
              "if TYPE_CHECKING:\n    from . import c\nelse:\n    from . import d\n"
              "try:\n    from .e import E\nexcept ImportError:\n    E = None\n"
              "class K:\n    from .f import F\n"
              "def g():\n    from . import h\n"
              "def __getattr__(name):\n    from . import i\n")
    modules = {f"p.{x}" for x in "abcdefghi"} | {"p"}
    assert module_dependencies(source, "p.a", "p", modules) == {"p.b", "p.d", "p.e", "p.f"}
    # lazy: the function body's import counts, a module __getattr__'s does not
    assert module_dependencies(source, "p.a", "p", modules, lazy=True) == {
        "p.b", "p.d", "p.e", "p.f", "p.h"}
    # everywhere: TYPE_CHECKING blocks and a module __getattr__ too
    assert module_dependencies(source, "p.a", "p", modules, everywhere=True) == {
        f"p.{x}" for x in "bcdefhi"}
    # importing p.q.r from p.a also loads the package p.q; ``from p import name`` needs p
    assert module_dependencies("import p.q.r\nfrom p import name\n", "p.a", "p",
                               modules | {"p.q", "p.q.r"}) == {"p.q", "p.q.r", "p"}


def test_package_dirs_come_from_setup():
    assert PACKAGE_OF_DIR == {"spgeo": "spgeo", "factors": "spgeo.factors",
                              "evaluation": "spgeo.evaluation"}
    assert setup_package_dirs("setup(name='x', package_dir={'p.q': 'q'})\n") == {"p.q": "q"}
    # a relative import resolves against the installed package, not the folder tree
    assert module_package(ROOT / "spgeo" / "apps" / "demo.py") == "spgeo.apps"
    assert module_package(ROOT / "evaluation" / "completion" / "void.py") == \
        "spgeo.evaluation.completion"
    assert [m for _, m in imported_modules("from ...apps import vo_run\n",
                                           "spgeo.evaluation.completion")] == [
        "spgeo.apps", "spgeo.apps.vo_run"]


def test_scanners_see_the_apps_importing_evaluation():
    """What spgeo/apps/demo.py and vo_outcome.py did before issue 50: relative and absolute
    imports of spgeo.evaluation inside functions, while evaluation modules import spgeo.apps
    (no two modules importing each other)."""
    demo = ("def _evaluate():\n    from ..evaluation.metrics import primitive_fit_errors\n"
            "def _demo_completion():\n"
            "    from ..completion import complete_depth\n"
            "    from ..evaluation.references.depth_completion import oracle_frontend\n"
            "    from ..evaluation.completion.void import void_metrics\n")
    assert sorted({line for line, m in imported_modules(demo, "spgeo.apps")
                   if is_forbidden(m)}) == [2, 5, 6]
    outcome = ("def ate(self):\n"
               "    from spgeo.evaluation.trajectory import ate_per_frame_and_keyframes\n")
    assert [is_forbidden(m) for _, m in imported_modules(outcome, "spgeo.apps")] == [True, True]
    graph = {"spgeo.apps.demo": {"spgeo.evaluation.metrics", "spgeo.frame"},
             "spgeo.apps.vo_outcome": {"spgeo.evaluation.trajectory"},
             "spgeo.evaluation.metrics": set(), "spgeo.evaluation.trajectory": {"spgeo.trajectory"},
             "spgeo.evaluation.vo.compare": {"spgeo.apps.vo_run"}, "spgeo.apps.vo_run": set(),
             "spgeo.frame": set(), "spgeo.trajectory": set(),
             "spgeo.__main__": {"spgeo.cli"}, "spgeo.cli": {"spgeo.apps.demo", "spgeo.frame"}}
    assert import_cycles(graph) == []                    # no circle between modules ...
    assert layer_circles(graph) == [                     # ... but one between layers
        "spgeo.apps -> spgeo.evaluation (spgeo.apps.demo -> spgeo.evaluation.metrics, "
        "spgeo.apps.vo_outcome -> spgeo.evaluation.trajectory); "
        "spgeo.evaluation -> spgeo.apps (spgeo.evaluation.vo.compare -> spgeo.apps.vo_run)"]
    del graph["spgeo.apps.demo"], graph["spgeo.apps.vo_outcome"]
    assert layer_circles(graph) == []


def test_cycle_finder():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"f"}, "f": {"e"},
             "g": {"a"}}
    assert import_cycles(graph) == [["a", "b", "c", "a"], ["e", "f", "e"]]
    assert import_cycles({"a": {"b"}, "b": set()}) == []


def test_nothing_in_spgeo_imports_evaluation():
    """The core, ``spgeo/apps/`` and ``spgeo/cli/`` (and ``factors/``) never import
    ``spgeo.evaluation``, by any import statement (``spgeo eval``'s ``importlib`` of a
    protocol's name is no import statement)."""
    files = _python_files("spgeo") + _python_files("factors")
    assert ROOT / "spgeo" / "apps" / "demo.py" in files
    offenders = [f"{path.relative_to(ROOT).as_posix()}:{line}"
                 for path in files for line in forbidden_import_lines(path)]
    assert not offenders, ("nothing in spgeo/ (apps and cli included) may import "
                           "spgeo.evaluation (docs/design.md §6.1):\n" + "\n".join(offenders))


def test_nothing_below_the_cli_imports_it():
    cli = ROOT / "spgeo" / "cli"
    files = [p for folder in PACKAGE_OF_DIR for p in _python_files(folder)
             if not p.is_relative_to(cli) and p != ROOT / CLI_ENTRY]
    offenders = [f"{path.relative_to(ROOT).as_posix()}:{line}"
                 for path in files for line in import_lines(path, is_cli)]
    assert not offenders, ("only spgeo/cli/ and spgeo/__main__.py may import spgeo.cli "
                           "(docs/design.md §6.1):\n" + "\n".join(offenders))


@pytest.mark.parametrize("lazy", [False, True], ids=["module-level", "with-lazy-imports"])
def test_no_import_cycles(lazy):
    files = _python_files("spgeo") + _python_files("factors")
    known = {module_name(p) for folder in PACKAGE_OF_DIR for p in _python_files(folder)}
    cycles = import_cycles(import_graph(files, known, lazy))
    assert not cycles, ("import cycles among the modules of spgeo/ and factors/"
                        + (" (imports inside functions counted)" if lazy else "") + ":\n"
                        + "\n".join(" -> ".join(c) for c in cycles))


def test_no_import_circles_anywhere():
    """No two modules of ``spgeo/``, ``factors/`` and ``evaluation/`` import each other,
    directly or round a circle, by any import statement in their source: module level,
    class bodies, function bodies, a module ``__getattr__`` and ``if TYPE_CHECKING:``
    blocks alike (relative imports resolved), so no module re-exports a name of a module
    that imports it (docs/design.md §6.1)."""
    files = [p for folder in PACKAGE_OF_DIR for p in _python_files(folder)]
    known = {module_name(p) for p in files}
    cycles = import_cycles(import_graph(files, known, everywhere=True))
    assert not cycles, ("import circles among the modules of spgeo/, factors/ and evaluation/ "
                        "(every import statement counted):\n"
                        + "\n".join(" -> ".join(c) for c in cycles))


def test_no_import_circle_between_layers():
    """The core, ``spgeo.apps``, ``spgeo.cli`` and ``spgeo.evaluation`` import each other
    without a circle, every import statement counted (docs/design.md §6.1)."""
    files = [p for folder in PACKAGE_OF_DIR for p in _python_files(folder)]
    known = {module_name(p) for p in files}
    graph = import_graph(files, known, everywhere=True)
    assert {layer_of(m) for m in graph} == {"core", *LAYERS}
    circles = layer_circles(graph)
    assert not circles, ("import circles between the layers (core, spgeo.apps, spgeo.cli, "
                         "spgeo.evaluation):\n" + "\n".join(circles))


def test_functions_at_most_60_lines_of_code():
    too_long = [f for folder in ("spgeo", "factors", "evaluation") for path in _python_files(folder)
                for f in long_functions(path)]
    assert not too_long, (f"functions over {MAX_FUNCTION_LINES} lines of code (compiled kernels "
                          f"may say why: a '{LONG_REASON} ...' line in their docstring):\n"
                          + "\n".join(too_long))


MAX_MODULE_LINES = 600
MAX_ODOMETRY_LINES = 375
ODOMETRY_MODULES = ("spgeo/vo/odometry.py", "spgeo/vo/readout.py")
MODE_ATTRIBUTES = {"mode", "in_worker", "schedule"}
MODE_STRINGS = {"live", "inline"}


def test_module_sizes():
    sizes = {p.relative_to(ROOT).as_posix(): len(p.read_text(encoding="utf-8").splitlines())
             for folder in ("spgeo", "factors", "evaluation") for p in _python_files(folder)}
    over = [f"{name}: {n}" for name, n in sorted(sizes.items()) if n > MAX_MODULE_LINES]
    assert not over, f"modules over {MAX_MODULE_LINES} lines:\n" + "\n".join(over)
    assert sizes["spgeo/vo/odometry.py"] <= MAX_ODOMETRY_LINES


def mode_mentions(source: str) -> List[int]:
    """Lines of ``source`` whose code names the mapping mode (module docstring)."""
    tree = ast.parse(source)
    docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                  if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef,
                                       ast.AsyncFunctionDef))
                  and node.body and isinstance(node.body[0], ast.Expr)
                  and isinstance(node.body[0].value, ast.Constant)}
    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr in MODE_ATTRIBUTES:
            lines.append(node.lineno)
        elif (isinstance(node, ast.Constant) and node.value in MODE_STRINGS
              and id(node) not in docstrings):
            lines.append(node.lineno)
    return sorted(lines)


def test_mode_scanner():
    source = ('"""live and inline in a docstring do not count"""\n'
              "a = config.mapping.mode\n"                   # line 2
              "b = cfg.mapping.in_worker or x == 'live'\n"   # line 3, twice
              "c = 'inline'\n"                               # line 4
              "d = config.mapping.lead\n")
    assert mode_mentions(source) == [2, 3, 3, 4]


def test_odometry_names_the_mapping_mode_at_most_twice():
    found = [f"{name}:{line}" for name in ODOMETRY_MODULES
             for line in mode_mentions((ROOT / name).read_text(encoding="utf-8"))]
    assert len(found) <= 2, ("the mapping mode belongs to the mapping port "
                             "(spgeo/vo/mapping_port.py), not the odometry:\n" + "\n".join(found))


def test_key_scanner():
    source = ('"""gtsam.symbol("x", 0) in a docstring does not count"""\n'
              "import gtsam\n"
              "a = gtsam.symbol('x', 0)\n"                                # line 3
              "b = gtsam.Symbol(a).index()\n"                             # line 4
              "from gtsam import symbol\n"                                # line 5
              "from gtsam.symbol_shorthand import X\n"                    # line 6
              "import gtsam.symbol_shorthand as S\n"                      # line 7
              "c = gtsam.Pose3()\nd = keys.symbol_index(a)\n")
    assert key_making_lines(source) == [3, 4, 5, 6, 7]


def test_one_key_scheme():
    files = [p for folder in ("spgeo", "factors") for p in _python_files(folder)
             if p != ROOT / KEY_MODULE]
    offenders = [f"{path.relative_to(ROOT).as_posix()}:{line}" for path in files
                 for line in key_making_lines(path.read_text(encoding="utf-8"))]
    assert (ROOT / KEY_MODULE).exists()
    assert not offenders, (f"gtsam keys are made only in {KEY_MODULE} (one key scheme; "
                           "use its functions):\n" + "\n".join(offenders))


def test_rotation_projection_scanner():
    source = ('"""np.linalg.svd(M) in a docstring does not count"""\n'
              "import numpy as np\n"
              "def rigid(T):\n"
              "    U, _, Vt = np.linalg.svd(T[:3, :3])\n"                       # line 4
              "    R = U @ Vt\n"
              "    if np.linalg.det(R) < 0:\n"
              "        R = U @ np.diag([1.0, 1.0, -1.0]) @ Vt\n"
              "    return R\n"
              "def by_det(R):\n"
              "    U, _, Vt = np.linalg.svd(R)\n"                               # line 10
              "    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt\n"
              "def kabsch(f1, f2):\n"
              "    U, _, Vt = np.linalg.svd(f1.T @ f2)\n"                       # line 13
              "    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])\n"
              "    return Vt.T @ D @ U.T\n"
              "def closest(m):\n"
              "    u, s, vt = svd(m)\n"                                         # line 17
              "    return np.dot(u, vt)\n"
              "def null_vector(A):\n"
              "    _, _, vt = np.linalg.svd(A)\n"
              "    return vt[-1]\n"
              "def umeyama(xd, xs):\n"
              "    U, D, Vt = np.linalg.svd(xd.T @ xs)\n"
              "    R = U @ np.diag([1.0, 1.0, 1.0]) @ Vt\n"
              "    return R, D.sum()\n"
              "def apart(M):\n"
              "    U, _, Vt = np.linalg.svd(M)\n"
              "    def inner(Vt):\n"
              "        return U @ Vt\n"
              "    return U @ M, Vt\n")
    assert rotation_projection_lines(source) == [4, 10, 13, 17]


def test_one_rotation_projection():
    files = [p for folder in ("spgeo", "factors") for p in _python_files(folder)
             if p != ROOT / ROTATION_MODULE]
    offenders = [f"{path.relative_to(ROOT).as_posix()}:{line}" for path in files
                 for line in rotation_projection_lines(path.read_text(encoding="utf-8"))]
    assert rotation_projection_lines((ROOT / ROTATION_MODULE).read_text(encoding="utf-8"))
    assert not offenders, (f"projections onto a rotation by SVD are made only in "
                           f"{ROTATION_MODULE} (use spgeo.geometry.nearest_rotation):\n"
                           + "\n".join(offenders))


TRACKER_MODULE = "spgeo/vo/frame_tracker.py"     # the one tracking decision
TRACK_EXCEPTIONS = {"spgeo/vo/scale_check.py"}   # tracks a keyframe image, not a frame
POLICY_MODULE = "spgeo/vo/keyframe_policy.py"     # the one keyframe policy
MAX_ODOMETRY_FIELDS = 22


def call_lines(source: str, name: str) -> List[int]:
    """Lines of ``source`` that call a function named ``name`` (by name or attribute)."""
    lines = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Call):
            f = node.func
            if (isinstance(f, ast.Name) and f.id == name) or (
                    isinstance(f, ast.Attribute) and f.attr == name):
                lines.append(node.lineno)
    return sorted(lines)


def threshold_reads(source: str, fields: Set[str]) -> List[int]:
    """Lines of ``source`` reading ``<x>.keyframe.<f>`` for ``f`` in ``fields``."""
    return sorted(node.lineno for node in ast.walk(ast.parse(source))
                  if isinstance(node, ast.Attribute) and node.attr in fields
                  and isinstance(node.value, ast.Attribute) and node.value.attr == "keyframe")


def private_reads(source: str) -> List[int]:
    """Lines of ``source`` with an attribute ``_name`` (not a dunder) of anything but
    ``self`` / ``cls``."""
    return sorted(node.lineno for node in ast.walk(ast.parse(source))
                  if isinstance(node, ast.Attribute) and node.attr.startswith("_")
                  and not node.attr.startswith("__")
                  and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")))


def test_decision_scanners():
    source = ("from spgeo.vo.tracking import track_frame\n"
              "tr = track_frame(kf, img, T)\n"                        # line 2
              "tr = tracking.track_frame(kf, img, T)\n"               # line 3
              "ok = cfg.keyframe.max_translation > 1\n"               # line 4
              "no = cfg.tracker.min_valid_fraction\n"
              "x = self._map\n"
              "y = vo._map.latest\n"                                  # line 7
              "z = obj.__class__\n")
    assert call_lines(source, "track_frame") == [2, 3]
    assert threshold_reads(source, {"max_translation", "min_valid_fraction"}) == [4]
    assert private_reads(source) == [7]


def test_one_tracking_decision():
    files = [p for folder in ("spgeo", "factors") for p in _python_files(folder)]
    offenders = [f"{path.relative_to(ROOT).as_posix()}:{line}" for path in files
                 if path.relative_to(ROOT).as_posix() not in TRACK_EXCEPTIONS | {TRACKER_MODULE}
                 for line in call_lines(path.read_text(encoding="utf-8"), "track_frame")]
    assert call_lines((ROOT / TRACKER_MODULE).read_text(encoding="utf-8"), "track_frame")
    assert not offenders, (f"frames are tracked only through {TRACKER_MODULE} "
                           "(FrameTracker.track):\n" + "\n".join(offenders))


def test_one_keyframe_policy():
    from spgeo.vo.config import KeyframeDecisionConfig
    import dataclasses
    fields = {f.name for f in dataclasses.fields(KeyframeDecisionConfig)}
    files = [p for p in _python_files("spgeo") if p != ROOT / POLICY_MODULE]
    offenders = [f"{path.relative_to(ROOT).as_posix()}:{line}" for path in files
                 for line in threshold_reads(path.read_text(encoding="utf-8"), fields)]
    assert not offenders, (f"the keyframe thresholds are read only in {POLICY_MODULE} "
                           "(KeyframePolicy):\n" + "\n".join(offenders))


def test_no_private_reads_across_objects():
    files = [p for folder in ("spgeo", "factors", "evaluation") for p in _python_files(folder)]
    offenders = [f"{path.relative_to(ROOT).as_posix()}:{line}" for path in files
                 for line in private_reads(path.read_text(encoding="utf-8"))]
    assert not offenders, ("private attributes are read from self / cls only (hand an object "
                           "what it needs):\n" + "\n".join(offenders))


def test_odometry_config_has_few_top_level_fields():
    import dataclasses
    from spgeo.vo.config import OdometryConfig
    n = len(dataclasses.fields(OdometryConfig))
    assert n <= MAX_ODOMETRY_FIELDS, f"OdometryConfig has {n} top-level fields"


TRIANGULATION_MODULE = "spgeo/triangulation.py"   # the one triangulator


def triangulator_twins(source: str) -> List[int]:
    """Lines of ``source``: calls of ``triangulatePoints``, and functions named
    ``triangulate*`` that call neither ``triangulate`` nor ``dlt_points``."""
    tree = ast.parse(source)
    lines = call_lines(source, "triangulatePoints")
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and \
                node.name.startswith("triangulate"):
            body = ast.unparse(node)
            if not (call_lines(body, "triangulate") or call_lines(body, "dlt_points")):
                lines.append(node.lineno)
    return sorted(lines)


def test_triangulator_scanner():
    source = ("def triangulate_pair(a, b):\n"                    # line 1: its own DLT
              "    return np.linalg.svd(a)\n"
              "def triangulate_depths(a):\n"                     # an adapter
              "    return triangulate(cam, poses, a)[:, 2]\n"
              "X = cv2.triangulatePoints(P1, P2, x1, x2)\n")     # line 5
    assert triangulator_twins(source) == [1, 5]


def test_one_triangulator():
    files = [p for folder in ("spgeo", "factors") for p in _python_files(folder)
             if p != ROOT / TRIANGULATION_MODULE]
    offenders = [f"{path.relative_to(ROOT).as_posix()}:{line}" for path in files
                 for line in triangulator_twins(path.read_text(encoding="utf-8"))]
    assert not offenders, (f"points are triangulated only by {TRIANGULATION_MODULE}:\n"
                           + "\n".join(offenders))
