"""Depth-completion baselines: dense depth from the sparse points alone, or
from the points and the image without primitives.

They run on exactly the inputs :func:`spgeo.completion.complete_depth` gets;
they are candidates of the held-out choice (:mod:`spgeo.completion.choose`) and
the baseline rows of every completion table (``spgeo.evaluation`` re-exports them):

* :func:`linear_interpolation_completion`: Delaunay triangulation of the sparse
  points, linear interpolation inside their convex hull, nearest sparse point
  outside it.
* :func:`ip_basic_completion`: the morphological completion of Ku, Harakeh and
  Waslander, *In Defense of Classical Image Processing: Fast Depth Completion on
  the CPU* (CRV 2018, "IP-Basic"), with its steps and kernels, plus a final
  fill for inputs far sparser than the LiDAR it was designed for
  (:class:`IPBasicConfig`).
* :func:`colorization_completion`: the image-guided fill of Levin, Lischinski
  and Weiss, *Colorization using Optimization* (SIGGRAPH 2004), as the NYU
  Depth v2 toolbox's ``fill_depth_colorization.m`` fills raw depth
  (:class:`ColorizationConfig`).

Sparse depth maps are (H, W) metres with 0 or NaN = missing (the VOID
convention is 0); negative or infinite values raise ``ValueError``.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import sparse as sp
from scipy.sparse.linalg import spsolve

from ..validation import check_sparse_depth
from .fill import nearest_fill, scattered_fill

__all__ = ["linear_interpolation_completion", "IPBasicConfig", "ip_basic_completion",
           "diamond_kernel", "ColorizationConfig", "colorization_completion"]


def linear_interpolation_completion(sparse_depth: np.ndarray, space: str = "depth"
                                    ) -> np.ndarray:
    """Dense depth from sparse points alone: Delaunay-linear inside the convex
    hull of the points, nearest point outside it.

    Args:
        sparse_depth: (H, W) metres, 0 / NaN = missing.
        space: interpolate ``"depth"`` (default), ``"inverse"`` depth (exact for
            planes seen through a pinhole) or ``"log"`` depth.
    Returns:
        (H, W) float64 metres, finite and > 0 everywhere.
    """
    d = check_sparse_depth(sparse_depth)
    if space not in ("depth", "inverse", "log"):
        raise ValueError(f"space must be 'depth', 'inverse' or 'log', got {space!r}")
    v, u = np.nonzero(d > 0)
    z = d[v, u]
    val = {"depth": z, "inverse": 1.0 / z, "log": np.log(z)}[space]
    out = scattered_fill(np.stack([u, v], 1), val, d.shape)
    if space == "inverse":
        return 1.0 / out
    if space == "log":
        return np.exp(out)
    return out


def diamond_kernel(size: int) -> np.ndarray:
    """(size, size) uint8 diamond (L1 ball) structuring element, ``size`` odd."""
    size = int(size)
    if size < 1 or size % 2 == 0:
        raise ValueError(f"diamond_kernel: size must be odd and >= 1, got {size}")
    r = size // 2
    y, x = np.mgrid[-r:r + 1, -r:r + 1]
    return (np.abs(x) + np.abs(y) <= r).astype(np.uint8)


@dataclass(frozen=True)
class IPBasicConfig:
    """Options of :func:`ip_basic_completion` (defaults: IP-Basic's "fast" variant).

    Attributes:
        max_depth: inversion constant ``D``: depths are stored as ``D - d`` so
            that dilation (a max filter) keeps the *closest* point; must exceed
            every sparse depth (raised automatically to 1.05 x the largest).
            Default 10 m (indoor; IP-Basic used 100 m for KITTI).
        dilation_size: the first dilation's diamond kernel size, default 5.
        closing_size: full kernel of the hole-closing, default 5.
        small_fill_size: full kernel of the small-hole fill, default 7.
        extend_to_top: copy each column's top-most value up to the image top
            (IP-Basic's step for LiDAR, which does not reach the top rows),
            default False (pointless for image-wide sparse points).
        large_fill_size: full kernel of the large-hole fill, default 31
            (IP-Basic runs it only with ``extrapolate``; sparse inputs always
            need it).
        median_size: median blur kernel (3 or 5; 0 = off), default 5.
        blur: ``"bilateral"`` (default; d=5, sigmaColor=0.5, sigmaSpace=2.0 on
            the inverted depth as in IP-Basic), ``"gaussian"`` (5x5) or ``"none"``;
            applied to filled pixels only (IP-Basic's Gaussian branch does this,
            its bilateral branch filters the whole map).
        final_fill: IP-Basic stops after the large fill; with 150 points in a
            640x480 image (a 45-pixel spacing) holes remain, so by default they
            are filled by repeating the large-kernel dilation (at most
            ``max_extra_iterations`` times) and then with the nearest value.
            ``False`` leaves them at 0.
        max_extra_iterations: see ``final_fill``, default 20.
    """

    max_depth: float = 10.0
    dilation_size: int = 5
    closing_size: int = 5
    small_fill_size: int = 7
    extend_to_top: bool = False
    large_fill_size: int = 31
    median_size: int = 5
    blur: str = "bilateral"
    final_fill: bool = True
    max_extra_iterations: int = 20

    def __post_init__(self) -> None:
        if not (np.isfinite(self.max_depth) and self.max_depth > 0):
            raise ValueError(f"IPBasicConfig: max_depth must be finite and > 0, "
                             f"got {self.max_depth}")
        for name in ("dilation_size", "closing_size", "small_fill_size", "large_fill_size"):
            v = getattr(self, name)
            if int(v) != v or v < 1 or v % 2 == 0:
                raise ValueError(f"IPBasicConfig: {name} must be an odd integer >= 1, got {v}")
        if self.median_size not in (0, 3, 5):
            raise ValueError(f"IPBasicConfig: median_size must be 0, 3 or 5, "
                             f"got {self.median_size}")
        if self.blur not in ("bilateral", "gaussian", "none"):
            raise ValueError(f"IPBasicConfig: blur must be 'bilateral', 'gaussian' or 'none', "
                             f"got {self.blur!r}")
        if int(self.max_extra_iterations) < 0:
            raise ValueError("IPBasicConfig: max_extra_iterations must be >= 0")


def ip_basic_completion(sparse_depth: np.ndarray, config: IPBasicConfig = IPBasicConfig()
                        ) -> np.ndarray:
    """IP-Basic morphological depth completion (Ku et al. 2018), see :class:`IPBasicConfig`.

    Steps: invert (``D - d``) -> dilate (diamond) -> close -> fill empty pixels
    from a 7x7 dilation -> (extend to top) -> fill from a 31x31 dilation ->
    median blur -> bilateral/Gaussian blur (valid pixels only) -> final fill
    -> re-invert.  Returns (H, W) float64 metres (> 0 wherever filled).
    """
    d = check_sparse_depth(sparse_depth)
    cfg = config
    big = max(float(cfg.max_depth), 1.05 * float(d.max()))
    valid0 = d > 0
    inv = np.where(valid0, big - d, 0.0).astype(np.float32)
    # IP-Basic treats 0 as empty; a point exactly at max depth would become 0
    inv[valid0] = np.maximum(inv[valid0], 1e-6)

    def full(n: int) -> np.ndarray:
        return np.ones((n, n), np.uint8)

    def fill_from(img: np.ndarray, kernel: np.ndarray) -> np.ndarray:
        dil = cv2.dilate(img, kernel)
        empty = img <= 0
        out = img.copy()
        out[empty] = dil[empty]
        return out

    x = cv2.dilate(inv, diamond_kernel(cfg.dilation_size))
    x = cv2.morphologyEx(x, cv2.MORPH_CLOSE, full(cfg.closing_size))
    x = fill_from(x, full(cfg.small_fill_size))
    if cfg.extend_to_top:
        h = x.shape[0]
        has = x > 0
        top = np.where(has.any(0), has.argmax(0), h)
        rows = np.arange(h)[:, None]
        cols = np.arange(x.shape[1])
        topval = x[np.minimum(top, h - 1), cols]
        above = (rows < top[None, :]) & (top[None, :] < h)
        x = np.where(above, topval[None, :], x)
    x = fill_from(x, full(cfg.large_fill_size))
    if cfg.median_size:
        med = cv2.medianBlur(x, cfg.median_size)
        x = np.where(x > 0, med, x).astype(np.float32)
    if cfg.blur == "bilateral":
        bl = cv2.bilateralFilter(x, 5, 0.5, 2.0)
        x = np.where(x > 0, bl, x).astype(np.float32)
    elif cfg.blur == "gaussian":
        bl = cv2.GaussianBlur(x, (5, 5), 0)
        x = np.where(x > 0, bl, x).astype(np.float32)
    if cfg.final_fill:
        for _ in range(int(cfg.max_extra_iterations)):
            if np.all(x > 0):
                break
            x = fill_from(x, full(cfg.large_fill_size))
        if not np.all(x > 0):
            x = nearest_fill(x.astype(np.float64), x > 0).astype(np.float32)
    out = np.where(x > 0, big - x.astype(np.float64), 0.0)
    return out


# ----------------------------------------------------------------- colorization fill
@dataclass(frozen=True)
class ColorizationConfig:
    """Options of :func:`colorization_completion` (defaults: the NYU toolbox's).

    Attributes:
        alpha: weight of the data term on known pixels (the toolbox's
            ``alpha``, default 1).
        var_factor: ``2 sigma_r^2 = var_factor * local variance`` of the grey
            values in the 3x3 window including the centre (toolbox: 0.6).
        min_sigma2: floor of ``2 sigma_r^2`` (toolbox: 2e-6).
    """

    alpha: float = 1.0
    var_factor: float = 0.6
    min_sigma2: float = 2e-6

    def __post_init__(self) -> None:
        for name in ("alpha", "var_factor", "min_sigma2"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"ColorizationConfig: {name} must be finite and > 0, got {v}")


def colorization_completion(image: np.ndarray, sparse_depth: np.ndarray,
                            config: ColorizationConfig = ColorizationConfig()) -> np.ndarray:
    """Colorization fill (Levin et al. 2004; NYU Depth v2 ``fill_depth_colorization.m``).

    Every pixel's depth is asked to equal the affinity-weighted mean of its
    3x3 neighbours, ``w_rs = exp(-(I_r - I_s)^2 / (2 sigma_r^2))`` normalised
    over the window, with ``2 sigma_r^2`` = ``var_factor`` x the window's grey
    variance (at least ``-min_s (I_r - I_s)^2 / log 0.01`` and ``min_sigma2``);
    known pixels add ``alpha (d - d_known)^2``.  One sparse solve
    (``(A + G) d = G d_known``, SuperLU), assembled without pixel loops.
    Depths are normalised by the largest known depth, as in the toolbox.

    Args:
        image: (H, W, 3) RGB or (H, W) grey; uint8 / uint16 / float in [0, 1].
        sparse_depth: (H, W) metres, 0 / NaN = missing.
        config: :class:`ColorizationConfig`.
    Returns:
        (H, W) float64 metres (> 0 wherever the solve is; clipped below at
        1e-3 x the smallest known depth).
    """
    from ..images import to_float_image, to_gray

    d = check_sparse_depth(sparse_depth)
    img = to_float_image(image)
    grey = (to_gray(img) if img.ndim == 3 else img).astype(np.float64)
    if grey.shape != d.shape:
        raise ValueError(f"image shape {grey.shape[:2]} != sparse depth shape {d.shape}")
    h, w = d.shape
    n = h * w
    known = d > 0
    dmax = float(d.max())
    idx = np.arange(n).reshape(h, w)
    gp = np.pad(grey, 1, mode="constant", constant_values=np.nan)
    ip = np.pad(idx, 1, mode="constant", constant_values=-1)
    offs = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)]
    nb_g = np.stack([gp[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] for dy, dx in offs])  # (8, h, w)
    nb_i = np.stack([ip[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] for dy, dx in offs])
    valid = nb_i >= 0
    win = np.concatenate([nb_g, grey[None]], 0)
    cnt = valid.sum(0) + 1
    mean = np.nansum(win, 0) / cnt
    var = np.nansum((win - mean) ** 2, 0) / cnt
    diff2 = np.where(valid, (nb_g - grey[None]) ** 2, np.inf)
    csig = np.maximum(config.var_factor * var, -diff2.min(0) / np.log(0.01))
    csig = np.maximum(csig, config.min_sigma2)
    wts = np.where(valid, np.exp(-np.where(valid, diff2, 0.0) / csig), 0.0)
    wts /= wts.sum(0, keepdims=True)
    rows = np.broadcast_to(idx, nb_i.shape)[valid]
    A = sp.csr_matrix((-wts[valid], (rows, nb_i[valid])), shape=(n, n))
    g = config.alpha * known.ravel().astype(np.float64)
    M = (A + sp.diags(1.0 + g)).tocsc()
    x = spsolve(M, g * (d.ravel() / dmax))
    out = x.reshape(h, w) * dmax
    return np.maximum(out, 1e-3 * float(d[known].min()))
