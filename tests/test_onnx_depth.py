"""Depth-network ONNX path: contract models of a known plane -> analytic normals, for every
output kind; contract errors name the model file; registry and front-end wiring."""
from __future__ import annotations

import numpy as np
import pytest

import onnx_builders as B
from spgeo import models
from spgeo.camera import PinholeCamera
from spgeo.frontend import FRONTENDS, make_frontend
from spgeo.frontend.base import NormalEstimator
from spgeo.frontend.from_cache import depth_normals_from_cache
from spgeo.frontend.onnx_depth import (DEPTH_PRESETS, DepthOnnxConfig, OnnxDepthNormals,
                                       network_input_size)

H, W = 42, 56
N_PLANE = np.array([0.3, -0.4, -1.0]) / np.linalg.norm([0.3, -0.4, -1.0])
OFFSET = 2.0  # plane n . X = -OFFSET (metres)
GREY = np.full((H, W, 3), 0.5, np.float32)


def cam(h=H, w=W):
    return PinholeCamera(0.8 * w, 0.8 * w, (w - 1) / 2, (h - 1) / 2, w, h)


def plane_coeffs(camera, n=N_PLANE, c=OFFSET):
    """(a, b, k) with 1/z = a x + b y + k in normalised coords x = (u + 0.5) / W, y = (v + 0.5) / H.

    1/z = -(n_x (u - cx) / fx + n_y (v - cy) / fy + n_z) / c and u = W x - 0.5."""
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    a = -n[0] * camera.width / (fx * c)
    b = -n[1] * camera.height / (fy * c)
    k = -(n[0] * (-0.5 - cx) / fx + n[1] * (-0.5 - cy) / fy + n[2]) / c
    return a, b, k


def angles_deg(normals, n):
    cosang = np.clip(np.abs(normals.reshape(-1, 3) @ n), -1.0, 1.0)
    return np.degrees(np.arccos(cosang))


def model(path, **kw):
    cfg = dict(input_size=None, aspect_side=56, multiple_of=14, mean=(0.0, 0.0, 0.0),
               std=(1.0, 1.0, 1.0))
    cfg.update(kw)
    return OnnxDepthNormals(DepthOnnxConfig(model_path=str(path), **cfg))


@pytest.fixture(scope="module")
def mdir(tmp_path_factory):
    d = tmp_path_factory.mktemp("onnx_depth")
    coeffs = plane_coeffs(cam())
    B.depth_model(d / "inv.onnx", coeffs, kind="inverse")
    B.depth_model(d / "depth.onnx", coeffs, kind="depth", output_rank=4)
    # ImageNet-normalised input, disparity = 3 * inverse depth (unknown scale)
    B.depth_model(d / "disp.onnx", tuple(3.0 * v for v in coeffs), kind="inverse",
                  mean=DEPTH_PRESETS["depth-anything-v2"].mean,
                  std=DEPTH_PRESETS["depth-anything-v2"].std, gain=3.0)
    B.depth_model(d / "fixed.onnx", coeffs, kind="inverse", input_size=(28, 42))
    B.depth_model(d / "rank3.onnx", coeffs, input_rank=3, input_size=(H, W))
    B.depth_model(d / "three.onnx", coeffs, output_rank=4, channels=3)
    return d


def test_network_input_size():
    # DPT rule: the side whose scale is nearer 1 lands on `side`, multiples of 14
    assert network_input_size(480, 640) == (518, 686)
    assert network_input_size(960, 1280) == (518, 686)
    assert network_input_size(H, W, side=56) == (H, W)
    with pytest.raises(ValueError, match="0x5"):
        network_input_size(0, 5)


@pytest.mark.parametrize("name, kind", [("inv.onnx", "inverse_depth"),
                                        ("depth.onnx", "depth"),
                                        ("inv.onnx", "disparity")])
