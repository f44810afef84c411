"""The sequences and variants of the long-run VO benchmark (:mod:`spgeo.evaluation.vo.long_run`).

:data:`SEQUENCES` (``--sequences`` name -> :class:`LongRunSequence`) plays each
sequence's frames as a :class:`Reordered` view (timestamps = position in the run; a
palindrome, :func:`spgeo.evaluation.vo.memory.palindrome`, returns to its first frame),
:data:`VARIANTS` (``--variants`` name -> :class:`~spgeo.apps.vo_run.VORunConfig`
overrides) and :func:`run_config` gives the configuration of one (sequence, variant).
What each sequence and variant is: the docstring of :mod:`spgeo.evaluation.vo.long_run`.
"""
from __future__ import annotations

import functools
from collections.abc import Sequence as SequenceABC
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from spgeo.evaluation.shared_data import shared_data_root
from spgeo.evaluation.vo.memory import palindrome

__all__ = ["SEVENSCENES_FRAMES", "SYNTHETIC_LOOP", "FOREIGN_SPAN", "Reordered", "Spliced",
           "LongRunSequence", "SEQUENCES",
           "VARIANTS", "DEPTH_VARIANTS", "runs_on", "run_config"]

#: Frames of the 7-Scenes sample the ``7scenes`` sequences use (frame numbers ``0:N``).
SEVENSCENES_FRAMES = 300
#: Synthetic loop: distinct poses, pose subsampling, seed and keyframe spacing of
#: ``scripts/loop_synthetic_experiment.py 80 0 0.03 3`` (docs/results.md).
SYNTHETIC_LOOP = {"n_unique": 80, "step": 3, "seed": 0, "size": (160, 120)}


class Reordered(SequenceABC):
    """Lazy, random-access view of a frame sequence in the order ``order``:
    item ``i`` is ``base[order[i]]`` with timestamp ``i``, name ``i``
    (zero-padded), depth only when ``depth`` (else None), and ground truth
    ``poses[order[i]]`` when ``poses`` is given (else the frame's own).  Frames
    are read from ``base`` at each access, so the view holds no image."""

    def __init__(self, base: Sequence, order: Sequence[int], poses: Optional[np.ndarray] = None,
                 depth: bool = True) -> None:
        self.base, self.order, self.poses, self.depth = base, list(order), poses, depth

    def __len__(self) -> int:
        return len(self.order)

    def __getitem__(self, i: int):
        if not isinstance(i, (int, np.integer)) or not 0 <= i < len(self.order):
            raise IndexError(i)
        j = self.order[i]
        f = self.base[j]
        gt = f.T_world_cam if self.poses is None else self.poses[j]
        return replace(f, timestamp=float(i), name=f"{i:06d}", T_world_cam=gt,
                       depth=f.depth if self.depth else None)


