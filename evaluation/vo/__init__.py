"""Monocular visual-odometry protocols: synthetic sequences (:mod:`.synthetic`), the
accuracy / speed / memory grid (:mod:`.frontier`), spgeo beside the reference methods
(:mod:`.compare`), the TUM fr1 protocol (:mod:`.tum_fr1`) and the keyframe scale-drift
diagnostic (:mod:`.scale_drift`)."""