def test_plane_normals_each_kind(mdir, name, kind):
    est = model(mdir / name, output_kind=kind)
    assert isinstance(est, NormalEstimator) and est.uses_depth is False
    n = est.estimate(GREY, cam())
    assert n.shape == (H, W, 3) and n.dtype == np.float32
    assert np.all(np.isfinite(n))
    assert np.allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-4)
    assert np.all(n.reshape(-1, 3) @ N_PLANE > 0)  # oriented towards the camera like the plane
    err = angles_deg(n, N_PLANE)
    assert np.median(err) < 0.05 and err.max() < 0.5, (np.median(err), err.max())
    # depth up to scale: proportional to the true plane depth
    z = est.predict_depth(GREY)
    a, b, k = plane_coeffs(cam())
    v, u = np.mgrid[0:H, 0:W]
    z_true = 1.0 / (a * (u + 0.5) / W + b * (v + 0.5) / H + k)
    ratio = z / z_true
    assert np.ptp(ratio) < 1e-4 * ratio.mean()


def test_disparity_normalisation_and_shift(mdir):
    """ImageNet normalisation must be undone exactly (else the image term shifts the plane);
    a disparity shift s turns the plane into the one with 1/z' = 1/z + s * p99(1/z)."""
    preset = DEPTH_PRESETS["depth-anything-v2"]
    kw = dict(output_kind="disparity", input_name="pixel_values", output_name="predicted_depth",
              mean=preset.mean, std=preset.std)
    n = model(mdir / "disp.onnx", **kw).estimate(GREY, cam())
    assert np.median(angles_deg(n, N_PLANE)) < 0.05
    wrong = model(mdir / "disp.onnx", **{**kw, "mean": (0.0, 0.0, 0.0)}).estimate(GREY, cam())
    assert np.median(angles_deg(wrong, N_PLANE)) > 2.0
    shift = 0.5
    shifted = model(mdir / "disp.onnx", **kw, disparity_shift=shift).estimate(GREY, cam())
    a, b, k = plane_coeffs(cam())
    v, u = np.mgrid[0:H, 0:W]
    p99 = np.percentile(a * (u + 0.5) / W + b * (v + 0.5) / H + k, 99.0)
    n_expected = N_PLANE / OFFSET - np.array([0.0, 0.0, shift * p99])  # -(A, B, C + s p)
    n_expected /= np.linalg.norm(n_expected)
    err = angles_deg(shifted, n_expected)
    assert np.median(err) < 0.05 and angles_deg(shifted, N_PLANE).min() > 2.0


def test_fixed_size_model_resized_back(mdir):
    """A static 28x42 model is fed 28x42 and its inverse depth resized to the image."""
    est = model(mdir / "fixed.onnx", output_kind="inverse_depth")
    assert est.input_size_for(H, W) == (28, 42)
    n = est.estimate(GREY, cam())
    inner = n[3:-3, 3:-3]  # bilinear resize clamps at the border
    err = angles_deg(inner, N_PLANE)
    assert np.median(err) < 0.1 and err.max() < 1.0
    with pytest.raises(ValueError, match="fixed.onnx.*input_size"):
        model(mdir / "fixed.onnx", input_size=(42, 56))


def test_contract_errors_name_the_file(mdir):
    with pytest.raises(ValueError, match=r"rank3\.onnx.*NCHW 3-channel"):
        model(mdir / "rank3.onnx")
    with pytest.raises(ValueError, match=r"three\.onnx.*one-channel.*3 channels"):
        model(mdir / "three.onnx")  # a declared 3-channel output is refused on opening
    with pytest.raises(ValueError, match=r"inv\.onnx.*expected output 'depth'"):
        model(mdir / "inv.onnx", output_name="depth")
    with pytest.raises(ValueError, match=r"inv\.onnx.*expected the single input 'image'"):
        model(mdir / "inv.onnx", input_name="image")
    with pytest.raises(FileNotFoundError, match="nope.onnx"):
        model(mdir / "nope.onnx")
    # an all-negative output has no valid depth
    with pytest.raises(ValueError, match=r"inv\.onnx.*min_inverse"):
        model(mdir / "inv.onnx", output_kind="disparity", disparity_shift=-5.0).estimate(
            GREY, cam())
    with pytest.raises(ValueError, match="image"):
        model(mdir / "inv.onnx").estimate(GREY[:-2], cam())


