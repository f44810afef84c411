"""Applications built on the spgeo core: the demo and batch runners (they import the core, never
``spgeo.evaluation``: docs/design.md §6.1)."""
