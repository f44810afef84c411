"""``spgeo eval PROTOCOL [ARGS...]``: the evaluation protocols and benchmarks of
:mod:`spgeo.evaluation` that have a ``main(argv)``; ``ARGS`` go unchanged to that
module's ``main``, imported only when run (``spgeo eval PROTOCOL --help`` shows its
own options).

:data:`PROTOCOLS` names the module of each protocol (``vo_synthetic`` ->
``spgeo.evaluation.vo.synthetic``; the names predate the task sub-packages and
stay as they were).  The one-line help is the first sentence of the module's
docstring, read from its source file, so ``spgeo eval --help`` imports no
protocol.
"""
from __future__ import annotations

import argparse
import importlib
import importlib.util
import re
import sys
from pathlib import Path
from typing import Dict, List, Optional

__all__ = ["PROTOCOLS", "protocols", "add_eval_cli", "run_protocol"]

#: ``spgeo eval`` name -> module under :mod:`spgeo.evaluation` with a top-level ``main(argv)``.
PROTOCOLS: Dict[str, str] = {
    # vo/: monocular visual odometry
    "vo_synthetic": "vo.synthetic",
    "vo_frontier": "vo.frontier",
    "vo_compare": "vo.compare",
    "vo_scale_drift": "vo.scale_drift",
    "vo_memory": "vo.memory",
    "vo_long_run": "vo.long_run",
    "vo_mesh": "vo.mesh",
    "vo_camera": "vo.camera",
    "tum_fr1": "vo.tum_fr1",
    # sfm/: few-view structure from motion
    "sfm_real": "sfm.real",
    "sfm_ablation": "sfm.ablation",
    "scannet": "sfm.scannet",
    # completion/: depth completion
    "completion_real": "completion.real",
    "completion_7scenes": "completion.seven_scenes",
    "completion_strata": "completion.strata",
    "void": "completion.void",
    # frontend/: single-frame primitives (segments, normals)
    "bench_segmenters": "frontend.segmenters",
    "manhattan_normals": "frontend.manhattan_normals",
    # references/: methods spgeo is compared with
    "colmap": "references.colmap",
    "colmap_vo": "references.colmap_vo",
    "feature_vo": "references.feature_vo",
    # bench/: speed micro-benchmarks
    "bench_factors": "bench.factors",
    "bench_integration": "bench.integration",
    "bench_vo": "bench.vo",
}

_DOC = re.compile(r'\A\s*(?:#[^\n]*\n\s*)*[rRuU]?("""|\'\'\')(.*?)\1', re.S)
_MAIN = re.compile(r"^def main\(", re.M)


def _evaluation_dir() -> Optional[Path]:
    spec = importlib.util.find_spec("spgeo.evaluation")
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(list(spec.submodule_search_locations)[0])


def _one_line(doc: str) -> str:
    para = " ".join(doc.strip().split("\n\n")[0].split())
    m = re.search(r"\.(\s+[A-Z(]|$)", para)
    line = para[:m.start() + 1] if m else para
    line = re.sub(r":[a-z]+:`~?([^`]*)`", r"\1", line).replace("``", "")
    return line if len(line) <= 100 else line[:97].rstrip() + "..."


def protocols() -> Dict[str, str]:
    """``{protocol name: one-line help}`` of :data:`PROTOCOLS` whose module file
    defines a top-level ``main``, sorted by name (empty if the package is missing)."""
    folder = _evaluation_dir()
    out: Dict[str, str] = {}
    if folder is None:
        return out
    for name in sorted(PROTOCOLS):
        path = folder.joinpath(*PROTOCOLS[name].split(".")).with_suffix(".py")
        if not path.is_file():
            continue
        text = path.read_text(encoding="utf-8", errors="replace")
        if not _MAIN.search(text):
            continue
        m = _DOC.match(text)
        out[name] = _one_line(m.group(2)) if m else ""
    return out


def add_eval_cli(subparsers) -> argparse.ArgumentParser:
    """Register ``spgeo eval`` with one sub-command per protocol; the protocol's
    arguments are not parsed here (see :func:`spgeo.cli.main`)."""
    p = subparsers.add_parser(
        "eval", help="evaluation protocols and benchmarks (spgeo.evaluation)",
        description="Run an evaluation protocol or benchmark of spgeo.evaluation; the "
                    "arguments after PROTOCOL go to it (spgeo eval PROTOCOL --help).")
    sub = p.add_subparsers(dest="protocol", metavar="PROTOCOL")
    sub.required = True
    for name, text in protocols().items():
        sub.add_parser(name, help=text or name, add_help=False)
    return p


def run_protocol(name: str, argv: List[str]) -> int:
    """``main(argv)`` of the protocol's module (``spgeo.evaluation.<PROTOCOLS[name]>``;
    its ``prog`` shows as ``spgeo eval <name>``); the exit code (None counts as 0;
    argparse exits give theirs)."""
    module = importlib.import_module(f"spgeo.evaluation.{PROTOCOLS[name]}")
    saved = sys.argv[0]
    sys.argv[0] = f"spgeo eval {name}"
    try:
        rc = module.main(list(argv))
    except SystemExit as exc:
        if exc.code is None or isinstance(exc.code, int):
            return int(exc.code or 0)
        print(exc.code, file=sys.stderr)
        return 1
    finally:
        sys.argv[0] = saved
    return int(rc or 0)