def _order(n: int, cap: Optional[int], loop: bool) -> List[int]:
    """Positions played: ``0..n-1`` (at most ``cap``), or with ``loop`` the
    palindrome ``0..m-1..0`` of ``m = min(n, (cap + 1) // 2)`` frames."""
    if not loop:
        return list(range(min(n, cap) if cap else n))
    m = min(n, (cap + 1) // 2) if cap else n
    return list(palindrome(m, 2 * m - 1))


def _sevenscenes(cap: Optional[int], depth: bool, loop: bool) -> Reordered:
    from spgeo.datasets import open_dataset

    path = shared_data_root() / "7scenes_redkitchen_dev"
    seq = open_dataset("7scenes", path, frames=f"0:{SEVENSCENES_FRAMES}", load_depth=depth)
    return Reordered(seq, _order(len(seq), cap, loop), depth=depth)


#: ``7scenes-foreign``: frames of another room put in place of the 7-Scenes frames
#: ``FOREIGN_SPAN`` (a hand over the lens, someone walking past; issue 51).
FOREIGN_SPAN = (50, 62)


class Spliced(SequenceABC):
    """``base`` with the items at the positions of ``foreign`` (position -> frame)
    replaced: the foreign frame with ``base``'s camera, timestamp and name and no
    ground truth or depth (it shows another place)."""

    def __init__(self, base: Sequence, foreign: Mapping[int, Any]) -> None:
        self.base, self.foreign = base, dict(foreign)

    def __len__(self) -> int:
        return len(self.base)

    def __getitem__(self, i: int):
        f = self.base[i]
        if i not in self.foreign:
            return f
        g = self.foreign[i]
        return replace(f, image=g.image, depth=None, T_world_cam=None)


def _foreign_frames(n: int) -> List[Any]:
    """``n`` frames of other rooms at 640x480: the shared TUM fr1_desk frames,
    then the ICL-NUIM living room's."""
    from spgeo.datasets import open_dataset

    root = shared_data_root()
    tum = open_dataset("tum", root / "tum_fr1_desk_9", load_depth=False)
    icl = open_dataset("icl", root / "icl_nuim_lr_5", load_depth=False)
    frames = [tum[i] for i in range(len(tum))] + [icl[i] for i in range(len(icl))]
    if len(frames) < n:
        raise ValueError(f"only {len(frames)} foreign frames in {root}, {n} needed")
    return frames[:n]


def _sevenscenes_foreign(cap: Optional[int], depth: bool, loop: bool = False) -> Spliced:
    """7-Scenes frames ``0:120`` with the span :data:`FOREIGN_SPAN` replaced by
    frames of other rooms (:func:`_foreign_frames`): the camera is back where it
    was when the foreign frames end."""
    a, b = FOREIGN_SPAN
    base = _sevenscenes(min(cap or 120, 120), depth, False)
    foreign = _foreign_frames(b - a)
    return Spliced(base, {i: foreign[i - a] for i in range(a, min(b, len(base)))})


def _kitti(cap: Optional[int], depth: bool, loop: bool = False) -> Reordered:
    """The KITTI clip: camera from P0 of ``calib.txt``, ground truth ``poses.txt``."""
    import cv2

    from spgeo.camera import PinholeCamera
    from spgeo.datasets import open_dataset
    from spgeo.datasets.kitti import read_kitti_calib, read_kitti_poses

    root = shared_data_root() / "kitti_odometry_clip_51"
    P0 = read_kitti_calib(root / "calib.txt")["P0"]
    first = sorted((root / "image_l").glob("*.png"))[0]
    h, w = cv2.imread(str(first), cv2.IMREAD_UNCHANGED).shape[:2]
    cam = PinholeCamera.from_K(P0[:, :3], w, h)
    seq = open_dataset("folder", root / "image_l", camera=cam, load_depth=False)
    poses = np.stack(read_kitti_poses(root / "poses.txt")[:len(seq)])
    return Reordered(seq, _order(len(seq), cap, loop), poses, depth=False)


@functools.lru_cache(maxsize=1)
def _synthetic_views(n: int) -> Tuple[Any, ...]:
    """The first ``n`` views of the synthetic loop (:data:`SYNTHETIC_LOOP`), rendered with depth."""
    from spgeo import synthetic

    p = SYNTHETIC_LOOP
    cam = synthetic.default_camera(*p["size"])
    poses = synthetic.make_trajectory(p["n_unique"] * p["step"], p["seed"])[::p["step"]]
    scene = synthetic.SyntheticScene.generate(p["seed"])
    return tuple(synthetic.render_frames(scene, cam, poses[:n]))


def _synthetic_loop(cap: Optional[int], depth: bool, loop: bool = True) -> Reordered:
    """The palindrome over the rendered views (rendered once per process)."""
    order = _order(SYNTHETIC_LOOP["n_unique"], cap, loop)
    return Reordered(_synthetic_views(max(order) + 1), order, depth=depth)


@functools.lru_cache(maxsize=1)
def _road_views(kind: str, n: int) -> Tuple[Any, ...]:
    """The first ``n`` frames of a synthetic road (:mod:`spgeo.synthetic.road`,
    ``kind`` "straight" or "block") at :func:`~spgeo.synthetic.street_camera`'s
    504 px, rendered once per process and kept as 8-bit grey (KITTI's images;
    about 77 kB a frame)."""
    from spgeo import synthetic
    from spgeo.synthetic.road import block_loop, straight_street

    road = straight_street() if kind == "straight" else block_loop()
    cam = synthetic.street_camera()
    out = []
    for i, T in enumerate(road.drive()[:n]):    # one at a time: a rendered Frame is ~2.5 MB
        f = synthetic.render_frames(road.scene, cam, T[None], [float(i)], supersample=2)[0]
        grey = np.round(255 * np.clip(f.image.mean(axis=2), 0, 1)).astype(np.uint8)
        out.append(replace(f, image=grey, depth=None, meta={}, name=f"{i:06d}"))
    return tuple(out)


def _road(kind: str, total: int) -> Callable[..., Reordered]:
    """``open`` of a synthetic road of ``total`` frames (never a palindrome:
    the block loop returns to its start by itself)."""
    def open_road(cap: Optional[int], depth: bool, loop: bool = False) -> Reordered:
        order = _order(total, cap, False)
        return Reordered(_road_views(kind, max(order) + 1), order, depth=False)
    return open_road


@dataclass(frozen=True)
class LongRunSequence:
    """A benchmark sequence.

    Attributes:
        open: ``open(cap, depth, loop) -> frames`` (a :class:`Reordered`):
            at most ``cap`` frames (None: all), with sensor depth when ``depth``.
        loop: played as a palindrome (returns to its first frame).
        overrides: :class:`~spgeo.apps.vo_run.VORunConfig` overrides of this
            sequence (dotted names), applied before the variant's.
        has_depth: every frame has sensor (or rendered) depth: its keyframes' depth
            is scored and the :data:`DEPTH_VARIANTS` run on it.
    """

    open: Callable[..., Reordered]
    loop: bool = False
    overrides: Mapping[str, Any] = field(default_factory=dict)
    has_depth: bool = False

    def frames(self, cap: Optional[int] = None, depth: bool = False) -> Reordered:
        """The frames of the sequence (see :attr:`open`)."""
        return self.open(cap, depth, self.loop)


#: ``--sequences`` name -> :class:`LongRunSequence`.
SEQUENCES: Dict[str, LongRunSequence] = {
    "7scenes": LongRunSequence(_sevenscenes, has_depth=True),
    "7scenes-palindrome": LongRunSequence(_sevenscenes, loop=True, has_depth=True),
    "kitti": LongRunSequence(_kitti),
    "7scenes-foreign": LongRunSequence(_sevenscenes_foreign),
    "synthetic-loop": LongRunSequence(
        _synthetic_loop, loop=True,
        overrides={"odometry.resolution": SYNTHETIC_LOOP["size"],
                   "odometry.keyframe.max_translation": 0.03}, has_depth=True),
    "road-straight": LongRunSequence(_road("straight", 500)),
    "road-block": LongRunSequence(_road("block", 725)),
}

#: ``--variants`` name -> :class:`~spgeo.apps.vo_run.VORunConfig` overrides (dotted names).
VARIANTS: Dict[str, Mapping[str, Any]] = {
    "default": {},
    "loops": {"odometry.loop_closure.enabled": True},
    "no-landmarks": {"odometry.landmarks.enabled": False},
    "no-landmarks+loops": {"odometry.landmarks.enabled": False,
                           "odometry.loop_closure.enabled": True},
    "inline": {"odometry.mapping.mode": "inline"},
    "no-feature-check": {"odometry.feature_retry.min_agreement": None},
    "sensor-depth": {"frontend": "depth"},
}

#: variants that read the sensor depth: run only on sequences that have it
#: (:attr:`LongRunSequence.has_depth`); ``sensor-depth`` is the depth columns' floor
DEPTH_VARIANTS = ("sensor-depth",)


def runs_on(sequence: str, variant: str) -> bool:
    """Whether the benchmark runs ``variant`` on ``sequence``: every variant but the
    :data:`DEPTH_VARIANTS` on every sequence, those only where it has depth."""
    return variant not in DEPTH_VARIANTS or SEQUENCES[sequence].has_depth


def run_config(sequence: str, variant: str):
    """The :class:`~spgeo.apps.vo_run.VORunConfig` of one run: no progress bar,
    the sequence's overrides, then the variant's.  Raises ``KeyError`` for an
    unknown name, :class:`spgeo.configs.ConfigError` for an unknown field."""
    from spgeo.apps.vo_run import VORunConfig
    from spgeo.configs import apply_overrides

    cfg = apply_overrides(VORunConfig(progress=False), dict(SEQUENCES[sequence].overrides))
    return apply_overrides(cfg, dict(VARIANTS[variant]))
