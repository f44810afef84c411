"""Data-set layouts written from rendered frames (test helper)."""
from __future__ import annotations

import cv2
import numpy as np


def write_7scenes(folder, frames, K, size=(640, 480), garbage_depth=False):
    """A 7-Scenes sequence folder: ``frame-NNNNNN.color.png`` (``size``, nearest
    neighbour), ``.depth.png`` (uint16 mm; with ``garbage_depth`` a file that is not
    a PNG, which a monocular run must never open), ``.pose.txt`` (4x4
    camera-to-world) and ``camera-intrinsics.txt`` (the 3x3 ``K`` at ``size``).
    Returns ``folder`` (created)."""
    folder.mkdir(parents=True)
    np.savetxt(folder / "camera-intrinsics.txt", K)
    for i, f in enumerate(frames):
        stem = folder / f"frame-{i:06d}"
        rgb8 = np.clip(np.round(f.image * 255), 0, 255).astype(np.uint8)
        big = cv2.resize(rgb8, size, interpolation=cv2.INTER_NEAREST)
        assert cv2.imwrite(f"{stem}.color.png", cv2.cvtColor(big, cv2.COLOR_RGB2BGR))
        if garbage_depth:
            (folder / f"frame-{i:06d}.depth.png").write_bytes(b"not a png")
        else:
            mm = np.clip(np.round(np.nan_to_num(f.depth, nan=0.0) * 1000), 0, 65534)
            assert cv2.imwrite(f"{stem}.depth.png", cv2.resize(
                mm.astype(np.uint16), size, interpolation=cv2.INTER_NEAREST))
        np.savetxt(f"{stem}.pose.txt", f.T_world_cam)
    return folder


def write_completion_inputs(folder):
    """The inputs of ``spgeo complete`` from a synthetic 160x120 view (seed 5):
    ``folder/rgb.png`` and 100 noise-free sparse depths at FAST keypoints.
    Returns ``(view, camera, rgb path, sparse (H, W) metres, 0 = missing)``."""
    from spgeo import synthetic
    from spgeo.evaluation.completion.void import keypoint_sparse_depth

    cam = synthetic.default_camera(160, 120)
    view = synthetic.SyntheticScene.generate(seed=5).render(
        cam, synthetic.make_trajectory(1, seed=5)[0])
    rgb = folder / "rgb.png"
    assert cv2.imwrite(str(rgb), cv2.cvtColor(np.rint(255 * view.rgb).astype(np.uint8),
                                              cv2.COLOR_RGB2BGR))
    sparse = keypoint_sparse_depth(view.rgb, view.depth, 100, rel_noise=0.0, seed=0)
    return view, cam, rgb, sparse
