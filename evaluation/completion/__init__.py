"""Depth-completion protocols: the real sample frames (:mod:`.real`), 7-Scenes
redkitchen (:mod:`.seven_scenes`), errors stratified by sparse points per primitive
(:mod:`.strata`) and VOID (:mod:`.void`, also its metrics and sparse-depth sampling)."""
