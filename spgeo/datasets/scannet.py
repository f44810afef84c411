"""ScanNet reader (SensReader export layout) and a writer of synthetic scenes in it.

Layout (what ScanNet's ``SensReader/python/reader.py`` writes with
``--export_depth_images --export_color_images --export_poses
--export_intrinsics``; see ``SensorData.export_*`` in github.com/ScanNet/ScanNet)::

    <root>/<scene_id>/
      color/<frame>.jpg                 8-bit RGB JPEG, 1296x968 in ScanNet
      depth/<frame>.png                 uint16 millimetres (depth shift 1000), 0 = none; 640x480
      pose/<frame>.txt                  4x4 camera-to-world; every entry -inf where tracking failed
      intrinsic/intrinsic_color.txt     4x4, K of the colour camera (top-left 3x3)
      intrinsic/intrinsic_depth.txt     4x4, K of the depth camera
      intrinsic/extrinsic_{color,depth}.txt   (not used)

``<frame>`` is the frame number without zero padding (``0.jpg``, ``1.jpg`` ...;
with ``--frame_skip k`` only multiples of ``k`` exist).  Poses are written with
``%f`` (6 decimals, float32 source) and are projected onto SE(3).

:class:`ScanNetScene` returns :class:`~spgeo.frame.Frame` s whose colour image is
resized to the depth resolution (``cv2.INTER_AREA``) with the colour intrinsics
resized to match (:meth:`PinholeCamera.resized`), so image and depth share one
pixel grid.  ScanNet's depth is the structure sensor's, calibrated to the colour
camera but not re-rendered into it: the alignment is as good as ScanNet's
calibration (``intrinsics="depth"`` uses the depth camera's K instead).

:func:`write_synthetic_scannet` writes a procedural room (:mod:`spgeo.synthetic`)
in this layout (JPEG colour at a different resolution than depth).

Not registered in :func:`spgeo.datasets.open_dataset` (the command line's
``--dataset`` kinds are exactly the registered readers).
"""
from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional, Sequence, Tuple

import cv2
import numpy as np

from ..camera import PinholeCamera
from ..configs import config_class
from ..frame import Frame
from ..images import read_raw_image
from .common import (FileRecord, FrameSelection, FrameSequence, check_depth_scale,
                     numbered_frames)
from .files import PathLike, read_depth_png, read_matrix_file, read_pose_file, read_rgb

__all__ = ["ScanNetConfig", "ScanNetScene", "list_scenes", "read_scannet_matrix",
           "resize_depth_nearest", "write_synthetic_scannet"]

log = logging.getLogger(__name__)

_FRAME_RE = re.compile(r"^(\d+)\.(jpg|jpeg|png)$", re.IGNORECASE)
_INTRINSICS = ("color", "depth")


def read_scannet_matrix(path: PathLike) -> np.ndarray:
    """A ScanNet 4x4 text matrix (pose or intrinsics) as float64; non-finite
    entries (``-inf`` of invalid poses) are kept.  Raises ``FileNotFoundError``
    or ``ValueError`` naming the file."""
    return read_matrix_file(path, (4, 4))


def _camera_from_4x4(path: Path, width: int, height: int) -> PinholeCamera:
    M = read_scannet_matrix(path)
    if not np.all(np.isfinite(M[:3, :3])):
        raise ValueError(f"intrinsics file {path} contains non-finite values")
    try:
        return PinholeCamera.from_K(M[:3, :3], width, height)
    except ValueError as exc:
        raise ValueError(f"invalid intrinsics in {path}: {exc}") from None


def _image_size(path: Path) -> Tuple[int, int]:
    img = read_raw_image(path)
    return int(img.shape[1]), int(img.shape[0])


@config_class
@dataclass
class ScanNetConfig:
    """Options of :class:`ScanNetScene`.

    Attributes:
        image_size: ``(width, height)`` of the returned images and depth maps;
            default None = the depth resolution (640x480 in ScanNet), so colour
            is resized onto the depth grid.
        intrinsics: ``"color"`` (default): the colour camera's K
            (``intrinsic_color.txt``) resized to ``image_size``; ``"depth"``:
            the depth camera's K (``intrinsic_depth.txt``) resized likewise.
        load_depth: read the depth maps (default True).
        depth_scale: raw depth units per metre (default 1000: millimetres, the
            SensReader's depth shift).
        frames: selection by frame number (``"A:B[:S]"``, slice, range or list;
            default None = all).
    """

    image_size: Optional[Tuple[int, int]] = None
    intrinsics: str = "color"
    load_depth: bool = True
    depth_scale: float = 1000.0
    frames: FrameSelection = None


