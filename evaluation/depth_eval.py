"""Dense depth of a reconstruction against sensor depth (issue 54): VO keyframes and the
few-view SfM's reference depth, each depth map after ONE median scale.

Contract (every function here):

* a depth map is compared to the frame's sensor depth resized to the map's size with
  nearest-neighbour interpolation (:func:`resize_depth`), on pixels where both are
  finite and > 0 and the sensor depth lies in ``(min_depth, max_depth)`` (metres;
  :data:`DEPTH_RANGE` by default, scene units on the synthetic scenes);
* the prediction is multiplied by ``scale = median(gt / pred)`` over those pixels (one
  scale per depth map: a monocular map has no metric scale, and the VO's scale drift is
  judged elsewhere, :mod:`spgeo.evaluation.vo.scale_drift`), then clipped to
  ``[min_depth, max_depth]`` (Eigen et al.'s protocol; ``clipped`` says how much was);
* ``abs_rel`` = mean ``|p - g| / g``, ``delta_1.25`` = fraction with
  ``max(p/g, g/p) < 1.25``, ``coverage`` = fraction of the valid sensor pixels the map
  predicts (:func:`spgeo.metrics.depth.depth_metrics`).

A VO keyframe's depth map is :meth:`PrimitiveSet.depth_map
<spgeo.primitives.PrimitiveSet.depth_map>` of its primitives at their final (smoothed or
stored) log-scales and shapes, at the processing size, in its own camera: the mean of
the overlapping primitives' depths along each pixel's ray.  That is the keyframe's cloud
(:func:`spgeo.vo.result.write_keyframe_clouds`) seen from its own camera without a
z-buffer: the same points, pixel for pixel, so no projection, rounding or hole filling
enters the metric.  A sequence's figure (:func:`summarize`) is the mean over its depth
maps (each map counts once, however many pixels it covers: the usual per-image
protocol), with the pixel-pooled ``abs_rel_pooled`` beside it.

:func:`primitive_breakdown` splits a map's relative error by primitive size, by a
pixel's distance from its primitive's anchor and by image region (a 3x3 grid), per
primitive entry, at the map's median scale.  :func:`oracle_depth_maps` gives the
headroom: the same primitives with each one's log-scale, or its log-depth plane (scale and
two slopes, a bent primitive), fitted to the sensor depth itself.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, Iterator, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from spgeo.metrics.depth import depth_metrics

__all__ = ["DEPTH_RANGE", "median_scaled_depth", "resize_depth", "DepthMapScore", "summarize",
           "keyframe_primitives", "vo_keyframe_depth", "sfm_reference_depth",
           "primitive_breakdown", "merge_breakdowns", "oracle_depth_maps", "SIZE_BINS",
           "ANCHOR_BINS"]

#: default ``(min_depth, max_depth)`` of the sensor pixels judged (metres)
DEPTH_RANGE = (0.1, 10.0)
#: primitive-size bins of :func:`primitive_breakdown`: fraction of the image's pixels
SIZE_BINS = (0.0, 0.005, 0.02, 0.08, np.inf)
#: anchor-distance bins of :func:`primitive_breakdown`: fraction of the image diagonal
ANCHOR_BINS = (0.0, 0.05, 0.1, 0.2, np.inf)
_KEYS = ("abs_rel", "median_rel", "delta_1.25", "coverage", "scale")


def median_scaled_depth(pred: np.ndarray, gt: np.ndarray, min_depth: float = DEPTH_RANGE[0],
                        max_depth: float = DEPTH_RANGE[1], clip: bool = True
                        ) -> Dict[str, float]:
    """Score ``pred`` against ``gt`` (both (H, W), same units) after one median scale.

    With ``clip`` (default) the scaled prediction is clipped to ``[min_depth,
    max_depth]`` before scoring (the usual protocol of Eigen et al.): a primitive at an
    absurd depth (a VO keyframe 0 holds a few at thousands of metres) then costs what a
    wrong depth at the range's end costs instead of dominating the mean.

    Returns ``abs_rel``, ``median_rel``, ``delta_1.25``, ``imae_per_km``,
    ``irmse_per_km`` (of the scaled prediction), ``scale`` (``median(gt / pred)``),
    ``clipped`` (fraction of the judged pixels whose scaled prediction lay outside
    the range; 0 without ``clip``), ``coverage`` and ``n_pixels`` (module docstring);
    NaN metrics with ``coverage`` 0 when no pixel is valid.  Raises ValueError for
    different shapes."""
    pred = np.asarray(pred, np.float64)
    gt = np.asarray(gt, np.float64)
    if pred.shape != gt.shape:
        raise ValueError(f"prediction shape {pred.shape} != ground-truth shape {gt.shape}")
    ok = (np.isfinite(pred) & (pred > 0) & np.isfinite(gt) & (gt > min_depth)
          & (gt < max_depth))
    keys = ("imae_per_km", "irmse_per_km", "abs_rel", "median_rel", "delta_1.25", "scale",
            "clipped")
    if not ok.any():
        return {k: float("nan") for k in keys} | {"coverage": 0.0, "n_pixels": 0}
    scale = float(np.median(gt[ok] / pred[ok]))
    scaled = pred * scale
    clipped = 0.0
    if clip:
        clipped = float(np.mean((scaled[ok] < min_depth) | (scaled[ok] > max_depth)))
        scaled = np.where(np.isfinite(scaled), np.clip(scaled, min_depth, max_depth), scaled)
    m = depth_metrics(scaled, gt, min_depth=min_depth, max_depth=max_depth)
    return {"imae_per_km": m["imae_per_km"], "irmse_per_km": m["irmse_per_km"],
            "abs_rel": m["mean_rel"], "median_rel": m["median_rel"],
            "delta_1.25": m["delta_1.25"], "scale": scale, "clipped": clipped,
            "coverage": m["coverage"], "n_pixels": m["n_pixels"]}


def resize_depth(depth: np.ndarray, size: Tuple[int, int]) -> np.ndarray:
    """(H, W) float32 depth resized to ``size`` = ``(width, height)`` with
    nearest-neighbour interpolation (no depth is invented between surfaces)."""
    import cv2

    d = np.asarray(depth, np.float32)
    if (d.shape[1], d.shape[0]) == tuple(size):
        return d
    return cv2.resize(d, (int(size[0]), int(size[1])), interpolation=cv2.INTER_NEAREST)


@dataclass
class DepthMapScore:
    """One depth map's score.

    Attributes:
        name: what the map is (e.g. ``"kf 3"``, ``"ref 60 gap 10"``).
        frame: the frame number (position in the run, or the data set's number).
        metrics: :func:`median_scaled_depth`'s dict.
        breakdown: :func:`primitive_breakdown` sums (None unless asked for).
    """

    name: str
    frame: int
    metrics: Dict[str, float]
    breakdown: Optional[Dict[str, Any]] = field(default=None, repr=False)


def summarize(scores: Sequence[DepthMapScore]) -> Dict[str, Any]:
    """A sequence's figures: ``n_maps`` (maps with a valid pixel), the mean over those
    maps of ``abs_rel``, ``median_rel``, ``delta_1.25``, ``coverage``, ``clipped`` (and of
    the ``oracle_*_abs_rel`` where the maps have them), and
    ``abs_rel_pooled`` (every valid pixel of every map weighted alike); NaN without maps."""
    ok = [s.metrics for s in scores if s.metrics.get("n_pixels", 0) > 0]
    out: Dict[str, Any] = {"n_maps": len(ok)}
    for k in ("abs_rel", "median_rel", "delta_1.25", "coverage", "clipped",
              "oracle_scale_abs_rel", "oracle_plane_abs_rel"):
        vals = [m[k] for m in ok if k in m]
        if vals or not k.startswith("oracle"):
            out[k] = float(np.mean(vals)) if vals else float("nan")
    n = np.array([m["n_pixels"] for m in ok], float)
    out["abs_rel_pooled"] = (float(np.sum(n * [m["abs_rel"] for m in ok]) / n.sum())
                             if ok else float("nan"))
    return out


def keyframe_primitives(odometry) -> Iterator[Tuple[int, int, Any]]:
    """``(keyframe index, frame number in the run, PrimitiveSet)`` of every keyframe of
    ``odometry`` (:class:`spgeo.vo.Odometry`) that carries depth and was made from a
    frame of this run, at its current state (retired keyframes read back one at a time)."""
    frame_of = {f.keyframe_index: f.index for f in odometry.frames
                if f.keyframe_index is not None}
    for k, _, kf in odometry.iter_keyframes(odometry.keyframes_with_depth()):
        if k in frame_of:
            yield k, frame_of[k], kf.primitives


def vo_keyframe_depth(odometry, frames, depth_range: Tuple[float, float] = DEPTH_RANGE,
                      breakdown: bool = False, oracle: bool = False) -> List[DepthMapScore]:
    """Score every keyframe depth map of a VO run (module docstring).

    Args:
        odometry: the run's :class:`spgeo.vo.Odometry` after its last frame
            (``VORun.odometry``).
        frames: the run's input frames, indexable in run order, with sensor ``depth``
            (any size; a frame without depth is left out).
        depth_range: ``(min_depth, max_depth)`` of the judged sensor pixels.
        breakdown: also :func:`primitive_breakdown` per keyframe.
        oracle: also the AbsRel of :func:`oracle_depth_maps` (metrics
            ``oracle_scale_abs_rel``, ``oracle_plane_abs_rel``).
    Returns:
        one :class:`DepthMapScore` per keyframe with sensor depth (``name`` ``"kf K"``)."""
    out = []
    for k, f, prims in keyframe_primitives(odometry):
        depth = frames[f].depth
        if depth is None:
            continue
        gt = resize_depth(depth, prims.camera.size)
        m = median_scaled_depth(prims.depth_map(), gt, *depth_range)
        b = (primitive_breakdown(prims, gt, m["scale"], depth_range)
             if breakdown and m["n_pixels"] else None)
        if oracle:
            for name, pred in oracle_depth_maps(prims, gt, depth_range).items():
                m[f"oracle_{name}_abs_rel"] = median_scaled_depth(pred, gt, *depth_range)["abs_rel"]
        out.append(DepthMapScore(f"kf {k}", f, m, b))
    return out


def _plane_log_depth(prims, lg: np.ndarray, ok: np.ndarray, min_points: int = 3) -> np.ndarray:
    """(M,) per entry: its primitive's least-squares log-depth plane ``a + b x + c y``
    (``x, y`` normalised image coordinates) through the valid (``ok``) log-depths ``lg``;
    NaN for a primitive with fewer than ``min_points`` valid entries."""
    cam, w, n = prims.camera, prims.camera.size[0], len(prims)
    ids = prims.primitive_ids
    A = np.stack([np.ones(ids.size), (prims.pixels % w - cam.cx) / cam.fx,
                  (prims.pixels // w - cam.cy) / cam.fy], axis=1)
    Aw = A * ok[:, None]
    ata = np.stack([np.bincount(ids, Aw[:, i] * A[:, j], minlength=n)
                    for i in range(3) for j in range(3)], axis=1).reshape(n, 3, 3)
    atb = np.stack([np.bincount(ids, Aw[:, i] * lg, minlength=n) for i in range(3)], axis=1)
    good = np.bincount(ids, ok.astype(float), minlength=n) >= min_points
    theta = np.full((n, 3), np.nan)
    if good.any():
        theta[good] = np.linalg.solve(ata[good] + 1e-9 * np.eye(3), atb[good][..., None])[..., 0]
    return np.einsum("ij,ij->i", A, theta[ids])


def oracle_depth_maps(prims, gt: np.ndarray, depth_range: Tuple[float, float] = DEPTH_RANGE
                      ) -> Dict[str, np.ndarray]:
    """Depth maps of ``prims``'s pixels with shapes fitted to the sensor depth ``gt`` (at
    the primitives' size), the headroom of a better scale or shape: ``"scale"``: each
    primitive's own shape at its median log-scale (:meth:`PrimitiveSet.fit_log_scales
    <spgeo.primitives.PrimitiveSet.fit_log_scales>`: perfect scales); ``"plane"``: each
    primitive's least-squares log-depth plane in normalised image coordinates (a scale
    and two slopes: a perfect bent primitive).  A primitive without valid sensor depth
    (three pixels for a plane) is NaN (not predicted)."""
    g = np.asarray(gt, np.float64)
    inside = np.where((g > depth_range[0]) & (g < depth_range[1]), g, np.nan)
    s, _ = prims.fit_log_scales(inside)
    gv = inside.reshape(-1)[prims.pixels]
    ok = np.isfinite(gv)
    lg = np.log(np.where(ok, gv, 1.0))
    npix = prims.camera.width * prims.camera.height
    out = {}
    for name, ld in (("scale", prims.log_depth + s[prims.primitive_ids]),
                     ("plane", _plane_log_depth(prims, lg, ok))):
        d = np.exp(ld)
        fin = np.isfinite(d)
        tot = np.bincount(prims.pixels[fin], weights=d[fin], minlength=npix)
        cnt = np.bincount(prims.pixels[fin], minlength=npix)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[name] = np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan).reshape(
                prims.camera.shape)
    return out


def sfm_reference_depth(result, ref_depth: np.ndarray,
                        depth_range: Tuple[float, float] = DEPTH_RANGE) -> Dict[str, float]:
    """:func:`median_scaled_depth` of a few-view SfM's reference depth
    (:class:`spgeo.sfm.SfMResult` ``depth``, NaN where unsupported, at its camera's
    size) against the reference frame's sensor depth ``ref_depth`` (any size)."""
    pred = np.asarray(result.depth, np.float64)
    gt = resize_depth(ref_depth, (pred.shape[1], pred.shape[0]))
    return median_scaled_depth(pred, gt, *depth_range)


def _bin_sums(values: np.ndarray, rel: np.ndarray, edges: Sequence[float]) -> Dict[str, list]:
    """Per bin of ``edges``: entries and sum of ``rel``."""
    b = np.clip(np.searchsorted(np.asarray(edges), values, side="right") - 1, 0, len(edges) - 2)
    n = np.bincount(b, minlength=len(edges) - 1)
    s = np.bincount(b, weights=rel, minlength=len(edges) - 1)
    return {"n": n.astype(int).tolist(), "sum_rel": s.tolist()}


def primitive_breakdown(prims, gt: np.ndarray, scale: float,
                        depth_range: Tuple[float, float] = DEPTH_RANGE) -> Dict[str, Any]:
    """Sums of the relative error ``|clip(scale * d) - g| / g`` over the primitive entries
    (pixel of a primitive; an overlapped pixel counts once per primitive) of ``prims``
    with valid sensor depth ``gt`` (at the primitives' size), binned by primitive size
    (:data:`SIZE_BINS`, ``"size"``), by the entry's distance from its primitive's anchor
    (:data:`ANCHOR_BINS`, ``"anchor"``) and by image region (3x3 grid, row-major,
    ``"region"``).  Each: ``{"n": [...], "sum_rel": [...]}`` (add maps with
    :func:`merge_breakdowns`)."""
    w, h = prims.camera.size
    g = np.asarray(gt, np.float64).reshape(-1)[prims.pixels]
    d = np.clip(scale * np.exp(prims.scaled_log_depth()), *depth_range)
    ok = np.isfinite(g) & (g > depth_range[0]) & (g < depth_range[1]) & np.isfinite(d)
    ids = prims.primitive_ids[ok]
    pix, rel = prims.pixels[ok], np.abs(d[ok] - g[ok]) / g[ok]
    size = (prims.sizes / float(w * h))[ids]
    anchor = prims.anchors[ids]
    dist = np.hypot(pix % w - anchor % w, pix // w - anchor // w) / np.hypot(w, h)
    region = np.minimum(3 * (pix // w) // h, 2) * 3 + np.minimum(3 * (pix % w) // w, 2)
    return {"size": _bin_sums(size, rel, SIZE_BINS),
            "anchor": _bin_sums(dist, rel, ANCHOR_BINS),
            "region": _bin_sums(region.astype(float), rel, np.arange(10, dtype=float))}


def merge_breakdowns(parts: Sequence[Optional[Mapping[str, Any]]]) -> Dict[str, Any]:
    """The sums of several :func:`primitive_breakdown` dicts (None ignored) and, per
    split, ``abs_rel`` (sum / n; NaN for an empty bin) and ``share`` (fraction of
    the entries)."""
    parts = [p for p in parts if p]
    out: Dict[str, Any] = {}
    for key in ("size", "anchor", "region"):
        if not parts:
            break
        n = np.sum([p[key]["n"] for p in parts], axis=0).astype(float)
        s = np.sum([p[key]["sum_rel"] for p in parts], axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[key] = {"n": n.astype(int).tolist(), "abs_rel": (s / n).tolist(),
                        "share": (n / max(n.sum(), 1.0)).tolist()}
    return out
