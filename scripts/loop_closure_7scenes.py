"""Loop-closure core on real frames: 7-Scenes keyframes (ground-truth poses, Kinect depth)
in a LoopCloser database, then query frames as if seen again much later, with their depth
scaled by a known factor (emulated scale drift).  Logs, per query, the loop found (or
none) and the verified S_cand_query's error against the ground truth.

    PYTHONPATH=$PWD python3 scripts/loop_closure_7scenes.py [DATA] [--keyframes 0:100:10]
        [--queries 0,5,45,150,200,250] [--drift 1.1]
"""
from __future__ import annotations

import argparse
import logging

import numpy as np

from spgeo.datasets.sevenscenes import SevenScenesConfig, SevenScenesSequence
from spgeo.geometry import invert_pose
from spgeo.loop import LoopCloser, LoopClosureConfig
from spgeo.similarity import sim3, sim3_difference

log = logging.getLogger("loop_closure_7scenes")


def _frames(path: str, selection: str) -> dict:
    frames = selection if ":" in selection else [int(v) for v in selection.split(",")]
    seq = SevenScenesSequence(path, SevenScenesConfig(frames=frames))
    return {int(f.meta["frame_number"]): f for f in seq}


def run(path: str, keyframes: str, queries: str, drift: float,
        config: LoopClosureConfig = LoopClosureConfig(enabled=True)) -> list:
    """Rows ``(query frame, candidate frame or None, inliers, matches, support,
    rotation deg, translation m, |log scale| error)``."""
    kfs = _frames(path, keyframes)
    qs = _frames(path, queries)
    first = next(iter(kfs.values()))
    closer = LoopCloser(first.camera, config)
    numbers = sorted(kfs)
    for i, n in enumerate(numbers):
        closer.add_keyframe(i, kfs[n].image, kfs[n].depth, kfs[n].T_world_cam)
    rows = []
    for j, n in enumerate(sorted(qs)):
        f = qs[n]
        features = closer_features(closer, f, drift)
        loop = closer.detect(1000 + j, features)
        if loop is None:
            rows.append((n, None, 0, 0, 0, np.nan, np.nan, np.nan))
            continue
        c = numbers[loop.candidate_id]
        truth = invert_pose(kfs[c].T_world_cam) @ f.T_world_cam @ sim3(np.eye(3), np.zeros(3),
                                                                        1.0 / drift)
        rot, trans, dlog = sim3_difference(truth, loop.S_cand_query)
        rows.append((n, c, loop.n_inliers, loop.n_matches, loop.neighbour_support, rot,
                     trans * drift, dlog))
    return rows


def closer_features(closer: LoopCloser, frame, drift: float):
    from spgeo.loop import extract_features
    return extract_features(frame.image, closer.camera, frame.depth * drift,
                            closer.config.recognition.features)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default="../shared/data/7scenes_redkitchen_dev")
    ap.add_argument("--keyframes", default="0:100:10")
    ap.add_argument("--queries", default="0,5,45,95,150,200,250,299")
    ap.add_argument("--drift", type=float, default=1.1)
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for n, c, n_in, m, sup, rot, trans, dlog in run(args.data, args.keyframes, args.queries,
                                                     args.drift):
        if c is None:
            log.info("query frame %d: no loop", n)
        else:
            log.info("query frame %d -> keyframe frame %d: %d/%d inliers, %d neighbours agree, "
                     "error %.2f deg, %.3f m, %.2f %% scale", n, c, n_in, m, sup, rot, trans,
                     100 * (np.exp(dlog) - 1))


if __name__ == "__main__":
    main()
