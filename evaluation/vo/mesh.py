"""Fused-mesh quality of a VO run against a TSDF of the sensor depth at ground-truth poses.

Accuracy, completeness and chamfer distance of the TSDF mesh of the keyframes::

    spgeo eval vo_mesh --dataset 7scenes PATH [--frames 0:300] [--frontend classical]
        [--threshold 0.05] [--samples 200000] [--gt-stride 1] [--set FIELD=VALUE ...]
        [--out DIR]

The VO runs with the default configuration (``classical`` front-end, the
``spgeo vo`` processing size); its keyframes are fused at their final poses
(:func:`spgeo.io.fusion.fuse_odometry`) and the mesh is mapped into the ground
truth's world by the Sim(3) alignment of the per-frame ATE
(:meth:`spgeo.apps.vo_run.VORun.ate`: ``x_gt = s R x_vo + t``).  The reference
is the TSDF of the sensor depth at the ground-truth poses (every
``--gt-stride``-th frame, full resolution, :func:`spgeo.io.fusion.fuse_views`
with the same :class:`~spgeo.io.fusion.FusionConfig` defaults; 7-Scenes depth
is not registered to colour: an approximate reference).

Metrics (:func:`mesh_metrics`, metres): points are sampled uniformly on each
mesh's area; **accuracy** is the mean distance from the estimated mesh's
samples to the reference surface, **completion** the mean distance from the
reference samples to the estimated mesh, **completeness** the fraction of
reference samples within ``--threshold`` of the estimated mesh, **chamfer** the
mean of accuracy and completion.  Two more meshes of the same keyframes split
the error: the sensor depth at the aligned VO poses (the poses' share) and the
VO depth maps, times the Sim(3) scale, at the ground-truth poses (the depths'
share).  The fused mesh of a short monocular run
covers only what its keyframes saw; the reference covers what every frame saw.
"""
from __future__ import annotations

import argparse
import json
import logging
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Dict, Iterator, Optional, Sequence

import numpy as np

from spgeo.evaluation.tables import cell, markdown_table
from spgeo.evaluation.runner import (add_vo_arguments, open_sequence, protocol_parser,
                                     run_protocol, run_vo_dataset)

