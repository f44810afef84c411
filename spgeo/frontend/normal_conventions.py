"""Normal-map conventions: named axes/sign conventions, their parser, and a check of a model's.

spgeo's convention: OpenCV camera frame (x right, y down, z forward), normals
pointing towards the camera.  A convention is a ``model_to_spgeo`` 3x3 signed
permutation ``M`` with ``n_spgeo = M @ n_model``.  :func:`check_convention_on_plane`
ranks all 48 signed permutations on a synthetic room with known normals.
"""
from __future__ import annotations

import itertools
import logging
import re
from dataclasses import dataclass
from types import MappingProxyType
from typing import Callable, List, Mapping, Optional, Tuple, Union

import numpy as np

from ..camera import PinholeCamera

__all__ = ["NORMAL_CONVENTIONS", "parse_convention", "signed_permutations",
           "render_synthetic_room", "ConventionScore", "RawNormalModel",
           "check_convention_on_plane"]

logger = logging.getLogger(__name__)

#: Named conventions as ``model_to_spgeo`` matrices (``n_spgeo = M @ n_model``).
#:
#: * ``spgeo`` / ``opencv-inward``: x right, y down, z forward, normals towards
#:   the camera (identity).
#: * ``opencv-outward`` / ``dsine``: same axes, opposite sign (a wall facing
#:   the camera is (0, 0, +1)).  DSINE's maintainer describes DSINE's output
#:   like this (github.com/baegwangbin/DSINE issue #12); not verified here.
#: * ``opengl``: x right, y up, z towards the viewer, normals towards the
#:   camera (a facing wall is (0, 0, +1)); the usual "blue = facing" colour maps.
#:
#: None of these is verified against a real model by spgeo: check with
#: :func:`check_convention_on_plane`.
NORMAL_CONVENTIONS: Mapping[str, Tuple[Tuple[float, ...], ...]] = MappingProxyType({
    "spgeo": ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    "opencv-inward": ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    "opencv-outward": ((-1, 0, 0), (0, -1, 0), (0, 0, -1)),
    "dsine": ((-1, 0, 0), (0, -1, 0), (0, 0, -1)),
    "opengl": ((1, 0, 0), (0, -1, 0), (0, 0, -1)),
})

_AXIS_WORDS = {
    "right": (0, 1), "left": (0, -1),
    "down": (1, 1), "up": (1, -1),
    "forward": (2, 1), "front": (2, 1), "into": (2, 1), "away": (2, 1),
    "back": (2, -1), "backward": (2, -1), "backwards": (2, -1), "towards": (2, -1),
    "toward": (2, -1), "out": (2, -1),
}


def parse_convention(text: str) -> np.ndarray:
    """``model_to_spgeo`` of a sentence like ``"x right, y up, z towards viewer"``.

    Each clause names a model axis (x, y, z) and the direction it points in
    the image: ``right``/``left``, ``down``/``up``, ``forward``/``front``/
    ``into (the scene)``/``away (from the camera)`` or ``back``/``towards
    (viewer|camera)``/``out (of the screen)``.  Add the clause
    ``"normals away from camera"`` (or ``"outward"``) when the model's normals
    point away from the camera; the default is towards it.  A named
    convention of :data:`NORMAL_CONVENTIONS` is accepted too.
    """
    if text in NORMAL_CONVENTIONS:
        return np.asarray(NORMAL_CONVENTIONS[text], dtype=np.float64)
    M = np.zeros((3, 3))
    flip = 1.0
    seen = set()
    for clause in re.split(r"[,;]", text.lower()):
        words = clause.split()
        if not words:
            continue
        if words[0] == "normals" or words[0] in ("outward", "inward"):
            if "outward" in words or ("away" in words and "from" in words):
                flip = -1.0
            continue
        if words[0] not in ("x", "y", "z") or len(words) < 2:
            raise ValueError(f"convention clause {clause.strip()!r} must look like 'x right'")
        model_axis = "xyz".index(words[0])
        direction = next((_AXIS_WORDS[w] for w in words[1:] if w in _AXIS_WORDS), None)
        if direction is None:
            raise ValueError(f"convention clause {clause.strip()!r}: unknown direction; use one "
                             f"of {sorted(_AXIS_WORDS)}")
        M[direction[0], model_axis] = direction[1]
        seen.add(words[0])
    if seen != {"x", "y", "z"} or abs(abs(np.linalg.det(M)) - 1) > 1e-9:
        raise ValueError(f"convention {text!r} must name x, y and z once each, along different "
                         "image directions")
    return flip * M


