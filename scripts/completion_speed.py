"""Seconds per 640x480 frame of :func:`spgeo.completion.complete_depth` with its defaults.

The 9 TUM fr1_desk frames and 7-Scenes frames 0:300:60 of the shared data, 150 sparse
points of the ``corners`` regime, with and without FastDepth; each frame is completed
twice and the second call timed (models and imports warm).  Prints the median and the
largest time per setting.

Run::

    python scripts/completion_speed.py \\
        --depth-model ../shared/models/fastdepth/fastdepth_nyu_224.onnx
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from spgeo.completion import CompletionConfig, complete_depth
from spgeo.evaluation.completion.real import open_sample, sparse_frames


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--depth-model", required=True, help="FastDepth .onnx")
    ap.add_argument("--root", default=None, help="shared data root (default: ../shared/data)")
    args = ap.parse_args()
    times: dict = {}
    for name, sel in (("tum", None), ("7scenes", "0:300:60")):
        ds = open_sample(name, args.root, sel)
        for f, _, sparse in sparse_frames(ds, 150, 0, progress=False, regime="corners"):
            for label, model in (("no network", None), ("FastDepth", args.depth_model)):
                complete_depth(f.image, sparse, f.camera, None, CompletionConfig(),
                               depth_model=model)
                t0 = time.perf_counter()
                complete_depth(f.image, sparse, f.camera, None, CompletionConfig(),
                               depth_model=model)
                times.setdefault(label, []).append(time.perf_counter() - t0)
    for label, t in times.items():
        print(f"{label}: {len(t)} frames, median {np.median(t):.3f} s, max {np.max(t):.3f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
