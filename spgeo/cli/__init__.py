"""The ``spgeo`` command (entry point ``spgeo.cli:main``): argument wiring only;
the work is in the library and in :mod:`spgeo.apps`.

Sub-commands: ``demo``, ``vo``, ``sfm``, ``complete`` (each with ``--config
FILE`` / ``--set FIELD=VALUE``, :mod:`spgeo.cli.config`), ``models`` and
``eval PROTOCOL [ARGS...]``.  Errors print one ``spgeo CMD: error: ...`` line
on stderr and return exit code 2.
"""
from __future__ import annotations

import argparse
import logging
import sys
from typing import List, Optional, Sequence

__all__ = ["main", "build_parser"]

_ERRORS = (ValueError, FileNotFoundError, OSError)


def build_parser() -> argparse.ArgumentParser:
    """The ``spgeo`` parser; each leaf sets ``func(args) -> exit code``."""
    from .complete import add_complete_cli
    from .demo import add_demo_cli
    from .eval import add_eval_cli
    from .models import add_cli as add_models_cli
    from .sfm import add_sfm_cli
    from .vo import add_vo_cli

    ap = argparse.ArgumentParser(prog="spgeo", description="Dense monocular reconstruction "
                                 "with SuperPrimitives")
    ap.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-v, -vv)")
    sub = ap.add_subparsers(dest="command", required=True)
    add_demo_cli(sub)
    add_models_cli(sub)
    add_complete_cli(sub)
    add_sfm_cli(sub)
    add_vo_cli(sub)
    add_eval_cli(sub)
    return ap


def _split_eval(argv: Sequence[str]):
    """``[..., "eval", PROTOCOL, *rest]`` -> (argv up to PROTOCOL, rest); rest is
    None when the command is not ``eval`` with a protocol."""
    for i, tok in enumerate(argv):
        if tok.startswith("-"):
            continue
        if tok == "eval" and i + 1 < len(argv) and not argv[i + 1].startswith("-"):
            return list(argv[:i + 2]), list(argv[i + 2:])
        break
    return list(argv), None


def _setup_logging(verbose: int) -> None:
    level = logging.WARNING - 10 * min(verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")


def main(argv: Optional[List[str]] = None) -> int:
    """Run ``spgeo`` with ``argv`` (default ``sys.argv[1:]``); returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    head, rest = _split_eval(argv)
    args = build_parser().parse_args(head)
    if rest is not None:
        from .eval import run_protocol

        if args.verbose:        # else the protocol's own -v decides
            _setup_logging(args.verbose)
        try:
            return run_protocol(args.protocol, rest)
        except _ERRORS as exc:
            print(f"spgeo eval {args.protocol}: error: {exc}", file=sys.stderr)
            return 2
    _setup_logging(args.verbose)
    try:
        return int(args.func(args) or 0)
    except _ERRORS as exc:
        print(f"spgeo {args.command}: error: {exc}", file=sys.stderr)
        return 2
