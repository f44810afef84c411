"""Applications: metrics, protocol runners, baselines and benchmarks (``spgeo.evaluation``).

The core of spgeo never imports this package (docs/design.md §6.1).  Importing it checks
that it comes from the same tree as ``spgeo`` (``spgeo.factors.assert_same_tree``).
"""
from spgeo.factors import assert_same_tree

assert_same_tree("evaluation", __file__)
