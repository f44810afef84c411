"""The factor builders shared by the project's GTSAM graphs (keys: :mod:`spgeo.graph.keys`).

* :class:`FactorBatch`: new factors, values and smoother timestamps.
* Keyframe graphs (the VO window smoother :class:`spgeo.vo.smoother.WindowMapper` builds
  its keyframe variables and photometric factor groups with these functions only):
  :func:`mapping_pixels`, :func:`pair_factor_group`, :func:`add_keyframe_variables`,
  :func:`add_factor_group`, :func:`link_keyframe_pair`.  Each keyframe is a
  :class:`~spgeo.vo.map.MapKeyframe` (live: its ``keyframe`` set), the options an
  :class:`~spgeo.vo.config.OdometryConfig`.
* The few-view SfM graph of one pyramid level (:func:`build_level_graph`, shared by
  :func:`spgeo.sfm.few_view_sfm` and the tests of the VO tracker, which minimises the
  same cost), its lattice pixels (:func:`level_pixels`) and the rotation-only stage's
  holding priors (:func:`hold_translation_and_shape`).
* :func:`projection_model`: the calibration and robust noise of the landmarks'
  projection factors (the VO window's :func:`spgeo.vo.landmarks.add_landmark_factors`
  and the few-view bundle's :func:`spgeo.sfm.bundle.add_landmark_factors`).
* :func:`gtsam_error_line`: a gtsam exception's message in one line (every solver's
  report and log).

Prior sigmas of the keyframe graphs (module constants: nothing overrides them):
:data:`GAUGE_SIGMA`, :data:`PLANAR_SLOPE_SIGMA`,
:data:`BRIGHTNESS_PRIOR_SIGMA`, and of the SfM depth stage's :func:`continuity_factors`:
:data:`CONTINUITY_SIGMA`, :data:`CONTINUITY_EDGE_SCALE`.
"""
from __future__ import annotations

from typing import List, Optional, Tuple

import numpy as np

import gtsam

from ..camera import PinholeCamera
from ..factors.photometric import PlanarShape, ScaledShape, ShapeModel
from ..factors.photometric_group import PhotometricFactorGroup
from ..factors.priors import (brightness_prior, log_scale_prior, planar_slope_prior,
                              pose_gauge_prior)
from ..primitive_models import shape_values
from ..primitives import PrimitiveSet
from .keys import brightness_key, pair_brightness_key, pose_key, scale_key

# OdometryConfig, MapKeyframe and SfMConfig in the annotations are the VO's and the SfM's
# (spgeo.vo.config, spgeo.vo.map, spgeo.sfm.config): not imported, as those packages
# import this module (no import circle, not even a type-only one: tests/test_layering.py)

__all__ = ["GAUGE_SIGMA", "PLANAR_SLOPE_SIGMA", "BRIGHTNESS_PRIOR_SIGMA",
           "CONTINUITY_SIGMA", "CONTINUITY_EDGE_SCALE", "gtsam_error_line", "primitive_shape",
           "continuity_factors",
           "FactorBatch", "mapping_pixels", "pair_factor_group", "add_keyframe_variables",
           "add_factor_group", "link_keyframe_pair", "level_pixels",
           "hold_translation_and_shape", "build_level_graph", "projection_model"]

#: sigma of the first keyframe's pose prior (the gauge)
GAUGE_SIGMA = 1e-6
#: sigma of the planar model's slope prior (towards fronto-parallel; weak)
PLANAR_SLOPE_SIGMA = 2.0
#: log-depth sigma of the continuity factors between adjacent primitives in the
#: few-view SfM's depth stage (:func:`continuity_factors`; docs/results.md, issue 54)
CONTINUITY_SIGMA = 5.0
#: colour-step scale of their weights (as ``CompletionConfig``'s edge scale)
CONTINUITY_EDGE_SCALE = 0.08
#: sigmas of the priors of the brightness ``(a, b)`` variables (as the SfM graph's
#: default ``SfMConfig.brightness_prior_sigma``)
BRIGHTNESS_PRIOR_SIGMA: Tuple[float, float] = (0.3, 0.3)


def projection_model(K: np.ndarray, pixel_sigma: float, huber_px: float):
    """``(gtsam.Cal3_S2, noise model)`` of the landmarks' projection factors (the VO's
    window and the few-view SfM's bundle): the pinhole ``K`` (3x3, no skew) and an
    isotropic ``pixel_sigma`` (pixels) under a Huber kernel at ``huber_px``."""
    cal = gtsam.Cal3_S2(float(K[0, 0]), float(K[1, 1]), 0.0, float(K[0, 2]), float(K[1, 2]))
    noise = gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(huber_px / pixel_sigma),
        gtsam.noiseModel.Isotropic.Sigma(2, pixel_sigma))
    return cal, noise