def signed_permutations() -> List[np.ndarray]:
    """All 48 3x3 signed permutation matrices (proper and improper)."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            M = np.zeros((3, 3))
            M[np.arange(3), perm] = signs
            out.append(M)
    return out


# --------------------------------------------------------- convention check
def render_synthetic_room(camera: Optional[PinholeCamera] = None, seed: int = 0
                          ) -> Tuple[np.ndarray, np.ndarray]:
    """Render a textured box room seen from inside; returns ``(image, normals)``.

    The camera (default 640x480, f = 525) sits at the origin looking along +z
    into a room with floor, ceiling, left/right walls and a back wall (plus a
    slanted panel), checker-textured and Lambert-shaded so a network sees
    perspective and shading cues.  ``normals`` (H, W, 3) are the true normals
    in spgeo's convention (towards the camera).
    """
    cam = camera or PinholeCamera(525.0, 525.0, 319.5, 239.5, 640, 480)
    rays = cam.rays()  # (H, W, 3), z = 1
    # planes: n . x = d with n pointing into the room (towards the camera)
    planes = [
        (np.array([0.0, -1.0, 0.0]), -1.2),   # floor y = 1.2 (below), normal up (-y)
        (np.array([0.0, 1.0, 0.0]), -1.3),    # ceiling y = -1.3, normal down (+y)
        (np.array([1.0, 0.0, 0.0]), -1.8),    # left wall x = -1.8, normal +x
        (np.array([-1.0, 0.0, 0.0]), -1.6),   # right wall x = 1.6, normal -x
        (np.array([0.0, 0.0, -1.0]), -4.0),   # back wall z = 4, normal -z
    ]
    s = np.sqrt(0.5)
    panel = (np.array([s, 0.0, -s]), -s * 2.6)  # slanted panel through (-0.4, ., 3.0)
    H, W = cam.height, cam.width
    best_t = np.full((H, W), np.inf)
    normals = np.zeros((H, W, 3))
    for n, d in planes + [panel]:
        denom = rays @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = d / denom
        ok = (denom < -1e-9) & (t > 0) & (t < best_t)
        if n is panel[0]:
            p = rays * t[..., None]
            ok &= (np.abs(p[..., 1]) < 0.45) & (p[..., 0] > -1.0) & (p[..., 0] < -0.1)
        best_t = np.where(ok, t, best_t)
        normals[ok] = n
    pts = rays * best_t[..., None]
    checker = ((np.floor(pts[..., 0] * 2.5) + np.floor(pts[..., 1] * 2.5)
                + np.floor(pts[..., 2] * 2.5)) % 2).astype(np.float64)
    light = np.array([0.3, -0.8, -0.5])
    light /= np.linalg.norm(light)
    shade = 0.35 + 0.65 * np.clip(normals @ light, 0.0, 1.0)  # light: direction to the lamp
    base = np.array([0.75, 0.7, 0.6]) * (0.6 + 0.4 * checker[..., None])
    rng = np.random.default_rng(seed)
    img = base * shade[..., None] * (1.0 / (1.0 + 0.08 * best_t[..., None]))
    img = np.clip(img + rng.normal(0.0, 0.01, img.shape), 0.0, 1.0).astype(np.float32)
    return img, normals.astype(np.float32)


@dataclass(frozen=True)
class ConventionScore:
    """Angular error (degrees) of the model on the synthetic scene for one
    candidate ``model_to_spgeo`` matrix.

    ``score_deg`` ranks the candidates: the mean over the scene's planes
    (distinct true normals) of each plane's median error, so that a large
    back wall cannot outvote the floor and side walls; with more than 32
    distinct true normals it is the mean over pixels.  ``median_deg`` /
    ``mean_deg`` are over all valid pixels; ``proper``: det = +1 (a rotation,
    not a reflection)."""

    model_to_spgeo: Tuple[Tuple[float, float, float], ...]
    score_deg: float
    median_deg: float
    mean_deg: float
    proper: bool


class RawNormalModel:
    """A normal model :func:`check_convention_on_plane` can query for its raw output.

    :class:`~spgeo.frontend.onnx_normals.NormalModel` derives from it (the model
    module builds on this one, not the other way round).
    """

    def predict_raw(self, image: np.ndarray):
        """An object whose ``normals`` are the (H, W, 3) output in the MODEL's convention."""
        raise NotImplementedError


