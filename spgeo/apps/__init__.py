"""Applications built on the spgeo core: the demo and batch runners (may use spgeo.evaluation)."""
