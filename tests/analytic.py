"""Exact depth and normals of analytic surfaces seen by a pinhole camera (test helpers)."""
from __future__ import annotations

import numpy as np

from spgeo.camera import PinholeCamera


def plane(camera: PinholeCamera, normal, d: float):
    """Plane ``n . X = d`` (n towards the camera, d < 0 for a plane in front)."""
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    r = camera.rays()
    with np.errstate(divide="ignore", invalid="ignore"):
        z = d / (r @ n)
    z = np.where(z > 0, z, np.nan)
    return z, np.broadcast_to(n, r.shape).copy()


def sphere(camera: PinholeCamera, centre, radius: float):
    """Front surface of a sphere; NaN where the ray misses."""
    C = np.asarray(centre, float)
    r = camera.rays()
    rr = np.sum(r * r, -1)
    rc = r @ C
    disc = rc ** 2 - rr * (C @ C - radius ** 2)
    with np.errstate(invalid="ignore"):
        z = (rc - np.sqrt(disc)) / rr
    z = np.where(disc > 0, z, np.nan)
    X = r * z[..., None]
    return z, (X - C) / radius


def cylinder(camera: PinholeCamera, centre, radius: float):
    """Vertical (y-axis) cylinder through ``centre``; front surface."""
    C = np.asarray(centre, float)
    r = camera.rays()
    a = r[..., 0] ** 2 + r[..., 2] ** 2
    bb = r[..., 0] * C[0] + r[..., 2] * C[2]
    cc = C[0] ** 2 + C[2] ** 2 - radius ** 2
    disc = bb ** 2 - a * cc
    with np.errstate(invalid="ignore"):
        z = (bb - np.sqrt(disc)) / a
    z = np.where(disc > 0, z, np.nan)
    X = r * z[..., None]
    n = X - C
    n[..., 1] = 0
    return z, n / radius


def scale_fitted_rel_error(log_depth: np.ndarray, true_depth: np.ndarray, mask: np.ndarray):
    """Relative depth errors on ``mask`` after fitting the best log-scale (median)."""
    ld = log_depth[mask]
    lt = np.log(true_depth[mask])
    s = np.median(lt - ld)
    return np.abs(np.exp(ld + s) / np.exp(lt) - 1.0)
