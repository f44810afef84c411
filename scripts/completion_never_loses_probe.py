"""Probe of issue 54's completion goal: a choice that never loses to linear
interpolation, scored offline (the slope model it also scored, ``shape_model="slope"``,
lived in commits ed4d51a-0a36718 and was removed: it lost to the plane model,
docs/results.md).

For every frame of 7-Scenes (frames 0:300:60), TUM fr1_desk, ICL-NUIM and four
synthetic views (:mod:`spgeo.synthetic`, 320x240, 1 % depth noise) and every
sparse regime (150 points: ``corners`` (strongest FAST corners, clustered),
``grid``, ``uniform``, ``tracks`` on the consecutive real sets), the classical
front-end runs once and these candidates are fitted on all points and without
each held-out fold (:func:`spgeo.completion.choose.fold_ids`, the defaults):
``primitives`` (the default, graph / plane), ``prim_scale`` (graph / scale),
``linear``,
``ip_basic`` and FastDepth aligned by the interpolated ratio (``net:interp``).
The cache (dense maps on every second pixel with reference depth, held-out
residuals) is then scored by choice rules (:func:`rule_mae`), each as MAE over
linear interpolation's on the same pixels (< 1: better).

Run (the cache is written to ``--cache`` and reused)::

    python scripts/completion_never_loses_probe.py \
        --depth-model ../shared/models/fastdepth/fastdepth_nyu_224.onnx
"""
from __future__ import annotations

import argparse
import logging
import pickle
from dataclasses import replace
from multiprocessing import Pool
from pathlib import Path
from typing import Dict, List, Sequence, Tuple

import numpy as np

log = logging.getLogger("completion_never_loses_probe")

SETS = {"tum": None, "synthetic": None, "7scenes": "0:300:60", "icl": None}
REGIMES = ("corners", "tracks", "uniform", "grid")
N_SYNTHETIC = 4


def _candidates(image, prims, cam, labels, net, config):
    from spgeo.completion.complete import _working_image, candidate_fits

    work = _working_image(image, prims)
    fits = candidate_fits(image, prims, cam, config, work, labels, net)
    out = {"primitives": fits["primitives"],
           "linear": fits["linear"], "ip_basic": fits["ip_basic"]}
    if net is not None:
        out["net:interp"] = fits["network:interp"]
    return out


def _frame_record(name, image, cam, gt, sparse, fe, model, config) -> dict:
    import cv2

    from spgeo.completion.choose import fold_ids, heldout_log_residuals, region_labels
    from spgeo.completion.complete import _working_image, candidate_fits
    from spgeo.completion.network import network_depth

    prims = fe.primify(image, cam, None)
    labels = cv2.resize(prims.label_image(), cam.size, interpolation=cv2.INTER_NEAREST)
    v, u = np.nonzero(sparse > 0)
    uv, sd = np.stack([u, v], 1).astype(np.int64), sparse[v, u]
    net = network_depth(model, image) if model is not None else None
    cands = _candidates(image, prims, cam, labels, net, config)
    scale = candidate_fits(image, prims, cam, replace(config, shape_model="scale"),
                           _working_image(image, prims), labels)["primitives"]
    folds = fold_ids(uv, gt.shape, 5, 2.0, 0)
    regions, cell = region_labels(labels, (4, 3))
    ok = (gt > 0.2) & (gt < 5.0) if name != "synthetic" else gt > 0
    sub = np.zeros_like(ok)
    sub[::2, ::2] = ok[::2, ::2]
    return {"frame": name, "names": list(cands), "uv": uv, "folds": folds, "cell": cell,
            "point_region": regions[v, u], "gt": gt[sub], "region": regions[sub],
            "maps": {c: fit(uv, sd)[sub].astype(np.float32)
                     for c, fit in {**cands, "prim_scale": scale}.items()},
            "held": heldout_log_residuals(cands, uv, sd, folds)}