__all__ = ["MeshMetrics", "sample_surface", "distance_to_mesh", "mesh_metrics",
           "sim3_transform_mesh", "aligned_pose", "keyframe_rotation_errors_deg",
           "sensor_views", "MeshResult", "evaluate_mesh", "build_parser", "run", "main"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MeshMetrics:
    """Surface metrics of an estimated mesh against a reference (metres).

    Attributes:
        accuracy: mean distance estimated samples -> reference surface.
        accuracy_median: their median.
        completion: mean distance reference samples -> estimated mesh.
        completeness: fraction of reference samples within ``threshold``.
        chamfer: ``(accuracy + completion) / 2``.
        threshold: the completeness threshold.
        n_estimated, n_reference: samples used on each side.
    """

    accuracy: float
    accuracy_median: float
    completion: float
    completeness: float
    chamfer: float
    threshold: float
    n_estimated: int
    n_reference: int

    def to_dict(self) -> Dict[str, float]:
        return asdict(self)


def sample_surface(vertices: np.ndarray, triangles: np.ndarray, n: int,
                   seed: int = 0) -> np.ndarray:
    """(n, 3) points drawn uniformly on the area of a triangle mesh
    (deterministic in ``seed``; (0, 3) for a mesh without area)."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if len(t) == 0:
        return np.zeros((0, 3))
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    if not area.sum() > 0:
        return np.zeros((0, 3))
    rng = np.random.default_rng(seed)
    tri = rng.choice(len(t), size=int(n), p=area / area.sum())
    r1, r2 = rng.random(int(n)), rng.random(int(n))
    s = np.sqrt(r1)
    return ((1 - s)[:, None] * a[tri] + (s * (1 - r2))[:, None] * b[tri]
            + (s * r2)[:, None] * c[tri])


def distance_to_mesh(points: np.ndarray, vertices: np.ndarray,
                     triangles: np.ndarray) -> np.ndarray:
    """(n,) unsigned distance of each point to the nearest triangle
    (open3d ``RaycastingScene.compute_distance``); inf for an empty mesh."""
    import open3d as o3d

    p = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    if len(np.asarray(triangles)) == 0:
        return np.full(len(p), np.inf)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(vertices, dtype=np.float32)),
                        o3d.core.Tensor(np.asarray(triangles, dtype=np.uint32)))
    return scene.compute_distance(o3d.core.Tensor(p)).numpy().astype(np.float64)


def mesh_metrics(est_vertices: np.ndarray, est_triangles: np.ndarray,
                 ref_vertices: np.ndarray, ref_triangles: np.ndarray,
                 threshold: float = 0.05, n_samples: int = 200_000,
                 ref_points: Optional[np.ndarray] = None, seed: int = 0) -> MeshMetrics:
    """:class:`MeshMetrics` of an estimated mesh against a reference mesh (same
    frame and unit).  ``ref_points``: the reference samples for completeness
    and completion (default: ``n_samples`` drawn on the reference mesh), e.g.
    the surface points the cameras saw.  Raises ``ValueError`` for an empty
    estimated mesh or reference."""
    est = sample_surface(est_vertices, est_triangles, n_samples, seed)
    ref = (sample_surface(ref_vertices, ref_triangles, n_samples, seed + 1)
           if ref_points is None else np.asarray(ref_points, dtype=np.float64).reshape(-1, 3))
    if len(est) == 0 or len(ref) == 0:
        raise ValueError("mesh_metrics: empty estimated mesh or reference")
    acc = distance_to_mesh(est, ref_vertices, ref_triangles)
    comp = distance_to_mesh(ref, est_vertices, est_triangles)
    return MeshMetrics(float(acc.mean()), float(np.median(acc)), float(comp.mean()),
                       float(np.mean(comp < threshold)), float(0.5 * (acc.mean() + comp.mean())),
                       float(threshold), len(est), len(ref))


def sim3_transform_mesh(vertices: np.ndarray, scale: float, rotation: np.ndarray,
                        translation: np.ndarray) -> np.ndarray:
    """(V, 3) ``scale * R v + t`` of every vertex (the ATE alignment
    :class:`~spgeo.evaluation.trajectory.AteResult` maps the estimate's world
    onto the ground truth's)."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    return float(scale) * v @ np.asarray(rotation).T + np.asarray(translation).reshape(1, 3)


def sensor_views(frames, stride: int = 1) -> Iterator[tuple]:
    """Fusion views ``(image, sensor depth, camera, ground-truth T_world_cam)``
    of every ``stride``-th frame that has depth and a ground-truth pose."""
    for i in range(0, len(frames), int(stride)):
        f = frames[i]
        if f.depth is not None and f.T_world_cam is not None:
            yield f.image, f.depth, f.camera, f.T_world_cam


def aligned_pose(T_world_cam: np.ndarray, scale: float, rotation: np.ndarray,
                 translation: np.ndarray) -> np.ndarray:
    """The camera-to-world pose in the ground truth's world of an estimated
    ``T_world_cam`` under the Sim(3) ``x_gt = s R x_est + t`` (rotation
    ``R R_est``, centre ``s R c_est + t``; depths scale by ``s``)."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(rotation) @ np.asarray(T_world_cam)[:3, :3]
    T[:3, 3] = float(scale) * np.asarray(rotation) @ np.asarray(T_world_cam)[:3, 3] + translation
    return T


def _keyframe_views(run, frames, a, mode: str):
    """Fusion views of the keyframes with depth: ``"pose"``: the sensor depth
    at the aligned VO poses (the poses' share of the error); ``"depth"``: the
    VO depth maps (times the Sim(3) scale) at the ground-truth poses (the
    depths' share)."""
    odo = run.odometry
    frame_of = {f.keyframe_index: f.index for f in odo.frames if f.keyframe_index is not None}
    for k, image, kf in odo.iter_keyframes(odo.keyframes_with_depth()):
        f = frames[frame_of[k]]
        if mode == "pose":
            yield f.image, f.depth, f.camera, aligned_pose(kf.T_world_kf, a.scale, a.rotation,
                                                          a.translation)
        elif f.T_world_cam is not None:
            prims = kf.primitives
            yield image, prims.depth_map() * a.scale, prims.camera, f.T_world_cam


def keyframe_rotation_errors_deg(run, a) -> np.ndarray:
    """Angle (degrees) between each keyframe's aligned VO orientation
    (:func:`aligned_pose`) and its ground-truth orientation (keyframes with
    ground truth): the part of the map's error that a position-only Sim(3)
    alignment leaves."""
    res = run.result()
    out = []
    for i in np.flatnonzero(res.is_keyframe):
        G = run.gt_poses[i]
        if G is None:
            continue
        R = aligned_pose(res.poses[i], a.scale, a.rotation, a.translation)[:3, :3].T @ G[:3, :3]
        out.append(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))
    return np.array(out)


def _row(name: str, fused, vertices, ref, threshold: float, samples: int) -> Dict[str, object]:
    m = mesh_metrics(vertices, fused.triangles, ref.vertices, ref.triangles, threshold, samples)
    return {"mesh": name, **m.to_dict(), "n_views": fused.n_views,
            "n_triangles": len(fused.triangles)}


@dataclass
class MeshResult:
    """:func:`evaluate_mesh`'s measurements, as written to ``results.json``
    (``data``: ``rows`` (one per mesh), ``keyframe_rotation_error_deg``,
    ``ate_rmse_m``, ``sim3_scale``, ``vo``, ``reference``, ``n_frames``,
    ``n_keyframes``, ``fps``)."""

    data: Dict[str, object]

    def table(self) -> str:
        """Markdown table of the three meshes and a summary line."""
        return _table(self.data)


def evaluate_mesh(run, frames, threshold: float = 0.05, samples: int = 200_000,
                  gt_stride: int = 1, out: Optional[Path] = None) -> MeshResult:
    """Fuse the VO ``run`` (:class:`spgeo.apps.vo_run.VORun`), build the sensor-depth
    reference from its input ``frames`` (every ``gt_stride``-th), and measure the
    three meshes (module docstring; ``threshold`` metres, ``samples`` points per
    mesh); ``out``: write the aligned VO mesh and the reference there.

    Raises:
        ValueError: the run has no per-frame ATE alignment."""
    from spgeo.io.fusion import FusionConfig, fuse_views

    ate = run.ate()
    if ate is None or ate.get("per-frame") is None:
        raise ValueError("no ATE alignment (no ground truth or too few poses)")
    a = ate["per-frame"]
    ref = fuse_views(sensor_views(frames, gt_stride), FusionConfig())
    est = run.fuse()
    v = sim3_transform_mesh(est.vertices, a.scale, a.rotation, a.translation)
    pose_only = fuse_views(_keyframe_views(run, frames, a, "pose"))
    depth_only = fuse_views(_keyframe_views(run, frames, a, "depth"))
    rows = [_row("VO depth at VO poses (the fused map)", est, v, ref, threshold, samples),
            _row("sensor depth at VO poses", pose_only, pose_only.vertices, ref, threshold,
                 samples),
            _row("VO depth at ground-truth poses", depth_only, depth_only.vertices, ref,
                 threshold, samples)]
    if out:
        _write_meshes(Path(out), est, v, ref)
    rot = keyframe_rotation_errors_deg(run, a)
    return MeshResult({"rows": rows, "keyframe_rotation_error_deg": {
                           "mean": float(rot.mean()), "min": float(rot.min()),
                           "max": float(rot.max())},
                       "ate_rmse_m": a.rmse, "sim3_scale": a.scale, "vo": est.summary(),
                       "reference": ref.summary(), "n_frames": run.n_frames,
                       "n_keyframes": int(run.result().is_keyframe.sum()), "fps": run.fps})


def _write_meshes(out: Path, est, aligned_vertices: np.ndarray, ref) -> None:
    """``vo_mesh_aligned.ply`` (the VO mesh in the ground truth's world) and
    ``reference_mesh.ply`` in ``out``."""
    import open3d as o3d

    out.mkdir(parents=True, exist_ok=True)
    est.mesh.vertices = o3d.utility.Vector3dVector(aligned_vertices)
    o3d.io.write_triangle_mesh(str(out / "vo_mesh_aligned.ply"), est.mesh)
    o3d.io.write_triangle_mesh(str(out / "reference_mesh.ply"), ref.mesh)


def _table(res: Dict[str, object]) -> str:
    thr = res["rows"][0]["threshold"]
    lines = markdown_table(
        ["mesh (keyframes with depth)", "accuracy (cm)", "accuracy median (cm)",
         "completion (cm)", f"completeness (< {100 * thr:.0f} cm)", "chamfer (cm)"],
        [[r["mesh"], cell(100 * r["accuracy"]), cell(100 * r["accuracy_median"]),
          cell(100 * r["completion"]), cell(100 * r["completeness"], "{:.1f} %"),
          cell(100 * r["chamfer"])] for r in res["rows"]])
    lines.append(
        f"{res['n_frames']} frames, {res['n_keyframes']} keyframes ({res['vo']['n_views']} "
        f"fused), ATE RMSE {res['ate_rmse_m']:.4f} m; VO mesh {res['vo']['n_triangles']} "
        f"triangles (voxel {100 * res['vo']['voxel_size'] * res['sim3_scale']:.2f} cm after "
        f"alignment); reference {res['reference']['n_triangles']} triangles from "
        f"{res['reference']['n_views']} sensor depth maps at the ground-truth poses (voxel "
        f"{100 * res['reference']['voxel_size']:.2f} cm); aligned keyframe orientations "
        f"{res['keyframe_rotation_error_deg']['mean']:.1f} deg from the ground truth's "
        f"(min {res['keyframe_rotation_error_deg']['min']:.1f}, max "
        f"{res['keyframe_rotation_error_deg']['max']:.1f})")
    return "\n".join(lines)


NAME = "vo_mesh"


def build_parser() -> argparse.ArgumentParser:
    """The command line (module docstring)."""
    ap = protocol_parser(None, __doc__)
    add_vo_arguments(ap)
    ap.add_argument("--threshold", type=float, default=0.05,
                    help="completeness threshold in metres (default 0.05)")
    ap.add_argument("--samples", type=int, default=200_000,
                    help="points sampled on each mesh (default 200000)")
    ap.add_argument("--gt-stride", type=int, default=1,
                    help="fuse every N-th sensor depth map into the reference (default 1)")
    ap.add_argument("--out", default=None,
                    help="folder for results.json and the two meshes (aligned VO, reference)")
    return ap


def run(args: argparse.Namespace) -> int:
    """Run the VO on ``args.dataset``, :func:`evaluate_mesh`, print the table, write
    ``--out/results.json``."""
    vo_run = run_vo_dataset(args)
    res = evaluate_mesh(vo_run, open_sequence(args, load_depth=None), args.threshold,
                        args.samples, args.gt_stride, args.out)
    print(res.table())
    if args.out:
        (Path(args.out) / "results.json").write_text(json.dumps(res.data, indent=1) + "\n",
                                                     encoding="utf-8")
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":
    raise SystemExit(main())
