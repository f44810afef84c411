"""``spgeo models list|fetch|path``: the model cache of :mod:`spgeo.models`
from the command line.  Errors go to stderr with the exit codes of
:mod:`spgeo.cli.exit_codes` (2: unknown name, failed or unverified download;
3: ``path`` of a model that is not in the cache)."""
from __future__ import annotations

import argparse
import sys

from .. import models
from .exit_codes import EXIT_BAD_INPUT, EXIT_FLAGGED, EXIT_OK

__all__ = ["add_cli"]


def _cli_list(args: argparse.Namespace) -> int:
    print(f"model directory: {models.model_dir()}")
    for entry, path, present in models.list_models():
        size = f"{entry.size / 1e6:.0f} MB" if entry.size else "? MB"
        sha = "sha256" if entry.sha256 else "unverified"
        print(f"{'*' if present else ' '} {entry.name:28s} {entry.kind:12s} {size:>8s}  "
              f"{sha:10s} {entry.licence:12s} {entry.preset}")
    print("(* = present)")
    return 0


def _cli_fetch(args: argparse.Namespace) -> int:
    try:
        path = models.fetch_model(args.name, force=args.force,
                                  allow_unverified=args.allow_unverified,
                                  progress=not args.no_progress)
    except (KeyError, ValueError, models.ModelDownloadError) as exc:
        print(f"spgeo models fetch: error: {exc.args[0] if exc.args else exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    print(path)
    return EXIT_OK


def _cli_path(args: argparse.Namespace) -> int:
    try:
        path, present = models.model_path(args.name)
    except KeyError as exc:
        print(f"spgeo models path: error: {exc.args[0]}", file=sys.stderr)
        return EXIT_BAD_INPUT
    print(path if present else f"{path} (missing)")
    return EXIT_OK if present else EXIT_FLAGGED


def add_cli(subparsers) -> argparse.ArgumentParser:
    """Add the ``models`` sub-command (``list``, ``fetch NAME``, ``path NAME``).

    ``subparsers`` is the object returned by ``ArgumentParser.add_subparsers()``;
    every leaf sets ``func`` so the caller runs ``args.func(args)`` (returns an
    exit code).
    """
    parser = subparsers.add_parser("models", help="list, fetch and locate ONNX models",
                                   description="Model cache in $SPGEO_MODEL_DIR (or the user "
                                               "cache directory).")
    sub = parser.add_subparsers(dest="models_command", metavar="{list,fetch,path}")
    sub.required = True
    p_list = sub.add_parser("list", help="known models and whether they are cached")
    p_list.set_defaults(func=_cli_list)
    p_fetch = sub.add_parser("fetch", help="download a model into the cache")
    p_fetch.add_argument("name", help="registry name (see `models list`)")
    p_fetch.add_argument("--force", action="store_true", help="download again")
    p_fetch.add_argument("--allow-unverified", action="store_true",
                         help="accept a model without a published sha256")
    p_fetch.add_argument("--no-progress", action="store_true", help="no progress bar")
    p_fetch.set_defaults(func=_cli_fetch)
    p_path = sub.add_parser("path", help="print where a model is (exit 3 if not cached)")
    p_path.add_argument("name")
    p_path.set_defaults(func=_cli_path)
    return parser
