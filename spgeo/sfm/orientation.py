"""Orientation hypotheses of planar primitives decided by the photometric cost
(few-view SfM, ``shape_model="planar"``; docs/design.md §5, "Orientation choice").

One image cannot always say which way a surface faces: a vanishing-point
normal may be wrong, and a fronto-parallel start may be wrong too.  The SfM
therefore solves from fronto-parallel planes (robust) and then, at the solved
poses, compares for every primitive the photometric cost of its solved plane
with the cost of each orientation hypothesis (e.g. the front-end's own normal)
through the same depth at the primitive's centre.  A primitive takes the
hypothesis whose cost is lowest; the caller then refines once more.

Orientations are written as slope ratios ``(a / c, b / c)`` of the
inverse-depth plane ``1/z = a x + b y + c`` (``(x, y)`` normalised image
coordinates): they do not depend on the depth scale.
"""
from __future__ import annotations

import logging
from typing import List, Sequence, Tuple

import numpy as np

import gtsam

from ..factors.photometric_group import PhotometricFactorGroup
from ..graph.keys import scale_key, symbol_index
from ..primitives import PrimitiveSet

__all__ = ["orientation_ratios", "scene_orientations", "centre_rays", "planes_with_orientation",
           "primitive_costs", "choose_orientations", "choose_planar_orientations"]

log = logging.getLogger(__name__)


def orientation_ratios(prims: PrimitiveSet) -> np.ndarray:
    """(N, 2) ``(a / c, b / c)`` of each primitive's least-squares plane
    (:meth:`~spgeo.primitives.PrimitiveSet.fit_planes` of its integrated
    shape); ``(0, 0)`` for a constant shape or a plane through the camera."""
    planes = prims.fit_planes()
    c = planes[:, 2:3]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(c > 0, planes[:, :2] / c, 0.0)
    return np.where(np.isfinite(out), out, 0.0)


def scene_orientations(prims: PrimitiveSet, ratios: np.ndarray, max_orientations: int = 3,
                       tolerance_deg: float = 5.0) -> List[np.ndarray]:
    """The dominant non-fronto-parallel orientations among the primitives'
    ``ratios`` (N, 2) (:func:`orientation_ratios`), by pixel count: up to
    ``max_orientations`` slope ratios, no two within ``tolerance_deg`` of each
    other (the ratio ``(a / c, b / c)`` is the plane normal's
    ``(n_x / n_z, n_y / n_z)``, the same wherever the plane is).  In a
    Manhattan scene these are its (up to three) surface orientations."""
    tilted = np.flatnonzero(np.any(np.abs(ratios) > 1e-9, axis=1))
    if tilted.size == 0:
        return []
    n = np.c_[ratios[tilted], np.ones(tilted.size)]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    w = prims.sizes[tilted].astype(float)
    cos_tol = np.cos(np.radians(tolerance_deg))
    out: List[np.ndarray] = []
    free = np.ones(tilted.size, dtype=bool)
    while free.any() and len(out) < max_orientations:
        # the direction with the most pixel weight within the tolerance
        sim = np.abs(n[free] @ n[free].T) >= cos_tol
        support = sim @ w[free]
        k = int(np.argmax(support))
        members = np.flatnonzero(free)[sim[k]]
        out.append(ratios[tilted[np.flatnonzero(free)[k]]].copy())
        free[members] = False
    return out


def centre_rays(prims: PrimitiveSet) -> np.ndarray:
    """(N, 2) mean normalised image coordinates ``(x, y)`` of each primitive's pixels."""
    rays = prims.camera.rays().reshape(-1, 3)[prims.pixels]
    n = np.maximum(prims.sizes, 1)
    return np.stack([np.bincount(prims.primitive_ids, weights=rays[:, c], minlength=len(prims))
                     for c in range(2)], 1) / n[:, None]


