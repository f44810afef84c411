"""Accuracy against ground truth, shared by the applications (the demo, a VO run's
outcome) and the evaluation protocols (:mod:`spgeo.evaluation`, which re-exports them):

* :mod:`~spgeo.metrics.ate`: the Sim(3)-aligned absolute trajectory error (evo),
  per frame and on the keyframes;
* :mod:`~spgeo.metrics.depth`: a depth map's errors, the shape accuracy of
  primitives (one scale each), the VOID completion metrics.
"""
from .ate import AteResult, ate_per_frame_and_keyframes, ate_sim3, path_length
from .depth import depth_metrics, primitive_fit_errors, void_metrics

__all__ = ["AteResult", "ate_sim3", "ate_per_frame_and_keyframes", "path_length",
           "depth_metrics", "primitive_fit_errors", "void_metrics"]