def test_config_validation():
    with pytest.raises(ValueError, match="output_kind"):
        DepthOnnxConfig(output_kind="metric")
    with pytest.raises(ValueError, match="multiple"):
        DepthOnnxConfig(input_size=(500, 500))
    with pytest.raises(ValueError, match="letterbox"):
        DepthOnnxConfig(input_size=None, resize_mode="letterbox")
    with pytest.raises(ValueError, match="min_inverse"):
        DepthOnnxConfig(min_inverse=0.0)


def test_registry_entry_and_frontend(mdir, tmp_path, monkeypatch):
    e = models.get_entry("depth-anything-v2-small")
    assert e.kind == "depth" and e.preset in DEPTH_PRESETS
    assert e.url.startswith("https://huggingface.co/onnx-community/depth-anything-v2-small/")
    assert e.sha256 is not None and len(e.sha256) == 64 and e.size and e.size > 10_000_000
    assert e.source and e.licence == "Apache-2.0"
    assert DEPTH_PRESETS[e.preset].output_kind == "disparity"
    # the factory resolves a registry name in the cache (file registered under the name)
    monkeypatch.setenv("SPGEO_MODEL_DIR", str(tmp_path / "cache"))
    src = mdir / "inv.onnx"
    reg = {"toy-depth": models.ModelEntry("toy-depth", "depth", src.as_uri(), None, None, "MIT",
                                          "depth-anything-v2", filename="toy-depth.onnx",
                                          source="test")}
    models.register_local("toy-depth", src, allow_unverified=True, registry=reg)
    est = depth_normals_from_cache("toy-depth", registry=reg, aspect_side=56,
                                   mean=(0.0, 0.0, 0.0), std=(1.0, 1.0, 1.0))
    assert est.config.output_kind == "disparity" and est.input_name == "pixel_values"
    assert "onnx-depth" in FRONTENDS
    fe = make_frontend("onnx-depth", normals={"name_or_path": str(src), "aspect_side": 56,
                                              "mean": (0.0, 0.0, 0.0), "std": (1.0, 1.0, 1.0)})
    assert isinstance(fe.normal_estimator, OnnxDepthNormals)
    assert fe.uses_depth is False
    # end to end on a plane: classical segments + contract-model normals -> primitives whose
    # integrated log-depth follows the tilted plane inside each primitive
    h, w = 96, 128
    camera = cam(h, w)
    src2 = B.depth_model(tmp_path / "plane128.onnx", plane_coeffs(camera), gain=0.0)
    fe = make_frontend("onnx-depth", normals={"name_or_path": str(src2), "input_size": (98, 126),
                                              "mean": (0.0, 0.0, 0.0), "std": (1.0, 1.0, 1.0),
                                              "output_kind": "inverse_depth"})
    rng = np.random.default_rng(0)
    image = rng.uniform(0.2, 0.8, (h, w, 3)).astype(np.float32)
    prims = fe.primify(image, camera)
    assert len(prims) > 1
    spreads = []
    for prim in prims:
        c = prim.camera
        u, v = prim.uv.T
        inv_z = -(N_PLANE[0] * (u - c.cx) / c.fx + N_PLANE[1] * (v - c.cy) / c.fy
                  + N_PLANE[2]) / OFFSET
        spreads.append(np.ptp(prim.log_depth + np.log(inv_z)))  # log(depth / true depth)
    spreads = np.array(spreads)
    const = [np.ptp(np.log(-(N_PLANE[1] * (p.uv[:, 1] - p.camera.cy) / p.camera.fy
                             + N_PLANE[0] * (p.uv[:, 0] - p.camera.cx) / p.camera.fx
                             + N_PLANE[2]))) for p in prims]  # what constant depth would miss
    assert np.median(spreads) < 0.1 * np.median(const), (np.median(spreads), np.median(const))
