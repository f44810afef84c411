"""One way to build a factor graph (docs/design.md §4, §5): the key scheme of every
GTSAM graph of the project (:mod:`spgeo.graph.keys`) and the factor builders shared by
the VO window smoother, the few-view SfM and the completion
(:mod:`spgeo.graph.builders`).
"""