class ScanNetScene(FrameSequence):
    """Lazy reader of one exported ScanNet scene (see the module docstring).

    ``Frame.timestamp`` is the frame number (ScanNet exports carry no times),
    ``Frame.T_world_cam`` is None where the pose is invalid (non-finite).
    Raises ``FileNotFoundError`` naming the missing folder or file.
    """

    def __init__(self, path: PathLike, config: Optional[ScanNetConfig] = None, **kwargs) -> None:
        super().__init__()
        cfg = self._open(path, ScanNetConfig, config, kwargs, "ScanNet scene folder")
        root = self.root
        need = ["color", "pose", "intrinsic"] + (["depth"] if cfg.load_depth else [])
        for sub in need:
            if not (root / sub).is_dir():
                raise FileNotFoundError(f"ScanNet scene {root}: folder not found: {root / sub} "
                                        "(expected the SensReader export layout)")
        found, selected = numbered_frames(root / "color", _FRAME_RE, "images", cfg.frames,
                                          lambda: f"no <frame>.jpg images in {root / 'color'}")
        self._records = [FileRecord(n, float(n), found[n], root / "depth" / f"{n}.png",
                                    pose_path=root / "pose" / f"{n}.txt") for n in selected]

        # sizes: colour from the first image, depth from the first depth map
        self.color_size = _image_size(self._records[0].color_path)
        depth_file = self._records[0].depth_path
        if depth_file.is_file():
            self.depth_size: Optional[Tuple[int, int]] = _image_size(depth_file)
        elif cfg.load_depth:
            raise FileNotFoundError(f"ScanNet depth file not found: {depth_file}")
        else:
            self.depth_size = None
        size = cfg.image_size or self.depth_size or self.color_size
        size = (int(size[0]), int(size[1]))
        intr = root / "intrinsic"
        self.color_camera = _camera_from_4x4(intr / "intrinsic_color.txt", *self.color_size)
        self.depth_camera = (_camera_from_4x4(intr / "intrinsic_depth.txt", *self.depth_size)
                             if self.depth_size is not None
                             and (intr / "intrinsic_depth.txt").is_file() else None)
        if cfg.intrinsics == "depth":
            if self.depth_camera is None:
                raise FileNotFoundError(f"ScanNet intrinsics file not found: "
                                        f"{intr / 'intrinsic_depth.txt'}")
            base = self.depth_camera
        else:
            base = self.color_camera
        self._raw_camera = base if base.size == size else base.resized(*size)

    def _check_config(self, cfg: ScanNetConfig) -> None:
        if cfg.intrinsics not in _INTRINSICS:
            raise ValueError(f"ScanNetConfig.intrinsics must be one of {_INTRINSICS}, "
                             f"got {cfg.intrinsics!r}")
        check_depth_scale(cfg.depth_scale)

    @property
    def scene_id(self) -> str:
        return self._name

    def frame_position(self, number: int) -> int:
        """Position in the selection of frame number ``number`` (``ValueError`` if absent)."""
        for i, r in enumerate(self._records):
            if r.number == int(number):
                return i
        raise ValueError(f"ScanNet scene {self._name}: no frame number {number}")

    def _pose(self, rec: FileRecord) -> Optional[np.ndarray]:
        return read_pose_file(rec.pose_path, "ScanNet", read_scannet_matrix)

    def _load(self, index: int, rec: FileRecord) -> Frame:
        cam = self._raw_camera
        image = read_rgb(rec.color_path)
        if image.shape[:2] != cam.shape:
            image = np.clip(cv2.resize(image, cam.size, interpolation=cv2.INTER_AREA), 0.0, 1.0)
        depth = None
        if self.config.load_depth:
            depth = read_depth_png(rec.depth_path, self.config.depth_scale)
            if depth.shape != cam.shape:
                depth = resize_depth_nearest(depth, cam.size)
        meta = {"dataset": "scannet", "scene": self._name, "index": index,
                "frame_number": rec.number, "rgb_path": str(rec.color_path),
                "depth_path": str(rec.depth_path) if depth is not None else None,
                "pose_path": str(rec.pose_path), "timestamp_is_frame_number": True,
                "color_size": self.color_size, "depth_size": self.depth_size}
        return Frame(image=np.ascontiguousarray(image, dtype=np.float32), camera=cam,
                     timestamp=rec.timestamp, depth=depth, T_world_cam=self._pose(rec),
                     name=str(rec.number), meta=meta)


def list_scenes(root: PathLike) -> List[Path]:
    """Scene folders (holding ``color/``) under ``root``, sorted; ``[root]`` if
    ``root`` is itself a scene.  Raises ``FileNotFoundError`` if there is none."""
    root = Path(root).expanduser()
    if not root.is_dir():
        raise FileNotFoundError(f"ScanNet root folder not found: {root}")
    if (root / "color").is_dir():
        return [root]
    scenes = sorted(p for p in root.iterdir() if p.is_dir() and (p / "color").is_dir())
    if not scenes:
        raise FileNotFoundError(f"no ScanNet scene folders (<scene_id>/color/) in {root}")
    return scenes


