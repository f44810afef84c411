"""Probe of completion's held-out choice (issue 39): which folds, candidates and
choice rules would win, measured offline on the shared frames.

For every frame of 7-Scenes (frames 0:300:30), TUM fr1_desk and ICL-NUIM and every
sparse regime (``corners``, ``grid``, ``uniform`` 150 and 500 points, ``tracks``
on the consecutive sets), the classical front-end's primitives are made once and
these candidates are fitted on all points and, per fold scheme, without each fold:

* ``primitives`` (the primitive completion, steps 1-6 of
  :mod:`spgeo.completion.complete`), ``prim_resid`` (the same times its
  log-residuals at the points interpolated over the image: exact at the points),
  ``linear``, ``ip_basic``, and FastDepth aligned by each of
  :data:`spgeo.completion.network.ALIGNMENTS` (``net:<alignment>``);
* fold schemes: ``block2`` / ``block4`` (whole blocks of 2 / 4 mean point
  spacings, :func:`spgeo.completion.choose.fold_ids`; ``block2`` is the
  default) and ``km5`` (five k-means clusters of the points, each held out whole).

The cache (dense maps on every second pixel with reference depth, held-out
residuals per scheme) is then scored by choice rules, each as MAE over the best
of linear interpolation and IP-Basic on the same pixels (< 1: better):

* ``region``: per region the pure candidate of the lowest shrunk held-out error
  (the default before issue 39's blends, ``blend_step=1``);
* ``blend<s>``: per region the log-linear blend of the lowest shrunk error,
  weights in steps ``s`` (:func:`spgeo.completion.choose.blend_weights`);
* ``image-pick`` / ``image-blend``: one candidate / one blend (step 0.1) per image;
* ``bands``: one blend per band of distance to the nearest point (< 20, 20-50,
  > 50 px), scored on held-out points by their distance to the kept ones;
* ``oracle``: the best single candidate per image (dense error; not a method).

Run (about 15 minutes on two cores; the cache is written to ``--cache``)::

    python scripts/completion_choice_probe.py \
        --depth-model ../shared/models/fastdepth/fastdepth_nyu_224.onnx
"""
from __future__ import annotations

import argparse
import logging
import pickle
from multiprocessing import Pool
from pathlib import Path
from typing import Dict, List, Sequence, Tuple

import numpy as np

log = logging.getLogger("completion_choice_probe")

SPECS = [("corners", 150), ("grid", 150), ("uniform", 150), ("uniform", 500), ("tracks", 150)]
SETS = {"7scenes": "0:300:30", "tum": None, "icl": None}
CANDIDATE_SETS = {
    "no network": ("primitives", "linear", "ip_basic"),
    "no network + prim_resid": ("primitives", "prim_resid", "linear", "ip_basic"),
    "FastDepth (default candidates)": ("primitives", "linear", "ip_basic", "net:global",
                                       "net:primitive"),
    "FastDepth + interp + prim_resid": ("primitives", "prim_resid", "linear", "ip_basic",
                                        "net:interp"),
    "FastDepth by the interpolated ratio": ("primitives", "linear", "ip_basic", "net:interp"),
}
RULES = ("region", "blend0.25", "blend0.1", "image-pick", "image-blend", "bands", "oracle")


# ----------------------------------------------------------------- the cache
def _candidates(image, prims, cam, labels, net, config):
    """name -> fit(uv, depth) -> (H, W) metres: the library's candidates
    (:func:`spgeo.completion.complete.candidate_fits`, the network's named
    ``net:<alignment>``) and ``prim_resid`` (module docstring)."""
    from spgeo.completion.complete import _working_image, candidate_fits
    from spgeo.completion.fill import scattered_fill

    fits = candidate_fits(image, prims, cam, config, _working_image(image, prims), labels, net)
    last: Dict[bytes, np.ndarray] = {}

    def prim(p, d):        # one fit per fold shared by "primitives" and "prim_resid"
        key = p.tobytes() + d.tobytes()
        if key not in last:
            last.clear()
            last[key] = fits["primitives"](p, d)
        return last[key]

    def prim_resid(p, d):
        m, q = prim(p, d), p.astype(np.int64)
        return m * np.exp(scattered_fill(q, np.log(d) - np.log(m[q[:, 1], q[:, 0]]), m.shape))

    out = {"primitives": prim, "prim_resid": prim_resid, "linear": fits["linear"],
           "ip_basic": fits["ip_basic"]}
    out.update({"net:" + k.split(":", 1)[1]: f for k, f in fits.items()
                if k.startswith("network:")})
    return out