def planes_with_orientation(thetas: np.ndarray, centres: np.ndarray,
                            ratios: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Planes of orientation ``ratios`` (N, 2) with the inverse depth of
    ``thetas`` (N, 3) at ``centres`` (N, 2).  Returns ``(planes (N, 3), ok (N,))``;
    ``ok`` False where the hypothesis' plane would not face the camera at the
    centre (those rows keep ``thetas``)."""
    r = np.c_[centres, np.ones(len(centres))]
    rho = np.einsum("ij,ij->i", thetas, r)
    denom = ratios[:, 0] * centres[:, 0] + ratios[:, 1] * centres[:, 1] + 1.0
    ok = (rho > 0) & (denom > 1e-3)
    c = np.where(ok, rho / np.where(ok, denom, 1.0), 0.0)
    planes = np.where(ok[:, None], c[:, None] * np.c_[ratios, np.ones(len(ratios))], thetas)
    return planes, ok


def primitive_costs(groups: Sequence[PhotometricFactorGroup], values: gtsam.Values,
                    thetas: np.ndarray, index_of_key) -> Tuple[np.ndarray, np.ndarray]:
    """Photometric cost ``sum |e|^2`` (N,) of each primitive over ``groups``
    at the poses / brightness in ``values`` and shape variables ``thetas``
    (N, dim), and its number of pixels inside the targets (N,);
    ``index_of_key``: shape key -> primitive index.  A primitive with no
    pixel inside any target has cost +inf (a plane that leaves every view is
    not cheap, it is unobserved)."""
    n = thetas.shape[0]
    cost = np.zeros(n)
    n_valid = np.zeros(n)
    for g in groups:
        idx = np.array([index_of_key(k) for k in g.shape_keys], dtype=np.int64)
        br = values.atVector(g.brightness_key) if g.brightness_key is not None else None
        res = g.evaluate(values.atPose3(g.ref_key).matrix(), values.atPose3(g.tgt_key).matrix(),
                         thetas[idx], br, jacobians=False)
        cost[idx] += np.bincount(g.ids, weights=res["e"] ** 2, minlength=idx.size)
        n_valid[idx] += np.bincount(g.ids, weights=res["valid"].astype(float), minlength=idx.size)
    return np.where(n_valid > 0, cost, np.inf), n_valid


def choose_orientations(groups: Sequence[PhotometricFactorGroup], values: gtsam.Values,
                        thetas: np.ndarray, centres: np.ndarray,
                        hypotheses: Sequence[np.ndarray], index_of_key,
                        min_valid_ratio: float = 0.5) -> Tuple[np.ndarray, np.ndarray, dict]:
    """Per primitive, the lowest-cost plane among its current one
    (``thetas``, (N, 3)) and each orientation hypothesis (``hypotheses``: (N, 2)
    slope ratios each) through the current inverse depth at its centre.  A
    hypothesis must keep at least ``min_valid_ratio`` of the pixels the
    current plane has inside the views (costs are per-primitive means over
    the pixels in view).

    Returns ``(planes (N, 3), choice (N,), report)``: ``choice`` is -1 where the
    current plane stays, else the hypothesis index; ``report`` counts the
    primitives per choice and the total cost before / after.
    """
    best = thetas.copy()
    best_cost, valid0 = primitive_costs(groups, values, thetas, index_of_key)
    cost0 = float(np.sum(best_cost[np.isfinite(best_cost)]))
    choice = np.full(thetas.shape[0], -1, dtype=np.int64)
    for h, ratios in enumerate(hypotheses):
        planes, ok = planes_with_orientation(thetas, centres, np.asarray(ratios, float))
        c, valid = primitive_costs(groups, values, planes, index_of_key)
        # the mean over fewer pixels is not comparable: a hypothesis must keep
        # at least half of the primitive's pixels in view
        better = ok & (c < best_cost) & (valid >= min_valid_ratio * valid0)
        best[better], best_cost[better], choice[better] = planes[better], c[better], h
    report = {"n_kept": int(np.sum(choice == -1)),
              "n_per_hypothesis": [int(np.sum(choice == h)) for h in range(len(hypotheses))],
              "cost_before": cost0,
              "cost_after": float(np.sum(best_cost[np.isfinite(best_cost)]))}
    return best, choice, report


def choose_planar_orientations(prims: PrimitiveSet, builders: Sequence[PhotometricFactorGroup],
                               values: gtsam.Values, report: dict):
    """The SfM's orientation step (``SfMConfig.orientation_choice``): the
    hypotheses are each primitive's own front-end orientation and the scene's
    dominant ones (:func:`scene_orientations`); ``builders`` are the finest
    level's groups, ``values`` the solved variables (planes under
    :func:`spgeo.graph.keys.scale_key`).  Returns ``(values, orientations)``:
    the values with the chosen planes and the (N, 2) slope ratios for the
    priors, or ``(values, None)`` when no primitive has another orientation
    to offer or none changed; ``report["orientation_choice"]`` gets the
    counts of :func:`choose_orientations`."""
    own = orientation_ratios(prims)
    if not builders or not np.any(np.abs(own) > 1e-9):
        return values, None
    thetas = np.array([values.atVector(scale_key(i)) for i in range(len(prims))])
    hyps = [own] + [np.broadcast_to(r, own.shape) for r in scene_orientations(prims, own)]
    planes, choice, rep = choose_orientations(
        builders, values, thetas, centre_rays(prims), hyps,
        symbol_index)
    report["orientation_choice"] = rep
    log.debug("orientation choice: %s", rep)
    if not np.any(choice >= 0):
        return values, None
    values = gtsam.Values(values)
    for i in np.flatnonzero(choice >= 0):
        values.update(scale_key(int(i)), planes[i])
    chosen = np.zeros_like(own)
    for h, r in enumerate(hyps):
        chosen[choice == h] = r[choice == h]
    return values, chosen
