"""The ``spgeo`` command (entry point ``spgeo.cli:main``): argument wiring only;
the work is in the library and in :mod:`spgeo.apps`.

Sub-commands: ``demo``, ``vo``, ``sfm``, ``complete`` (each with ``--config
FILE`` / ``--set FIELD=VALUE``, :mod:`spgeo.configs`, :mod:`spgeo.cli.config_args`), ``models`` and
``eval PROTOCOL [ARGS...]``.

Exit codes (one convention for every command, :mod:`spgeo.cli.exit_codes`): :data:`EXIT_OK` 0 (done, result
ok), :data:`EXIT_FAILED` 1 (an unexpected error: one line on stderr, the
traceback with ``-v``), :data:`EXIT_BAD_INPUT` 2 (bad arguments or input files:
one ``spgeo CMD: error: ...`` line on stderr naming the value or file, before any
output is written), :data:`EXIT_FLAGGED` 3 (finished, outputs written, but the
result is flagged: SfM status not ok, VO without a map, a model not cached) and
:data:`EXIT_INTERRUPTED` 130 (Ctrl-C; VO writes the frames processed so far,
marked interrupted).
"""
from __future__ import annotations

import argparse
import logging
import re
import sys
from typing import List, Optional, Sequence

from .exit_codes import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_FLAGGED, EXIT_INTERRUPTED, EXIT_OK

__all__ = ["main", "build_parser", "EXIT_OK", "EXIT_FAILED", "EXIT_BAD_INPUT", "EXIT_FLAGGED",
           "EXIT_INTERRUPTED"]

#: exceptions that mean bad input (InputError is a ValueError; PermissionError,
#: IsADirectoryError and FileNotFoundError are OSErrors)
_ERRORS = (ValueError, OSError, TypeError)

log = logging.getLogger("spgeo.cli")

#: options whose value may start with a minus sign (``fx,fy,cx,cy`` with a negative number)
_SIGNED_VALUE_OPTIONS = ("--intrinsics",)
_NEGATIVE_VALUE = re.compile(r"-\.?\d")


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


def _join_signed_values(argv: Sequence[str]) -> List[str]:
    """``--intrinsics -129.3,...`` -> ``--intrinsics=-129.3,...`` for the options of
    :data:`_SIGNED_VALUE_OPTIONS`: argparse takes a value that starts with ``-`` and is
    not a plain number for another option ("expected one argument"), so the negative
    value would never reach the check that names it.  Tokens after ``--`` are left as they are."""
    out: List[str] = []
    i = 0
    while i < len(argv):
        tok = argv[i]
        if tok == "--":
            return out + list(argv[i:])
        if (tok in _SIGNED_VALUE_OPTIONS and i + 1 < len(argv)
                and _NEGATIVE_VALUE.match(argv[i + 1])):
            out.append(f"{tok}={argv[i + 1]}")
            i += 2
        else:
            out.append(tok)
            i += 1
    return out


def _setup_logging(verbose: int) -> None:
    """Root logging at WARNING (INFO with -v, DEBUG with -v -v), one line per
    record; Python warnings (e.g. numpy's) become log records of ``py.warnings``."""
    level = logging.WARNING - 10 * min(verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    logging.captureWarnings(True)


def _guarded(name: str, run) -> int:
    """``run()``'s exit code, every exception mapped to one stderr line and the
    module docstring's exit codes (tracebacks only at DEBUG, ``-v -v``)."""
    try:
        return int(run() or 0)
    except KeyboardInterrupt:
        print(f"spgeo {name}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except MemoryError as exc:
        print(f"spgeo {name}: error: out of memory{f' ({exc})' if str(exc) else ''}: "
              "reduce the resolution or the number of frames", file=sys.stderr)
        return EXIT_BAD_INPUT
    except _ERRORS as exc:
        log.debug("traceback", exc_info=True)
        print(f"spgeo {name}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as exc:  # noqa: BLE001 - the CLI never shows a bare traceback
        log.debug("traceback", exc_info=True)
        print(f"spgeo {name}: error: unexpected {type(exc).__name__}: {exc} "
              "(run with -v -v for the traceback)", file=sys.stderr)
        return EXIT_FAILED


def main(argv: Optional[List[str]] = None) -> int:
    """Run ``spgeo`` with ``argv`` (default ``sys.argv[1:]``); returns the exit code
    (module docstring)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    head, rest = _split_eval(argv)
    args = build_parser().parse_args(_join_signed_values(head))
    if rest is not None:
        from .eval import run_protocol

        if args.verbose:        # else the protocol's own -v decides
            _setup_logging(args.verbose)
        return _guarded(f"eval {args.protocol}", lambda: run_protocol(args.protocol, rest))
    _setup_logging(args.verbose)
    return _guarded(args.command, lambda: args.func(args))
