"""ONNX front-end pieces built from model names: the registry of :mod:`spgeo.models` resolves
a name (or a local path) to a file, the presets of :mod:`.onnx_sam` / :mod:`.onnx_normals` /
:mod:`.onnx_depth` drive it.  Nothing is downloaded here (``spgeo models fetch`` does that).
"""
from __future__ import annotations

from typing import Mapping, Optional

from ..models import ModelEntry, PathLike, resolve_model
from .mask_generator import SamMaskGenerator, SamMaskGeneratorConfig
from .onnx_depth import OnnxDepthNormals
from .onnx_normals import NormalModel
from .onnx_sam import SegmentModel

__all__ = ["sam_model_from_cache", "sam_frontend_from_cache", "normal_model_from_cache",
           "depth_normals_from_cache", "metric_depth_from_cache"]


def sam_model_from_cache(family: Optional[str] = "efficientsam-vitt",
                         encoder: Optional[PathLike] = None,
                         decoder: Optional[PathLike] = None, preset: Optional[str] = None,
                         registry: Optional[Mapping[str, ModelEntry]] = None,
                         **overrides) -> SegmentModel:
    """A :class:`~spgeo.frontend.onnx_sam.SegmentModel` from the cache or from files.

    Args:
        family: registry family (``<family>-encoder`` / ``<family>-decoder``),
            e.g. ``"efficientsam-vitt"`` or ``"sam-vit-h"``.
        encoder, decoder: registry names or paths overriding the family's files.
        preset: SAM preset; default: the registry entry's, else ``"sam-official"``.
        registry: entries to use instead of :data:`spgeo.models.REGISTRY`.
        overrides: :class:`~spgeo.frontend.onnx_sam.SamOnnxConfig` fields
            (e.g. ``upsample_to=(960, 1280)``).

    Raises:
        ValueError: neither a family nor both files; a model that breaks its contract.
        FileNotFoundError: a registry model not in the cache, or a missing file.
    """
    if encoder is None or decoder is None:
        if family is None:
            raise ValueError("give a model family or both encoder and decoder")
    enc_path, enc_entry = resolve_model(encoder if encoder is not None else f"{family}-encoder",
                                        registry)
    dec_path, dec_entry = resolve_model(decoder if decoder is not None else f"{family}-decoder",
                                        registry)
    if preset is None:
        preset = (enc_entry or dec_entry).preset if (enc_entry or dec_entry) else "sam-official"
    return SegmentModel.from_paths(enc_path, dec_path, preset=preset, **overrides)


def sam_frontend_from_cache(family: Optional[str] = "efficientsam-vitt",
                            encoder: Optional[PathLike] = None, decoder: Optional[PathLike] = None,
                            generator_config: Optional[SamMaskGeneratorConfig] = None,
                            preset: Optional[str] = None,
                            registry: Optional[Mapping[str, ModelEntry]] = None,
                            **overrides) -> SamMaskGenerator:
    """A :class:`~spgeo.frontend.mask_generator.SamMaskGenerator` (a ``Segmenter``) over
    :func:`sam_model_from_cache` (same arguments); ``generator_config`` default
    ``SamMaskGeneratorConfig()``."""
    model = sam_model_from_cache(family, encoder, decoder, preset, registry, **overrides)
    return SamMaskGenerator(model, generator_config or SamMaskGeneratorConfig())


def normal_model_from_cache(name_or_path: PathLike = "metric3d-vit-small-fp16",
                            preset: Optional[str] = None,
                            registry: Optional[Mapping[str, ModelEntry]] = None,
                            **overrides) -> NormalModel:
    """A :class:`~spgeo.frontend.onnx_normals.NormalModel` from a registry name or a path.

    ``preset`` defaults to the registry entry's, else ``"generic-480x640"``;
    ``overrides`` are :class:`~spgeo.frontend.onnx_normals.NormalOnnxConfig`
    fields.  Raises ``FileNotFoundError`` for a model not in the cache or a
    missing file.
    """
    path, entry = resolve_model(name_or_path, registry)
    preset = preset or (entry.preset if entry else "generic-480x640")
    return NormalModel.from_path(path, preset=preset, **overrides)


def depth_normals_from_cache(name_or_path: PathLike = "depth-anything-v2-small",
                             preset: Optional[str] = None,
                             registry: Optional[Mapping[str, ModelEntry]] = None,
                             **overrides) -> OnnxDepthNormals:
    """An :class:`~spgeo.frontend.onnx_depth.OnnxDepthNormals` (depth network -> normals)
    from a registry name or a path.

    ``preset`` defaults to the registry entry's, else ``"generic-depth-518"``;
    ``overrides`` are :class:`~spgeo.frontend.onnx_depth.DepthOnnxConfig`
    fields (e.g. ``output_kind="depth"`` for a metric-depth export).  Raises
    ``FileNotFoundError`` for a model not in the cache or a missing file.
    """
    path, entry = resolve_model(name_or_path, registry)
    preset = preset or (entry.preset if entry else "generic-depth-518")
    return OnnxDepthNormals.from_path(path, preset=preset, **overrides)


def metric_depth_from_cache(name_or_path: PathLike, preset: Optional[str] = None,
                            registry: Optional[Mapping[str, ModelEntry]] = None,
                            **overrides) -> OnnxDepthNormals:
    """A metric-depth network (:class:`~spgeo.frontend.base.MetricDepthEstimator`:
    :meth:`~spgeo.frontend.onnx_depth.OnnxDepthNormals.predict_metric`, metres) from
    a registry name (built-in or registered with :func:`spgeo.models.register_model`)
    or a path.

    ``preset`` defaults to the registry entry's; for a path without an entry it
    defaults to ``"fastdepth"`` (the metric preset; ``depth_normals_from_cache``'s
    ``"generic-depth-518"`` is up to scale and would be refused).  ``overrides`` are
    :class:`~spgeo.frontend.onnx_depth.DepthOnnxConfig` fields (e.g.
    ``intra_op_num_threads=1``, or ``metric=True`` with another preset).

    Raises:
        ValueError: the resulting config is not metric (naming the model and
            preset), an unknown preset, a model that breaks the preset's contract
            (input not one 3-channel image of the preset's size, output not one
            channel), or a user model whose file changed since it was registered.
        FileNotFoundError: a registry model not in the cache, or a missing file.
    """
    path, entry = resolve_model(name_or_path, registry)
    preset = preset or (entry.preset if entry else "fastdepth")
    model = OnnxDepthNormals.from_path(path, preset=preset, **overrides)
    if not model.config.metric:
        raise ValueError(f"depth model {path}: preset {preset!r} is not metric (output_kind "
                         f"{model.config.output_kind!r}), so it gives no depth in metres; use a "
                         "metric preset such as 'fastdepth' (`spgeo models register NAME PATH "
                         "--preset fastdepth`)")
    return model
