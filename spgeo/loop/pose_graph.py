"""Sim(3) pose-graph optimisation of keyframes (GTSAM ``BetweenFactorSimilarity3``).

Each keyframe ``k`` is a variable ``S_world_k`` (convention of :mod:`spgeo.similarity`:
``x_world = s R x_k + t``), initialised from its rigid input pose ``T_world_kf``
(``s = 1``).  An edge ``(i, j, S_i_j)`` measures ``inv(S_world_i) @ S_world_j``:
odometry edges between consecutive keyframes are the input poses' relative motions
(scale 1 unless the caller measured one), loop edges come from verification
(:func:`spgeo.loop.verify_sim3`) and carry the scale ratio of the two keyframes' depth
units.  The first keyframe is held at its input pose and scale 1 by a tight prior (the
gauge), so the corrected map is in its units.  The result's ``scales[k]`` is how much
keyframe ``k``'s depths grow (its primitives' log-scales gain ``log scales[k]``) when
its pose becomes ``T_world_kf[k]`` (docs/design.md §5.2).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import List, Optional, Sequence

import numpy as np

from ..geometry import check_pose, invert_pose
from ..graph.keys import similarity_key
from ..similarity import check_sim3, from_gtsam, sim3_parts, to_gtsam
from .config import PoseGraphConfig

__all__ = ["Sim3Edge", "PoseGraphResult", "odometry_edges", "optimise_sim3_pose_graph"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Sim3Edge:
    """A relative Sim(3) measurement between keyframes ``i`` and ``j`` (indices into the
    keyframe list given to :func:`optimise_sim3_pose_graph`).

    Attributes:
        i, j: keyframe indices.
        S_i_j: 4x4 similarity mapping keyframe ``j``'s camera points (in its depth
            units) into keyframe ``i``'s camera (in its units).
        sigmas: ``(7,)`` standard deviations of the error in GTSAM's Similarity3
            tangent order (rotation rad x3, translation x3, log-scale), or None for
            the configuration's default of the edge's kind.
        loop: a loop edge (else odometry).
        information: ``(7, 7)`` information matrix of the error in the same tangent
            (a right perturbation of ``S_i_j``); used instead of ``sigmas`` when given.
    """

    i: int
    j: int
    S_i_j: np.ndarray
    sigmas: Optional[np.ndarray] = None
    loop: bool = False
    information: Optional[np.ndarray] = None


@dataclass
class PoseGraphResult:
    """Corrected keyframes.

    Attributes:
        S_world_kf: (N, 4, 4) optimised similarities (camera-to-world).
        T_world_kf: (N, 4, 4) their rigid parts ``[[R, t], [0, 1]]``: the corrected
            camera-to-world poses.
        scales: (N,) ``s`` of each keyframe: multiply its depths by ``s`` (log-scale
            ``+= log s``) together with moving it to ``T_world_kf``.
        initial_error, final_error: GTSAM graph error (half the sum of squared
            whitened residuals) before and after.
        iterations: Levenberg-Marquardt iterations run.
    """

    S_world_kf: np.ndarray
    T_world_kf: np.ndarray
    scales: np.ndarray
    initial_error: float
    final_error: float
    iterations: int


def _sigmas3(triple: Sequence[float]) -> np.ndarray:
    r, t, s = (float(v) for v in triple)
    return np.array([r, r, r, t, t, t, s])


def odometry_edges(T_world_kf: Sequence[np.ndarray],
                   sigmas: Optional[np.ndarray] = None) -> List[Sim3Edge]:
    """Edges ``(k, k+1)`` with the relative rigid motion ``inv(T_world_k) @ T_world_k+1``
    of the given camera-to-world poses (scale 1)."""
    poses = [check_pose(T, f"T_world_kf[{k}]") for k, T in enumerate(T_world_kf)]
    return [Sim3Edge(k, k + 1, invert_pose(poses[k]) @ poses[k + 1], sigmas)
            for k in range(len(poses) - 1)]


def _edge_noise(edge: Sim3Edge, config: PoseGraphConfig):
    import gtsam

    if edge.information is not None:
        info = np.asarray(edge.information, np.float64)
        if info.shape != (7, 7) or not np.all(np.isfinite(info)):
            raise ValueError(f"Sim3Edge({edge.i}, {edge.j}): information must be a finite 7x7 "
                             "matrix")
        info = 0.5 * (info + info.T)
        if np.linalg.eigvalsh(info).min() <= 0:
            raise ValueError(f"Sim3Edge({edge.i}, {edge.j}): information must be positive "
                             "definite")
        noise = gtsam.noiseModel.Gaussian.Information(info)
    else:
        default = config.loop_sigmas if edge.loop else config.odometry_sigmas
        sig = _sigmas3(default) if edge.sigmas is None else np.asarray(edge.sigmas, np.float64)
        if sig.shape != (7,) or not np.all(sig > 0):
            raise ValueError(f"Sim3Edge({edge.i}, {edge.j}): sigmas must be 7 positive values")
        noise = gtsam.noiseModel.Diagonal.Sigmas(sig)
    if edge.loop and config.loop_huber > 0:
        noise = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Huber.Create(config.loop_huber), noise)
    return noise


def _build_graph(poses: List[np.ndarray], edges: Sequence[Sim3Edge], config: PoseGraphConfig):
    import gtsam

    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for k, T in enumerate(poses):
        values.insert(similarity_key(k), to_gtsam(T))
    graph.add(gtsam.PriorFactorSimilarity3(
        similarity_key(0), to_gtsam(poses[0]),
        gtsam.noiseModel.Isotropic.Sigma(7, config.gauge_sigma)))
    for e in edges:
        if not (0 <= e.i < len(poses) and 0 <= e.j < len(poses)) or e.i == e.j:
            raise ValueError(f"Sim3Edge({e.i}, {e.j}): indices must differ and lie in "
                             f"[0, {len(poses)})")
        S = check_sim3(e.S_i_j, f"Sim3Edge({e.i}, {e.j}).S_i_j")
        graph.add(gtsam.BetweenFactorSimilarity3(similarity_key(e.i), similarity_key(e.j),
                                                 to_gtsam(S), _edge_noise(e, config)))
    return graph, values


def optimise_sim3_pose_graph(T_world_kf: Sequence[np.ndarray], edges: Sequence[Sim3Edge],
                             config: PoseGraphConfig = PoseGraphConfig()) -> PoseGraphResult:
    """Sim(3) pose graph over keyframes; the first keyframe is the gauge.

    Args:
        T_world_kf: N >= 1 rigid camera-to-world keyframe poses (4x4), the initial values.
        edges: odometry and loop :class:`Sim3Edge` s (indices into ``T_world_kf``);
            a keyframe no edge reaches keeps its input pose.
        config: :class:`PoseGraphConfig`.
    Returns:
        :class:`PoseGraphResult`; with edges consistent with the input poses (no loop)
        the input comes back unchanged (to the solver's precision).
    Raises:
        ValueError: bad poses, similarities, indices or sigmas.
    """
    import gtsam

    poses = [check_pose(T, f"T_world_kf[{k}]") for k, T in enumerate(T_world_kf)]
    if not poses:
        raise ValueError("optimise_sim3_pose_graph: no keyframes")
    graph, values = _build_graph(poses, edges, config)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(config.max_iterations))
    params.setRelativeErrorTol(float(config.relative_error_tol))
    params.setAbsoluteErrorTol(0.0)
    optimiser = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    initial = float(graph.error(values))
    solution = optimiser.optimize()
    S = np.stack([from_gtsam(solution.atSimilarity3(similarity_key(k))) for k in range(len(poses))])
    T = np.repeat(np.eye(4)[None], len(poses), axis=0)
    scales = np.empty(len(poses))
    for k in range(len(poses)):
        R, t, s = sim3_parts(S[k])
        T[k, :3, :3], T[k, :3, 3], scales[k] = R, t, s
    final = float(graph.error(solution))
    log.debug("Sim(3) pose graph: %d keyframes, %d edges, error %.3g -> %.3g in %d iterations",
              len(poses), len(edges), initial, final, optimiser.iterations())
    return PoseGraphResult(S, T, scales, initial, final, int(optimiser.iterations()))
