import sys, os, hashlib, numpy as np
sys.argv=['x']
exec(open('scripts/depth_anchor/dp_synth.py').read().split("n = int(sys.argv[1])")[0])
from spgeo.vo.depth_prior import depth_targets
os.environ["DP_NOPRIOR"]="1"
frames = synthetic_sequence(SyntheticVOConfig(n_frames=120, seed=0, rotation=None))
cam = frames[0].camera
model = FakeDepth(frames, 0.0)
vo = Odometry(cam, OdometryConfig(), make_frontend("classical", FrontEndConfig(working_size=cam.size)), depth_model=model)
for f in frames: vo.track(Frame(f.image, cam, f.timestamp))
for k in vo._kf_order:
    mk = vo._kfs[k]; img, kf = mk.restore(vo._store, 3)
    prims = kf.primitives; f = frames[mk.frame]
    t = depth_targets(model, img, prims)
    c = t.offset(prims.log_scales)
    dvo = prims.depth_map(); ok = np.isfinite(dvo) & np.isfinite(f.depth) & (dvo > 0)
    cpix = np.median(np.log(f.depth[ok]) - np.log(dvo[ok]))
    w = t.weights(); used = w > 0
    cmean = np.dot(w[used], (t.log_scales - prims.log_scales)[used])
    print(f"kf {k}@{mk.frame}: c_wmedian {c:+.3f}  c_wmean {cmean:+.3f}  c_pixel {cpix:+.3f}  n_prims {len(prims)} fitted {used.sum()}")
