"""``spgeo models list|fetch|path|register``: the model cache of :mod:`spgeo.models`
from the command line.  Errors go to stderr (one line) with the exit codes of
:mod:`spgeo.cli.exit_codes` (2: unknown name, failed or unverified download, a
user model that cannot be registered or whose file changed; 3: ``path`` of a
model that is not in the cache)."""
from __future__ import annotations

import argparse
import sys

from .. import models
from .exit_codes import EXIT_BAD_INPUT, EXIT_FLAGGED, EXIT_OK

__all__ = ["add_cli"]


def _error(command: str, exc: BaseException) -> int:
    """Print ``exc`` as one line on stderr; return :data:`EXIT_BAD_INPUT`."""
    text = str(exc.args[0]) if exc.args else str(exc)
    print(f"spgeo models {command}: error: {' '.join(text.split())}", file=sys.stderr)
    return EXIT_BAD_INPUT


def _cli_list(args: argparse.Namespace) -> int:
    try:
        listing = models.list_models()
    except ValueError as exc:  # an unreadable registry.json
        return _error("list", exc)
    print(f"model directory: {models.model_dir()}")
    for entry, path, present in listing:
        size = f"{entry.size / 1e6:.0f} MB" if entry.size else "? MB"
        sha = "sha256" if entry.sha256 else "unverified"
        user = f"  user: {path}" if entry.local_path else ""
        print(f"{'*' if present else ' '} {entry.name:28s} {entry.kind:12s} {size:>8s}  "
              f"{sha:10s} {entry.licence:12s} {entry.preset}{user}")
    print("(* = present; user = registered with `spgeo models register`)")
    return 0


def _cli_fetch(args: argparse.Namespace) -> int:
    try:
        path = models.fetch_model(args.name, force=args.force,
                                  allow_unverified=args.allow_unverified,
                                  progress=not args.no_progress)
    except (KeyError, ValueError, FileNotFoundError, models.ModelDownloadError) as exc:
        return _error("fetch", exc)
    print(path)
    return EXIT_OK


def _cli_path(args: argparse.Namespace) -> int:
    try:
        path, present = models.model_path(args.name)
    except (KeyError, ValueError) as exc:
        return _error("path", exc)
    print(path if present else f"{path} (missing)")
    return EXIT_OK if present else EXIT_FLAGGED


def _preset_names(kind: str):
    """The config presets of a user-model kind (front-end import deferred to the call)."""
    if kind == "depth":
        from ..frontend.onnx_depth import DEPTH_PRESETS

        return DEPTH_PRESETS
    from ..frontend.onnx_normals import NORMAL_PRESETS

    return NORMAL_PRESETS


def _cli_register(args: argparse.Namespace) -> int:
    presets = _preset_names(args.kind)
    if args.preset is not None and args.preset not in presets:
        return _error("register", ValueError(f"unknown {args.kind} preset {args.preset!r}; "
                                             f"known: {sorted(presets)}"))
    try:
        entry = models.register_model(args.name, args.path, kind=args.kind, preset=args.preset,
                                      licence=args.licence, notes=args.notes)
    except (ValueError, FileNotFoundError) as exc:
        return _error("register", exc)
    print(f"{entry.name}: {entry.local_path} ({entry.kind}, preset {entry.preset}, "
          f"sha256 {entry.sha256})")
    return EXIT_OK


def add_cli(subparsers) -> argparse.ArgumentParser:
    """Add the ``models`` sub-command (``list``, ``fetch NAME``, ``path NAME``,
    ``register NAME PATH [--kind depth|normals] [--preset PRESET]``).

    ``subparsers`` is the object returned by ``ArgumentParser.add_subparsers()``;
    every leaf sets ``func`` so the caller runs ``args.func(args)`` (returns an
    exit code).
    """
    parser = subparsers.add_parser("models", help="list, fetch and locate ONNX models",
                                   description="Model cache in $SPGEO_MODEL_DIR (or the user "
                                               "cache directory).")
    sub = parser.add_subparsers(dest="models_command", metavar="{list,fetch,path,register}")
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
    p_reg = sub.add_parser(
        "register", help="record a local model file under a name (file used in place)",
        description="Record a local ONNX file as a user model in <model dir>/registry.json "
                    "(sha256 stored and re-checked on use), usable by NAME wherever a "
                    "model name is accepted.  Built-in names cannot be taken.")
    p_reg.add_argument("name", help="new model name (letters, digits, ._+-)")
    p_reg.add_argument("path", help="the .onnx file")
    p_reg.add_argument("--kind", choices=models.USER_KINDS, default="depth",
                       help="model kind (default depth)")
    p_reg.add_argument("--preset", default=None,
                       help="config preset (e.g. fastdepth for a FastDepth export; default "
                            "generic-depth-518 / generic-480x640 by kind)")
    p_reg.add_argument("--licence", default="unknown", help="licence of the weights")
    p_reg.add_argument("--notes", default="", help="free text kept with the record")
    p_reg.set_defaults(func=_cli_register)
    return parser
