"""Few-view SfM on synthetic rooms at wide baselines, against exact ground truth (issue 40):
the ``synthetic`` cases of ``spgeo eval sfm_real`` (:mod:`.real`).

Per rotation angle ``A`` (degrees between each view and the reference) and seed: a
synthetic room (:meth:`spgeo.synthetic.SyntheticScene.generate`), a reference and two
views orbiting the reference's median depth point, ``A`` degrees from it, at a baseline
of ``2 sin(A / 2)`` times that depth (:func:`spgeo.synthetic.make_view_set`), rendered
at ``size``.  The estimators run through :func:`spgeo.evaluation.sfm.gaps.run_gap_triplet`
without a judge, so the tables of :class:`~spgeo.evaluation.sfm.gaps.GapResults` hold the
errors against the exact ground truth (their "gap" column is the angle, "ref" the seed).
"""
from __future__ import annotations

import logging
import math
from typing import Callable, Dict, List, Sequence, Tuple

import numpy as np

from spgeo.frame import Frame
from spgeo.evaluation.sfm.gaps import (GapResults, coverage_report, run_gap_triplet,
                                       summarize_views, methods_with)

__all__ = ["ANGLES", "view_set_frames", "run_baselines"]

log = logging.getLogger(__name__)

#: default rotation angles (degrees) of the views from the reference
ANGLES = (5, 20, 45)


def view_set_frames(angle_deg: float, seed: int, size: Tuple[int, int] = (640, 480)
                    ) -> List[Frame]:
    """The reference and two views of a synthetic room ``angle_deg`` degrees apart
    (module docstring), as :class:`~spgeo.frame.Frame` objects with exact
    ``T_world_cam`` and depth, at ``size`` = (width, height)."""
    from spgeo import synthetic

    camera = synthetic.default_camera(*size)
    scene = synthetic.SyntheticScene.generate(seed)
    base = 2.0 * math.sin(math.radians(angle_deg) / 2.0)
    T_ref, T_views = synthetic.make_view_set(scene, camera, 2, angle_deg, base, seed)
    frames = []
    for k, T in enumerate([T_ref, *T_views]):
        view = scene.render(camera, T, supersample=2)
        frames.append(Frame(image=np.asarray(view.rgb, np.float32), camera=camera,
                            timestamp=float(k), depth=view.depth, T_world_cam=T,
                            name=f"synthetic-{seed}-{angle_deg:g}deg-{k}"))
    return frames


class _Triplet:
    """Three frames as the sequence :func:`run_gap_triplet` reads (frame numbers 0-2)."""

    def __init__(self, frames: Sequence[Frame]) -> None:
        self.frames = list(frames)
        self.frame_numbers = list(range(len(self.frames)))

    def __getitem__(self, i: int) -> Frame:
        return self.frames[i]


def run_baselines(angles: Sequence[float], seeds: Sequence[int],
                  make_estimators: Callable[[], Dict[str, Callable]],
                  size: Tuple[int, int] = (640, 480), k: float = 3.0) -> GapResults:
    """Every angle and seed (module docstring) through ``make_estimators()``'s
    estimators; per angle the summaries (:func:`summarize_views`) and per method with
    covariances the coverage of its rotation errors by ``k`` sigma
    (:func:`coverage_report`, against the ground truth)."""
    out = GapResults(data=f"synthetic rooms {size[0]}x{size[1]}", gaps=[int(a) for a in angles],
                     refs=[int(s) for s in seeds], judge="ground truth (exact)",
                     label="angle deg", ref_label="seed")
    seconds: Dict[int, Dict[str, List[float]]] = {}
    for angle in angles:
        for seed in seeds:
            log.info("synthetic room %d, %g degrees", seed, angle)
            triplet, records = run_gap_triplet(_Triplet(view_set_frames(angle, seed, size)), 1,
                                               0, make_estimators(), judge="")
            triplet.update(gap=int(angle), ref=int(seed))
            for r in records:
                r.update(gap=int(angle), ref=int(seed))
            out.triplets.append(triplet)
            out.records.extend(records)
            for m, s in triplet["comparison"]["time_s"].items():  # type: ignore[index]
                seconds.setdefault(int(angle), {}).setdefault(m, []).append(float(s))
    for angle in out.gaps:
        out.summary[f"gap {angle}"] = summarize_views(
            [r for r in out.records if r["gap"] == angle], seconds.get(angle))
    for m in methods_with(out.records, "sigma_rot_deg"):
        out.coverage[m] = coverage_report(out.records, m, k)
    return out
