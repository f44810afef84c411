"""VO with the 'depth' front-end fed FastDepth's metric depth instead of the sensor's."""
import sys, os, numpy as np
os.environ["DP_NOPRIOR"] = "1"
from spgeo.datasets import open_dataset
from spgeo.apps.vo_run import run_odometry, VORunConfig
from spgeo.frontend import metric_depth_from_cache
from spgeo.frame import Frame
from spgeo.configs import apply_overrides
M = os.path.join(os.environ.get("SPGEO_SHARED", "../shared"), "models/fastdepth/fastdepth_nyu_224.onnx")
net = metric_depth_from_cache(M)
import cv2
def frames(seq):
    for f in seq:
        img = f.image
        small = cv2.resize(np.asarray(img, np.float32) if img.dtype == np.float32 else img.astype(np.float32) / 255.0, (320, 240), interpolation=cv2.INTER_AREA)
        d = net.predict_metric(small)
        d = cv2.resize(d, (f.camera.width, f.camera.height), interpolation=cv2.INTER_NEAREST)
        yield Frame(f.image, f.camera, f.timestamp, d, f.T_world_cam, f.name)
rng = sys.argv[1] if len(sys.argv) > 1 else "0:300"
seq = open_dataset("7scenes", os.path.join(os.environ.get("SPGEO_SHARED", "../shared"), "data/7scenes_redkitchen_dev"), frames=rng)
cfg = VORunConfig(frontend="depth", progress=False)
run = run_odometry(frames(seq), cfg)
a = run.ate(); print("fastdepth-as-sensor", rng, {k: (getattr(v, "rmse", None), getattr(v, "scale", None)) for k, v in a.items()})
