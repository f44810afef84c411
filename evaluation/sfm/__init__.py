"""Few-view SfM protocols: real sample frames against COLMAP and SIFT two-view
(:mod:`.real`; its wide-baseline gap cases judged against COLMAP: :mod:`.gaps`), the
front-end x shape-model ablation (:mod:`.ablation`) and the ScanNet protocol
(:mod:`.scannet`)."""
