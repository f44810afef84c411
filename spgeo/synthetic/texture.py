"""Solid (3-D) procedural textures: albedo as a function of the world point.

A surface point has the same albedo in every view (colour depends on the 3-D
hit point only).
"""
from __future__ import annotations

import colorsys
import math
from typing import Optional, Tuple

import numpy as np

from .config import TextureConfig

__all__ = ["SolidTexture", "FlatTexture", "make_texture"]


_PATTERN_STRIPES, _PATTERN_CHECKER, _PATTERN_BLOBS = "stripes", "checker", "blobs"


class SolidTexture:
    """Albedo as a function of the world point (vectorised, float32).

    ``albedo = where(pattern > threshold, c2, c1) * (1 + contrast * noise) + tint``
    with ``noise`` a unit-std multi-octave sum of sinusoids, ``pattern`` a
    product (stripes, checker) or sum (blobs) of sinusoids, ``tint`` a
    low-frequency colour variation.
    """

    def __init__(self, k_noise: np.ndarray, ph_noise: np.ndarray, amp_noise: np.ndarray,
                 k_tint: np.ndarray, ph_tint: np.ndarray, amp_tint: np.ndarray,
                 tint: np.ndarray, pattern: str, k_pat: np.ndarray, ph_pat: np.ndarray,
                 threshold: float, c1: np.ndarray, c2: np.ndarray, contrast: float) -> None:
        f32 = np.float32
        # column layout (K, 1) so that evaluation broadcasts over rows of points
        self.k_noise = np.asarray(k_noise, f32).T[:, :, None]  # (3, Kn, 1)
        self.ph_noise = np.asarray(ph_noise, f32)[:, None]
        self.amp_noise = (contrast * np.asarray(amp_noise)).astype(f32)[:, None]
        self.k_tint = np.asarray(k_tint, f32).T[:, :, None]
        self.ph_tint = np.asarray(ph_tint, f32)[:, None]
        self.amp_tint = np.asarray(amp_tint, f32)[:, None]
        self.tint = np.asarray(tint, f32)[:, None]
        self.pattern = pattern
        self.k_pat = np.asarray(k_pat, f32).T[:, :, None]
        self.ph_pat = np.asarray(ph_pat, f32)[:, None]
        self.threshold = f32(threshold)
        self.c1 = np.asarray(c1, f32)[:, None]
        self.c2 = np.asarray(c2, f32)[:, None]

    @staticmethod
    def _waves(p: np.ndarray, k: np.ndarray, ph: np.ndarray) -> np.ndarray:
        """sin(k . p + ph) as (K, N) (elementwise: no BLAS call for 3-long dot products)."""
        s = k[0] * p[0]
        s += k[1] * p[1]
        s += k[2] * p[2]
        s += ph
        return np.sin(s, out=s)

    def evaluate_rows(self, p: np.ndarray) -> np.ndarray:
        """(3, N) float32 albedo in [0, 1] of float32 world points given as rows (3, N)."""
        mod = (self._waves(p, self.k_noise, self.ph_noise) * self.amp_noise).sum(axis=0)
        mod += 1.0
        tint = (self._waves(p, self.k_tint, self.ph_tint) * self.amp_tint).sum(axis=0)
        pat = self._waves(p, self.k_pat, self.ph_pat)
        value = pat.sum(axis=0) if self.pattern == _PATTERN_BLOBS else pat[0] * pat[1] * pat[2]
        rgb = np.where(value > self.threshold, self.c2, self.c1)
        rgb *= mod
        rgb += tint * self.tint
        return np.clip(rgb, 0.0, 1.0, out=rgb)

    def evaluate(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) float32 albedo in [0, 1] at world points (N, 3)."""
        p = np.ascontiguousarray(np.asarray(points, np.float32).reshape(-1, 3).T)
        return self.evaluate_rows(p).T


class FlatTexture:
    """A constant albedo ``grey`` (in [0, 1], every channel): a textureless
    surface (:meth:`spgeo.synthetic.scene.SyntheticScene.paint_flat`)."""

    def __init__(self, grey: float) -> None:
        self.grey = np.float32(np.clip(grey, 0.0, 1.0))

    def evaluate_rows(self, p: np.ndarray) -> np.ndarray:
        """(3, N) float32 albedo of world points given as rows (3, N)."""
        return np.full((3, p.shape[1]), self.grey, np.float32)

    def evaluate(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) float32 albedo at world points (N, 3)."""
        return np.full((np.asarray(points).reshape(-1, 3).shape[0], 3), self.grey, np.float32)


def _random_unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _in_plane(k: np.ndarray, normal: Optional[np.ndarray], rng: np.random.Generator) -> np.ndarray:
    """Project wave vectors onto a plane keeping their length (planes only)."""
    if normal is None:
        return k
    length = np.linalg.norm(k, axis=1, keepdims=True)
    kp = k - (k @ normal)[:, None] * normal
    norm = np.linalg.norm(kp, axis=1, keepdims=True)
    bad = norm[:, 0] < 1e-6 * np.maximum(length[:, 0], 1e-12)
    if np.any(bad):  # wave vector along the normal: any in-plane direction
        u, _ = _plane_basis(normal)
        kp[bad] = u
        norm[bad] = 1.0
    return kp / norm * length