def resize_depth_nearest(depth: np.ndarray, size: Tuple[int, int]) -> np.ndarray:
    """Nearest-neighbour resampling of a depth map to ``size = (width, height)``
    with pixel centres aligned (``cv2.resize`` / :meth:`PinholeCamera.resized`
    convention): output pixel ``i`` takes input pixel ``floor((i + 0.5) * in / out)``.
    Never mixes depths across edges."""
    depth = np.asarray(depth)
    h, w = depth.shape
    W, H = int(size[0]), int(size[1])
    cols = np.minimum(((np.arange(W) + 0.5) * (w / W)).astype(np.int64), w - 1)
    rows = np.minimum(((np.arange(H) + 0.5) * (h / H)).astype(np.int64), h - 1)
    return depth[rows[:, None], cols[None, :]]


def _save_matrix(path: Path, M: np.ndarray) -> None:
    """4x4 text like ``SensorData.save_mat_to_file`` (one ``%f`` row per line)."""
    with open(path, "w", encoding="utf-8") as fh:
        for row in np.asarray(M, np.float64):
            fh.write(" ".join("%f" % v for v in row) + "\n")


def write_synthetic_scannet(root: PathLike, scene_id: str = "scene0000_00", seed: int = 0,
                            n_frames: int = 61, color_size: Tuple[int, int] = (640, 480),
                            depth_size: Tuple[int, int] = (320, 240), frame_skip: int = 1,
                            fps: float = 30.0, trajectory=None, supersample: int = 2,
                            invalid_pose_frames: Sequence[int] = (), jpeg_quality: int = 95,
                            scene=None, progress: bool = False) -> Path:
    """Write a synthetic scene in the ScanNet export layout and return its folder.

    A procedural room (:meth:`SyntheticScene.generate`, ``seed``) seen along a
    smooth hand-held trajectory (:func:`spgeo.synthetic.make_trajectory`,
    ``n_frames`` at ``fps``, :class:`TrajectoryConfig` ``trajectory``); frames
    ``0, frame_skip, 2 frame_skip, ...`` are written like SensReader's
    ``--frame_skip``: ``color/<n>.jpg`` (``color_size``, JPEG quality
    ``jpeg_quality``, rendered with ``supersample``), ``depth/<n>.png``
    (``depth_size``, uint16 mm, 0 = none), ``pose/<n>.txt`` (4x4
    camera-to-world, ``-inf`` everywhere for frames in ``invalid_pose_frames``,
    as ScanNet marks lost tracking), ``intrinsic/intrinsic_{color,depth}.txt``
    and identity ``extrinsic_{color,depth}.txt``.  Colour and depth cameras are
    the same view (:func:`spgeo.synthetic.default_camera` at each size), so a
    reader that resizes colour to the depth grid must align them exactly.
    ``scene``: a ready :class:`SyntheticScene` (skips generation);
    ``progress``: tqdm progress bar over the frames.
    """
    from .. import synthetic

    if int(n_frames) < 1 or int(frame_skip) < 1:
        raise ValueError("n_frames and frame_skip must be >= 1")
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", scene_id):
        raise ValueError(f"invalid scene id {scene_id!r}")
    out = Path(root) / scene_id
    for sub in ("color", "depth", "pose", "intrinsic"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    scene = scene if scene is not None else synthetic.SyntheticScene.generate(seed=int(seed))
    poses = synthetic.make_trajectory(int(n_frames), int(seed),
                                      trajectory or synthetic.TrajectoryConfig(fps=fps))
    cam_c = synthetic.default_camera(*color_size)
    cam_d = synthetic.default_camera(*depth_size)
    invalid = set(int(i) for i in invalid_pose_frames)
    numbers = list(range(0, int(n_frames), int(frame_skip)))
    from tqdm import tqdm

    for n in tqdm(numbers, desc=f"synthetic ScanNet {scene_id}", disable=not progress):
        T = poses[n]
        view = scene.render(cam_c, T, supersample=supersample)
        bgr = cv2.cvtColor(np.clip(np.rint(view.rgb * 255), 0, 255).astype(np.uint8),
                           cv2.COLOR_RGB2BGR)
        if not cv2.imwrite(str(out / "color" / f"{n}.jpg"), bgr,
                           [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)]):
            raise OSError(f"could not write {out / 'color' / f'{n}.jpg'}")
        d = scene.render_depth(cam_d, T)
        d16 = np.clip(np.rint(np.nan_to_num(d * 1000.0, nan=0.0)), 0, 65535).astype(np.uint16)
        if not cv2.imwrite(str(out / "depth" / f"{n}.png"), d16):
            raise OSError(f"could not write {out / 'depth' / f'{n}.png'}")
        _save_matrix(out / "pose" / f"{n}.txt", np.full((4, 4), -np.inf) if n in invalid else T)
    for name, cam in (("color", cam_c), ("depth", cam_d)):
        K4 = np.eye(4)
        K4[:3, :3] = cam.K
        _save_matrix(out / "intrinsic" / f"intrinsic_{name}.txt", K4)
        _save_matrix(out / "intrinsic" / f"extrinsic_{name}.txt", np.eye(4))
    log.info("wrote synthetic ScanNet scene %s (%d frames) to %s", scene_id, len(numbers), out)
    return out
