"""Data-set readers.  Every reader is a lazy random-access sequence of
:class:`spgeo.frame.Frame` (``len``, ``seq[i]``, ``seq[a:b]`` -> list, iteration,
``.camera`` of the returned images, ``.name``).

* :class:`TUMSequence` (``"tum"``): TUM RGB-D raw layout.
* :class:`SevenScenesSequence` (``"7scenes"``): Microsoft 7-Scenes ``seq-XX`` folder.
* :class:`ICLSequence` (``"icl"``): ICL-NUIM PNG release, converted to the
  OpenCV camera convention.
* :class:`FolderSequence` (``"folder"``): plain image folder + intrinsics.
* :class:`ScanNetScene`: one ScanNet scene in the SensReader export layout
  (:mod:`spgeo.datasets.scannet`; not an :func:`open_dataset` kind).
* :class:`VOIDDataset`: VOID depth-completion samples (:mod:`spgeo.datasets.void`;
  yields :class:`~spgeo.datasets.void.VOIDSample` s, not frames).

:func:`open_dataset` is the factory the CLI uses (the kinds in quotes above); :func:`parse_frame_range`
parses ``--frames A:B[:S]`` (selection by frame number ``A <= n < B``, step S).
The 9-frame TUM fr1/desk sample ships with the package: :func:`bundled_tum_path`,
:func:`load_bundled_tum`.
"""
from __future__ import annotations

from pathlib import Path
from typing import Union

from .common import FrameSelection, FrameSequence, parse_frame_range, select_frames
from .folder import FolderConfig, FolderSequence
from .icl import ICL_CAMERA, ICLConfig, ICLSequence, icl_pose_to_opencv
from .scannet import ScanNetConfig, ScanNetScene
from .sevenscenes import SEVEN_SCENES_CAMERA, SevenScenesConfig, SevenScenesSequence
from .tum import (TUM_CALIBRATIONS, TUMConfig, TUMSequence, associate, interpolate_poses,
                  read_tum_groundtruth, read_tum_list, tum_camera)
from .void import VOIDDataset, VOIDSample
from .warp import photometric_error, warp_image

__all__ = [
    "FrameSelection", "FrameSequence", "parse_frame_range", "select_frames", "warp_image",
    "photometric_error", "TUMConfig", "TUMSequence", "TUM_CALIBRATIONS", "tum_camera",
    "associate", "interpolate_poses", "read_tum_list", "read_tum_groundtruth",
    "SevenScenesConfig", "SevenScenesSequence", "SEVEN_SCENES_CAMERA", "ICLConfig",
    "ICLSequence", "ICL_CAMERA", "icl_pose_to_opencv", "FolderConfig", "FolderSequence",
    "ScanNetConfig", "ScanNetScene", "VOIDDataset", "VOIDSample",
    "DATASET_KINDS", "open_dataset", "bundled_tum_path", "load_bundled_tum",
]

#: Reader class of each data-set kind accepted by :func:`open_dataset`.
DATASET_KINDS = {
    "tum": TUMSequence,
    "7scenes": SevenScenesSequence,
    "icl": ICLSequence,
    "folder": FolderSequence,
}

_ALIASES = {
    "tum": "tum", "tum-rgbd": "tum", "tum_rgbd": "tum",
    "7scenes": "7scenes", "7-scenes": "7scenes", "7_scenes": "7scenes", "sevenscenes": "7scenes",
    "icl": "icl", "icl-nuim": "icl", "icl_nuim": "icl", "iclnuim": "icl",
    "folder": "folder", "images": "folder",
}


def open_dataset(kind: str, path: Union[str, Path], **kwargs) -> FrameSequence:
    """Open a data set of ``kind`` in ``{"tum", "7scenes", "icl", "folder"}`` at ``path``.

    Keyword arguments are the fields of the reader's config (e.g.
    ``frames="0:100:2"``, ``load_depth=False``, ``undistort=False``) or
    ``config=`` a config object.  Raises ``ValueError`` for an unknown kind and
    ``TypeError`` for an option the reader does not have.
    """
    key = _ALIASES.get(str(kind).strip().lower())
    if key is None:
        raise ValueError(f"unknown data-set kind {kind!r}; expected one of {sorted(DATASET_KINDS)}")
    return DATASET_KINDS[key](path, **kwargs)


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