def _synthetic_frames(regime: str):
    from spgeo import synthetic
    from spgeo.completion.sparse_points import keypoint_sparse_depth, uniform_sparse_depth

    cam = synthetic.default_camera(320, 240)
    for seed in range(N_SYNTHETIC):
        scene = synthetic.SyntheticScene.generate(seed=seed)
        view = scene.render(cam, synthetic.make_trajectory(1, seed=seed)[0])
        gt = np.nan_to_num(view.depth)
        if regime == "uniform":
            sp = uniform_sparse_depth(gt, 150, rel_noise=0.01, seed=seed)
        else:
            sp = keypoint_sparse_depth(view.rgb, gt, 150, rel_noise=0.01, seed=seed,
                                       spread=regime == "grid")
        yield view.rgb, cam, gt, sp


def _job(args: Tuple[str, str, str]) -> Tuple[Tuple[str, str], List[dict]]:
    from spgeo.completion import CompletionConfig, working_size_for
    from spgeo.evaluation.completion.real import open_sample, sparse_frames
    from spgeo.frontend import FrontEndConfig, make_frontend, metric_depth_from_cache

    name, regime, model_path = args
    model, config = metric_depth_from_cache(model_path), CompletionConfig()
    if name == "synthetic":
        fe = make_frontend("classical", FrontEndConfig())
        rows = [_frame_record(name, im, cam, gt, sp, fe, model, config)
                for im, cam, gt, sp in _synthetic_frames(regime)]
    else:
        ds = open_sample(name, None, SETS[name])
        seq = open_sample(name, None, "0:") if regime == "tracks" else None
        fe = make_frontend("classical",
                           FrontEndConfig(working_size=working_size_for(ds.camera, 320)))
        rows = [_frame_record(name, f.image, f.camera, gt, sp, fe, model, config)
                for f, gt, sp in sparse_frames(ds, 150, 0, name, False, regime, seq)]
    log.info("%s %s: %d frames", name, regime, len(rows))
    return (name, regime), rows


# ----------------------------------------------------------------- the rules
def _mae(r: dict, cands: Sequence[str], weights: np.ndarray) -> float:
    """MAE (mm) of the blend ``weights`` ((C,) or (Q, C) per pixel) of ``cands``."""
    logm = np.stack([np.log(r["maps"][c].astype(np.float64)) for c in cands], 1)
    pred = np.exp((np.broadcast_to(weights, logm.shape) * logm).sum(1))
    return 1e3 * float(np.mean(np.abs(pred - r["gt"])))


def _scores(r, cands, step=0.25, prior=10.0):
    from spgeo.completion.choose import _worst_filled, blend_weights, region_scores

    res = _worst_filled(r["held"][[r["names"].index(c) for c in cands]])
    w = blend_weights(len(cands), step)
    return w, region_scores(np.abs(w @ res), r["point_region"], r["cell"], prior)


def rule_weights(r: dict, cands: Sequence[str], rule: str) -> np.ndarray:
    """(R, C) blend per region of ``rule``: ``blend`` (before issue 54: the blend
    of the lowest shrunk held-out score), ``margin<m>`` (the library's
    :attr:`~spgeo.completion.choose.ChooseConfig.margin`: each blend's score
    times ``1 + m`` times its weight off linear), ``additive<m>`` (plus ``m``
    times linear's score per unit of weight off linear), ``gate<m>`` (plus ``m``
    times linear's score for any blend off linear), ``lcb<z>`` (plus ``z``
    standard errors of the blend's held-out gain over linear), ``linear``."""
    w, sc = _scores(r, cands)
    lin = np.eye(len(cands))[list(cands).index("linear")]
    if rule == "linear":
        return np.repeat(lin[None], sc.shape[1], 0)
    if rule.startswith("margin"):      # the library's rule (ChooseConfig.margin)
        from spgeo.completion.choose import ChooseConfig, _with_margin

        sc = _with_margin(sc, w, tuple(cands), ChooseConfig(margin=float(rule[6:])))
    if rule.startswith("additive"):    # margin times linear's score per unit off linear
        f = list(cands).index("linear")
        pure = int(np.flatnonzero(w[:, f] == 1.0)[0])
        sc = sc + float(rule[8:]) * (1.0 - w[:, f])[:, None] * sc[pure][None, :]
    if rule.startswith("gate"):
        f = list(cands).index("linear")
        pure = int(np.flatnonzero(w[:, f] == 1.0)[0])
        sc = sc + float(rule[4:]) * (w[:, f] < 1.0)[:, None] * sc[pure][None, :]
    if rule.startswith("lcb"):
        sc = sc + _lcb_penalty(r, cands, w, float(rule[3:]))
    return w[np.argmin(sc, 0)]


