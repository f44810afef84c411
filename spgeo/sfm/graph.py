"""The few-view SfM factor graph: variable keys, one pyramid level's factors, gauge priors,
the gauge-free scale marginals and gtsam error messages in one line.

Variables (docs/design.md §4): ``pose_key(j)`` the pose of image ``j`` (0 = reference),
``scale_key(i)`` primitive ``i``'s shape variable, ``brightness_key(j)`` view ``j``'s affine
brightness.  :func:`build_graph` is shared by :func:`spgeo.sfm.few_view_sfm` and the tests
of the VO tracker, which minimises the same cost.
"""
from __future__ import annotations

from typing import List, Optional

import numpy as np

import gtsam

from ..factors.photometric import PlanarShape, ScaledShape
from ..factors.photometric_group import PhotometricFactorGroup
from ..factors.priors import (brightness_prior, log_scale_prior, planar_slope_prior,
                              pose_gauge_prior)
from ..primitives import PrimitiveSet
from .config import SfMConfig

__all__ = ["pose_key", "scale_key", "brightness_key", "level_pixels", "build_graph",
           "hold_translation_and_shape", "gtsam_error_line", "gauge_free_scale_std"]


def gtsam_error_line(exc: BaseException) -> str:
    """The first paragraph of a gtsam exception's message joined into one line
    (``IndeterminantLinearSystemException``'s names the variable there, then
    adds a many-line explanation that must not reach the user's terminal), for
    one logged line or a report entry."""
    para = str(exc).strip().split("\n\n")[0]
    return " ".join(para.split()) or type(exc).__name__


def pose_key(j: int) -> int:
    """Key of ``T_world_cam`` of image ``j`` (0 = reference)."""
    return gtsam.symbol("x", j)


def scale_key(i: int) -> int:
    """Key of primitive ``i``'s shape variable (log-scale or plane)."""
    return gtsam.symbol("s", i)


def brightness_key(j: int) -> int:
    """Key of view ``j``'s affine brightness ``(a, b)``."""
    return gtsam.symbol("b", j)


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


def build_graph(prims: PrimitiveSet, rays_all: np.ndarray, ref_pyr, view_pyrs, lvl: int,
                values: gtsam.Values, config: "SfMConfig",
                orientations: Optional[np.ndarray] = None):
    """The graph of one pyramid level; returns ``(graph, groups)``: one
    :class:`PhotometricFactorGroup` per view over the primitives with at least
    ``min_level_pixels`` pixels on the level's lattice.  ``orientations``:
    planar model, (N, 2) ``(a / c, b / c)`` the slope priors pull towards
    (None: fronto-parallel)."""
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
    shape = (ScaledShape(rays, prims.log_depth[ent]) if config.shape_model == "scaled"
             else PlanarShape(rays))
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


def gauge_free_scale_std(marg: "gtsam.Marginals", n: int, prior_sigma: float):
    """Std of each log-scale with the global-scale gauge removed, and a mask of
    the scales constrained by nothing but their prior.

    The joint marginal ``C`` of all log-scales carries the global scale (fixed
    only by the weak prior) as one large shared mode.  Scales whose own std is
    over half the prior's are constrained by the prior alone (returned in the
    mask, raw std kept).  The others are conditioned on their mean log-scale:
    ``diag(C - C 1 1^T C / (1^T C 1))`` over that set.
    """
    keys = gtsam.KeyVector([scale_key(i) for i in range(n)])
    C = marg.jointMarginalCovariance(keys).fullMatrix()
    std = np.sqrt(np.maximum(np.diag(C), 0.0))
    con = np.flatnonzero(std <= 0.5 * prior_sigma)
    if con.size >= 2:
        Cc = C[np.ix_(con, con)]
        c1 = Cc.sum(axis=1)
        std[con] = np.sqrt(np.maximum(np.diag(Cc) - c1 ** 2 / c1.sum(), 0.0))
    prior_only = np.ones(n, dtype=bool)
    prior_only[con] = False
    return std, prior_only
