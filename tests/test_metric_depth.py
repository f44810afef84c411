"""Metric depth: the ``fastdepth`` preset, ``OnnxDepthNormals.predict_metric`` and
``metric_depth_from_cache``, on self-built contract models (exact planes, broken contracts) and
on the real FastDepth network (../shared/models; skipped when absent) against 7-Scenes depth."""
from __future__ import annotations

import numpy as np
import pytest

import onnx_builders as B
from conftest import shared_data_dir
from spgeo import models
from spgeo.frontend import MetricDepthEstimator, metric_depth_from_cache
from spgeo.frontend.onnx_depth import DEPTH_PRESETS, DepthOnnxConfig, OnnxDepthNormals

FASTDEPTH = DEPTH_PRESETS["fastdepth"]
FASTDEPTH_SHA256 = "172cda523fbdbd5b624913008d6d41a2aa156dd06e0e320362187afcd8d37139"


def fastdepth_like(path, **kw):
    """A contract model with FastDepth's tensor names and (by default) its 224x224 input."""
    args = dict(kind="depth", input_size=(224, 224), output_rank=4,
                input_name=FASTDEPTH.input_name, output_name=FASTDEPTH.output_name)
    args.update(kw)
    return B.depth_model(path, **args)


@pytest.fixture(scope="module")
def mdir(tmp_path_factory):
    d = tmp_path_factory.mktemp("metric_depth")
    fastdepth_like(d / "plane.onnx", coeffs=(0.2, -0.1, 0.5))      # 1/z affine: exact plane
    fastdepth_like(d / "cross.onnx", coeffs=(1.0, 0.0, -0.5), kind="inverse")  # 1/z <= 0 left
    fastdepth_like(d / "small.onnx", coeffs=(0.0, 0.0, 0.5), input_size=(112, 112))
    fastdepth_like(d / "grey1.onnx", coeffs=(0.0, 0.0, 0.5), in_channels=1)
    fastdepth_like(d / "three.onnx", coeffs=(0.0, 0.0, 0.5), channels=3)
    fastdepth_like(d / "inf.onnx", coeffs=(0.0, 0.0, 0.0), gain=0.0)  # depth 1 / 0
    return d


def plane_inverse(h, w, a, b, c):
    """1/z = a x + b y + c at the pixel centres, x = (u + 0.5) / w, y = (v + 0.5) / h."""
    v, u = np.mgrid[0:h, 0:w]
    return a * (u + 0.5) / w + b * (v + 0.5) / h + c


def test_fastdepth_preset():
    cfg = FASTDEPTH
    assert cfg.metric and cfg.output_kind == "depth" and cfg.input_size == (224, 224)
    assert cfg.resize_mode == "stretch" and cfg.input_range == "0-1"
    assert cfg.mean == (0.0, 0.0, 0.0) and cfg.std == (1.0, 1.0, 1.0)
    assert (cfg.channel_order, cfg.layout, cfg.output_layout) == ("RGB", "NCHW", "NCHW")
    assert cfg.input_name == "serving_default_input.1_0"
    assert cfg.output_name == "StatefulPartitionedCall_0"
    assert not any(p.metric for name, p in DEPTH_PRESETS.items() if name != "fastdepth")
    with pytest.raises(ValueError, match="metric.*disparity"):
        DepthOnnxConfig(output_kind="disparity", metric=True)


@pytest.mark.parametrize("shape", [(120, 160), (300, 400)])
def test_predict_metric_is_the_plane_in_metres(mdir, shape):
    """No normalisation: the network's metres come back at the image size (inverse-depth
    bilinear resampling keeps the plane exact), for shrinking and enlarging."""
    h, w = shape
    est = OnnxDepthNormals.from_path(mdir / "plane.onnx", preset="fastdepth")
    assert isinstance(est, MetricDepthEstimator)
    grey = np.full((h, w), 0.5, np.float32)
    z = est.predict_metric(grey)
    assert z.shape == (h, w) and z.dtype == np.float32 and np.all(np.isfinite(z))
    z_true = 1.0 / plane_inverse(h, w, 0.2, -0.1, 0.5)
    inner = (slice(2, -2), slice(2, -2))  # bilinear enlarging clamps at the border
    assert np.allclose(z[inner], z_true[inner], rtol=1e-4)
    # grey (H, W) float == the same grey as RGB, float or uint8
    assert np.array_equal(est.predict_metric(np.repeat(grey[..., None], 3, axis=2)), z)
    rgb8 = np.full((h, w, 3), 128, np.uint8)
    assert np.allclose(est.predict_metric(rgb8),
                       est.predict_metric(np.full((h, w), 128 / 255, np.float32)), rtol=1e-6)
    # predict_depth is the same map up to its normalisation
    ratio = est.predict_depth(grey) / z
    assert np.ptp(ratio) < 1e-4 * ratio.mean()


def test_predict_metric_invalid_pixels_are_nan(mdir):
    """Non-positive inverse depth and pixels interpolated from it are NaN, not huge."""
    est = OnnxDepthNormals.from_path(mdir / "cross.onnx", preset="fastdepth",
                                     output_kind="inverse_depth")
    h, w = 60, 80
    z = est.predict_metric(np.full((h, w, 3), 0.5, np.float32))
    q = plane_inverse(h, w, 1.0, 0.0, -0.5)
    assert np.all(np.isnan(z[q <= 0]))
    far_from_edge = q > 2.0 / 224
    assert np.allclose(z[far_from_edge], 1.0 / q[far_from_edge], rtol=1e-3)
    assert np.nanmax(z) < 1.0 / (1.0 / 224)


