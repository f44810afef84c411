import sys, os, hashlib, numpy as np
argv = sys.argv[1:]; sys.argv=['x']
exec(open('scripts/depth_anchor/dp_synth.py').read().split("n = int(sys.argv[1])")[0])
seed = int(argv[0])
frames = synthetic_sequence(SyntheticVOConfig(n_frames=200, seed=seed, rotation=None))
for label, env, model in [("none", {}, None), ("init-only", {"DP_NOPRIOR": "1"}, FakeDepth(frames, 0.1)),
                     ("ctl b0.3 K5", {"DP_NOPRIOR": "1", "DP_BETA": "0.3", "DP_K": "5"}, FakeDepth(frames, 0.1)),
                     ("ctl b0.1 K5", {"DP_NOPRIOR": "1", "DP_BETA": "0.1", "DP_K": "5"}, FakeDepth(frames, 0.1)),
                     ("ctl b0.3 K5 bias0.8", {"DP_NOPRIOR": "1", "DP_BETA": "0.3", "DP_K": "5"}, FakeDepth(frames, 0.1, 0.8))]:
    for k in ("DP_NOPRIOR", "DP_BETA", "DP_K"): os.environ.pop(k, None)
    os.environ.update(env)
    r = run(frames, model, OdometryConfig())
    print(f"seed {seed} {label:20s} ATE {r[0]:.2f}%  scale first/last third {r[1]:.3f}/{r[2]:.3f} drift {r[2]/r[1]:.3f} lost {r[3]}", flush=True)
