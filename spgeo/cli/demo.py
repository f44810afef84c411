"""``spgeo demo``: argument wiring and printed tables of
:func:`spgeo.apps.demo.run_demo`.

    spgeo demo [--out DIR] [--seed N] [--no-sfm] [--no-vo]
               [--config FILE] [--set FIELD=VALUE ...]

``--config`` / ``--set`` set ``DemoConfig`` fields (explicit options override
``--config``; ``--set`` overrides both); the effective config goes to
``DIR/report.json`` under ``"config"``.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..configs import apply_overrides, config_to_dict, resolve_config
from .config_args import add_config_arguments

__all__ = ["add_demo_cli"]


def _default_demo_config():
    from ..apps.demo import DemoConfig

    return DemoConfig()


def _demo_config(args: argparse.Namespace):
    """The effective ``DemoConfig``: defaults < --config < explicit options < --set."""
    from ..apps.demo import DemoConfig

    cfg = resolve_config(DemoConfig(), args.config_file)
    explicit = {}
    if args.out is not None:
        explicit["out_dir"] = args.out
    if args.seed is not None:
        explicit["synthetic_seed"] = args.seed
    if args.no_sfm:
        explicit["sfm"] = False
    if args.no_vo:
        explicit["vo"] = False
    if explicit:
        cfg = apply_overrides(cfg, explicit)
    return resolve_config(cfg, sets=args.set)


def _cmd_demo(args: argparse.Namespace) -> int:
    import dataclasses

    from ..apps.demo import run_demo
    from ..io.outputs import StagedFolder

    cfg = _demo_config(args)
    staged = StagedFolder(cfg.out_dir, "--out", "spgeo demo")   # checked before the run
    with staged:
        res = run_demo(dataclasses.replace(cfg, out_dir=str(staged.path)))
        (staged.path / "report.json").write_text(
            json.dumps({"config": config_to_dict(cfg)}, indent=1), encoding="utf-8")
        staged.commit(described=res.described)
    staged_prefix, target = str(staged.path), str(Path(cfg.out_dir))
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
    for name, path in {**res.files, "report": str(staged.path / "report.json")}.items():
        print(f"wrote {name}: {str(path).replace(staged_prefix, target, 1)}")
    return 0


def add_demo_cli(subparsers) -> argparse.ArgumentParser:
    """Register ``spgeo demo`` on an argparse sub-parser collection."""
    p = subparsers.add_parser("demo", help="run the offline demo on embedded data")
    p.add_argument("--out", default=None, help="output folder (default: spgeo-demo)")
    p.add_argument("--seed", type=int, default=None, help="synthetic scene seed (default 0)")
    p.add_argument("--no-sfm", action="store_true", help="skip the few-view SfM part")
    p.add_argument("--no-vo", action="store_true", help="skip the monocular VO part")
    add_config_arguments(p, "DemoConfig", _default_demo_config)
    p.set_defaults(func=_cmd_demo)
    return p