def _plane_basis(normal: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    n = normal / np.linalg.norm(normal)
    ref = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(ref, n)
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


_LUMA = np.array([0.299, 0.587, 0.114])


def _colour_with_luma(hue: float, sat: float, luma: float) -> np.ndarray:
    """RGB of a hue/saturation with BT.601 luminance ``luma`` (darken, or blend with white)."""
    rgb = np.array(colorsys.hsv_to_rgb(hue, sat, 1.0))
    y = float(rgb @ _LUMA)
    if y >= luma:
        return rgb * (luma / y)
    return rgb + (luma - y) / (1.0 - y) * (1.0 - rgb)


def _contrasting_colours(rng: np.random.Generator) -> Tuple[np.ndarray, np.ndarray]:
    """Base and pattern colours whose luminances differ by 0.2-0.35 (texture in grey too)."""
    h1, s1, y1 = rng.uniform(), rng.uniform(0.15, 0.8), rng.uniform(0.3, 0.75)
    h2, s2 = (h1 + rng.uniform(-0.3, 0.3)) % 1.0, rng.uniform(0.1, 0.8)
    dy = rng.uniform(0.2, 0.35)
    y2 = y1 - dy if y1 > 0.5 else y1 + dy
    return _colour_with_luma(h1, s1, y1), _colour_with_luma(h2, s2, float(np.clip(y2, 0.08, 0.95)))


def make_texture(rng: np.random.Generator, cfg: TextureConfig,
                  normal: Optional[np.ndarray]) -> SolidTexture:
    """Random solid texture; ``normal`` (planes) keeps all waves in-plane."""
    n_oct = max(1, int(math.floor(math.log2(cfg.max_wavelength / cfg.min_wavelength))) + 1)
    wavelengths = cfg.max_wavelength * 0.5 ** np.arange(n_oct)
    wpo = max(1, int(cfg.waves_per_octave))
    lam = np.repeat(wavelengths, wpo) * rng.uniform(0.8, 1.25, n_oct * wpo)
    k_noise = _random_unit(rng, lam.size) * (2 * np.pi / lam)[:, None]
    k_noise = _in_plane(k_noise, normal, rng)
    amp = (lam / cfg.max_wavelength) ** 0.4
    amp = amp / np.sqrt(0.5 * np.sum(amp ** 2))  # unit std of the sum
    ph_noise = rng.uniform(0, 2 * np.pi, lam.size)

    lam_t = rng.uniform(0.6, 2.0, 3)
    k_tint = _in_plane(_random_unit(rng, 3) * (2 * np.pi / lam_t)[:, None], normal, rng)
    amp_tint = np.full(3, cfg.tint_strength / np.sqrt(1.5))
    tint = rng.normal(size=3)
    tint = tint / np.linalg.norm(tint)

    pattern = str(cfg.patterns[rng.integers(len(cfg.patterns))]) if cfg.patterns else _PATTERN_STRIPES
    period = rng.uniform(*cfg.pattern_period)
    ph_pat = rng.uniform(0, 2 * np.pi, 3)
    if pattern == _PATTERN_CHECKER:
        if normal is not None:  # a 2-D checker in the plane
            u, v = _plane_basis(normal)
            a = rng.uniform(0, np.pi)
            k_pat = np.stack([np.cos(a) * u + np.sin(a) * v, -np.sin(a) * u + np.cos(a) * v,
                              np.zeros(3)]) * (2 * np.pi / period)
            k_pat[2] = 0.0
            ph_pat[2] = np.pi / 2
        else:  # 3-D checker (random orientation)
            q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
            k_pat = q * (2 * np.pi / period)
        threshold = 0.0
    elif pattern == _PATTERN_STRIPES:
        k_pat = np.zeros((3, 3))
        k_pat[0] = _in_plane(_random_unit(rng, 1), normal, rng)[0] * (2 * np.pi / period)
        ph_pat[1:] = np.pi / 2
        threshold = float(rng.uniform(-0.4, 0.4))
    elif pattern == _PATTERN_BLOBS:
        k_pat = _in_plane(_random_unit(rng, 3) * (2 * np.pi / (1.5 * period)), normal, rng)
        threshold = float(rng.uniform(0.2, 0.9))
    else:
        raise ValueError(f"unknown texture pattern {pattern!r}")
    c1, c2 = _contrasting_colours(rng)
    return SolidTexture(k_noise, ph_noise, amp, k_tint, rng.uniform(0, 2 * np.pi, 3), amp_tint,
                         tint, pattern, k_pat, ph_pat, threshold, c1, c2,
                         float(rng.uniform(*cfg.noise_contrast)))

