"""Dense depth of the VO keyframes and of the few-view SfM's reference depth against
sensor depth (issue 54): AbsRel and delta < 1.25 after one median scale per depth map
(:mod:`spgeo.evaluation.depth_eval`), with ATE / rotation error and run time, to compare
shape models and settings.

    python scripts/dense_depth_probe.py [--vo SPEC ...] [--frontends classical,depth]
        [--sfm SPEC ...] [--refs 0,60,120] [--sfm-frontends classical]
        [--set FIELD=VALUE ...] [--sfm-set FIELD=VALUE ...] [--breakdown] [--oracle]
        [--json OUT]

VO specs: ``7scenes[:A:B]`` (shared 7-Scenes redkitchen frames A:B; only 0:300 exist),
``tum`` (TUM fr1_desk, 9 frames), ``icl`` (ICL-NUIM, 5 wide frames), ``synthetic[:SEED[:N]]``
(rendered room, exact depth, 160x120).  SfM specs: ``7scenes:G`` (triplets ref, ref+G,
ref+2G for each of --refs), ``tum`` (0, 4, 8), ``icl`` (1, 2, 3).  ``--vo none`` /
``--sfm none``: skip that part.  ``--frontends``: the VO front-ends, each a row per
sequence (``depth``: the sensor-depth front-end, the floor row).  ``--set`` applies to the
VO's :class:`~spgeo.apps.vo_run.VORunConfig` (odometry fields without prefix, e.g.
``primitive_model=bent`` or ``window=7``), ``--sfm-set`` to the :class:`~spgeo.sfm.SfMConfig`.
``--sfm-frontends``: ``classical``, ``depth`` (SfM with the sensor-depth front-end's shapes:
its scales are still the views'), ``floor`` (no SfM: the depth front-end's primitives with
scales fitted to the sensor depth, :func:`spgeo.evaluation.dense_depth.sensor_depth_floor`).
``--breakdown``: AbsRel by primitive size, anchor distance and image region;
``--oracle``: the keyframes' AbsRel with perfect per-primitive scales / log-depth planes
(:func:`spgeo.evaluation.depth_eval.oracle_depth_maps`), the headroom.

Defaults: VO on 7scenes:0:300, tum, icl, synthetic:0, synthetic:1 (90 frames) with the
classical and depth front-ends; SfM 7scenes:10 and 7scenes:30 at refs 0,60,120, classical
and floor.  A run that raises is a row with its error.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from typing import Any, Dict, List, Optional, Sequence

DEFAULT_VO = ("7scenes:0:300", "tum", "icl", "synthetic:0", "synthetic:1")
DEFAULT_SFM = ("7scenes:10", "7scenes:30")

COLUMNS = (("kind", "kind", None), ("sequence", "sequence", None), ("front-end", "frontend", None),
           ("maps", "n_maps", 0), ("AbsRel", "abs_rel", 3), ("d<1.25", "delta_1.25", 3),
           ("coverage", "coverage", 2), ("clipped", "clipped", 4),
           ("AbsRel pooled", "abs_rel_pooled", 3),
           ("frames", "frames", 0), ("ATE m", "ate_m", 4), ("rot err deg", "rot_err_deg", 2),
           ("s", "seconds", 1), ("error", "error", None))


def _list(text: str) -> List[str]:
    return [p.strip() for p in text.split(",") if p.strip()]


def _specs(values: Optional[Sequence[str]], default: Sequence[str]) -> List[str]:
    if not values:
        return list(default)
    out = [s for v in values for s in v.split()]
    return [] if out == ["none"] else out


def _cell(v: Any, decimals: Optional[int]) -> str:
    if v is None:
        return "-"
    if decimals is None:
        return str(v)
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    return "nan" if f != f else f"{f:.{decimals}f}"


#: the columns of ``--oracle`` (before ``error``)
ORACLE_COLUMNS = (("oracle scale AbsRel", "oracle_scale_abs_rel", 3),
                  ("oracle bent AbsRel", "oracle_plane_abs_rel", 3))


def table(rows: Sequence[Dict[str, Any]]) -> str:
    """The rows as a Markdown table (:data:`COLUMNS`, and :data:`ORACLE_COLUMNS` when a
    row has them)."""
    cols = COLUMNS
    if any("oracle_scale_abs_rel" in r for r in rows):
        cols = COLUMNS[:-1] + ORACLE_COLUMNS + COLUMNS[-1:]
    lines = ["| " + " | ".join(h for h, _, _ in cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join(_cell(r.get(k), d) for _, k, d in cols) + " |")
    return "\n".join(lines)


def breakdown_lines(row: Dict[str, Any]) -> List[str]:
    """The breakdown of a VO row (per primitive entry, at each map's median scale)."""
    from spgeo.evaluation.depth_eval import ANCHOR_BINS, SIZE_BINS

    b = row.get("breakdown") or {}
    if not b:
        return []
    out = [f"breakdown {row['sequence']} {row['frontend']} (per primitive entry: AbsRel / share)"]
    for key, edges, unit in (("size", SIZE_BINS, "of image"), ("anchor", ANCHOR_BINS,
                                                              "of diagonal")):
        cells = [f"{lo:g}-{hi:g}: {a:.3f} / {s:.2f}" for lo, hi, a, s in
                 zip(edges[:-1], edges[1:], b[key]["abs_rel"], b[key]["share"])]
        out.append(f"  {key} ({unit}): " + ";  ".join(cells))
    reg = b["region"]
    for i in range(3):
        out.append("  region row %d: " % i + "  ".join(
            f"{reg['abs_rel'][3 * i + j]:.3f} ({reg['share'][3 * i + j]:.2f})" for j in range(3)))
    return out


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--vo", nargs="+", default=None, metavar="SPEC",
                    help=f"VO sequences (default {' '.join(DEFAULT_VO)}; 'none': no VO)")
    ap.add_argument("--frontends", default="classical,depth",
                    help="VO front-ends, a row each (default %(default)s)")
    ap.add_argument("--sfm", nargs="+", default=None, metavar="SPEC",
                    help=f"SfM cases (default {' '.join(DEFAULT_SFM)}; 'none': no SfM)")
    ap.add_argument("--refs", default="0,60,120", help="7-Scenes SfM reference frames")
    ap.add_argument("--sfm-frontends", default="classical,floor",
                    help="SfM front-ends (default %(default)s; 'floor': no SfM, the depth "
                         "front-end's primitives with scales fitted to the sensor depth; "
                         "'depth': SfM with the depth front-end's shapes, photometric scales)")
    ap.add_argument("--set", dest="set", nargs="+", action="extend", default=[],
                    metavar="FIELD=VALUE", help="VORunConfig / OdometryConfig overrides")
    ap.add_argument("--sfm-set", dest="sfm_set", nargs="+", action="extend", default=[],
                    metavar="FIELD=VALUE", help="SfMConfig overrides")
    ap.add_argument("--breakdown", action="store_true",
                    help="VO rows: AbsRel by primitive size, anchor distance, image region")
    ap.add_argument("--oracle", action="store_true",
                    help="VO rows: AbsRel of the keyframes' primitives with each one's scale, or "
                         "its log-depth plane (scale + 2 slopes: a perfect bent primitive), "
                         "fitted to the sensor depth: the headroom")
    ap.add_argument("--label", default="", help="a label written into the JSON")
    ap.add_argument("--json", default=None, help="write the rows (and settings) here")
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")

    from spgeo.apps.vo_run import VORunConfig
    from spgeo.configs import apply_overrides
    from spgeo.evaluation.dense_depth import sfm_depth_row, vo_depth_row
    from spgeo.sfm import SfMConfig

    vo_cfg = apply_overrides(VORunConfig(progress=False), list(args.set))
    sfm_cfg = apply_overrides(SfMConfig(), list(args.sfm_set))
    refs = [int(r) for r in _list(args.refs)]
    jobs = [("vo", s, fe) for s in _specs(args.vo, DEFAULT_VO) for fe in _list(args.frontends)]
    jobs += [("sfm", s, fe) for s in _specs(args.sfm, DEFAULT_SFM)
             for fe in _list(args.sfm_frontends)]
    rows: List[Dict[str, Any]] = []
    t0 = time.perf_counter()
    for kind, spec, fe in jobs:
        try:
            if kind == "vo":
                row = vo_depth_row(spec, apply_overrides(vo_cfg, {"frontend": fe}),
                                   breakdown=args.breakdown, oracle=args.oracle)
            else:
                row = sfm_depth_row(spec, refs, fe, sfm_cfg)
        except Exception as exc:        # a failed run is a row, the others go on
            logging.getLogger("dense_depth_probe").exception("%s %s %s failed", kind, spec, fe)
            row = {"kind": kind, "sequence": spec, "frontend": fe,
                   "error": f"{type(exc).__name__}: {exc}"}
        rows.append(row)
        print(table([row]).splitlines()[-1], flush=True)
    print()
    print(table(rows))
    for r in rows:
        for line in breakdown_lines(r):
            print(line)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s; --set {' '.join(args.set) or '-'}; "
          f"--sfm-set {' '.join(args.sfm_set) or '-'}")
    if args.json:
        from spgeo.evaluation.jobs import provenance
        from spgeo.jsonio import json_default

        prov = provenance({"argv": list(sys.argv[1:] if argv is None else argv),
                           "label": args.label})
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"rows": rows, "provenance": prov}, fh, indent=1, default=json_default)
    return 1 if any(r.get("error") for r in rows) else 0


if __name__ == "__main__":
    raise SystemExit(main())
