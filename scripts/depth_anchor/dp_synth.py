"""Depth prior on synthetic sequences: a fake metric model (GT depth x per-keyframe noise)."""
import sys, time, hashlib
import numpy as np
from spgeo.evaluation.vo.synthetic import SyntheticVOConfig, synthetic_sequence
from spgeo.evaluation.trajectory import ate_per_frame_and_keyframes
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.frame import Frame
from spgeo.vo import Odometry, OdometryConfig

class FakeDepth:
    def __init__(self, frames, sigma, bias=1.0, seed=0):
        self.table = {hashlib.md5(np.ascontiguousarray(f.image).tobytes()).hexdigest(): f.depth for f in frames}
        self.rng = np.random.default_rng(seed); self.sigma = sigma; self.bias = bias
    def predict_metric(self, image):
        d = self.table[hashlib.md5(np.ascontiguousarray(image).tobytes()).hexdigest()]
        return (d * self.bias * np.exp(self.sigma * self.rng.standard_normal())).astype(np.float32)

def scale_of(res, frames):
    ok = res.tracked
    est = res.poses[ok][:, :3, 3]; gt = np.array([f.T_world_cam for f in frames])[ok][:, :3, 3]
    de = np.linalg.norm(np.diff(est, axis=0), axis=1); dg = np.linalg.norm(np.diff(gt, axis=0), axis=1)
    n = len(de)//3
    return de[:n].sum()/dg[:n].sum(), de[-n:].sum()/dg[-n:].sum()

def run(frames, model, cfg):
    cam = frames[0].camera
    vo = Odometry(cam, cfg, make_frontend("classical", FrontEndConfig(working_size=cam.size)), depth_model=model)
    t = time.perf_counter()
    for f in frames:
        vo.track(Frame(f.image, cam, f.timestamp))
    secs = time.perf_counter() - t
    res = vo.result(); ok = res.tracked
    gt = (np.array([f.timestamp for f in frames]), np.array([f.T_world_cam for f in frames]))
    a = ate_per_frame_and_keyframes((res.timestamps[ok], res.poses[ok]), gt, keyframe_mask=res.is_keyframe[ok])
    s0, s1 = scale_of(res, frames)
    return a["per-frame"].rmse_percent_of_length, s0, s1, int((~ok).sum()), len(frames)/secs

n = int(sys.argv[1]) if len(sys.argv) > 1 else 300
for seed in [int(x) for x in (sys.argv[2] if len(sys.argv) > 2 else "0").split(",")]:
    frames = synthetic_sequence(SyntheticVOConfig(n_frames=n, seed=seed, rotation=None))
    for label, model, sig in [("none", None, 0.1), ("gt", FakeDepth(frames, 0.0), 0.1),
                              ("noisy10", FakeDepth(frames, 0.10), 0.1),
                              ("bias0.8+noisy10", FakeDepth(frames, 0.10, 0.8), 0.1)]:
        r = run(frames, model, OdometryConfig(depth_prior_sigma=sig))
        print(f"seed {seed} {label:16s} ATE {r[0]:.2f}%  scale first/last third {r[1]:.3f}/{r[2]:.3f} drift {r[2]/r[1]:.3f} lost {r[3]} fps {r[4]:.1f}", flush=True)