def check_convention_on_plane(model: Union[RawNormalModel, Callable[[np.ndarray], np.ndarray]],
                              camera: Optional[PinholeCamera] = None,
                              image: Optional[np.ndarray] = None,
                              normals_gt: Optional[np.ndarray] = None) -> List[ConventionScore]:
    """Rank the 48 signed permutations by how well they map the model's raw
    output onto the true normals of a synthetic scene.

    Args:
        model: a :class:`RawNormalModel` such as
            :class:`~spgeo.frontend.onnx_normals.NormalModel` (its raw, unconverted
            output is used) or a callable ``image -> (H, W, 3)`` raw normals.
        camera: camera of the default synthetic room (640x480, f = 525).
        image, normals_gt: use this image and its true spgeo-convention normals
            instead of :func:`render_synthetic_room`.

    Returns:
        :class:`ConventionScore` list, best (lowest ``score_deg``) first; use
        ``result[0].model_to_spgeo`` as ``NormalOnnxConfig.model_to_spgeo``.
        Logs the top candidates.
    """
    if (image is None) != (normals_gt is None):
        raise ValueError("check_convention_on_plane: give both image and normals_gt, or neither")
    if image is None:
        image, normals_gt = render_synthetic_room(camera)
    raw = model.predict_raw(image).normals if isinstance(model, RawNormalModel) else model(image)
    raw = np.asarray(raw, dtype=np.float64)
    gt = np.asarray(normals_gt, dtype=np.float64)
    if raw.shape != gt.shape or raw.shape[-1] != 3:
        raise ValueError(f"raw normals {raw.shape} and ground truth {gt.shape} must both be "
                         "(H, W, 3)")
    valid = np.all(np.isfinite(raw), -1) & np.all(np.isfinite(gt), -1) & (
        np.linalg.norm(gt, axis=-1) > 0.5) & (np.linalg.norm(raw, axis=-1) > 1e-6)
    if not valid.any():
        raise ValueError("check_convention_on_plane: no valid pixels")
    idx = np.flatnonzero(valid)
    idx = idx[::max(1, len(idx) // 40000)]  # a regular subsample is plenty for 48 candidates
    r = raw.reshape(-1, 3)[idx]
    r /= np.linalg.norm(r, axis=-1, keepdims=True)
    g = gt.reshape(-1, 3)[idx]
    g /= np.linalg.norm(g, axis=-1, keepdims=True)
    mats = np.stack(signed_permutations())  # (48, 3, 3)
    mapped = np.einsum("kij,nj->kni", mats, r)
    ang = np.degrees(np.arccos(np.clip(np.einsum("kni,ni->kn", mapped, g), -1.0, 1.0)))
    med, mean = np.median(ang, axis=1), ang.mean(axis=1)
    _, plane = np.unique(np.round(g, 3), axis=0, return_inverse=True)
    plane = plane.reshape(-1)
    if plane.max() < 32:
        score = np.mean([np.median(ang[:, plane == p], axis=1) for p in range(plane.max() + 1)],
                        axis=0)
    else:
        score = mean
    order = np.lexsort((mean, score))
    scores = [ConventionScore(tuple(tuple(float(v) for v in row) for row in mats[k]),
                              float(score[k]), float(med[k]), float(mean[k]),
                              bool(np.linalg.det(mats[k]) > 0)) for k in order]
    for s in scores[:3]:
        logger.info("convention candidate %s: %.1f deg per plane (median %.1f, mean %.1f)%s",
                    s.model_to_spgeo, s.score_deg, s.median_deg, s.mean_deg,
                    "" if s.proper else " (reflection)")
    return scores
