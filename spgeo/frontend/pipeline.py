"""The front-end pipeline shared by every segmenter / normal estimator pair:

regions -> 4-connected parts (small parts dropped) -> batched normal
integration -> split where the integrated log-depth jumps -> re-integration of
the split parts -> :class:`~spgeo.primitives.PrimitiveSet`.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import List, Optional, Tuple

import cv2
import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph

from ..camera import PinholeCamera
from ..configs import config_class
from ..images import to_float_image
from ..integration import IntegrationConfig, integrate_normals_regions
from ..primitives import PrimitiveSet, interior_anchor
from .base import NormalEstimator, Segmentation, Segmenter

__all__ = ["FrontEndConfig", "PrimitiveFrontEnd", "split_regions", "LabelSegmenter"]

log = logging.getLogger(__name__)


@config_class
@dataclass(frozen=True)
class FrontEndConfig:
    """Options of :class:`PrimitiveFrontEnd`.

    Attributes:
        working_size: ``(width, height)`` of the grid on which segments and
            normals are computed and integrated (the primitives live there);
            None keeps the input resolution.  The authors integrated at 320x240.
        min_area_frac: connected parts smaller than this fraction of the image
            are dropped (docs/design.md §3: 1e-3).
        split_depth_jumps: split regions where the log-depth jumps.
        jump_threshold: a jump is a step between neighbouring pixels with
            ``|d log z| * f > jump_threshold`` in the integrated log-depth (f the
            focal length in pixels of the step's axis; the product is
            dimensionless: ``tan`` of the incidence angle for a plane, 5.7 is
            80 degrees), or a pixel whose own normal implies such a gradient
            (grazing normals at occluding rims, which least squares would
            smooth over).  This replaces a 3x3 Scharr filter of the integrated
            log-depth: inside a mask both measure the same gradient, and the
            kernel would reach outside the mask at its border.  Front-ends
            that read depth also cut where the measured depth jumps by as much.
        integration: options of the batched integration; front-ends fill pixels
            whose normal is unknown (``unknown_normals="fill"``) because a
            :class:`~spgeo.primitives.PrimitiveSet` holds finite log-depth only.
    """

    working_size: Optional[Tuple[int, int]] = None
    min_area_frac: float = 1e-3
    split_depth_jumps: bool = True
    jump_threshold: float = 5.7
    integration: IntegrationConfig = field(
        default_factory=lambda: IntegrationConfig(unknown_normals="fill"))

    def __post_init__(self) -> None:
        if not 0 <= self.min_area_frac < 1:
            raise ValueError(f"min_area_frac must be in [0, 1), got {self.min_area_frac}")
        if self.jump_threshold <= 0:
            raise ValueError(f"jump_threshold must be > 0, got {self.jump_threshold}")


def _neighbour_edges(pix: np.ndarray, rid: np.ndarray, width: int, height: int):
    """4-neighbour edges (p, q) between entries of the same region, and the step axis."""
    npix = width * height
    key = rid * npix + pix
    pu, pv = pix % width, pix // width
    out_p, out_q, axis = [], [], []
    for step, ok_border, ax in ((1, pu < width - 1, 0), (width, pv < height - 1, 1)):
        target = key + step
        pos = np.searchsorted(key, target)
        pos_c = np.minimum(pos, key.size - 1)
        ok = (pos < key.size) & (key[pos_c] == target) & ok_border
        p = np.flatnonzero(ok)
        out_p.append(p)
        out_q.append(pos_c[p])
        axis.append(np.full(p.size, ax, dtype=np.int8))
    return np.concatenate(out_p), np.concatenate(out_q), np.concatenate(axis)


def _implied_gradient(normals: np.ndarray, cam: PinholeCamera) -> np.ndarray:
    """(H, W) dimensionless log-depth gradient ``f |grad log z|`` implied by each
    pixel's normal: ``sqrt(nx^2 + ny^2) / |n . r|`` (tan of the incidence angle
    for ``r`` on the optical axis); NaN normals give 0."""
    r = cam.rays()
    n = np.nan_to_num(normals)
    m = np.abs(np.sum(n * r, axis=-1))
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.hypot(n[..., 0], n[..., 1]) / m
    return np.where(np.isfinite(g), g, np.where(np.hypot(n[..., 0], n[..., 1]) > 0, np.inf, 0.0))


def split_regions(regions: List[np.ndarray], width: int, height: int, min_area: int,
                  cut: Optional[np.ndarray] = None, edges=None
                  ) -> Tuple[List[np.ndarray], np.ndarray]:
    """Split regions into 4-connected parts; drop parts smaller than ``min_area`` pixels.

    Args:
        regions: sorted flat-index arrays.
        cut: optional bool per edge of ``edges`` (from :func:`_neighbour_edges`)
            marking edges to remove before finding the parts.
    Returns:
        ``(parts, parent)``: the parts (sorted flat indices) and the index of
        the region each came from.
    """
    n = len(regions)
    if n == 0:
        return [], np.zeros(0, np.int64)
    sizes = np.array([r.size for r in regions])
    pix = np.concatenate(regions)
    rid = np.repeat(np.arange(n), sizes)
    if edges is None:
        edges = _neighbour_edges(pix, rid, width, height)
    p, q, _ = edges
    if cut is not None:
        p, q = p[~cut], q[~cut]
    m = pix.size
    adj = sp.csr_matrix((np.ones(p.size, dtype=np.int8), (p, q)), shape=(m, m))
    n_comp, comp = csgraph.connected_components(adj, directed=False)
    comp_size = np.bincount(comp, minlength=n_comp)
    keep_entry = comp_size[comp] >= max(int(min_area), 1)
    # entries of each kept component, in (component, pixel) order
    order = np.lexsort((pix, comp))
    order = order[keep_entry[order]]
    comp_sorted = comp[order]
    bounds = np.flatnonzero(np.diff(comp_sorted)) + 1
    parts = np.split(pix[order], bounds)
    parent = rid[order][np.concatenate([[0], bounds])] if order.size else np.zeros(0, np.int64)
    if order.size == 0:
        parts = []
    return parts, parent


class LabelSegmenter:
    """A segmenter that returns given labels (ground-truth surface ids, or any
    external segmentation).  Labels < 0 are unlabelled."""

    def __init__(self, labels: np.ndarray) -> None:
        self.labels = np.asarray(labels)
        if self.labels.ndim != 2:
            raise ValueError(f"labels must be (H, W), got {self.labels.shape}")

    def segment(self, image: np.ndarray, camera: PinholeCamera) -> Segmentation:
        labels = self.labels
        if labels.shape != camera.shape:
            labels = cv2.resize(labels.astype(np.float32), camera.size,
                                interpolation=cv2.INTER_NEAREST).astype(np.int64)
        flat = labels.reshape(-1)
        idx = np.flatnonzero(flat >= 0)
        order = np.argsort(flat[idx], kind="stable")
        idx = idx[order]
        vals = flat[idx]
        bounds = np.flatnonzero(np.diff(vals)) + 1
        regions = np.split(idx, bounds) if idx.size else []
        anchors = []
        for r in regions:
            m = np.zeros(flat.size, bool)
            m[r] = True
            anchors.append(interior_anchor(m.reshape(camera.shape)))
        return Segmentation(camera.height, camera.width, regions, np.array(anchors, np.int64),
                            np.ones(len(regions)), {"segmenter": "labels"})


class PrimitiveFrontEnd:
    """image (+ optional depth) + camera -> :class:`PrimitiveSet`.

    Args:
        segmenter: any :class:`~spgeo.frontend.base.Segmenter`.
        normals: any :class:`~spgeo.frontend.base.NormalEstimator`.
        config: :class:`FrontEndConfig`.
    """

    def __init__(self, segmenter: Segmenter, normals: NormalEstimator,
                 config: FrontEndConfig = FrontEndConfig(), name: str = "") -> None:
        self.segmenter = segmenter
        self.normal_estimator = normals
        self.config = config
        self.name = name or f"{type(segmenter).__name__}+{type(normals).__name__}"

    @property
    def uses_depth(self) -> bool:
        """True when the normal estimator reads depth (RGB-D / oracle front-ends)."""
        return bool(getattr(self.normal_estimator, "uses_depth", False))

    def working_camera(self, camera: PinholeCamera) -> PinholeCamera:
        ws = self.config.working_size
        return camera if ws is None or tuple(ws) == camera.size else camera.resized(*ws)

    def primify(self, image: np.ndarray, camera: PinholeCamera,
                depth: Optional[np.ndarray] = None) -> PrimitiveSet:
        """Cut ``image`` into SuperPrimitives.

        Args:
            image: (H, W, 3) RGB or (H, W) grey, uint8/uint16/float [0, 1].
            camera: intrinsics of ``image`` (undistorted).
            depth: (H, W) metres (NaN/0 invalid); required if the normal
                estimator uses depth, never read otherwise.
        Returns:
            A :class:`PrimitiveSet` on ``working_camera(camera)`` with log-scales 0
            (or fitted to ``depth`` when the estimator used depth), with
            ``meta['timings']`` (seconds per stage).
        """
        t0 = time.perf_counter()
        img = to_float_image(camera.check_image(image))
        cam = self.working_camera(camera)
        if cam is not camera:
            img = cv2.resize(img, cam.size, interpolation=cv2.INTER_AREA)
        dep = None
        if self.uses_depth:
            if depth is None:
                raise ValueError(f"front-end {self.name!r} uses depth but none was given")
            dep = np.asarray(camera.check_image(depth, "depth"), dtype=np.float32)
            if cam is not camera:
                dep = cv2.resize(dep, cam.size, interpolation=cv2.INTER_NEAREST)
            if not np.any(np.isfinite(dep) & (dep > 0)):
                raise ValueError("depth has no valid pixel")
        t_prep = time.perf_counter()
        seg = self.segmenter.segment(img, cam)
        t_seg = time.perf_counter()
        normals = self.normal_estimator.estimate(img, cam, dep)
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != (cam.height, cam.width, 3):
            raise ValueError(f"normal estimator returned shape {normals.shape}, expected "
                             f"({cam.height}, {cam.width}, 3)")
        t_nrm = time.perf_counter()
        prims = self._build(seg, normals, cam, dep)
        t_int = time.perf_counter()
        if dep is not None and len(prims):
            s, cnt = prims.fit_log_scales(dep)
            s = np.where(np.isfinite(s), s, np.nanmedian(s) if np.any(np.isfinite(s)) else 0.0)
            prims.log_scales = s
        prims.meta.update({
            "frontend": self.name, "uses_depth": self.uses_depth,
            "segmenter_meta": seg.meta, "n_regions_in": len(seg),
            "timings": {"prepare": t_prep - t0, "segment": t_seg - t_prep,
                        "normals": t_nrm - t_seg, "integrate": t_int - t_nrm,
                        "total": time.perf_counter() - t0},
        })
        log.debug("primify: %d regions -> %d primitives in %.1f ms", len(seg), len(prims),
                  1e3 * (time.perf_counter() - t0))
        return prims

    def _build(self, seg: Segmentation, normals: np.ndarray, cam: PinholeCamera,
               depth: Optional[np.ndarray] = None) -> PrimitiveSet:
        if (seg.height, seg.width) != cam.shape:
            raise ValueError(f"segmentation is {seg.width}x{seg.height}, expected {cam.width}x{cam.height}")
        cfg = self.config
        w, h = cam.width, cam.height
        min_area = int(np.ceil(cfg.min_area_frac * w * h))
        if seg.meta.get("regions_4connected") and seg.meta.get("min_region_pixels", 0) >= min_area:
            # the segmenter's regions are already 4-connected parts large enough
            parts, parent = list(seg.regions), np.arange(len(seg.regions))
        else:
            parts, parent = split_regions(list(seg.regions), w, h, min_area)
        anchors = self._anchors(parts, parent, seg.anchors, cam)
        # normals with no image-plane component (fronto-parallel) integrate to
        # log-depth 0 exactly and imply no jump: no solve, no log-depth cut
        flat = (bool(np.all(normals[..., :2] == 0.0)) and bool(np.all(normals[..., 2] < 0))
                and bool(np.all(np.isfinite(normals))))

        def integrate(parts: List[np.ndarray], anchors: np.ndarray) -> List[np.ndarray]:
            if flat:
                return [np.zeros(part.size) for part in parts]
            res = integrate_normals_regions(normals, parts, cam, anchors, cfg.integration)
            return [res.region(i) for i in range(len(parts))]

        log_depth = integrate(parts, anchors)
        if cfg.split_depth_jumps and parts and not (flat and depth is None):
            res_ld = np.concatenate(log_depth)
            pix = np.concatenate(parts)
            rid = np.repeat(np.arange(len(parts)), [p.size for p in parts])
            edges = _neighbour_edges(pix, rid, w, h)
            p, q, axis = edges
            focal = np.where(axis == 0, cam.fx, cam.fy)
            cut = np.abs(res_ld[q] - res_ld[p]) * focal > cfg.jump_threshold
            # the gradient each pixel's own normal implies (what a gradient
            # filter of the integrated depth sees inside the mask): grazing
            # normals mark occluding rims that least squares would smooth over
            steep = _implied_gradient(normals, cam).reshape(-1)[pix] > cfg.jump_threshold
            cut |= steep[p] | steep[q]
            if depth is not None:
                # depth-using front-ends also cut where the measured depth jumps
                with np.errstate(invalid="ignore", divide="ignore"):
                    logd = np.log(np.where(depth > 0, depth, np.nan)).reshape(-1)[pix]
                jump = np.abs(logd[q] - logd[p]) * focal > cfg.jump_threshold
                cut |= np.nan_to_num(jump, nan=0.0).astype(bool)
            if np.any(cut):
                new_parts, new_parent = split_regions(parts, w, h, min_area, cut, edges)
                log.debug("depth-jump split: %d -> %d parts", len(parts), len(new_parts))
                parent = parent[new_parent]
                anchors = self._anchors(new_parts, parent, seg.anchors, cam)
                parts = new_parts
                log_depth = integrate(parts, anchors)
        nrm = np.concatenate([normals.reshape(-1, 3)[p] for p in parts]) if parts else None
        return PrimitiveSet.from_regions(cam, parts, log_depth,
                                         anchors, scores=seg.scores[parent] if len(parts) else None,
                                         normals=nrm,
                                         meta={"parent_region": parent.tolist()})

    @staticmethod
    def _anchors(parts: List[np.ndarray], parent: np.ndarray, seg_anchors: np.ndarray,
                 cam: PinholeCamera) -> np.ndarray:
        """The segment's anchor if it lies in the part, else the part's most interior pixel."""
        out = np.empty(len(parts), dtype=np.int64)
        w = cam.width
        for i, part in enumerate(parts):
            a = seg_anchors[parent[i]]
            j = np.searchsorted(part, a)
            if j < part.size and part[j] == a:
                out[i] = a
                continue
            u, v = part % w, part // w
            u0, v0 = u.min(), v.min()
            crop = np.zeros((v.max() - v0 + 1, u.max() - u0 + 1), dtype=bool)
            crop[v - v0, u - u0] = True
            k = interior_anchor(crop)
            cw = crop.shape[1]
            out[i] = (v0 + k // cw) * w + (u0 + k % cw)
        return out
