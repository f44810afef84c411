"""The one pattern every ``spgeo eval`` protocol follows (after evo's ``main_ape``).

A protocol module has

* ``build_parser() -> argparse.ArgumentParser`` (made with :func:`protocol_parser`,
  which adds the shared ``--dataset KIND PATH`` / ``--frames`` and ``-v``);
* a function that takes arrays / configs and returns a result object with its table
  (``result.table() -> str``, Markdown), importable without the CLI;
* ``run(args) -> int``: opens the inputs (:func:`open_sequence` for a data set),
  calls that function, prints the table and writes the outputs;
* ``main(argv=None) -> int``: ``return run_protocol(build_parser(), run, argv, NAME)``.

:func:`run_protocol` is the shared opening and closing: parse, set up logging, run,
and turn a bad input (``ValueError``, ``TypeError``, ``OSError``) into one line on
stderr and exit code 2 instead of a traceback.
"""
from __future__ import annotations

import argparse
import logging
import sys
from typing import Callable, Optional, Sequence

from spgeo.apps.args import add_dataset_arguments, add_verbose_argument, setup_logging

__all__ = ["protocol_parser", "open_sequence", "run_protocol", "BAD_INPUT", "protocol_argv",
           "add_vo_arguments", "run_vo_dataset", "write_json"]

log = logging.getLogger(__name__)

#: the exceptions that mean "bad input" (exit code 2 with a message, no traceback)
BAD_INPUT = (ValueError, TypeError, OSError)


def protocol_parser(prog: Optional[str], description: str, dataset: bool = True,
                    frames_help: Optional[str] = None,
                    verbose: bool = True) -> argparse.ArgumentParser:
    """An ``ArgumentParser`` for ``spgeo eval``'s protocol ``prog`` with the shared
    arguments: ``--dataset KIND PATH`` and ``--frames`` (``dataset``; ``frames_help``
    replaces the default help text) and ``-v`` / ``--verbose`` (``verbose``).  ``prog``
    None: argparse's default (``spgeo eval NAME`` when run by ``spgeo eval``)."""
    parser = argparse.ArgumentParser(prog=prog, description=description,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    if dataset:
        if frames_help is None:
            add_dataset_arguments(parser)
        else:
            add_dataset_arguments(parser, frames_help=frames_help)
    if verbose:
        add_verbose_argument(parser)
    return parser


def open_sequence(args: argparse.Namespace, load_depth: Optional[bool] = False, **kwargs):
    """The data set of ``args.dataset`` / ``args.frames``
    (:func:`spgeo.datasets.open_dataset`; ``kwargs`` go to it).  ``load_depth``
    None: the reader's own default (sensor depth where the kind has it).

    Raises:
        ValueError / OSError: unknown kind, missing folder, bad frame range (the
            reader's message names the path or value)."""
    from spgeo.datasets import open_dataset

    kind, path = args.dataset
    if load_depth is None:
        return open_dataset(kind, path, frames=args.frames, **kwargs)
    return open_dataset(kind, path, frames=args.frames, load_depth=load_depth, **kwargs)


def run_protocol(parser: argparse.ArgumentParser,
                 run: Callable[[argparse.Namespace], int],
                 argv: Optional[Sequence[str]] = None, name: Optional[str] = None) -> int:
    """Parse ``argv`` with ``parser``, set up logging (``-v``) and return ``run(args)``;
    a :data:`BAD_INPUT` exception becomes ``"NAME: error: MESSAGE"`` on stderr and
    exit code 2.  ``name`` defaults to the parser's ``prog``."""
    args = parser.parse_args(argv)
    setup_logging(getattr(args, "verbose", False))
    try:
        return int(run(args))
    except BAD_INPUT as exc:
        print(f"{name or parser.prog}: error: {exc}", file=sys.stderr)
        return 2


def protocol_argv(argv: Optional[Sequence[str]] = None) -> list:
    """``argv`` as a list; ``sys.argv[1:]`` when None (what ``argparse`` would parse).
    For the protocols that look at their arguments before parsing them (a child
    process mode) or record them (provenance)."""
    return list(sys.argv[1:] if argv is None else argv)


def add_vo_arguments(parser: argparse.ArgumentParser) -> None:
    """``--frontend`` (default ``classical``) and ``--set FIELD=VALUE ...``
    (:class:`~spgeo.vo.OdometryConfig` overrides) of a protocol that runs the VO on
    ``--dataset`` (:func:`run_vo_dataset`)."""
    parser.add_argument("--frontend", default="classical")
    parser.add_argument("--set", nargs="+", default=[], metavar="FIELD=VALUE",
                        help="OdometryConfig overrides (Python literals)")


def run_vo_dataset(args: argparse.Namespace):
    """The :class:`spgeo.apps.vo_run.VORun` of ``args.dataset`` / ``args.frames``
    (:func:`spgeo.apps.vo_run.run_dataset`, no progress bar) with ``args.frontend``
    and the ``args.set`` overrides (:func:`add_vo_arguments`).

    Raises:
        ValueError / TypeError / OSError: a bad override, front-end or data set."""
    from spgeo.apps.vo_run import VORunConfig, run_dataset
    from spgeo.configs import apply_overrides, nest, parse_assignments

    kind, path = args.dataset
    over = nest(parse_assignments(args.set, strict=True))
    cfg = apply_overrides(VORunConfig(frontend=args.frontend, progress=False),
                          {"odometry": over} if over else {})
    return run_dataset(kind, path, args.frames, cfg)


def write_json(path, payload, indent: int = 2) -> None:
    """Write ``payload`` to ``path`` as UTF-8 JSON (``indent``; numpy values through
    :func:`spgeo.jsonio.json_default`), atomically
    (:func:`spgeo.io.outputs.write_bytes_atomic`: a reader never sees half a file)."""
    import json

    from spgeo.io.outputs import write_bytes_atomic
    from spgeo.jsonio import json_default

    text = json.dumps(payload, indent=indent, default=json_default)
    write_bytes_atomic(path, text.encode("utf-8"), "JSON output")
