import sys, hashlib, numpy as np
sys.argv=['x']
exec(open('scripts/depth_anchor/dp_synth.py').read().split("n = int(sys.argv[1])")[0])
frames = synthetic_sequence(SyntheticVOConfig(n_frames=200, seed=0, rotation=None))
for label, model, cfg in [("sig0.3", FakeDepth(frames, 0.0), OdometryConfig(depth_prior_sigma=0.3)),
                          ("sig1", FakeDepth(frames, 0.0), OdometryConfig(depth_prior_sigma=1.0)),
                          ("sig0.1 noscalecheck", FakeDepth(frames, 0.0), OdometryConfig(depth_prior_sigma=0.1, kf_scale_check=False)),
                          ("none noscalecheck", None, OdometryConfig(kf_scale_check=False))]:
    r = run(frames, model, cfg)
    print(f"{label:20s} ATE {r[0]:.2f}%  scale first/last third {r[1]:.3f}/{r[2]:.3f} drift {r[2]/r[1]:.3f} lost {r[3]}", flush=True)
