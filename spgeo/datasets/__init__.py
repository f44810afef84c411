"""Data-set readers.  Every reader is a lazy random-access sequence of
:class:`spgeo.frame.Frame` (``len``, ``seq[i]``, ``seq[a:b]`` -> list, iteration,
``.camera`` of the returned images, ``.name``).

* :class:`TUMSequence` (``"tum"``): TUM RGB-D raw layout.
* :class:`SevenScenesSequence` (``"7scenes"``): Microsoft 7-Scenes ``seq-XX`` folder.
* :class:`ICLSequence` (``"icl"``): ICL-NUIM PNG release, converted to the
  OpenCV camera convention.
* :class:`FolderSequence` (``"folder"``): plain image folder + intrinsics.
* :class:`KITTISequence` (``"kitti"``): KITTI odometry ``sequences/XX`` folder.
* :class:`EuRoCSequence` (``"euroc"``): EuRoC MAV sequence (``mav0/cam0``).
* :class:`VideoSequence` (``"video"``): a video file (``cv2.VideoCapture``).
* :class:`CameraStream` (``"camera"``): a live camera by device index (an
  iterable without length, not a :class:`FrameSequence`).
* :class:`ScanNetScene`: one ScanNet scene in the SensReader export layout
  (:mod:`spgeo.datasets.scannet`; not an :func:`open_dataset` kind).
* :class:`VOIDDataset`: VOID depth-completion samples (:mod:`spgeo.datasets.void`;
  yields :class:`~spgeo.datasets.void.VOIDSample` s, not frames).

:func:`open_dataset` is the factory the CLI uses (the kinds in quotes above); :func:`parse_frame_range`
parses ``--frames A:B[:S]`` (selection by frame number ``A <= n < B``, step S).
Calibration when there is none (:mod:`spgeo.datasets.calibration`; another
tool's calibration file, :func:`read_calibration`):
``open_dataset(..., given_camera=CameraSpec(...))`` replaces any reader's camera,
and the readers without a calibration file guess one (a warning); every reader's
``intrinsics`` says which (``source`` ``"file"`` | ``"given"`` | ``"guessed"``).
The 9-frame TUM fr1/desk sample ships with the package: :func:`bundled_tum_path`,
:func:`load_bundled_tum`.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Optional, Tuple, Union

from .calibration import (DEFAULT_HFOV_DEG, CameraSpec, camera_from_fov, guess_camera,
                          intrinsics_report)
from .calibration_files import Calibration, read_calibration
from .common import (CameraSource, FrameSelection, FrameSequence, check_depth_scale,
                     parse_frame_range, select_frames)
from .euroc import EuRoCConfig, EuRoCSequence
from .folder import FolderConfig, FolderSequence
from .icl import ICL_CAMERA, ICLConfig, ICLSequence, icl_pose_to_opencv
from .kitti import KITTIConfig, KITTISequence
from .scannet import ScanNetConfig, ScanNetScene
from .sevenscenes import SEVEN_SCENES_CAMERA, SevenScenesConfig, SevenScenesSequence
from .tum import (TUM_CALIBRATIONS, TUMConfig, TUMSequence, associate, interpolate_poses,
                  read_tum_groundtruth, read_tum_list, tum_camera)
from .video import CameraStream, VideoConfig, VideoSequence
from .void import VOIDDataset, VOIDSample
from .warp import photometric_error, warp_image

__all__ = [
    "FrameSelection", "FrameSequence", "parse_frame_range", "select_frames", "warp_image",
    "photometric_error", "TUMConfig", "TUMSequence", "TUM_CALIBRATIONS", "tum_camera",
    "associate", "interpolate_poses", "read_tum_list", "read_tum_groundtruth",
    "SevenScenesConfig", "SevenScenesSequence", "SEVEN_SCENES_CAMERA", "ICLConfig",
    "ICLSequence", "ICL_CAMERA", "icl_pose_to_opencv", "FolderConfig", "FolderSequence",
    "ScanNetConfig", "ScanNetScene", "VOIDDataset", "VOIDSample", "KITTIConfig",
    "KITTISequence", "EuRoCConfig", "EuRoCSequence", "VideoConfig", "VideoSequence",
    "CameraStream", "CameraSource", "CameraSpec", "camera_from_fov", "guess_camera",
    "intrinsics_report", "DEFAULT_HFOV_DEG", "Calibration", "read_calibration",
    "DATASET_KINDS", "DATASET_CONFIGS", "open_dataset", "bundled_tum_path", "load_bundled_tum",
    "check_depth_scale", "reader_options",
]

#: Reader class of each data-set kind accepted by :func:`open_dataset`.
DATASET_KINDS = {
    "tum": TUMSequence,
    "7scenes": SevenScenesSequence,
    "icl": ICLSequence,
    "folder": FolderSequence,
    "kitti": KITTISequence,
    "euroc": EuRoCSequence,
    "video": VideoSequence,
    "camera": CameraStream,
}

#: Config class of each kind's reader: its fields are the options :func:`open_dataset`
#: passes on (:func:`reader_options`).
DATASET_CONFIGS = {
    "tum": TUMConfig,
    "7scenes": SevenScenesConfig,
    "icl": ICLConfig,
    "folder": FolderConfig,
    "kitti": KITTIConfig,
    "euroc": EuRoCConfig,
    "video": VideoConfig,
    "camera": VideoConfig,
}

#: Kinds whose reader takes a given camera at construction (``camera=``), so that
#: no guess is made and logged for a camera that is then replaced.
_CAMERA_AT_OPEN = ("folder", "video", "camera")

_ALIASES = {
    "tum": "tum", "tum-rgbd": "tum", "tum_rgbd": "tum",
    "7scenes": "7scenes", "7-scenes": "7scenes", "7_scenes": "7scenes", "sevenscenes": "7scenes",
    "icl": "icl", "icl-nuim": "icl", "icl_nuim": "icl", "iclnuim": "icl",
    "folder": "folder", "images": "folder",
    "kitti": "kitti", "kitti-odometry": "kitti", "kitti_odometry": "kitti",
    "euroc": "euroc", "euroc-mav": "euroc", "euroc_mav": "euroc",
    "video": "video", "camera": "camera", "webcam": "camera",
}


def open_dataset(kind: str, path: Union[str, Path], given_camera: Optional[CameraSpec] = None,
                 **kwargs) -> Union[FrameSequence, CameraStream]:
    """Open a data set of ``kind`` (a key of :data:`DATASET_KINDS`) at ``path``.

    ``path`` is the sequence folder, the video file (``"video"``) or the device
    index (``"camera"``, e.g. ``"0"``; a :class:`CameraStream`, iterable
    without length).  Keyword arguments are the fields of the reader's config
    (e.g. ``frames="0:100:2"``, ``load_depth=False``, ``undistort=False``) or
    ``config=`` a config object.  ``given_camera`` (``--intrinsics`` /
    ``--fov`` / ``--calibration``) replaces the reader's camera, built at the
    stored image size (without distortion, but a calibration file's, which
    the reader then undistorts; a file for another size is an
    :class:`~spgeo.validation.InputError` naming both); the reader's
    ``intrinsics["source"]`` is then ``"given"``.  Raises ``ValueError`` for an unknown kind and ``TypeError``
    for an option the reader does not have.
    """
    key = _kind(kind)
    if given_camera is not None and key in _CAMERA_AT_OPEN:
        return DATASET_KINDS[key](path, camera=given_camera, **kwargs)
    seq = DATASET_KINDS[key](path, **kwargs)
    if given_camera is not None:
        seq.set_camera(given_camera)
    return seq


def reader_options(kind: str) -> Tuple[str, ...]:
    """Names of the options (config fields) the reader of ``kind`` takes, e.g. whether
    it has a ``depth_scale``; ``ValueError`` for an unknown kind."""
    return tuple(f.name for f in dataclasses.fields(DATASET_CONFIGS[_kind(kind)]))


def _kind(kind: str) -> str:
    """The key of :data:`DATASET_KINDS` that ``kind`` (or an alias) names;
    ``ValueError`` for an unknown kind."""
    key = _ALIASES.get(str(kind).strip().lower())
    if key is None:
        raise ValueError(f"unknown data-set kind {kind!r}; expected one of {sorted(DATASET_KINDS)}")
    return key


def bundled_tum_path() -> Path:
    """Folder of the 9-frame TUM ``rgbd_dataset_freiburg1_desk`` sample shipped in
    ``spgeo/data/tum_fr1_desk_9`` (CC BY 4.0, see its ATTRIBUTION.md)."""
    try:
        from importlib.resources import files

        path = Path(str(files("spgeo") / "data" / "tum_fr1_desk_9"))
    except (ImportError, ModuleNotFoundError, TypeError):  # pragma: no cover
        path = Path(__file__).resolve().parents[1] / "data" / "tum_fr1_desk_9"
    if not (path / "rgb.txt").is_file():
        raise FileNotFoundError(f"bundled TUM sample not found at {path} (broken installation?)")
    return path


def load_bundled_tum(**kwargs) -> TUMSequence:
    """:class:`TUMSequence` of the bundled sample (fr1 calibration from its name);
    keyword arguments as for :class:`TUMConfig`."""
    return TUMSequence(bundled_tum_path(), **kwargs)
