"""SuperPrimitives: a connected mask plus an unscaled log-depth on it (docs/design.md §2).

True log-depth of primitive ``i`` at pixel ``u`` is ``log D_i(u) + s_i`` where the
unscaled ``log D_i`` is stored normalised to ``log D_i(p_i) = 0`` at the anchor
pixel ``p_i``; the log depth-scale ``s_i`` is therefore the log-depth (log metres)
at the anchor, and a sparse depth at the anchor sets ``s_i`` directly.

Storage is compressed (CSR-like): the pixels of all primitives are concatenated as
flat indices ``v * width + u`` with ``offsets`` delimiting each primitive, so memory
grows with the pixels covered, not with the number of dense masks.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import Iterator, Optional, Sequence, Tuple, Union

import numpy as np

from .camera import PinholeCamera

__all__ = ["SuperPrimitive", "PrimitiveSet", "PointCloud", "interior_anchor"]

_FORMAT_VERSION = 1


def interior_anchor(mask: np.ndarray) -> int:
    """Flat index of the most interior pixel of a (H, W) bool mask (maximum of
    the L2 distance transform; ties broken by the lowest flat index)."""
    import cv2

    mask = np.asarray(mask, dtype=bool)
    if mask.ndim != 2:
        raise ValueError(f"interior_anchor: mask must be (H, W), got {mask.shape}")
    if not mask.any():
        raise ValueError("interior_anchor: mask is empty")
    padded = np.pad(mask, 1).astype(np.uint8)
    dist = cv2.distanceTransform(padded, cv2.DIST_L2, 5)[1:-1, 1:-1]
    return int(np.argmax(dist))


@dataclass
class PointCloud:
    """Points in the camera frame of the primitives' image (metres).

    ``colors`` float (M, 3) in [0, 1] or None; ``primitive_ids`` (M,) int;
    ``pixels`` (M,) flat pixel index of each point.
    """

    points: np.ndarray
    colors: Optional[np.ndarray]
    primitive_ids: np.ndarray
    pixels: np.ndarray

    def transformed(self, T_a_cam: np.ndarray) -> "PointCloud":
        """The cloud expressed in frame ``a`` (e.g. pass ``T_world_cam``)."""
        from .geometry import transform_points

        return PointCloud(transform_points(T_a_cam, self.points), self.colors,
                          self.primitive_ids, self.pixels)

    def to_open3d(self):
        """An ``open3d.geometry.PointCloud`` (legacy API)."""
        import open3d as o3d

        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self.points.astype(np.float64)))
        if self.colors is not None:
            pcd.colors = o3d.utility.Vector3dVector(self.colors.astype(np.float64))
        return pcd

    def save_ply(self, path: Union[str, os.PathLike]) -> None:
        """Write a binary PLY (via open3d)."""
        import open3d as o3d

        path = os.fspath(path)
        if not o3d.io.write_point_cloud(path, self.to_open3d()):
            raise OSError(f"could not write point cloud to {path}")


@dataclass
class SuperPrimitive:
    """A view of one primitive of a :class:`PrimitiveSet` (arrays are not copied).

    Attributes:
        index: position in the set.
        pixels: (K,) flat pixel indices ``v * width + u`` (sorted).
        log_depth: (K,) unscaled log-depth, 0 at the anchor.
        anchor: flat index of the anchor pixel.
        log_scale: ``s`` (log metres at the anchor).
        camera: intrinsics of the image the primitive lives in.
    """

    index: int
    pixels: np.ndarray
    log_depth: np.ndarray
    anchor: int
    log_scale: float
    camera: PinholeCamera

    @property
    def size(self) -> int:
        return int(self.pixels.size)

    @property
    def uv(self) -> np.ndarray:
        """(K, 2) float pixel coordinates (u = column, v = row)."""
        w = self.camera.width
        return np.stack([self.pixels % w, self.pixels // w], -1).astype(np.float64)

    @property
    def anchor_uv(self) -> Tuple[int, int]:
        return (self.anchor % self.camera.width, self.anchor // self.camera.width)

    @property
    def mask(self) -> np.ndarray:
        """Dense (H, W) bool mask."""
        m = np.zeros(self.camera.width * self.camera.height, dtype=bool)
        m[self.pixels] = True
        return m.reshape(self.camera.shape)

    @property
    def depth(self) -> np.ndarray:
        """(K,) metric depth ``exp(log D + s)`` (metres)."""
        return np.exp(self.log_depth + self.log_scale)

    def points(self) -> np.ndarray:
        """(K, 3) camera-frame points (metres)."""
        return self.camera.unproject(self.uv, self.depth)


class PrimitiveSet:
    """All SuperPrimitives of one image, stored compressed.

    Args:
        camera: intrinsics of the image (primitives live at this resolution).
        pixels: (M,) flat pixel indices of all primitives, concatenated; each
            primitive's run sorted and unique.
        offsets: (N+1,) run boundaries: primitive ``i`` is ``pixels[offsets[i]:offsets[i+1]]``.
        log_depth: (M,) unscaled log-depth per entry.  It is re-normalised here so
            that each primitive's value at its anchor is 0.
        anchors: (N,) flat anchor pixel of each primitive (must lie in it).
        log_scales: (N,) log depth-scales ``s`` (default 0: depth 1 m at the anchor).
        scores: (N,) optional quality scores from the segmenter.
        normals: optional (M, 3) unit normals per entry (camera frame) used to
            build the primitives; kept for planar initialisation and plots.
        meta: free-form provenance (front-end name, whether depth was used, ...).
    """

    def __init__(self, camera: PinholeCamera, pixels: np.ndarray, offsets: np.ndarray,
                 log_depth: np.ndarray, anchors: np.ndarray,
                 log_scales: Optional[np.ndarray] = None, scores: Optional[np.ndarray] = None,
                 normals: Optional[np.ndarray] = None, meta: Optional[dict] = None) -> None:
        self.camera = camera
        self.pixels = np.ascontiguousarray(pixels, dtype=np.int64).reshape(-1)
        self.offsets = np.ascontiguousarray(offsets, dtype=np.int64).reshape(-1)
        self.log_depth = np.array(log_depth, dtype=np.float64).reshape(-1)
        self.anchors = np.ascontiguousarray(anchors, dtype=np.int64).reshape(-1)
        n = self.offsets.size - 1
        self.log_scales = (np.zeros(n) if log_scales is None
                           else np.array(log_scales, dtype=np.float64).reshape(-1))
        self.scores = (np.ones(n) if scores is None
                       else np.asarray(scores, dtype=np.float64).reshape(-1))
        self.normals = None if normals is None else np.asarray(normals, dtype=np.float32)
        self.meta = dict(meta or {})
        self._ids: Optional[np.ndarray] = None
        self._validate()
        # Normalise so that log D(anchor) = 0 for every primitive.
        at_anchor = self.log_depth[self._anchor_entries()]
        self.log_depth -= np.repeat(at_anchor, self.sizes)

    def __getstate__(self) -> dict:
        """Pickled state: the arrays, without the cached per-entry primitive ids
        (recomputed on demand)."""
        state = dict(self.__dict__)
        state["_ids"] = None
        return state

    # ------------------------------------------------------------ validation
    def _validate(self) -> None:
        n = self.offsets.size - 1
        m = self.pixels.size
        npix = self.camera.width * self.camera.height
        if n < 0 or self.offsets[0] != 0 or self.offsets[-1] != m or np.any(np.diff(self.offsets) <= 0):
            raise ValueError("PrimitiveSet: offsets must start at 0, end at len(pixels) and "
                             "increase strictly (no empty primitive)")
        if self.log_depth.shape != (m,):
            raise ValueError(f"PrimitiveSet: log_depth has shape {self.log_depth.shape}, "
                             f"expected ({m},)")
        if not np.all(np.isfinite(self.log_depth)):
            raise ValueError("PrimitiveSet: log_depth contains NaN or inf")
        for name, arr in (("anchors", self.anchors), ("log_scales", self.log_scales),
                          ("scores", self.scores)):
            if arr.shape != (n,):
                raise ValueError(f"PrimitiveSet: {name} has shape {arr.shape}, expected ({n},)")
        if not np.all(np.isfinite(self.log_scales)):
            raise ValueError("PrimitiveSet: log_scales contain NaN or inf")
        if m and (self.pixels.min() < 0 or self.pixels.max() >= npix):
            raise ValueError("PrimitiveSet: pixel indices outside the image")
        step = np.diff(self.pixels)
        starts = self.offsets[1:-1]
        inner = np.ones(max(m - 1, 0), dtype=bool)
        inner[starts - 1] = False
        if np.any(step[inner] <= 0):
            raise ValueError("PrimitiveSet: each primitive's pixels must be sorted and unique")
        if self.normals is not None and self.normals.shape != (m, 3):
            raise ValueError(f"PrimitiveSet: normals have shape {self.normals.shape}, expected ({m}, 3)")
        self._anchor_entries()  # raises if an anchor lies outside its primitive

    def _anchor_entries(self) -> np.ndarray:
        """Entry index (into ``pixels``) of each primitive's anchor."""
        n = len(self)
        key = self.primitive_ids * (self.camera.width * self.camera.height) + self.pixels
        akey = np.arange(n) * (self.camera.width * self.camera.height) + self.anchors
        pos = np.searchsorted(key, akey)
        pos_c = np.minimum(pos, max(key.size - 1, 0))
        ok = (pos < key.size) & (key[pos_c] == akey) if n else np.ones(0, bool)
        if not np.all(ok):
            bad = np.flatnonzero(~ok)[:5]
            raise ValueError(f"PrimitiveSet: anchor outside its primitive for primitives {bad.tolist()}")
        return pos_c

    # ------------------------------------------------------------ construction
    @classmethod
    def from_regions(cls, camera: PinholeCamera, regions: Sequence[np.ndarray],
                     log_depths: Sequence[np.ndarray], anchors: Sequence[int], **kwargs
                     ) -> "PrimitiveSet":
        """Build from per-primitive flat-index arrays and their log-depths."""
        if len(regions) != len(log_depths) or len(regions) != len(anchors):
            raise ValueError("from_regions: regions, log_depths and anchors differ in length")
        sizes = np.array([len(r) for r in regions], dtype=np.int64)
        offsets = np.concatenate([[0], np.cumsum(sizes)])
        pixels = np.concatenate(regions) if len(regions) else np.zeros(0, np.int64)
        ld = np.concatenate(log_depths) if len(regions) else np.zeros(0)
        return cls(camera, pixels, offsets, ld, np.asarray(anchors), **kwargs)

    @classmethod
    def from_masks(cls, camera: PinholeCamera, masks: np.ndarray, log_depth: np.ndarray,
                   anchors: Optional[Sequence[int]] = None, **kwargs) -> "PrimitiveSet":
        """Build from dense (N, H, W) masks and (N, H, W) log-depth (values outside masks ignored)."""
        masks = np.asarray(masks, dtype=bool)
        log_depth = np.asarray(log_depth)
        if masks.ndim != 3 or masks.shape[1:] != camera.shape:
            raise ValueError(f"from_masks: masks must be (N, {camera.height}, {camera.width}), "
                             f"got {masks.shape}")
        if log_depth.shape != masks.shape:
            raise ValueError(f"from_masks: log_depth shape {log_depth.shape} != masks {masks.shape}")
        regions = [np.flatnonzero(m) for m in masks]
        for i, r in enumerate(regions):
            if r.size == 0:
                raise ValueError(f"from_masks: mask {i} is empty")
        lds = [log_depth[i].reshape(-1)[r] for i, r in enumerate(regions)]
        if anchors is None:
            anchors = [interior_anchor(m) for m in masks]
        return cls.from_regions(camera, regions, lds, anchors, **kwargs)

    # ------------------------------------------------------------ basic access
    def __len__(self) -> int:
        return self.offsets.size - 1

    @property
    def sizes(self) -> np.ndarray:
        """(N,) pixel count of each primitive."""
        return np.diff(self.offsets)

    @property
    def primitive_ids(self) -> np.ndarray:
        """(M,) primitive index of every entry."""
        if self._ids is None:
            self._ids = np.repeat(np.arange(len(self)), self.sizes)
        return self._ids

    def __getitem__(self, i: int) -> SuperPrimitive:
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"primitive index {i} out of range for {n} primitives")
        i %= n
        a, b = self.offsets[i], self.offsets[i + 1]
        return SuperPrimitive(i, self.pixels[a:b], self.log_depth[a:b], int(self.anchors[i]),
                              float(self.log_scales[i]), self.camera)

    def __iter__(self) -> Iterator[SuperPrimitive]:
        return (self[i] for i in range(len(self)))

    def __repr__(self) -> str:
        return (f"PrimitiveSet({len(self)} primitives, {self.pixels.size} entries, "
                f"{self.camera.width}x{self.camera.height}, coverage {self.coverage_fraction():.2f})")

    # ------------------------------------------------------------ derived maps
    def scaled_log_depth(self, log_scales: Optional[np.ndarray] = None) -> np.ndarray:
        """(M,) metric log-depth ``log D + s`` per entry (log metres)."""
        s = self.log_scales if log_scales is None else np.asarray(log_scales, dtype=np.float64)
        if s.shape != (len(self),):
            raise ValueError(f"log_scales must have shape ({len(self)},), got {s.shape}")
        return self.log_depth + s[self.primitive_ids]

    def coverage(self) -> np.ndarray:
        """(H, W) int32 number of primitives covering each pixel."""
        c = np.bincount(self.pixels, minlength=self.camera.width * self.camera.height)
        return c.reshape(self.camera.shape).astype(np.int32)

    def coverage_fraction(self) -> float:
        """Fraction of image pixels covered by at least one primitive."""
        if self.pixels.size == 0:
            return 0.0
        return float(np.unique(self.pixels).size / (self.camera.width * self.camera.height))

    def depth_map(self, log_scales: Optional[np.ndarray] = None) -> np.ndarray:
        """(H, W) float depth (metres): the mean of the primitives' depths along each
        pixel's ray where primitives overlap; NaN where no primitive covers the pixel."""
        npix = self.camera.width * self.camera.height
        depth = np.exp(self.scaled_log_depth(log_scales))
        total = np.bincount(self.pixels, weights=depth, minlength=npix)
        count = np.bincount(self.pixels, minlength=npix)
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.where(count > 0, total / np.maximum(count, 1), np.nan)
        return out.reshape(self.camera.shape)

    def label_image(self) -> np.ndarray:
        """(H, W) int32 index of the *smallest* primitive covering each pixel (-1: none);
        a display helper for overlapping sets."""
        npix = self.camera.width * self.camera.height
        out = np.full(npix, -1, dtype=np.int32)
        order = np.argsort(-self.sizes, kind="stable")  # large first, small overwrite
        ids = np.repeat(order, self.sizes[order])
        pix = np.concatenate([self.pixels[self.offsets[i]:self.offsets[i + 1]] for i in order]) \
            if len(self) else np.zeros(0, np.int64)
        out[pix] = ids
        return out.reshape(self.camera.shape)

    def masks(self, indices: Optional[Sequence[int]] = None) -> np.ndarray:
        """Dense (K, H, W) bool masks (all primitives unless ``indices`` is given).
        Memory is K*H*W bytes: prefer the compressed arrays in hot paths."""
        idx = np.arange(len(self)) if indices is None else np.asarray(indices, dtype=np.int64)
        npix = self.camera.width * self.camera.height
        out = np.zeros((idx.size, npix), dtype=bool)
        for k, i in enumerate(idx):
            out[k, self.pixels[self.offsets[i]:self.offsets[i + 1]]] = True
        return out.reshape(idx.size, *self.camera.shape)

    def point_cloud(self, image: Optional[np.ndarray] = None,
                    log_scales: Optional[np.ndarray] = None) -> PointCloud:
        """Union of the unprojected primitives (camera frame, metres); overlapping
        primitives each contribute their own points.  ``image`` gives colours."""
        w = self.camera.width
        uv = np.stack([self.pixels % w, self.pixels // w], -1).astype(np.float64)
        pts = self.camera.unproject(uv, np.exp(self.scaled_log_depth(log_scales)))
        colors = None
        if image is not None:
            from .images import to_float_image

            img = to_float_image(self.camera.check_image(image))
            flat = img.reshape(-1, 3) if img.ndim == 3 else np.repeat(img.reshape(-1, 1), 3, 1)
            colors = flat[self.pixels]
        return PointCloud(pts, colors, self.primitive_ids.copy(), self.pixels.copy())

    # ------------------------------------------------------------ scales
    def with_log_scales(self, log_scales: np.ndarray) -> "PrimitiveSet":
        """A copy sharing geometry with new log-scales."""
        out = self.subset(np.arange(len(self)))
        s = np.asarray(log_scales, dtype=np.float64).reshape(-1)
        if s.shape != (len(self),) or not np.all(np.isfinite(s)):
            raise ValueError(f"log_scales must be ({len(self)},) finite")
        out.log_scales = s.copy()
        return out

    def with_scaled_log_depth(self, scaled_log_depth: np.ndarray) -> "PrimitiveSet":
        """A copy whose shapes follow a new per-pixel metric log-depth (N
        entries, as :meth:`scaled_log_depth`): the log-scale becomes its value
        at the anchor and the unscaled shape the rest."""
        L = np.asarray(scaled_log_depth, dtype=np.float64).reshape(-1)
        if L.shape != self.log_depth.shape or not np.all(np.isfinite(L)):
            raise ValueError(f"scaled_log_depth must be ({self.log_depth.size},) finite")
        s = L[self._anchor_entries()]
        out = PrimitiveSet(self.camera, self.pixels, self.offsets, L - np.repeat(s, self.sizes),
                           self.anchors, s, self.scores, self.normals, self.meta)
        return out

    def fit_planes(self, log_scales: Optional[np.ndarray] = None,
                   ridge: float = 1e-6) -> np.ndarray:
        """Least-squares inverse-depth plane of each primitive.

        Returns ``(N, 3)`` ``theta`` with ``1/z ~= theta . (x, y, 1)`` over the
        primitive's pixels (``(x, y)`` normalised image coordinates; ``z`` the
        scaled depth, metres, with ``log_scales`` or the set's own).  The
        slope ``(a, b)`` is damped by ``ridge`` (times the pixel count and the
        mean squared inverse depth) so one-pixel or collinear primitives get a
        fronto-parallel plane instead of a singular solve.
        """
        w = self.camera.width
        x = (self.pixels % w - self.camera.cx) / self.camera.fx
        y = (self.pixels // w - self.camera.cy) / self.camera.fy
        rho = np.exp(-self.scaled_log_depth(log_scales))
        r = np.stack([x, y, np.ones_like(x)], -1)
        ids = self.primitive_ids
        n = len(self)
        A = np.zeros((n, 3, 3))
        b = np.zeros((n, 3))
        for i in range(3):
            b[:, i] = np.bincount(ids, weights=r[:, i] * rho, minlength=n)
            for j in range(i, 3):
                A[:, i, j] = A[:, j, i] = np.bincount(ids, weights=r[:, i] * r[:, j], minlength=n)
        damp = ridge * self.sizes * np.bincount(ids, weights=rho ** 2, minlength=n) / self.sizes
        A[:, 0, 0] += damp + 1e-12
        A[:, 1, 1] += damp + 1e-12
        return np.linalg.solve(A, b[:, :, None])[:, :, 0]

    def with_planes(self, planes: np.ndarray, min_inverse_depth: float = 1e-6
                    ) -> Tuple["PrimitiveSet", np.ndarray]:
        """A copy whose primitives lie on the given inverse-depth planes
        (:meth:`fit_planes` convention).  Primitives whose plane is behind the
        camera (or parallel to a ray) at any of their pixels keep their shape;
        returns ``(set, replaced (N,) bool)``."""
        th = np.asarray(planes, dtype=np.float64).reshape(len(self), 3)
        w = self.camera.width
        x = (self.pixels % w - self.camera.cx) / self.camera.fx
        y = (self.pixels // w - self.camera.cy) / self.camera.fy
        ids = self.primitive_ids
        rho = th[ids, 0] * x + th[ids, 1] * y + th[ids, 2]
        ok_pix = np.isfinite(rho) & (rho > min_inverse_depth)
        ok = np.bincount(ids, weights=~ok_pix, minlength=len(self)) == 0
        L = self.scaled_log_depth().copy()
        use = ok[ids]
        L[use] = -np.log(rho[use])
        return self.with_scaled_log_depth(L), ok

    def fit_log_scales(self, depth: np.ndarray, min_points: int = 1
                       ) -> Tuple[np.ndarray, np.ndarray]:
        """Per-primitive robust scale from a (possibly sparse) metric depth map.

        ``s_i = median over valid pixels of (log depth - log D_i)`` (docs/design.md §5).
        Args:
            depth: (H, W) metres; NaN / <= 0 are missing.
            min_points: primitives with fewer valid pixels get NaN.
        Returns:
            ``(log_scales (N,) with NaN where unfitted, n_points (N,))``.
        """
        depth = np.asarray(self.camera.check_image(depth, "depth"), dtype=np.float64)
        if depth.ndim != 2:
            raise ValueError(f"depth must be (H, W), got {depth.shape}")
        d = depth.reshape(-1)[self.pixels]
        with np.errstate(invalid="ignore", divide="ignore"):
            valid = np.isfinite(d) & (d > 0)
            resid = np.log(np.where(valid, d, 1.0)) - self.log_depth
        ids = self.primitive_ids[valid]
        r = resid[valid]
        n_points = np.bincount(ids, minlength=len(self))
        s = np.full(len(self), np.nan)
        if r.size:
            # grouped median: sort by (id, residual) and pick middle elements
            order = np.lexsort((r, ids))
            r_s = r[order]
            starts = np.concatenate([[0], np.cumsum(n_points)[:-1]])
            has = n_points >= max(1, min_points)
            lo = starts + (n_points - 1) // 2
            hi = starts + n_points // 2
            s[has] = 0.5 * (r_s[lo[has]] + r_s[hi[has]])
        return s, n_points

    # ------------------------------------------------------------ subsets / io
    def subset(self, indices: Sequence[int]) -> "PrimitiveSet":
        """New set with the given primitives (in that order)."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        if idx.size and (idx.min() < -len(self) or idx.max() >= len(self)):
            raise IndexError("subset: primitive index out of range")
        idx %= max(len(self), 1)
        sl = [np.arange(self.offsets[i], self.offsets[i + 1]) for i in idx]
        ent = np.concatenate(sl) if sl else np.zeros(0, np.int64)
        sizes = self.sizes[idx]
        return PrimitiveSet(self.camera, self.pixels[ent], np.concatenate([[0], np.cumsum(sizes)]),
                            self.log_depth[ent], self.anchors[idx], self.log_scales[idx],
                            self.scores[idx], None if self.normals is None else self.normals[ent],
                            self.meta)

    def save(self, path: Union[str, os.PathLike]) -> None:
        """Save to a compressed ``.npz`` (camera, arrays and JSON meta)."""
        path = os.fspath(path)
        arrays = dict(pixels=self.pixels.astype(np.int32), offsets=self.offsets,
                      log_depth=self.log_depth.astype(np.float32), anchors=self.anchors,
                      log_scales=self.log_scales, scores=self.scores,
                      camera=json.dumps(self.camera.to_dict()), meta=json.dumps(self.meta, default=str),
                      format_version=_FORMAT_VERSION)
        if self.normals is not None:
            arrays["normals"] = self.normals.astype(np.float16)
        np.savez_compressed(path, **arrays)

    @classmethod
    def load(cls, path: Union[str, os.PathLike]) -> "PrimitiveSet":
        """Load a set written by :meth:`save`."""
        path = os.fspath(path)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"primitive file not found: {path}")
        try:
            z = np.load(path, allow_pickle=False)
        except Exception as exc:  # zip / format errors
            raise ValueError(f"cannot read primitive file {path}: {exc}") from exc
        with z:
            if "format_version" not in z or int(z["format_version"]) != _FORMAT_VERSION:
                raise ValueError(f"{path} is not a spgeo PrimitiveSet file (version "
                                 f"{_FORMAT_VERSION})")
            cam = PinholeCamera.from_dict(json.loads(str(z["camera"])))
            normals = z["normals"].astype(np.float32) if "normals" in z else None
            return cls(cam, z["pixels"], z["offsets"], z["log_depth"].astype(np.float64),
                       z["anchors"], z["log_scales"], z["scores"], normals,
                       json.loads(str(z["meta"])))
