"""Applications: metrics, protocol runners, baselines and benchmarks (``spgeo.evaluation``).

The core of spgeo never imports this package (docs/design.md §6.1).  Importing it checks
that it comes from the same tree as ``spgeo`` (``spgeo.factors.assert_same_tree``).

One sub-package per task, each protocol a module with a ``main(argv)`` (``spgeo eval
NAME``, names in :data:`spgeo.cli.eval.PROTOCOLS`):

* :mod:`.vo`: monocular visual odometry;
* :mod:`.sfm`: few-view structure from motion;
* :mod:`.completion`: depth completion;
* :mod:`.frontend`: single-frame segments and normals;
* :mod:`.references`: the methods spgeo is compared with (COLMAP, the OpenCV feature
  VO, depth-completion baselines);
* :mod:`.bench`: speed micro-benchmarks.

The modules here at the top are shared by several of them: :mod:`.jobs` (running a
protocol's jobs locally or on Ray, the merged table), :mod:`.metrics` (depth),
:mod:`.pose_metrics` and :mod:`.pose_compare` (relative poses, tables of several
methods), :mod:`.trajectory` (Sim(3) ATE), :mod:`.tables` (the one cell formatter and
Markdown table writer of every protocol's table) and :mod:`.shared_data` (where the
sample data is).
"""
from spgeo.factors import assert_same_tree

assert_same_tree("evaluation", __file__)
