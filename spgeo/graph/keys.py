"""The one key scheme of the project's GTSAM graphs, in GTSAM's symbol-shorthand style.

Every variable key of every graph is made here (no ``gtsam.symbol`` call elsewhere in
``spgeo/`` or ``factors/``; tests/test_layering.py checks it).  A key is a character and
an index (``gtsam.symbol(char, index)``):

====  =======================================  ============================================
char  variable                                 index
====  =======================================  ============================================
x     camera pose ``T_world_cam`` (Pose3)      SfM: image ``j`` (0 = reference);
                                               VO: keyframe ``k``
s     primitive shape (log-scale (1,) or       primitive ``i`` of keyframe ``k``:
      inverse-depth plane (3,))                ``k * MAX_PRIMS + i`` (SfM, completion: k = 0)
b     affine brightness ``(a, b)``             SfM: view ``j`` seen from the reference;
                                               VO: keyframe ``k`` seen from ``k - 1``
c     affine brightness ``(a, b)``             VO: keyframe ``k - 1`` seen from ``k``
e     affine brightness ``(a, b)``             VO: keyframe ``hi`` seen from ``lo < hi - 1``:
                                               ``hi * MAX_PRIMS + lo``
g     affine brightness ``(a, b)``             VO: keyframe ``lo`` seen from ``hi > lo + 1``:
                                               ``hi * MAX_PRIMS + lo``
f     supporting frame's pose (Pose3)          VO: frame number
d     supporting frame's brightness            VO: frame number
l     sparse landmark's world point (Point3)   VO: landmark id (:mod:`spgeo.vo.landmarks`)
====  =======================================  ============================================

The loop-closure pose graph (:mod:`spgeo.loop.pose_graph`) holds one kind of variable,
each keyframe's ``Similarity3``: its keys are the plain integers ``k``
(:func:`similarity_key`).

The values never change: GTSAM orders the variables by key, and the floating-point
results of a solve depend on that order.
"""
from __future__ import annotations

import gtsam

__all__ = ["MAX_PRIMS", "pose_key", "scale_key", "brightness_key", "pair_brightness_key",
           "support_pose_key", "support_brightness_key", "landmark_key", "similarity_key", "symbol_index"]

#: primitives per keyframe in the packed index of ``s`` (and of ``e`` / ``g``)
MAX_PRIMS = 1_000_000


def pose_key(j: int) -> int:
    """Key ``x j`` of ``T_world_cam`` of image ``j`` (SfM; 0 = reference) or keyframe
    ``j`` (VO)."""
    return gtsam.symbol("x", int(j))


def scale_key(i: int, keyframe: int = 0) -> int:
    """Key ``s (keyframe * MAX_PRIMS + i)`` of primitive ``i``'s shape variable
    (log-scale, or plane with the planar model) in keyframe ``keyframe`` (0: the one
    primitive set of SfM and completion)."""
    return gtsam.symbol("s", int(keyframe) * MAX_PRIMS + int(i))


def brightness_key(j: int) -> int:
    """Key ``b j`` of SfM view ``j``'s affine brightness ``(a, b)`` (seen from the
    reference)."""
    return gtsam.symbol("b", j)


def pair_brightness_key(ref: int, tgt: int) -> int:
    """Key of the affine brightness of keyframe ``tgt`` seen from ``ref`` (any two
    keyframes; consecutive ones use the symbols ``b``/``c`` indexed by the later
    keyframe, others ``e``/``g``)."""
    hi, lo = int(max(ref, tgt)), int(min(ref, tgt))
    if hi - lo == 1:
        return gtsam.symbol("b" if tgt > ref else "c", hi)
    return gtsam.symbol("e" if tgt > ref else "g", hi * MAX_PRIMS + lo)


def support_pose_key(frame: int) -> int:
    """Key ``f frame`` of supporting frame ``frame``'s pose (frame number)."""
    return gtsam.symbol("f", int(frame))


def support_brightness_key(frame: int) -> int:
    """Key ``d frame`` of supporting frame ``frame``'s brightness (seen from its keyframe)."""
    return gtsam.symbol("d", int(frame))


def landmark_key(landmark: int) -> int:
    """Key ``l landmark`` of a sparse landmark's world point (landmark id)."""
    return gtsam.symbol("l", int(landmark))


def similarity_key(k: int) -> int:
    """Key of keyframe ``k``'s ``Similarity3`` in the loop pose graph: the integer ``k``."""
    return int(k)


def symbol_index(key: int) -> int:
    """The index of a symbol key (e.g. ``i`` of :func:`scale_key` ``(i)``)."""
    return gtsam.Symbol(key).index()