def _kmeans_folds(uv: np.ndarray, k: int) -> np.ndarray:
    from scipy.cluster.vq import kmeans2

    return kmeans2(uv.astype(np.float64), k, minit="++", seed=0)[1].astype(np.int64)


def _frame_record(f, gt, sparse, fe, model, config) -> dict:
    """The cache of one frame (module docstring)."""
    import cv2

    from spgeo.completion.choose import fold_ids, heldout_log_residuals, region_labels
    from spgeo.completion.network import network_depth

    prims = fe.primify(f.image, f.camera, None)
    labels = cv2.resize(prims.label_image(), f.camera.size, interpolation=cv2.INTER_NEAREST)
    v, u = np.nonzero(sparse > 0)
    uv, sd = np.stack([u, v], 1).astype(np.int64), sparse[v, u]
    cands = _candidates(f.image, prims, f.camera, labels, network_depth(model, f.image), config)
    folds = {"block2": fold_ids(uv, gt.shape, 5, 2.0, 0),
             "block4": fold_ids(uv, gt.shape, 5, 4.0, 0), "km5": _kmeans_folds(uv, 5)}
    regions, cell = region_labels(labels, (4, 3))
    ok = (gt > 0.2) & (gt < 5.0)
    sub = np.zeros_like(ok)
    sub[::2, ::2] = ok[::2, ::2]
    return {"frame": f.name, "names": list(cands), "uv": uv, "folds": folds, "cell": cell,
            "shape": gt.shape,
            "point_region": regions[v, u], "gt": gt[sub], "region": regions[sub],
            "pixels": np.stack(np.nonzero(sub), 1).astype(np.int32),
            "maps": {c: fit(uv, sd)[sub].astype(np.float32) for c, fit in cands.items()},
            "held": {s: heldout_log_residuals(cands, uv, sd, fo) for s, fo in folds.items()}}


def _job(args: Tuple[str, str, int, str]) -> Tuple[Tuple[str, str, int], List[dict]]:
    from spgeo.completion import CompletionConfig, working_size_for
    from spgeo.evaluation.completion.real import open_sample, sparse_frames
    from spgeo.frontend import FrontEndConfig, make_frontend, metric_depth_from_cache

    name, regime, n, model_path = args
    ds = open_sample(name, None, SETS[name])
    seq = open_sample(name, None, "0:") if regime == "tracks" else None
    fe = make_frontend("classical", FrontEndConfig(working_size=working_size_for(ds.camera, 320)))
    model, config = metric_depth_from_cache(model_path), CompletionConfig()
    rows = [_frame_record(f, gt, sp, fe, model, config)
            for f, gt, sp in sparse_frames(ds, n, 0, name, False, regime, seq)]
    log.info("%s %s %d: %d frames", name, regime, n, len(rows))
    return (name, regime, n), rows


# ----------------------------------------------------------------- the rules
def _mae(r: dict, cands: Sequence[str], weights: np.ndarray) -> float:
    """MAE (mm) of the blend ``weights`` ((C,) or (Q, C) per pixel) of ``cands``."""
    logm = np.stack([np.log(r["maps"][c].astype(np.float64)) for c in cands], 1)
    pred = np.exp((np.broadcast_to(weights, logm.shape) * logm).sum(1))
    return 1e3 * float(np.mean(np.abs(pred - r["gt"])))


def _residuals(r: dict, cands: Sequence[str], scheme: str = "block2") -> np.ndarray:
    from spgeo.completion.choose import _worst_filled

    return _worst_filled(r["held"][scheme][[r["names"].index(c) for c in cands]])


