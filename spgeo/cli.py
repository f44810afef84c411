"""The ``spgeo`` command: argument wiring only; the work is in the library."""
from __future__ import annotations

import argparse
import logging
import sys
from typing import List, Optional

__all__ = ["main", "build_parser"]


def _cmd_demo(args: argparse.Namespace) -> int:
    from .demo import DemoConfig, run_demo

    res = run_demo(DemoConfig(out_dir=args.out, synthetic_seed=args.seed, sfm=not args.no_sfm,
                              vo=not args.no_vo))
    print("== SuperPrimitives: shape accuracy")
    print(res.table())
    print("median rel. error: depth after fitting one scale per primitive to ground truth "
          "(synthetic: rendered depth; TUM: Kinect depth)")
    if res.sfm_rows:
        print("\n== Few-view SfM (reference + 2 unposed views), rotation error vs ground truth")
        print(res.sfm_table())
        print("depth err: median relative error of the reference depth after median scaling; "
              "'depth' front-end = normals from depth (oracle)")
    for title, table in res.extra_tables.items():
        print(f"\n== {title}")
        print(table)
    for name, path in res.files.items():
        print(f"wrote {name}: {path}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="spgeo", description="Dense monocular reconstruction "
                                 "with SuperPrimitives")
    ap.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-v, -vv)")
    sub = ap.add_subparsers(dest="command", required=True)
    p = sub.add_parser("demo", help="run the offline demo on embedded data")
    p.add_argument("--out", default="spgeo-demo", help="output folder (default: spgeo-demo)")
    p.add_argument("--seed", type=int, default=0, help="synthetic scene seed (default 0)")
    p.add_argument("--no-sfm", action="store_true", help="skip the few-view SfM part")
    p.add_argument("--no-vo", action="store_true", help="skip the monocular VO part")
    p.set_defaults(func=_cmd_demo)
    from .models import add_cli as add_models_cli

    add_models_cli(sub)
    from .cli_complete import add_complete_cli  # spgeo complete (depth completion)

    add_complete_cli(sub)
    from .cli_sfm import add_sfm_cli  # spgeo sfm (few-view SfM)

    add_sfm_cli(sub)
    from .cli_vo import add_vo_cli  # spgeo vo (visual odometry)

    add_vo_cli(sub)
    return ap


def main(argv: Optional[List[str]] = None) -> int:
    args = build_parser().parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError, OSError) as exc:
        print(f"spgeo {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
