"""Pictures for notebooks and the demo: segments, normals and depth as uint8 RGB."""
from __future__ import annotations

from typing import Optional, Sequence

import cv2
import numpy as np

__all__ = ["colorize_labels", "colorize_normals", "colorize_depth", "side_by_side"]


def colorize_labels(labels: np.ndarray, seed: int = 0) -> np.ndarray:
    """(H, W) int labels -> (H, W, 3) uint8; label < 0 is black."""
    labels = np.asarray(labels)
    n = int(labels.max()) + 1 if labels.size and labels.max() >= 0 else 0
    palette = np.random.default_rng(seed).integers(40, 256, size=(max(n, 1), 3)).astype(np.uint8)
    out = np.zeros(labels.shape + (3,), np.uint8)
    ok = labels >= 0
    out[ok] = palette[labels[ok]]
    return out


def colorize_normals(normals: np.ndarray) -> np.ndarray:
    """Camera-frame unit normals -> RGB ``(1 + (x, -y, -z)) / 2`` (x right red,
    up green, towards camera blue); NaN is black."""
    n = np.asarray(normals, dtype=np.float64)
    rgb = (1.0 + n * np.array([1.0, -1.0, -1.0])) / 2.0
    rgb = np.where(np.isfinite(rgb), rgb, 0.0)
    return (np.clip(rgb, 0, 1) * 255).astype(np.uint8)


def colorize_depth(depth: np.ndarray, d_min: Optional[float] = None,
                   d_max: Optional[float] = None) -> np.ndarray:
    """Depth (metres, NaN invalid) -> turbo colour map on inverse depth; NaN black."""
    depth = np.asarray(depth, dtype=np.float64)
    ok = np.isfinite(depth) & (depth > 0)
    out = np.zeros(depth.shape + (3,), np.uint8)
    if not ok.any():
        return out
    lo = np.percentile(depth[ok], 2) if d_min is None else d_min
    hi = np.percentile(depth[ok], 98) if d_max is None else d_max
    inv = np.where(ok, 1.0 / np.clip(depth, lo, hi), 0)
    t = (inv - 1.0 / hi) / max(1.0 / lo - 1.0 / hi, 1e-12)
    col = cv2.applyColorMap((np.clip(t, 0, 1) * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    out[ok] = col[..., ::-1][ok]
    return out


def side_by_side(panels: Sequence[np.ndarray], titles: Sequence[str] = (),
                 height: Optional[int] = None) -> np.ndarray:
    """Concatenate RGB uint8 (or float [0, 1]) panels horizontally with titles."""
    rows = []
    h = height or max(p.shape[0] for p in panels)
    for i, p in enumerate(panels):
        p = np.asarray(p)
        if p.dtype != np.uint8:
            p = (np.clip(p, 0, 1) * 255).astype(np.uint8)
        if p.ndim == 2:
            p = np.repeat(p[..., None], 3, -1)
        if p.shape[0] != h:
            p = cv2.resize(p, (int(round(p.shape[1] * h / p.shape[0])), h),
                           interpolation=cv2.INTER_NEAREST)
        p = np.ascontiguousarray(p)
        if i < len(titles):
            cv2.putText(p, titles[i], (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 2,
                        cv2.LINE_AA)
            cv2.putText(p, titles[i], (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1,
                        cv2.LINE_AA)
        rows.append(p)
        rows.append(np.full((h, 4, 3), 255, np.uint8))
    return np.concatenate(rows[:-1], axis=1)


def save_png(path, rgb: np.ndarray) -> None:
    """Write an RGB uint8 image as PNG (raises OSError on failure)."""
    import os

    if not cv2.imwrite(os.fspath(path), np.ascontiguousarray(rgb[..., ::-1])):
        raise OSError(f"could not write {path}")

