"""Options of :func:`spgeo.completion.complete_depth` (docs/design.md §5):
:class:`CompletionConfig` and the names its ``method`` / ``shape_model`` accept."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Tuple

import numpy as np

from ..configs import config_class
from .choose import ChooseConfig
from .network import ALIGNMENTS

__all__ = ["CompletionConfig", "METHODS", "SHAPE_MODELS", "CHOOSE", "CANDIDATES"]

METHODS = ("median", "joint", "graph")
SHAPE_MODELS = ("scale", "plane")
CHOOSE = ("none", "heldout")
#: Candidate names of ``CompletionConfig.candidates``; ``"network:<alignment>"``
#: for each alignment of :data:`spgeo.completion.network.ALIGNMENTS`.
CANDIDATES = ("primitives", "linear", "ip_basic", "colorization") + tuple(
    f"network:{a}" for a in ALIGNMENTS)


@config_class
@dataclass(frozen=True)
class CompletionConfig:
    """Options of :func:`spgeo.completion.complete_depth`.

    Attributes:
        method: ``"median"`` (the paper's per-primitive median of the
            log-depth ratios), ``"joint"`` (GTSAM Levenberg–Marquardt over
            all log-scales with robust
            :class:`~spgeo.factors.sparse_depth.SparseDepthFactor` s) or
            ``"graph"`` (default; :mod:`spgeo.completion.graph`: Cauchy-robust
            scales coupled across weak image edges; primitives without points
            get scales through the coupling, outlier points are down-weighted;
            docs/results.md says why it is the default).
        graph_coupling: ``"graph"``: weight of a neighbour coupling relative
            to one sparse point (>= 0).
        plane_prior_flat: ``"graph"`` with ``"plane"``: ``plane_prior`` for
            primitives whose shape is constant (fronto-parallel: no normal
            was known), so that points and continuity decide their tilt (>= 0).
        plane_coupling: ``"graph"`` with ``"plane"``: weight of one boundary
            pixel pair's continuity term relative to one sparse point
            (:func:`spgeo.completion.graph.solve_planes_graph`; >= 0).
        working_width: when the front-end is built here (``frontend`` None or
            a name), primitives are computed on a copy resized to this width
            (aspect kept) if the image is wider; None keeps the input size.
            Default 320 (the authors integrated at 320x240).  A front-end
            object passed in keeps its own ``FrontEndConfig.working_size``.
        min_points: primitives with fewer sparse points are dropped.  Default 1.
        sigma: ``"joint"``: sparse-depth noise in log units.  Default 0.01 (1 %).
        huber_k: ``"joint"``: Huber threshold in units of ``sigma`` (None: least
            squares).  Default 1.345.
        max_iterations: ``"joint"``: Levenberg–Marquardt iteration limit.  Default 50.
        min_coverage: below this fraction of the image covered by supported
            primitives, fall back to plain linear interpolation.  Default 0.05.
        shape_model: ``"scale"`` (the paper: one log-scale per primitive, its
            shape kept) or ``"plane"`` (default; :mod:`spgeo.completion.planes`: a
            planar inverse-depth correction fitted where a primitive holds
            ``plane_min_points`` points, normal hypotheses from
            ``PrimitiveSet.meta["normal_hypotheses"]`` ((N, H, 3) camera-frame
            normals) tried, and depth lent to empty primitives across weak
            edges; with ``method="graph"`` one joint solve with continuity
            across weak edges, :func:`spgeo.completion.graph.solve_planes_graph`).
        plane_min_points: ``"plane"``: points needed for the planar fit (>= 3).
        plane_prior: ``"plane"``: ridge weight pulling the plane towards the
            primitive's own orientation (>= 0).
        plane_huber: ``"plane"``: Huber threshold on the relative
            inverse-depth residual (> 0).
        lend_edge_threshold: ``"plane"``: largest mean absolute colour step
            (image in [0, 1]) along a shared boundary across which a neighbour
            lends depth to a primitive without points; None: no lending.
        lend_rounds: ``"plane"``: lending passes (depth spreads one primitive
            per pass).
        residual_clip: step 6's largest correction in log units (>= 0; 0 or
            None: off).  Default 0.05 (docs/results.md says why).
        choose: ``"none"`` (the primitive completion alone) or ``"heldout"``
            (step 7: per region, the blend of ``candidates`` with the lowest
            error on held-out sparse points, :mod:`spgeo.completion.choose`).
        candidates: names of :data:`CANDIDATES` for ``"heldout"``; the first
            wins ties; ``"network:*"`` ones are skipped when no depth model is given.
        heldout: :class:`~spgeo.completion.choose.ChooseConfig` (folds, seed,
            shrinkage, cells) of ``"heldout"``.
        depth_model: registry name or path of a metric-depth network
            (:func:`spgeo.frontend.metric_depth_from_cache`) for the
            ``"network:*"`` candidates; None: none (``complete_depth``'s
            ``depth_model`` argument overrides it).
        network_min_points: ``"network:primitive"``: points a primitive needs
            for its own scale (>= 1).
        max_sparse_points: more valid sparse points than this (dense depth given
            as "sparse") are subsampled to this many, drawn uniformly with a fixed
            seed (:func:`spgeo.completion.sparse_points.uniform_sparse_depth`),
            with a logged warning; ``CompletionResult.n_sparse_given`` keeps the
            count given.  The cost grows with the number of points, not the
            image size (each held-out fold and candidate triangulates all of
            them: about 0.3 ms a point, a minute or more for a Kinect frame's
            250,000 valid pixels); the default 25,000 (about 10 s at 640x480)
            keeps VOID's 150-1,500 points and a KITTI LiDAR frame's ~20,000
            whole (>= 1).
    """

    method: str = "graph"
    working_width: Optional[int] = 320
    min_points: int = 1
    sigma: float = 0.01
    huber_k: Optional[float] = 1.345
    max_iterations: int = 50
    min_coverage: float = 0.05
    shape_model: str = "plane"
    plane_min_points: int = 3
    plane_prior: float = 0.1
    plane_huber: float = 0.05
    lend_edge_threshold: Optional[float] = 0.08
    lend_rounds: int = 3
    graph_coupling: float = 1.0
    plane_coupling: float = 0.03
    plane_prior_flat: float = 1e-4
    residual_clip: Optional[float] = 0.05
    choose: str = "heldout"
    candidates: Tuple[str, ...] = ("primitives", "linear", "ip_basic", "network:interp")
    heldout: ChooseConfig = field(default_factory=ChooseConfig)
    depth_model: Optional[str] = None
    network_min_points: int = 3
    max_sparse_points: int = 25000

    def __post_init__(self) -> None:
        self._check_choice()
        if self.residual_clip is not None and not (
                np.isfinite(self.residual_clip) and self.residual_clip >= 0):
            raise ValueError(f"CompletionConfig: residual_clip must be >= 0 or None, "
                             f"got {self.residual_clip}")
        if not (np.isfinite(self.plane_prior_flat) and self.plane_prior_flat >= 0):
            raise ValueError(f"CompletionConfig: plane_prior_flat must be >= 0, "
                             f"got {self.plane_prior_flat}")
        if not (np.isfinite(self.plane_coupling) and self.plane_coupling >= 0):
            raise ValueError(f"CompletionConfig: plane_coupling must be >= 0, "
                             f"got {self.plane_coupling}")
        if not (np.isfinite(self.graph_coupling) and self.graph_coupling >= 0):
            raise ValueError(f"CompletionConfig: graph_coupling must be >= 0, "
                             f"got {self.graph_coupling}")
        if self.shape_model not in SHAPE_MODELS:
            raise ValueError(f"CompletionConfig: shape_model must be one of {SHAPE_MODELS}, "
                             f"got {self.shape_model!r}")
        if int(self.plane_min_points) != self.plane_min_points or self.plane_min_points < 3:
            raise ValueError(f"CompletionConfig: plane_min_points must be an integer >= 3, "
                             f"got {self.plane_min_points}")
        if not (np.isfinite(self.plane_prior) and self.plane_prior >= 0):
            raise ValueError(f"CompletionConfig: plane_prior must be >= 0, got {self.plane_prior}")
        if not (np.isfinite(self.plane_huber) and self.plane_huber > 0):
            raise ValueError(f"CompletionConfig: plane_huber must be > 0, got {self.plane_huber}")
        if self.lend_edge_threshold is not None and not (
                np.isfinite(self.lend_edge_threshold) and self.lend_edge_threshold >= 0):
            raise ValueError(f"CompletionConfig: lend_edge_threshold must be >= 0 or None, "
                             f"got {self.lend_edge_threshold}")
        if int(self.lend_rounds) < 0:
            raise ValueError(f"CompletionConfig: lend_rounds must be >= 0, got {self.lend_rounds}")
        if self.method not in METHODS:
            raise ValueError(f"CompletionConfig: method must be one of {METHODS}, "
                             f"got {self.method!r}")
        if self.working_width is not None and int(self.working_width) < 8:
            raise ValueError("CompletionConfig: working_width must be >= 8 or None")
        if int(self.min_points) != self.min_points or self.min_points < 1:
            raise ValueError(f"CompletionConfig: min_points must be an integer >= 1, "
                             f"got {self.min_points}")
        if not (np.isfinite(self.sigma) and self.sigma > 0):
            raise ValueError(f"CompletionConfig: sigma must be finite and > 0, got {self.sigma}")
        if self.huber_k is not None and not (np.isfinite(self.huber_k) and self.huber_k > 0):
            raise ValueError(f"CompletionConfig: huber_k must be > 0 or None, got {self.huber_k}")
        if int(self.max_iterations) < 1:
            raise ValueError("CompletionConfig: max_iterations must be >= 1")
        if not 0.0 <= self.min_coverage <= 1.0:
            raise ValueError(f"CompletionConfig: min_coverage must be in [0, 1], "
                             f"got {self.min_coverage}")

    def _check_choice(self) -> None:
        object.__setattr__(self, "candidates", tuple(self.candidates))
        if self.choose not in CHOOSE:
            raise ValueError(f"CompletionConfig: choose must be one of {CHOOSE}, "
                             f"got {self.choose!r}")
        bad = [c for c in self.candidates if c not in CANDIDATES]
        if bad or not self.candidates or len(set(self.candidates)) != len(self.candidates):
            raise ValueError(f"CompletionConfig: candidates must be distinct names of "
                             f"{CANDIDATES}, got {tuple(self.candidates)!r}")
        if not isinstance(self.heldout, ChooseConfig):
            raise ValueError(f"CompletionConfig: heldout must be a ChooseConfig, "
                             f"got {type(self.heldout).__name__}")
        if int(self.max_sparse_points) != self.max_sparse_points or self.max_sparse_points < 1:
            raise ValueError(f"CompletionConfig: max_sparse_points must be an integer >= 1, "
                             f"got {self.max_sparse_points}")
        if int(self.network_min_points) != self.network_min_points or \
                self.network_min_points < 1:
            raise ValueError(f"CompletionConfig: network_min_points must be an integer >= 1, "
                             f"got {self.network_min_points}")
