"""A 30 Hz camera played from recorded frames (issue 32: "drops no frame"): prints JSON.

Frame n "arrives" at n / rate seconds after the start, into a driver ring of ``--buffers``
frames (OpenCV's V4L2 capture keeps 4); a frame that arrives while the ring is full is
dropped, as a camera driver drops it.  The VO (``Odometry.track``, the defaults, classical
front-end) takes the oldest waiting frame whenever it is free and waits for the next arrival
when none is.  No thread: arrivals are computed from the clock, so the interpreter lock
cannot delay them.  Reports frames dropped, the most frames ever waiting (the ring a capture
thread would need to drop none: run with a large ``--buffers``), the run's ATE on the frames processed and the mapping
worker's report.  A live camera runs with ``--schedule ready`` (``spgeo vo --dataset camera``
does; checkouts before issue 37 have no schedule: leave it out there).

    python3 scripts/paced_camera.py [--data DIR] [--frames 0:300] [--rate 30] [--buffers 4] [--schedule ready]
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from realtime_speed import clip_and_config, clip_arguments   # this folder's (run as a script)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    clip_arguments(ap)
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--buffers", type=int, default=4)
    args = ap.parse_args()

    from spgeo.apps.vo_run import blas_threads
    from spgeo.evaluation.trajectory import ate_sim3
    from spgeo.frame import Frame
    from spgeo.frontend import FrontEndConfig, make_frontend
    from spgeo.vo import Odometry

    frames, cfg = clip_and_config(args)
    cam = frames[0].camera
    size = cfg.processing_size_for(cam.size)
    vo = Odometry(cam, cfg, make_frontend("classical", FrontEndConfig(working_size=size)))
    period = 1.0 / args.rate
    waiting, dropped, kept, most = [], [], [], 0
    arrived = 0            # frames that have arrived so far
    t0 = time.perf_counter()
    with blas_threads(1):
        while arrived < len(frames) or waiting:
            now = time.perf_counter() - t0
            while arrived < len(frames) and arrived * period <= now:
                (waiting if len(waiting) < args.buffers else dropped).append(arrived)
                arrived += 1
            most = max(most, len(waiting))
            if not waiting:
                time.sleep(max(arrived * period - now, 0.0))
                continue
            i = waiting.pop(0)
            f = frames[i]
            vo.track(Frame(f.image, cam, f.timestamp))
            kept.append(i)
    res = vo.result()
    rep = vo.report()
    if hasattr(vo, "close"):     # releases before issue 32 have no mapping worker
        vo.close()
    gt = (np.array([frames[i].timestamp for i in kept]),
          np.array([frames[i].T_world_cam for i in kept]))
    print(json.dumps({"mapping": rep.get("mapping_mode", "inline"), "rate_hz": args.rate,
                      "buffers": args.buffers, "frames": len(frames), "dropped": len(dropped),
                      "dropped_frames": dropped[:50], "most_waiting": most,
                      "keyframes": rep["n_keyframes"], "ate_m": float(ate_sim3(res, gt).rmse),
                      "mapping_worker": rep.get("mapping_worker")}))


if __name__ == "__main__":
    main()