def _lcb_penalty(r, cands, w, z, prior=10.0):
    """(K, R) ``z`` standard errors of each blend's held-out gain over linear per
    region: ``z * sd_k / sqrt(n_r + prior)``, ``sd_k`` the image's standard
    deviation of ``|e_k| - |e_linear|`` over the points, ``n_r`` the region's points."""
    from spgeo.completion.choose import _worst_filled

    res = _worst_filled(r["held"][[r["names"].index(c) for c in cands]])
    lin = list(cands).index("linear")
    delta = np.abs(w @ res) - np.abs(res[lin])[None]
    sd = delta.std(1)
    n = np.bincount(r["point_region"], minlength=r["cell"].size)
    return z * sd[:, None] / np.sqrt(n + prior)[None, :]


def rule_mae(r: dict, cands: Sequence[str], rule: str) -> float:
    if rule.startswith("alone:"):
        return _mae(r, (rule[6:],), np.ones(1))
    return _mae(r, cands, rule_weights(r, cands, rule)[r["region"]])


def table(cache: Dict[tuple, List[dict]], cands: Sequence[str], rules: Sequence[str]) -> str:
    keys = sorted(cache)
    rows = ["| rule | " + " | ".join(f"{k[0]} {k[1]}" for k in keys) + " | worst | mean |",
            "|---|" + "---:|" * (len(keys) + 2)]
    for rule in rules:
        cells = []
        for k in keys:
            lin = np.mean([_mae(r, ("linear",), np.ones(1)) for r in cache[k]])
            cells.append(np.mean([rule_mae(r, cands, rule) for r in cache[k]]) / lin)
        rows.append(f"| {rule} | " + " | ".join(f"{c:.3f}" for c in cells)
                    + f" | {max(cells):.3f} | {np.mean(cells):.3f} |")
    return "\n".join(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--depth-model", required=True, help="FastDepth .onnx")
    ap.add_argument("--cache", default="completion_never_loses_probe",
                    help="folder of the per set and regime caches (reused)")
    ap.add_argument("--score-only", action="store_true", help="score the caches there")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO)
    folder = Path(args.cache)
    folder.mkdir(parents=True, exist_ok=True)
    jobs = [(d, reg, args.depth_model) for reg in REGIMES for d in SETS
            if (reg != "tracks" or d in ("7scenes", "tum"))
            and not (folder / f"{d}_{reg}.pkl").exists()]
    if not args.score_only:
        with Pool(args.workers) as pool:
            for key, rows in pool.imap_unordered(_job, jobs):
                (folder / f"{key[0]}_{key[1]}.pkl").write_bytes(pickle.dumps(rows))
    cache = {tuple(p.stem.split("_", 1)): pickle.loads(p.read_bytes())
             for p in sorted(folder.glob("*.pkl"))}
    alone = [f"alone:{c}" for c in ("primitives", "prim_scale", "ip_basic")]
    sets = {"no network": ("primitives", "linear", "ip_basic"),
            "FastDepth": ("primitives", "linear", "ip_basic", "net:interp")}
    margins = (["blend"] + [f"margin{m}" for m in (0.4, 0.6, 0.8, 1.0)]
               + [f"additive{m}" for m in (0.3, 0.4, 0.5)] + [f"gate{m}" for m in (0.2, 0.3)]
               + [f"lcb{z}" for z in (1, 3)])
    print(table(cache, ("linear",), alone + ["alone:net:interp"]))
    for title, cands in sets.items():
        print(f"\n{title}: {', '.join(cands)}\n")
        print(table(cache, cands, margins))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