def primitive_shape(prims: PrimitiveSet, entries: np.ndarray, rays: np.ndarray,
                    model: str) -> ShapeModel:
    """The factors' shape model of the entries ``entries`` (into ``prims.pixels``)
    with rays ``rays`` (K, 3): :class:`PlanarShape` for ``model == "planar"``,
    else :class:`ScaledShape` on the primitives' unscaled log-depth."""
    if model == "planar":
        return PlanarShape(rays)
    return ScaledShape(rays, prims.log_depth[entries])


def continuity_factors(prims: PrimitiveSet, image: np.ndarray, keys: List[int],
                       sigma: float = CONTINUITY_SIGMA,
                       edge_scale: float = CONTINUITY_EDGE_SCALE) -> List[gtsam.NonlinearFactor]:
    """Factors that keep adjacent primitives' depths continuous across weak image
    edges (docs/design.md §5, "Depth stage").

    For each pair ``(i, j)`` of primitives that touch along a boundary whose mean
    colour step is at most ``2 edge_scale`` (intensity units;
    :func:`spgeo.completion.graph.weak_edges`), one ``BetweenFactorVector`` on
    their log-scales, ``s_j - s_i = c_ij`` with ``c_ij`` the mean of
    ``l_i(p) - l_j(q)`` over the boundary pixel pairs ``(p, q)`` (``l``: the
    unscaled log-depth), Gaussian noise of sigma
    ``sigma / sqrt(w_ij)`` (log units; ``w_ij = exp(-(step / edge_scale)^2)``).
    Gaussian, not robust: far from 0 a Cauchy kernel's pull vanishes and a
    Huber kernel's stops growing, and a primitive that no view constrains ran
    away again with them (docs/results.md).

    Args:
        prims: the primitives (``prims.camera`` their resolution).
        image: (H, W) grey or (H, W, C) image in [0, 1] at ``prims.camera``'s size.
        keys: ``keys[i]`` the 1-DoF log-scale variable of primitive ``i``.
        sigma, edge_scale: > 0.
    Raises:
        ValueError: ``image`` of another size, ``keys`` of another length.
    """
    from ..completion.graph import weak_edges

    if len(keys) != len(prims):
        raise ValueError(f"continuity_factors: {len(keys)} keys for {len(prims)} primitives")
    e = weak_edges(prims, image, edge_scale)
    ok = (e.ent_p >= 0) & (e.ent_q >= 0)
    ld = prims.log_depth
    n_e = e.edge_a.size
    c = (np.bincount(e.pair_edge[ok], weights=ld[e.ent_p[ok]] - ld[e.ent_q[ok]], minlength=n_e)
         / np.maximum(np.bincount(e.pair_edge[ok], minlength=n_e), 1))
    return [gtsam.BetweenFactorVector(keys[a], keys[b], np.array([cab]),
                                      gtsam.noiseModel.Isotropic.Sigma(1, sigma / np.sqrt(w)))
            for a, b, w, cab in zip(e.edge_a, e.edge_b, e.edge_weight, c)]


def gtsam_error_line(exc: BaseException) -> str:
    """The first paragraph of a gtsam exception's message joined into one line
    (``IndeterminantLinearSystemException``'s names the variable there, then
    adds a many-line explanation that must not reach the user's terminal), for
    one logged line or a report entry."""
    para = str(exc).strip().split("\n\n")[0]
    return " ".join(para.split()) or type(exc).__name__


class FactorBatch:
    """New factors, values and key timestamps of one smoother update."""

    def __init__(self) -> None:
        self.graph = gtsam.NonlinearFactorGraph()
        self.values = gtsam.Values()
        self.stamps = gtsam.FixedLagSmootherKeyTimestampMap()

    def insert(self, key: int, value, t: int) -> None:
        """A new variable and its smoother timestamp ``t`` (a keyframe index)."""
        self.values.insert(key, value)
        self.stamps.insert((key, float(t)))