def test_non_metric_config_refuses(mdir):
    est = OnnxDepthNormals.from_path(mdir / "plane.onnx", preset="fastdepth", metric=False)
    with pytest.raises(ValueError, match=r"plane\.onnx.*not a metric-depth model"):
        est.predict_metric(np.full((30, 40), 0.5, np.float32))
    with pytest.raises(ValueError, match=r"plane\.onnx.*'generic-depth-518' is not metric"):
        metric_depth_from_cache(mdir / "plane.onnx", preset="generic-depth-518",
                                input_name=FASTDEPTH.input_name, input_size=(224, 224),
                                output_name=FASTDEPTH.output_name)


def test_contract_errors_name_the_file(mdir):
    with pytest.raises(ValueError, match=r"small\.onnx.*112x112.*input_size is \(224, 224\)"):
        metric_depth_from_cache(mdir / "small.onnx")
    with pytest.raises(ValueError, match=r"grey1\.onnx.*NCHW 3-channel"):
        metric_depth_from_cache(mdir / "grey1.onnx")
    with pytest.raises(ValueError, match=r"three\.onnx.*one-channel.*3 channels"):
        metric_depth_from_cache(mdir / "three.onnx")
    with pytest.raises(ValueError, match=r"plane\.onnx.*expected the single input 'image'"):
        metric_depth_from_cache(mdir / "plane.onnx", input_name="image")
    est = metric_depth_from_cache(mdir / "inf.onnx")
    with pytest.raises(ValueError, match=r"inf\.onnx.*NaN/inf"):
        est.predict_metric(np.full((30, 40), 0.5, np.float32))
    with pytest.raises(ValueError, match="float image values"):
        metric_depth_from_cache(mdir / "plane.onnx").predict_metric(
            np.full((30, 40), 128.0, np.float32))  # floats must be in [0, 1]
    with pytest.raises(FileNotFoundError, match="nope.onnx"):
        metric_depth_from_cache(mdir / "nope.onnx")


def test_registered_user_model_is_metric(mdir, tmp_path, monkeypatch):
    monkeypatch.setenv("SPGEO_MODEL_DIR", str(tmp_path / "cache"))
    models.register_model("toy-metric", mdir / "plane.onnx", preset="fastdepth")
    est = metric_depth_from_cache("toy-metric", intra_op_num_threads=1)
    assert est.config.metric and est.config.model_path == str((mdir / "plane.onnx").resolve())
    models.register_model("toy-generic", mdir / "plane.onnx")  # default preset: up to scale
    with pytest.raises(ValueError, match="not metric.*--preset fastdepth"):
        metric_depth_from_cache("toy-generic", input_name=FASTDEPTH.input_name,
                                output_name=FASTDEPTH.output_name, input_size=(224, 224))


# ------------------------------------------------------------------ the real network
@pytest.fixture(scope="module")
def fastdepth():
    path = shared_data_dir().parent / "models" / "fastdepth" / "fastdepth_nyu_224.onnx"
    if not path.is_file():
        pytest.skip(f"shared FastDepth model not found at {path}")
    assert models.sha256_file(path) == FASTDEPTH_SHA256
    return metric_depth_from_cache(path, intra_op_num_threads=1)


def test_fastdepth_contract(fastdepth):
    img = np.random.default_rng(0).integers(0, 256, (240, 320, 3), dtype=np.uint8)
    z = fastdepth.predict_metric(img)
    assert z.shape == (240, 320) and z.dtype == np.float32
    assert np.isfinite(z).mean() > 0.99
    assert 0.1 < np.nanmin(z) and np.nanmax(z) < 20.0  # indoor metres
    grey = img.mean(axis=2).astype(np.float32) / 255.0
    zg = fastdepth.predict_metric(grey)  # (H, W) grey float in [0, 1]
    assert zg.shape == (240, 320) and np.isfinite(zg).mean() > 0.99
    assert fastdepth.predict_raw(img).shape == (224, 224)


def test_fastdepth_7scenes_accuracy(fastdepth):
    """Metric AbsRel and median scale GT / prediction on every 30th frame of 0..299
    (sensor depth not registered to colour: approximate ground truth)."""
    from spgeo.datasets import open_dataset

    root = shared_data_dir() / "7scenes_redkitchen_dev"
    if not root.is_dir():
        pytest.skip(f"shared sample data not found at {root}")
    seq = open_dataset("7scenes", root, frames="0:300:30")
    assert len(seq) == 10
    gt_all, pred_all = [], []
    for frame in seq:
        pred = fastdepth.predict_metric(frame.image)
        ok = np.isfinite(frame.depth) & (frame.depth > 0) & np.isfinite(pred)
        assert ok.mean() > 0.5, frame.name
        gt_all.append(frame.depth[ok])
        pred_all.append(pred[ok])
    gt, pred = np.concatenate(gt_all), np.concatenate(pred_all)
    abs_rel = float(np.mean(np.abs(pred - gt) / gt))
    scale = float(np.median(gt / pred))
    assert abs_rel < 0.3, abs_rel
    assert 0.85 <= scale <= 1.15, scale
