"""Reference methods the protocols compare spgeo with: COLMAP few-view poses
(:mod:`.colmap`) and VO trajectories (:mod:`.colmap_vo`, shared helpers in
:mod:`.colmap_common`), the OpenCV feature VO (:mod:`.feature_vo`, with
:mod:`.feature_vo_frontend` and :mod:`.feature_vo_result`) and the depth-completion
baselines from the sparse depth alone (:mod:`.depth_completion`)."""