# ------------------------------------------------------------ keyframe graphs (VO)
def mapping_pixels(config: OdometryConfig, ref: MapKeyframe):
    """Mapping pixels of a (live) keyframe: ``(entries, compact ids, primitive
    index, reference intensities)`` or None when no primitive has enough
    pixels: the pixels of level ``mapping.level``; with ``mapping.pixel_fraction < 1``
    its highest-gradient fraction (at least ``min_level_pixels`` per
    primitive).  Cached in ``ref.map_pixels`` (mapping changes scales and pose,
    never pixels or image)."""
    cfg = config
    if ref.map_pixels is not None:
        return ref.map_pixels[0]
    data = ref.keyframe.level_data(cfg.mapping.level, 1, cfg.tracker.min_level_pixels, None)
    out = None
    if data.prim_index.size:
        entries, ids, ref_int = data.entries, data.ids, data.ref_intensity
        if cfg.mapping.pixel_fraction < 1.0:
            # central differences, as the factors' bilinear image derivatives
            img = ref.keyframe.pyramid.images[cfg.mapping.level].astype(np.float64)
            gy, gx = np.gradient(img)
            mag = np.hypot(gx, gy)
            w = ref.keyframe.primitives.camera.width
            stride = 2 ** cfg.mapping.level
            pix = ref.keyframe.primitives.pixels[entries]
            g = mag[(pix // w) // stride, (pix % w) // stride]
            thr = np.quantile(g, 1.0 - cfg.mapping.pixel_fraction)
            order = np.lexsort((-g, ids))                  # by primitive, strongest first
            rank = np.empty(ids.size, dtype=np.int64)
            starts = np.concatenate([[0], np.cumsum(np.bincount(ids))[:-1]])
            rank[order] = np.arange(ids.size) - starts[ids[order]]
            keep = (g >= thr) | (rank < cfg.tracker.min_level_pixels)
            entries, ids, ref_int = entries[keep], ids[keep], ref_int[keep]
        out = (entries, ids, data.prim_index, ref_int)
    ref.map_pixels = (out,)
    return out


def pair_factor_group(config: OdometryConfig, ref: MapKeyframe, tgt_key: int,
                      tgt_image: np.ndarray, tgt_camera: PinholeCamera,
                      bkey: int) -> Optional[PhotometricFactorGroup]:
    """The photometric factors of ``ref``'s primitives (its :func:`mapping_pixels`)
    observed in a target: pose key ``tgt_key``, grey image ``tgt_image`` (H, W)
    of camera ``tgt_camera`` (level ``mapping.level``), brightness key ``bkey``.
    None when ``ref`` has no mapping pixel."""
    sel = mapping_pixels(config, ref)
    if sel is None:
        return None
    entries, ids, prim_index, ref_int = sel
    prims = ref.keyframe.primitives
    rays = prims.camera.rays().reshape(-1, 3)[prims.pixels[entries]]
    shape = primitive_shape(prims, entries, rays, config.primitive_model)
    counts = np.bincount(ids, minlength=prim_index.size)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    keys = [scale_key(i, keyframe=ref.index) for i in prim_index]
    return PhotometricFactorGroup(pose_key(ref.index), tgt_key, keys, shape, offsets,
                                  ref_int, tgt_image, tgt_camera, bkey,
                                  config.tracker.photometric, n_pixels=counts.astype(float),
                                  chunk=max(1, config.mapping.chunk // shape.dim))


def add_keyframe_variables(batch: FactorBatch, kf: MapKeyframe, config: OdometryConfig) -> None:
    """A (live) keyframe's pose and shape variables at their current values,
    with the shapes' priors (weights ``kf.prior_weights`` (N,), else
    ``scale_prior_weight``; planar: the slope prior too); timestamps ``kf.index``."""
    batch.insert(pose_key(kf.index), gtsam.Pose3(kf.keyframe.T_world_kf), kf.index)
    th = shape_values(kf.keyframe.primitives, config.primitive_model)
    pw = kf.prior_weights
    if pw is None:
        pw = np.full(th.shape[0], config.scale_prior_weight)
    for i in range(th.shape[0]):
        key = scale_key(i, keyframe=kf.index)
        batch.insert(key, th[i].copy(), kf.index)
        if config.primitive_model == "planar":
            batch.graph.add(planar_slope_prior(key, float(th[i, 2]), PLANAR_SLOPE_SIGMA,
                                               1.0 / np.sqrt(pw[i]), slope=th[i, :2]))
        else:
            batch.graph.add(log_scale_prior(key, float(th[i, 0]), pw[i]))


def add_factor_group(batch: FactorBatch, group: Optional[PhotometricFactorGroup], bkey: int,
                     b0, t: int, groups: List[PhotometricFactorGroup]) -> int:
    """A factor group (None: nothing) with its brightness variable (initial
    ``b0``, timestamp ``t``) and prior, appended to ``groups``; its factor count."""
    if group is None:
        return 0
    for f in group.factors:
        batch.graph.add(f)
    groups.append(group)
    batch.insert(bkey, np.asarray(b0, dtype=float), t)
    batch.graph.add(brightness_prior(bkey, BRIGHTNESS_PRIOR_SIGMA))
    return len(group)


def link_keyframe_pair(batch: FactorBatch, config: OdometryConfig, a: MapKeyframe,
                       b: MapKeyframe, t: int, groups: List[PhotometricFactorGroup]) -> int:
    """Photometric factors between two live keyframes in both directions (a's
    primitives in b's image and b's in a's, level ``mapping.level``), each
    direction with its brightness (:func:`~spgeo.graph.keys.pair_brightness_key`, initial 0,
    timestamp ``t``); the groups go to ``groups``.  Returns the factor count."""
    lvl = config.mapping.level
    n = 0
    for ref, tgt in ((a, b), (b, a)):
        bkey = pair_brightness_key(ref.index, tgt.index)
        g = pair_factor_group(config, ref, pose_key(tgt.index),
                              tgt.keyframe.pyramid.images[lvl],
                              tgt.keyframe.pyramid.cameras[lvl], bkey)
        n += add_factor_group(batch, g, bkey, np.zeros(2), t, groups)
    return n


# ------------------------------------------------------------ few-view SfM graph
def level_pixels(prims: PrimitiveSet, stride: int):
    """Per primitive: entry indices whose pixel lies on the level's lattice."""
    w = prims.camera.width
    on = ((prims.pixels % w) % stride == 0) & ((prims.pixels // w) % stride == 0)
    return [np.flatnonzero(on[a:b]) + a for a, b in zip(prims.offsets[:-1], prims.offsets[1:])]


def hold_translation_and_shape(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                               n_views: int, n_prims: int) -> None:
    """Tight priors that keep view translations and primitive shapes at their
    current values (rotation-only stage)."""
    sig = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e3, 1e3, 1e3, 1e-6, 1e-6, 1e-6]))
    for j in range(n_views):
        k = pose_key(j + 1)
        graph.add(gtsam.PriorFactorPose3(k, values.atPose3(k), sig))
    for i in range(n_prims):
        theta = values.atVector(scale_key(i))
        graph.add(gtsam.PriorFactorVector(scale_key(i), theta,
                                          gtsam.noiseModel.Isotropic.Sigma(theta.size, 1e-6)))


def build_level_graph(prims: PrimitiveSet, rays_all: np.ndarray, ref_pyr, view_pyrs, lvl: int,
                values: gtsam.Values, config: "SfMConfig",
                orientations: Optional[np.ndarray] = None, continuity: bool = False):
    """The graph of one pyramid level; returns ``(graph, groups)``: one
    :class:`PhotometricFactorGroup` per view over the primitives with at least
    ``min_level_pixels`` pixels on the level's lattice.  ``orientations``:
    planar model, (N, 2) ``(a / c, b / c)`` the slope priors pull towards
    (None: fronto-parallel).  ``continuity``: with the 1-DoF model, the
    :func:`continuity_factors` of the reference's primitives too (the depth
    stage)."""
    graph = gtsam.NonlinearFactorGraph()
    builders: List[PhotometricFactorGroup] = []
    graph.add(pose_gauge_prior(pose_key(0), None, config.ref_prior_sigma))
    n_views = len(view_pyrs)
    if config.brightness:
        for j in range(n_views):
            graph.add(brightness_prior(brightness_key(j + 1), config.brightness_prior_sigma))
    if config.shape_model == "scaled":
        for i in range(len(prims)):
            graph.add(log_scale_prior(scale_key(i), prims.log_scales[i], config.scale_prior_weight))
    else:
        for i in range(len(prims)):
            c0 = values.atVector(scale_key(i))[2]
            # slope prior towards the primitive's orientation (a/c, b/c), at the current c
            slope = (0.0, 0.0) if orientations is None else c0 * orientations[i]
            graph.add(planar_slope_prior(scale_key(i), c0, config.planar_prior_sigma,
                                         1.0 / np.sqrt(config.scale_prior_weight), slope=slope))
    if continuity and config.shape_model == "scaled":
        for f in continuity_factors(prims, ref_pyr.images[0],
                                    [scale_key(i) for i in range(len(prims))]):
            graph.add(f)
    stride = 2 ** lvl
    ref_img = ref_pyr.images[lvl]
    w = prims.camera.width
    per_prim = level_pixels(prims, stride)
    keep = [i for i, ent in enumerate(per_prim) if ent.size >= config.min_level_pixels]
    if not keep:
        return graph, builders
    ent = np.concatenate([per_prim[i] for i in keep])
    sizes = np.array([per_prim[i].size for i in keep])
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    pix = prims.pixels[ent]
    ref_int = ref_img[(pix // w) // stride, (pix % w) // stride].astype(np.float64)
    rays = rays_all[ent]
    shape = primitive_shape(prims, ent, rays, config.shape_model)
    keys = [scale_key(i) for i in keep]
    for j in range(n_views):
        g = PhotometricFactorGroup(
            pose_key(0), pose_key(j + 1), keys, shape, offsets, ref_int,
            view_pyrs[j].images[lvl], view_pyrs[j].cameras[lvl],
            brightness_key(j + 1) if config.brightness else None, config.photometric,
            chunk=config.chunk)
        for f in g.factors:
            graph.add(f)
        builders.append(g)
    return graph, builders
