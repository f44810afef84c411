"""``spgeo complete``: argument wiring for zero-shot depth completion
(:func:`spgeo.completion.complete_depth`); the work is in the library.

    spgeo complete --rgb IMG --sparse SPARSE --intrinsics fx,fy,cx,cy --out DEPTH.png
                   [--frontend classical|manhattan|onnx|onnx-depth] [--method median|joint]
                   [--depth-model NAME|PATH]
                   [--config FILE] [--set FIELD=VALUE ...]
                   [--rerun spawn | save FILE.rrd | connect [ADDR]]

``SPARSE`` is a 16-bit PNG in millimetres (0 = missing) or a ``.npy`` array in
metres (0 / NaN = missing); the output is a 16-bit PNG in millimetres.
``--config`` / ``--set`` set ``CompletionConfig`` fields (``--method``
overrides ``--config``; ``--set`` overrides both).  ``--depth-model`` names a
metric-depth network (registry name, or an ``.onnx`` path read with the
``fastdepth`` preset) whose depth, aligned to the sparse points, is a
candidate of the held-out choice (``CompletionConfig.choose``).
"""
from __future__ import annotations

import argparse

from ..frontend import MONOCULAR_FRONTENDS
from ..validation import InputError
from ..apps.args import parse_intrinsics
from ..configs import apply_overrides, resolve_config
from .config_args import add_config_arguments
from .rerun_args import add_rerun_argument, open_rerun

__all__ = ["add_complete_cli"]


def _completion_config(args: argparse.Namespace):
    """The effective ``CompletionConfig``: defaults < --config < --method < --set."""
    from ..completion import CompletionConfig

    cfg = resolve_config(CompletionConfig(), args.config_file)
    if args.method is not None:
        cfg = apply_overrides(cfg, {"method": args.method})
    return resolve_config(cfg, sets=args.set)


def _cmd_complete(args: argparse.Namespace) -> int:
    from ..camera import PinholeCamera
    from ..completion import complete_depth
    from ..images import load_image
    from ..io.depth_files import read_sparse_depth, write_depth_png_mm
    from ..io.outputs import prepare_output_file

    if not args.out.lower().endswith(".png"):
        raise InputError(f"--out must be a .png file, got {args.out!r}")
    prepare_output_file(args.out, "--out")      # before the work, not after it
    cfg = _completion_config(args)
    image = load_image(args.rgb)
    fx, fy, cx, cy = parse_intrinsics(args.intrinsics)
    cam = PinholeCamera(fx, fy, cx, cy, image.shape[1], image.shape[0])
    sparse = read_sparse_depth(args.sparse)
    res = complete_depth(image, sparse, cam, args.frontend, cfg, depth_model=args.depth_model)
    with open_rerun(args) as viewer:
        if viewer is not None:
            viewer.log_completion(image, cam, res, sparse)
    write_depth_png_mm(args.out, res.depth)
    print(res.summary())
    print(f"wrote {args.out} (16-bit PNG, millimetres)")
    return 0


def add_complete_cli(subparsers) -> argparse.ArgumentParser:
    """Register ``spgeo complete`` on an argparse sub-parser collection."""
    from ..completion import CompletionConfig

    p = subparsers.add_parser(
        "complete", help="zero-shot depth completion: image + sparse depth -> dense depth",
        description="Dense metric depth from one RGB image and sparse metric depth with "
                    "SuperPrimitives (the sparse depth is not given to the front-end).")
    p.add_argument("--rgb", required=True, help="input colour image")
    p.add_argument("--sparse", required=True,
                   help="sparse depth: 16-bit PNG in mm (0 = missing) or .npy in metres")
    p.add_argument("--intrinsics", required=True, help="fx,fy,cx,cy in pixels of --rgb")
    p.add_argument("--out", required=True, help="output depth, 16-bit PNG in millimetres")
    p.add_argument("--frontend", default="classical", choices=MONOCULAR_FRONTENDS,
                   help="primitive front-end (default classical; onnx and onnx-depth need "
                        "'spgeo models fetch')")
    p.add_argument("--method", default=None, choices=("median", "joint"),
                   help="per-primitive scale: 'median' (robust median) or 'joint' (joint "
                        "GTSAM solve); without it CompletionConfig.method decides (default "
                        f"{CompletionConfig.method!r}; --config / --set may change it)")
    p.add_argument("--depth-model", default=None, metavar="NAME|PATH",
                   help="metric-depth network for the held-out choice: a name from "
                        "'spgeo models list' / 'spgeo models register', or an .onnx path "
                        "(preset fastdepth)")
    add_rerun_argument(p, "the image, sparse and completed depth, primitives and cloud")
    add_config_arguments(p, "CompletionConfig", CompletionConfig)
    p.set_defaults(func=_cmd_complete)
    return p
