"""Single-frame front-end evaluations: boundary quality of the classical segmenters
(:mod:`.segmenters`) and vanishing-point normals against reference normals
(:mod:`.manhattan_normals`)."""
