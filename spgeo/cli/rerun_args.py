"""``--rerun {spawn | save FILE.rrd | connect [ADDR]}`` for ``spgeo vo|sfm|complete``
(argparse wiring of :class:`spgeo.apps.rerun_logger.RerunLogger`; rerun is imported only
when the option is given)."""
from __future__ import annotations

import argparse
import contextlib

__all__ = ["add_rerun_argument", "open_rerun"]


class _RerunAction(argparse.Action):
    """Parses ``MODE [ARG]`` into a ``RerunLoggerConfig`` (one-line argparse error)."""

    def __call__(self, parser, namespace, values, option_string=None):
        from ..apps.rerun_logger import RerunLoggerConfig

        try:
            setattr(namespace, self.dest, RerunLoggerConfig.from_spec(values))
        except ValueError as exc:
            raise argparse.ArgumentError(self, str(exc)) from None


def add_rerun_argument(parser: argparse.ArgumentParser, what: str) -> None:
    """Add ``--rerun MODE [ARG]`` (dest ``rerun``: a ``RerunLoggerConfig`` or None)."""
    parser.add_argument(
        "--rerun", nargs="+", action=_RerunAction, default=None, metavar=("MODE", "ARG"),
        help=f"show {what} in the rerun viewer (pip install 'spgeo[viz]'): 'spawn' (a local "
             "viewer), 'save FILE.rrd' (open later with `rerun FILE.rrd`) or 'connect [ADDR]' "
             "(a running viewer, e.g. rerun+http://127.0.0.1:9876/proxy)")


def open_rerun(args: argparse.Namespace):
    """Context manager giving a :class:`spgeo.apps.rerun_logger.RerunLogger` for ``args.rerun``
    (closed on exit), or None without the option.  Without rerun installed:
    :class:`~spgeo.validation.InputError` with the install hint (the CLI's exit 2)."""
    from ..validation import InputError

    cfg = getattr(args, "rerun", None)
    if cfg is None:
        return contextlib.nullcontext(None)
    from ..apps.rerun_logger import RerunLogger

    try:
        return RerunLogger(cfg)
    except ImportError as exc:
        raise InputError(f"--rerun: {exc}") from None
