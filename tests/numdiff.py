"""Central-difference Jacobians of gtsam factors on their manifolds (test helper)."""
from __future__ import annotations

from typing import Iterable

import numpy as np

import gtsam


def numerical_jacobian(factor, values: gtsam.Values, key: int, pose_keys: Iterable[int],
                       eps: float = 1e-6) -> np.ndarray:
    """d unwhitenedError / d delta_key by central differences of ``values.retract``;
    ``pose_keys`` are the Pose3 keys (tangent dimension 6), the others Vectors."""
    pose_keys = set(pose_keys)

    def dim(k):
        return 6 if k in pose_keys else values.atVector(k).size

    cols = []
    for j in range(dim(key)):
        out = []
        for sgn in (1, -1):
            delta = gtsam.VectorValues()
            for k in values.keys():
                vec = np.zeros(dim(k))
                if k == key:
                    vec[j] = sgn * eps
                delta.insert(k, vec)
            out.append(factor.unwhitenedError(values.retract(delta)))
        cols.append((out[0] - out[1]) / (2 * eps))
    return np.stack(cols, axis=1)
