"""Synthetic palindrome loop-closure comparison (docs/results.md, issue 23: loop closure in the VO).

    PYTHONPATH=. python3 scripts/loop_synthetic_experiment.py N_UNIQUE SEED KF_MAX_TRANSLATION STEP [check]

Renders make_trajectory(N_UNIQUE*STEP, SEED)[::STEP] at 160x120 as 0..N-1..0, runs the VO
(classical front-end) with loop closure off and on; prints ATE (Sim(3), positions), the
last-vs-first distance in ground-truth units and the loop report.  With a 5th argument it
prints each accepted loop's rotation / translation-direction error against ground truth.
Environment LOOP_HUBER sets PoseGraphConfig.loop_huber (the loop edges carry their own
information since issue 30, so PoseGraphConfig.loop_sigmas no longer applies to them).
"""
import sys, time, logging
import numpy as np
from dataclasses import replace
from spgeo import synthetic
from spgeo.frame import Frame
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.vo import KeyframeDecisionConfig, Odometry, OdometryConfig
from spgeo.loop import LoopClosureConfig
from spgeo.evaluation.vo.memory import palindrome
#logging.basicConfig(level=logging.INFO)
N=int(sys.argv[1]); seed=int(sys.argv[2]); kft=float(sys.argv[3])
cam = synthetic.default_camera(160, 120)
scene = synthetic.SyntheticScene.generate(seed)
step=int(sys.argv[4]); poses = synthetic.make_trajectory(N*step, seed)[::step]
idx = list(palindrome(N, 2*N-1))
views = {j: scene.render(cam, poses[j]).rgb for j in set(idx)}
import os
from spgeo.loop import PoseGraphConfig
PG = PoseGraphConfig()
from spgeo.loop import VerificationConfig
VC = VerificationConfig()
PG = replace(PG, loop_huber=float(os.environ.get("LOOP_HUBER", PG.loop_huber)))   # e.g. LOOP_HUBER=1
def run(on):
    cfg = OdometryConfig(keyframe=KeyframeDecisionConfig(max_translation=kft), loop_closure=LoopClosureConfig(enabled=on, pose_graph=PG, verification=VC))
    vo = Odometry(cam, cfg, make_frontend("classical", FrontEndConfig(working_size=(160, 120))))
    t=time.perf_counter()
    for i, j in enumerate(idx):
        vo.track(Frame(views[j], cam, float(i)))
    dt=time.perf_counter()-t
    res = vo.result(); P = res.poses
    gt = poses[idx]
    from spgeo.similarity import umeyama as um
    S = um(P[:,:3,3], gt[:,:3,3])
    A = (S[:3,:3] @ P[:,:3,3].T).T + S[:3,3]
    ate = np.sqrt(np.mean(np.sum((A-gt[:,:3,3])**2,1)))
    end = np.linalg.norm(P[-1,:3,3]-P[0,:3,3]) * np.linalg.norm(S[:3,0])
    rep = vo.report()
    print(on, f"{dt:.1f}s kf={rep['n_keyframes']} seg={rep['n_segments']} ate={ate:.4f} end-start={end:.4f} status={rep['status_counts']} loops={rep['loop_closures']}")
    return P
if len(sys.argv) <= 5: a=run(False); b=run(True)
from spgeo.similarity import sim3_parts
from spgeo.geometry import rotation_angle_deg, invert_pose
def check(on):
    cfg = OdometryConfig(keyframe=KeyframeDecisionConfig(max_translation=kft), loop_closure=LoopClosureConfig(enabled=on, verification=VC))
    vo = Odometry(cam, cfg, make_frontend("classical", FrontEndConfig(working_size=(160, 120))))
    for i, j in enumerate(idx):
        vo.track(Frame(views[j], cam, float(i)))
    for lp in vo._loops.closer.loops:
        gq = poses[idx[vo._map.kfs[lp.query_id].frame]]; gc = poses[idx[vo._map.kfs[lp.candidate_id].frame]]
        G = invert_pose(gc) @ gq
        R, t, s = sim3_parts(lp.S_cand_query)
        cosang = t @ G[:3,3] / (np.linalg.norm(t)*np.linalg.norm(G[:3,3])+1e-12)
        print(lp.query_id, lp.candidate_id, "rot err deg", round(rotation_angle_deg(R.T @ G[:3,:3]),2), "gt rot", round(rotation_angle_deg(G[:3,:3]),1), "t dir cos", round(cosang,3), "|t_gt|", round(np.linalg.norm(G[:3,3]),3))
if len(sys.argv) > 5: check(True)