def _per_region(r, cands, step, scheme="block2") -> float:
    from spgeo.completion.choose import blend_weights, region_scores

    w = blend_weights(len(cands), step)
    sc = region_scores(np.abs(w @ _residuals(r, cands, scheme)), r["point_region"], r["cell"],
                       10.0)
    return _mae(r, cands, w[np.argmin(sc, 0)][r["region"]])


def _per_image(r, cands, step) -> float:
    from spgeo.completion.choose import blend_weights

    w = blend_weights(len(cands), step)
    return _mae(r, cands, w[np.argmin(np.abs(w @ _residuals(r, cands)).mean(1))])


def _bands(r, cands, edges=(20.0, 50.0)) -> float:
    from scipy import ndimage
    from scipy.spatial import cKDTree

    from spgeo.completion.choose import blend_weights, region_scores

    uv, folds = r["uv"], r["folds"]["block2"]
    dist = np.zeros(len(uv))
    for k in np.unique(folds):
        t = folds == k
        dist[t] = cKDTree(uv[~t]).query(uv[t])[0]
    free = np.ones(r["shape"], bool)
    free[uv[:, 1], uv[:, 0]] = False
    pix_dist = ndimage.distance_transform_edt(free)[r["pixels"][:, 0], r["pixels"][:, 1]]
    w = blend_weights(len(cands), 0.25)
    nb = len(edges) + 1
    sc = region_scores(np.abs(w @ _residuals(r, cands)), np.digitize(dist, edges),
                       np.zeros(nb, np.int64), 10.0)
    return _mae(r, cands, w[np.argmin(sc, 0)][np.digitize(pix_dist, edges)])


def rule_mae(r: dict, cands: Sequence[str], rule: str, scheme: str = "block2") -> float:
    """MAE (mm) of one frame's completion by ``rule`` (:data:`RULES`)."""
    if rule == "region":
        return _per_region(r, cands, 1.0, scheme)
    if rule.startswith("blend"):
        return _per_region(r, cands, float(rule[5:]), scheme)
    if rule in ("image-pick", "image-blend"):
        return _per_image(r, cands, 1.0 if rule == "image-pick" else 0.1)
    if rule == "bands":
        return _bands(r, cands)
    return min(_mae(r, (c,), np.ones(1)) for c in cands)


def table(cache: Dict[tuple, List[dict]], cands: Sequence[str], rules: Sequence[str],
          scheme: str = "block2") -> str:
    """Markdown: per rule and set / regime, mean MAE over the best baseline's."""
    keys = sorted(cache)
    head = "| rule | " + " | ".join(f"{k[0]} {k[1]} {k[2]}" for k in keys) + " |"
    rows = [head, "|---|" + "---:|" * len(keys)]
    for rule in rules:
        cells = []
        for k in keys:
            best = min(np.mean([_mae(r, (b,), np.ones(1)) for r in cache[k]])
                       for b in ("linear", "ip_basic"))
            mae = np.mean([rule_mae(r, cands, rule, scheme) for r in cache[k]])
            cells.append(f"{mae / best:.3f}")
        rows.append(f"| {rule} ({scheme}) | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--depth-model", required=True, help="FastDepth .onnx")
    ap.add_argument("--cache", default="completion_choice_probe.pkl")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO)
    cache_path = Path(args.cache)
    if cache_path.exists():
        cache = pickle.loads(cache_path.read_bytes())
    else:
        jobs = [(d, reg, n, args.depth_model) for reg, n in SPECS for d in SETS
                if reg != "tracks" or d != "icl"]
        with Pool(args.workers) as pool:
            cache = dict(pool.imap_unordered(_job, jobs))
        tmp = cache_path.with_suffix(".tmp")
        tmp.write_bytes(pickle.dumps(cache))
        tmp.replace(cache_path)
    for title, cands in CANDIDATE_SETS.items():
        print(f"\n{title}: {', '.join(cands)}\n")
        print(table(cache, cands, RULES))
        print(table(cache, cands, ("region", "blend0.25"), "block4"))
        print(table(cache, cands, ("region", "blend0.25"), "km5"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
