"""Live 3-D viewing with rerun (optional dependency ``rerun-sdk``; ``pip install spgeo[viz]``).

:class:`RerunLogger` writes what spgeo computes to a rerun recording: the
viewer spawned locally (``"spawn"``), an ``.rrd`` file (``"save"``) or a
running viewer / server (``"connect"``).  ``rerun`` is imported only when a
logger is created: importing this module, :mod:`spgeo` or running the VO
without a logger never imports it.

Entity paths are named after spgeo's frames; ``world`` is the VO's world
(keyframe 0's camera, x right, y down, z forward: rerun's ``RDF``), or the
SfM / completion reference camera:

* ``world/camera``: ``Transform3D`` (``T_world_cam``, camera-to-world) and
  ``Pinhole`` (intrinsics, image size); ``world/camera/image``: the frame.
* ``world/trajectory``: ``LineStrips3D`` of the camera centres so far;
  ``world/ground_truth``: the ground-truth centres when known, mapped into
  the VO's world for display only (anchored at the first frame with ground
  truth, scale fitted by least squares on the centres so far; set
  :attr:`RerunLoggerConfig.ground_truth_scale` to fix it).
* ``world/keyframes/<k>``: ``Transform3D`` (``T_world_kf``) with
  ``.../points`` (``Points3D`` of :meth:`PrimitiveSet.point_cloud`, keyframe
  frame, coloured) and ``.../image`` (``Pinhole``) holding ``rgb``,
  ``segments`` (``SegmentationImage``: primitive index + 1, 0 = none),
  ``depth`` (``DepthImage``, VO units) and ``normals`` (camera-frame normals
  as colours, when the primitives carry normals).  A keyframe is logged again
  whenever the VO replaces it (mapping refines its pose and scales).
* ``world/mesh``: the fused mesh (``Mesh3D``, :meth:`RerunLogger.log_mesh`;
  ``spgeo vo --mesh``), logged once at the last frame.
* ``status``: ``TextLog`` per frame; ``timings/<stage>``: seconds per stage
  (``Scalars``); ``tracking/valid_fraction``, ``tracking/relative_cost``.

Everything per frame is on the ``frame`` sequence timeline (frame index).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence, Set, Tuple

import numpy as np

from ..configs import config_class
from ..viz import colorize_normals

__all__ = ["RerunLoggerConfig", "RerunLogger", "RERUN_MODES"]

log = logging.getLogger(__name__)

#: Sink modes of :class:`RerunLoggerConfig`.
RERUN_MODES = ("spawn", "save", "connect", "none")


@config_class
@dataclass(frozen=True)
class RerunLoggerConfig:
    """Options of :class:`RerunLogger`.

    Attributes:
        mode: ``"spawn"`` (start a local viewer and stream to it),
            ``"save"`` (write ``target``, an ``.rrd`` file), ``"connect"``
            (stream over gRPC to ``target``, a URL such as
            ``rerun+http://127.0.0.1:9876/proxy``; None: rerun's default) or
            ``"none"`` (no sink: the caller sets one on :attr:`RerunLogger.recording`).
        target: the file (``save``) or URL (``connect``).
        application_id: rerun application id (default ``"spgeo"``).
        recording_id: rerun recording id (default None: a random one).
        timeline: name of the frame-index sequence timeline.
        max_points_per_keyframe: points logged per keyframe cloud, evenly
            subsampled (> 0).
        log_images: log the frame image under ``world/camera/image``.
        jpeg_quality: colour images are stored JPEG-compressed at this quality
            (1-100; None: raw pixels).
        trajectory_every: re-log ``world/trajectory`` / ``world/ground_truth``
            every this many frames (>= 1).
        ground_truth_scale: display scale of the ground truth in the VO's
            units (None: least-squares fit on the camera centres so far).
        frustum_fraction: drawn frustum depth as a fraction of the
            keyframe's median depth (> 0).
    """

    mode: str = "spawn"
    target: Optional[str] = None
    application_id: str = "spgeo"
    recording_id: Optional[str] = None
    timeline: str = "frame"
    max_points_per_keyframe: int = 20000
    log_images: bool = True
    jpeg_quality: Optional[int] = 90
    trajectory_every: int = 1
    ground_truth_scale: Optional[float] = None
    frustum_fraction: float = 0.2

    def __post_init__(self) -> None:
        if self.mode not in RERUN_MODES:
            raise ValueError(f"RerunLoggerConfig.mode must be one of {RERUN_MODES}, "
                             f"got {self.mode!r}")
        if self.mode == "save" and not self.target:
            raise ValueError("RerunLoggerConfig: mode 'save' needs target (an .rrd file)")
        if int(self.max_points_per_keyframe) <= 0:
            raise ValueError("RerunLoggerConfig.max_points_per_keyframe must be > 0, "
                             f"got {self.max_points_per_keyframe!r}")
        if int(self.trajectory_every) < 1:
            raise ValueError("RerunLoggerConfig.trajectory_every must be >= 1, "
                             f"got {self.trajectory_every!r}")
        if self.ground_truth_scale is not None and not self.ground_truth_scale > 0:
            raise ValueError("RerunLoggerConfig.ground_truth_scale must be > 0 or None, "
                             f"got {self.ground_truth_scale!r}")
        if self.jpeg_quality is not None and not 1 <= int(self.jpeg_quality) <= 100:
            raise ValueError("RerunLoggerConfig.jpeg_quality must be in 1..100 or None, "
                             f"got {self.jpeg_quality!r}")
        if not self.frustum_fraction > 0:
            raise ValueError("RerunLoggerConfig.frustum_fraction must be > 0, "
                             f"got {self.frustum_fraction!r}")

    @classmethod
    def from_spec(cls, spec: Sequence[str], **options: Any) -> "RerunLoggerConfig":
        """Config from a command-line spec: ``["spawn"]``, ``["save", "FILE.rrd"]``
        or ``["connect"]`` / ``["connect", "ADDR"]``; ``options``: further fields.
        Raises ``ValueError`` (one line) for anything else."""
        spec = [str(s) for s in spec]
        usage = "expected 'spawn', 'save FILE.rrd' or 'connect [ADDR]'"
        if not spec:
            raise ValueError(usage)
        mode, args = spec[0].lower(), spec[1:]
        if mode == "spawn" and not args:
            return cls(mode="spawn", **options)
        if mode == "save" and len(args) == 1:
            if not args[0].lower().endswith(".rrd"):
                raise ValueError(f"save: the file must end in .rrd, got {args[0]!r}")
            return cls(mode="save", target=args[0], **options)
        if mode == "connect" and len(args) <= 1:
            return cls(mode="connect", target=args[0] if args else None, **options)
        raise ValueError(f"{usage}, got {' '.join(spec)!r}")


def _rgb_uint8(image: np.ndarray) -> np.ndarray:
    """(H, W[, 3]) uint8 or float [0, 1] -> (H, W, 3) uint8."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=-1)
    return img


def _subsample(n: int, m: int) -> np.ndarray:
    """``min(n, m)`` evenly spread indices of ``range(n)``."""
    if n <= m:
        return np.arange(n)
    return np.linspace(0, n - 1, m).round().astype(np.int64)


class RerunLogger:
    """Logs spgeo's frames, keyframes, trajectories and reconstructions to rerun
    (module docstring: entity paths and units).

    Use it as the per-frame hook of :func:`spgeo.apps.vo_run.run_odometry`
    (``on_frame=logger``) or call :meth:`on_frame` from any loop that has a
    frame, a :class:`~spgeo.vo.result.FrameResult`-like result (``index``,
    ``T_world_cam``, ``status``, optional ``keyframe_index``, ``timings``,
    ``track``) and an odometry-like object (optional ``keyframes``, a list of
    :class:`~spgeo.vo.keyframe.Keyframe`).  The lower-level ``log_*`` methods
    take arrays.  Close it (or use it as a context manager) to flush the sink.

    Args:
        config: :class:`RerunLoggerConfig`.
        recording: an existing ``rerun.RecordingStream`` to log to (its sinks
            are left alone when ``config.mode == "none"``).

    Raises ``ImportError`` (naming ``rerun-sdk``) when rerun is not installed.
    """

    def __init__(self, config: RerunLoggerConfig = RerunLoggerConfig(),
                 recording: Optional[Any] = None) -> None:
        try:
            import rerun as rr
        except ImportError as exc:
            raise ImportError("spgeo's viewer needs rerun: pip install 'spgeo[viz]' "
                              f"(rerun-sdk) [{exc}]") from None
        self._rr = rr
        self.config = config
        self.recording = recording if recording is not None else rr.RecordingStream(
            config.application_id, recording_id=config.recording_id)
        if config.mode == "spawn":
            self.recording.spawn()
        elif config.mode == "save":
            Path(config.target).parent.mkdir(parents=True, exist_ok=True)
            self.recording.save(config.target)
        elif config.mode == "connect":
            self.recording.connect_grpc(config.target)
        self.recording.log("world", rr.ViewCoordinates.RDF, static=True)
        self._logged_kfs: Dict[int, Any] = {}
        self._seen_kfs: Set[int] = set()
        self._kf_images: Dict[int, np.ndarray] = {}
        self._centres: List[np.ndarray] = []
        self._gt: List[Tuple[int, np.ndarray, np.ndarray]] = []   # (frame, gt, estimate)
        self._frame_depth = 1.0
        self._closed = False

    # ------------------------------------------------------------ plumbing
    def set_frame(self, index: int) -> None:
        """Set the frame-sequence timeline to ``index``."""
        self.recording.set_time(self.config.timeline, sequence=int(index))

    def _transform(self, T: np.ndarray):
        T = np.asarray(T, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"RerunLogger: a pose must be a finite 4x4 matrix, got shape "
                             f"{T.shape}")
        return self._rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3])

    def _pinhole(self, camera, plane_distance: Optional[float] = None):
        return self._rr.Pinhole(image_from_camera=np.asarray(camera.K, dtype=np.float64),
                                resolution=[camera.width, camera.height],
                                image_plane_distance=plane_distance)

    def _colour_image(self, image: np.ndarray):
        img = self._rr.Image(_rgb_uint8(image))
        q = self.config.jpeg_quality
        return img if q is None else img.compress(jpeg_quality=int(q))

    # ------------------------------------------------------------ arrays
    def log_camera(self, T_world_cam: np.ndarray, camera, image: Optional[np.ndarray] = None,
                   path: str = "world/camera", depth: Optional[np.ndarray] = None) -> None:
        """A camera at ``path``: pose (4x4 camera-to-world), pinhole frustum
        (``camera``: :class:`~spgeo.camera.PinholeCamera`), optional image
        (``path/image``) and depth (metres or VO units, ``path/depth``)."""
        rr = self._rr
        self.recording.log(path, self._transform(T_world_cam),
                           self._pinhole(camera, self._frame_depth * self.config.frustum_fraction))
        if image is not None:
            self.recording.log(f"{path}/image", self._colour_image(image))
        if depth is not None:
            d = np.nan_to_num(np.asarray(depth, dtype=np.float32), nan=0.0)
            self.recording.log(f"{path}/depth", rr.DepthImage(d, meter=1.0))

    def log_trajectory(self, positions: np.ndarray, path: str = "world/trajectory",
                       color: Sequence[int] = (255, 140, 0)) -> None:
        """(n, 3) camera centres as one line strip at ``path``."""
        p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        p = p[np.all(np.isfinite(p), axis=1)]
        self.recording.log(path, self._rr.LineStrips3D([p], colors=[tuple(color)]))

    def log_points(self, path: str, points: np.ndarray,
                   colors: Optional[np.ndarray] = None) -> None:
        """(n, 3) points, optional (n, 3) colours (float [0, 1] or uint8), evenly
        subsampled to ``max_points_per_keyframe``."""
        pts = np.asarray(points, dtype=np.float32).reshape(-1, 3)
        keep = _subsample(len(pts), int(self.config.max_points_per_keyframe))
        cols = None
        if colors is not None:
            cols = np.asarray(colors)[keep]
            cols = cols if cols.dtype == np.uint8 else (np.clip(cols, 0, 1) * 255).astype(np.uint8)
        self.recording.log(path, self._rr.Points3D(pts[keep], colors=cols))

    def log_mesh(self, path: str, vertices: np.ndarray, triangles: np.ndarray,
                 colors: Optional[np.ndarray] = None,
                 normals: Optional[np.ndarray] = None) -> None:
        """A triangle mesh (world frame) as ``Mesh3D`` at ``path``: (V, 3)
        ``vertices``, (T, 3) ``triangles`` (vertex indices), optional (V, 3)
        vertex ``colors`` (float [0, 1] or uint8) and ``normals``."""
        cols = None
        if colors is not None:
            cols = np.asarray(colors)
            cols = cols if cols.dtype == np.uint8 else (np.clip(cols, 0, 1) * 255).astype(np.uint8)
        self.recording.log(path, self._rr.Mesh3D(
            vertex_positions=np.asarray(vertices, dtype=np.float32).reshape(-1, 3),
            triangle_indices=np.asarray(triangles, dtype=np.uint32).reshape(-1, 3),
            vertex_colors=cols,
            vertex_normals=None if normals is None else np.asarray(normals, np.float32)))

    def log_primitives(self, path: str, primitives, image: Optional[np.ndarray] = None,
                       plane_distance: Optional[float] = None) -> None:
        """A :class:`~spgeo.primitives.PrimitiveSet`'s pictures under ``path``
        (a ``Pinhole`` with ``rgb``, ``segments``, ``depth`` and, when the set
        has normals, ``normals``)."""
        rr = self._rr
        cam = primitives.camera
        self.recording.log(path, self._pinhole(cam, plane_distance))
        if image is not None:
            self.recording.log(f"{path}/rgb", self._colour_image(image))
        self.recording.log(f"{path}/segments",
                           rr.SegmentationImage((primitives.label_image() + 1).astype(np.uint16)))
        self.log_depth(f"{path}/depth", primitives.depth_map())
        if getattr(primitives, "normals", None) is not None:
            n = np.full((cam.width * cam.height, 3), np.nan, np.float32)
            n[primitives.pixels] = primitives.normals
            self.recording.log(f"{path}/normals",
                               rr.Image(colorize_normals(n.reshape(cam.height, cam.width, 3))))

    def log_depth(self, path: str, depth: np.ndarray) -> None:
        """(H, W) depth (NaN invalid) as a ``DepthImage`` (one unit per metre)."""
        d = np.nan_to_num(np.asarray(depth, dtype=np.float32), nan=0.0)
        self.recording.log(path, self._rr.DepthImage(d, meter=1.0))

    def log_keyframe(self, k: int, keyframe, image: Optional[np.ndarray] = None,
                     pictures: bool = True) -> None:
        """Keyframe ``k`` (:class:`~spgeo.vo.keyframe.Keyframe`): pose, coloured
        cloud (keyframe frame, under the pose) and its primitive pictures
        (with ``pictures``; else only its depth, e.g. after new scales)."""
        path = f"world/keyframes/{int(k)}"
        prims = keyframe.primitives
        img = image if image is not None else keyframe.pyramid.images[0]
        if np.asarray(img).shape[:2] != prims.camera.shape:
            img = None
        self.recording.log(path, self._transform(keyframe.T_world_kf))
        cloud = prims.point_cloud(img)
        self.log_points(f"{path}/points", cloud.points, cloud.colors)
        if pictures:
            self.log_primitives(f"{path}/image", prims, img,
                                float(keyframe.median_depth) * self.config.frustum_fraction)
        else:
            self.log_depth(f"{path}/image/depth", prims.depth_map())

    def log_status(self, index: int, status: str, timings: Optional[Mapping[str, float]] = None,
                   track: Any = None) -> None:
        """Per-frame status (``TextLog`` at ``status``), timings in seconds
        (``timings/<stage>``) and, from a tracking result, ``tracking/*`` scalars."""
        rr = self._rr
        level = "WARN" if str(status) in ("lost", "reinit") else "INFO"
        self.recording.log("status", rr.TextLog(f"frame {index}: {status}", level=level))
        for stage, sec in (timings or {}).items():
            self.recording.log(f"timings/{stage}", rr.Scalars(float(sec)))
        if track is not None:
            for name in ("valid_fraction", "relative_cost"):
                v = getattr(track, name, None)
                if v is not None and np.isfinite(v):
                    self.recording.log(f"tracking/{name}", rr.Scalars(float(v)))

    # ------------------------------------------------------------ VO hook
    def on_frame(self, frame, frame_result, odometry=None) -> None:
        """Per-frame hook (see the class docstring).  ``frame``: the frame the
        VO saw (its ``T_world_cam``, when set, is the ground truth, data-set
        world); ``frame_result``: the VO's per-frame result; ``odometry``:
        gives the keyframes (logged when new or replaced)."""
        idx = int(frame_result.index)
        self.set_frame(idx)
        k_new = getattr(frame_result, "keyframe_index", None)
        if k_new is not None:
            self._kf_images[int(k_new)] = np.asarray(frame.image)
        kfs = self._log_keyframes(odometry)
        if kfs:
            self._frame_depth = float(kfs[-1].median_depth)
        T = np.asarray(frame_result.T_world_cam, dtype=np.float64)
        self.log_camera(T, frame.camera, frame.image if self.config.log_images else None)
        self._centres.append(T[:3, 3].copy())
        gt = getattr(frame, "T_world_cam", None)
        if gt is not None:
            self._gt.append((idx, np.asarray(gt, dtype=np.float64), T))
        if idx % int(self.config.trajectory_every) == 0:
            self._log_paths()
        self.log_status(idx, str(frame_result.status), getattr(frame_result, "timings", None),
                        getattr(frame_result, "track", None))

    __call__ = on_frame

    def finish(self, odometry) -> None:
        """Log the final state at the last frame: every keyframe as it is now,
        the final trajectory (``odometry.result().poses``) and the ground truth
        aligned to it."""
        res = odometry.result()
        if len(res.poses) == 0:
            return
        self.set_frame(len(res.poses) - 1)
        self._log_keyframes(odometry)
        poses = np.asarray(res.poses, dtype=np.float64)
        self._centres = [p for p in poses[:, :3, 3]]
        self._gt = [(i, g, poses[i]) for i, g, _ in self._gt if i < len(poses)]
        self._log_paths()

    def _log_keyframes(self, odometry) -> list:
        """Log the keyframes that are new (everything) or replaced (pose, cloud,
        depth) since the last call; returns them (in index order).

        With an odometry that has ``window_keyframes()`` (:class:`spgeo.vo.Odometry`)
        only those are looked at: a keyframe that left the window is final and
        was logged at its final state while in it; the logger then forgets it
        (its object and image), so its memory does not grow with the keyframes."""
        window = getattr(odometry, "window_keyframes", None)
        if callable(window):
            items = dict(window())
        else:
            items = dict(enumerate(getattr(odometry, "keyframes", ()) or ()))
        for k, kf in items.items():
            if self._logged_kfs.get(k) is not kf:
                self.log_keyframe(k, kf, self._kf_images.get(k), k not in self._seen_kfs)
                self._logged_kfs[k] = kf
                self._seen_kfs.add(k)
        if callable(window):
            for k in [k for k in self._logged_kfs if k not in items]:
                del self._logged_kfs[k]
                self._kf_images.pop(k, None)
        return [items[k] for k in sorted(items)]

    def _log_paths(self) -> None:
        if self._centres:
            self.log_trajectory(np.array(self._centres))
        if len(self._gt) >= 2:
            self.log_trajectory(self._ground_truth_in_world(), "world/ground_truth",
                                color=(40, 200, 60))

    def _ground_truth_in_world(self) -> np.ndarray:
        """Ground-truth centres in the VO's world: the first pair's relative
        pose anchors them, the scale is fixed or least squares (display only)."""
        gts = np.array([g for _, g, _ in self._gt])
        ests = np.array([e for _, _, e in self._gt])
        R = ests[0, :3, :3] @ gts[0, :3, :3].T
        a = (gts[:, :3, 3] - gts[0, :3, 3]) @ R.T
        b = ests[:, :3, 3] - ests[0, :3, 3]
        s = self.config.ground_truth_scale
        if s is None:
            den = float(np.sum(a * a))
            s = float(np.sum(a * b)) / den if den > 1e-12 else 1.0
            s = s if s > 0 else 1.0
        return ests[0, :3, 3] + s * a

    # ------------------------------------------------------------ SfM / completion
    def log_sfm(self, result, reference_image: np.ndarray,
                view_images: Sequence[np.ndarray] = ()) -> None:
        """A few-view SfM result (:class:`~spgeo.sfm.SfMResult`; world = the
        reference camera): ``world/reference`` (identity pose, primitives'
        pictures under ``world/reference/image``), ``world/views/<i>`` (pose
        ``T_ref_view``, frustum, image) and ``world/cloud``."""
        import cv2

        cam = result.camera
        ref = cv2.resize(np.asarray(reference_image), cam.size, interpolation=cv2.INTER_AREA)
        self.set_frame(0)
        depth = float(np.nanmedian(result.depth)) if np.any(np.isfinite(result.depth)) else 1.0
        self._frame_depth = depth
        self.recording.log("world/reference", self._transform(np.eye(4)))
        self.log_primitives("world/reference/image", result.primitives, ref,
                            depth * self.config.frustum_fraction)
        for i, T in enumerate(result.T_ref_view):
            img = view_images[i] if i < len(view_images) else None
            if img is not None:
                img = cv2.resize(np.asarray(img), cam.size, interpolation=cv2.INTER_AREA)
            self.log_camera(T, cam, img, path=f"world/views/{i}")
        cloud = result.primitives.point_cloud(ref)
        self.log_points("world/cloud", cloud.points, cloud.colors)
        self.recording.log("status", self._rr.TextLog(
            f"sfm: {result.status} ({', '.join(result.view_status)})"))

    def log_completion(self, image: np.ndarray, camera, result,
                       sparse: Optional[np.ndarray] = None) -> None:
        """A depth-completion result (:class:`~spgeo.completion.CompletionResult`)
        at the input resolution (``camera``): ``world/camera`` with the image,
        ``depth`` and ``sparse`` depth images, the primitives' pictures under
        ``world/primitives`` (their working resolution) and the completed
        cloud ``world/cloud``."""
        self.set_frame(0)
        depth = np.asarray(result.depth, dtype=np.float64)
        self._frame_depth = float(np.median(depth))
        self.log_camera(np.eye(4), camera, image, depth=depth)
        if sparse is not None:
            self.log_depth("world/camera/sparse", sparse)
        if len(result.primitives):
            self.recording.log("world/primitives", self._transform(np.eye(4)))
            self.log_primitives("world/primitives/image", result.primitives)
        pts = camera.unproject_depth_map(depth).reshape(-1, 3)
        self.log_points("world/cloud", pts, _rgb_uint8(image).reshape(-1, 3))

    # ------------------------------------------------------------ lifetime
    def close(self) -> None:
        """Flush and disconnect the sink (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self.recording.flush()
        if self.config.mode != "none":
            self.recording.disconnect()

    def __enter__(self) -> "RerunLogger":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
