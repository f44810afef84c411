"""What a mapper in a worker process would have to receive (issue 32): pickled size and
time of the VO's window keyframes, its newest keyframe, the supporting-frame candidates
and the landmark map after the first frames of the shared 7-Scenes clip.

Usage: python scripts/mapper_transfer_cost.py [DATA] [--frames N]
(DATA: the 7-Scenes folder, default ../shared/data/7scenes_redkitchen_dev)
"""
from __future__ import annotations

import argparse
import pickle
import time
from pathlib import Path


def _cost(obj) -> str:
    t = time.perf_counter()
    blob = pickle.dumps(obj, protocol=5)
    dumps = time.perf_counter() - t
    t = time.perf_counter()
    pickle.loads(blob)
    loads = time.perf_counter() - t
    return f"{len(blob) / 1e6:.2f} MB, dumps {dumps * 1e3:.1f} ms, loads {loads * 1e3:.1f} ms"


def main() -> None:
    from spgeo.datasets.sevenscenes import SevenScenesConfig, SevenScenesSequence
    from spgeo.frontend import FrontEndConfig, make_frontend
    from spgeo.vo import Odometry, OdometryConfig

    default = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "7scenes_redkitchen_dev"
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default=str(default))
    ap.add_argument("--frames", type=int, default=120)
    args = ap.parse_args()
    frames = list(SevenScenesSequence(args.data, SevenScenesConfig(frames=list(range(args.frames)))))
    vo = Odometry(frames[0].camera, OdometryConfig(), make_frontend("classical", FrontEndConfig()))
    for f in frames:
        vo.track(f)
    window = vo._map.window_kfs(extra=1)
    print(f"after {args.frames} frames, {vo.n_keyframes} keyframes")
    for name, obj in (("window keyframes", window), ("newest keyframe", window[-1]),
                      ("supporting-frame candidates", vo._map.candidates),
                      ("landmark map", vo._landmarks)):
        print(f"{name}: {_cost(obj)}")


if __name__ == "__main__":
    main()
