"""``spgeo sfm``: argument wiring for :func:`spgeo.sfm.few_view_sfm`."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from .jsonio import json_default

__all__ = ["add_sfm_cli", "parse_intrinsics"]


def parse_intrinsics(text: str, width: int, height: int):
    """``"fx,fy,cx,cy"`` -> PinholeCamera of the given image size."""
    from .camera import PinholeCamera

    parts = text.replace(" ", "").split(",")
    if len(parts) != 4:
        raise ValueError(f"--intrinsics needs fx,fy,cx,cy, got {text!r}")
    try:
        fx, fy, cx, cy = (float(p) for p in parts)
    except ValueError as exc:
        raise ValueError(f"--intrinsics needs four numbers, got {text!r}") from exc
    return PinholeCamera(fx, fy, cx, cy, width, height)


def _run(args: argparse.Namespace) -> int:
    from .geometry import pose_to_tum
    from .images import load_image
    from .sfm import SfMConfig, few_view_sfm

    ref = load_image(args.ref)
    views = [load_image(p) for p in args.views]
    cam = parse_intrinsics(args.intrinsics, ref.shape[1], ref.shape[0])
    for p, v in zip(args.views, views):
        if v.shape[:2] != ref.shape[:2]:
            raise ValueError(f"{p} is {v.shape[1]}x{v.shape[0]}, the reference is "
                             f"{ref.shape[1]}x{ref.shape[0]}: all images must share one camera")
    cfg = SfMConfig(shape_model=args.shape_model, init=args.init)
    res = few_view_sfm(ref, views, cam, args.frontend, cfg)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # one line per image: name tx ty tz qx qy qz qw (camera-to-reference, the
    # reference at identity, translation in the reconstruction's unknown scale)
    with open(out / "poses.txt", "w") as fh:
        names = [Path(args.ref).name] + [Path(p).name for p in args.views]
        for name, T in zip(names, [np.eye(4)] + res.T_ref_view):
            fh.write(name + " " + " ".join(f"{x:.9f}" for x in pose_to_tum(T)) + "\n")
    depth = res.depth
    if depth.shape != ref.shape[:2]:
        import cv2

        depth = cv2.resize(depth.astype(np.float32), (ref.shape[1], ref.shape[0]),
                           interpolation=cv2.INTER_NEAREST)
    np.save(out / "depth.npy", depth.astype(np.float32))
    res.point_cloud(_resized(ref, res.camera.size)).save_ply(out / "cloud.ply")
    report = {"status": res.status, "view_status": res.view_status,
              "log_scale_std_median": float(np.nanmedian(res.log_scale_std))
              if np.any(np.isfinite(res.log_scale_std)) else None,
              "pose_covariances": [None if c is None else c.tolist() for c in res.pose_covariances],
              **{k: v for k, v in res.report.items()}}
    with open(out / "report.json", "w") as fh:
        json.dump(report, fh, indent=2, default=json_default)
    print(f"status: {res.status}  ({', '.join(res.view_status)})")
    print(f"wrote {out / 'poses.txt'}, depth.npy, cloud.ply, report.json")
    return 0 if res.ok else 3


def _resized(img, size):
    import cv2

    return img if img.shape[1::-1] == tuple(size) else cv2.resize(img, size,
                                                                  interpolation=cv2.INTER_AREA)




def add_sfm_cli(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("sfm", help="few-view SfM: reference + unposed views -> poses, depth")
    p.add_argument("--ref", required=True, help="reference image")
    p.add_argument("--views", required=True, nargs="+", help="supporting images (same camera)")
    p.add_argument("--intrinsics", required=True, help="fx,fy,cx,cy in pixels (undistorted)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--frontend", default="classical", choices=["classical", "onnx"],
                   help="front-end (default classical; onnx needs `spgeo models fetch`)")
    p.add_argument("--shape-model", default="scaled", choices=["scaled", "planar"])
    p.add_argument("--init", default="twoview", choices=["twoview", "identity"])
    p.set_defaults(func=_run)
    return p
