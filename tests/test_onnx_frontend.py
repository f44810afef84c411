"""ONNX front-end: SAM-style segmenter (docs/design.md §3 rules) and ONNX normals.

Every test runs real onnxruntime sessions on small models built in
``onnx_builders`` that follow the official I/O contracts.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import onnx_builders as B
from spgeo.camera import PinholeCamera
from spgeo.frontend.base import NormalEstimator, Segmenter
from spgeo.frontend.mask_generator import (SamMaskGenerator, SamMaskGeneratorConfig, box_nms,
                                           mask_boxes, stability_scores)
from spgeo.frontend.normal_conventions import (check_convention_on_plane, parse_convention,
                                               render_synthetic_room, signed_permutations)
from spgeo.frontend.onnx_normals import NormalModel, NormalOnnxConfig
from spgeo.frontend.onnx_sam import SamOnnxConfig, SegmentModel, resize_longest_side

MEAN = np.array([123.675, 116.28, 103.53])
STABLE = (5.5, 10.5, 20.5)


def disc_area(r):
    """Pixels of the lattice disc d < r."""
    v, u = np.mgrid[-40:41, -40:41]
    return int((np.hypot(u, v) < r).sum())
STD = np.array([58.395, 57.12, 57.375])


def cam(h, w):
    return PinholeCamera(0.8 * w, 0.8 * w, (w - 1) / 2, (h - 1) / 2, w, h)


def textured(h, w, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.1, 0.9, (h, w, 3)).astype(np.float32)


@pytest.fixture(scope="module")
def mdir(tmp_path_factory):
    """All test models, built once."""
    d = tmp_path_factory.mktemp("onnx")
    B.sam_encoder(d / "enc.onnx")
    B.sam_encoder(d / "enc_image.onnx", input_name="image")
    B.sam_decoder(d / "dec.onnx")                             # radii 4 (unstable), 10.5, 20.5
    B.sam_decoder(d / "dec_stable.onnx", radii=STABLE, slopes=(30, 30, 30),
                  ious=(0.8, 0.9, 0.99))
    B.sam_decoder(d / "dec_unstable.onnx", slopes=(0.05, 0.05, 0.05))
    B.sam_decoder(d / "dec_offset.onnx", offset=(30.0, 0.0))
    B.sam_decoder(d / "dec_offset_small.onnx", radii=STABLE, slopes=(30, 30, 30),
                  offset=(7.0, 0.0))
    B.sam_decoder(d / "dec4.onnx", radii=(30.5,) + STABLE, slopes=(30, 30, 30, 30),
                  ious=(0.5, 0.8, 0.9, 0.99))
    B.sam_decoder(d / "dec_badnames.onnx", input_names=[
        "image_embeddings", "points", "point_labels", "mask_input", "has_mask_input",
        "orig_im_size"])
    B.efficientsam_encoder(d / "esam_enc.onnx")
    B.efficientsam_decoder(d / "esam_dec.onnx")
    return d


def sam(mdir, dec="dec.onnx", enc="enc.onnx", **kw):
    return SegmentModel(SamOnnxConfig(encoder_path=str(mdir / enc), decoder_path=str(mdir / dec),
                                      encoder_input_name="x", **kw))


def centroid(mask):
    v, u = np.nonzero(mask)
    return u.mean(), v.mean()


# ------------------------------------------------------------------ encoder
def test_encoder_preprocessing(mdir):
    model = sam(mdir)
    h, w = 120, 160
    color = np.array([0.2, 0.5, 0.8], np.float32)
    img = np.broadcast_to(color, (h, w, 3)).copy()
    emb = model.encode(img).embedding
    assert emb.shape == (1, 256, 64, 64)
    nh, nw = resize_longest_side(h, w, 1024)
    assert (nh, nw) == (768, 1024)
    expect = (color * 255 - MEAN) / STD
    # channels are tiled RGB; valid rows hold the normalised colour, padding is zero
    for c in range(6):
        np.testing.assert_allclose(emb[0, c, : nh // 16], expect[c % 3], atol=1e-3)
        np.testing.assert_allclose(emb[0, c, nh // 16:], 0.0, atol=1e-6)
    # orientation: a bright bottom half shows in the bottom embedding rows
    img2 = np.zeros((h, w, 3), np.float32)
    img2[h // 2:] = 1.0
    e2 = model.encode(img2).embedding[0, 0]
    assert e2[5, 10] < 0 < e2[40, 10] and e2[60, 10] == 0
    # grey input is replicated to RGB
    assert model.encode(np.full((h, w), 0.5, np.float32)).embedding.shape == (1, 256, 64, 64)


def test_encoder_hwc_raw_layout(mdir):
    """Exports that pre-process inside the graph get the resized 0-255 HWC image."""
    path = B.sam_encoder_hwc_raw(mdir / "enc_hwc.onnx")
    m = SegmentModel(SamOnnxConfig(encoder_path=str(path), decoder_path=str(mdir / "dec.onnx"),
                                   encoder_layout="hwc-raw"))
    assert m.backend.encoder_input == "input_image"
    img = textured(120, 160)
    np.testing.assert_allclose(m.encode(img).embedding, sam(mdir).encode(img).embedding,
                               atol=1e-4)
    with pytest.raises(ValueError, match="rank 4"):  # the layout must fit the model
        SegmentModel(SamOnnxConfig(encoder_path=str(path), decoder_path=str(mdir / "dec.onnx")))


def test_encoder_input_name_from_file_and_checked(mdir):
    m = SegmentModel(SamOnnxConfig(encoder_path=str(mdir / "enc_image.onnx"),
                                   decoder_path=str(mdir / "dec.onnx")))
    assert m.backend.encoder_input == "image"
    with pytest.raises(ValueError, match=r"expected input 'x'.*\['image'\]"):
        SegmentModel.from_paths(mdir / "enc_image.onnx", mdir / "dec.onnx", preset="sam-labelme")


# ------------------------------------------------------- coordinate mapping
@pytest.mark.parametrize("h,w", [(480, 640), (120, 160), (160, 120), (100, 100)])
def test_mask_centred_on_prompt(mdir, h, w):
    model = sam(mdir, dec="dec_stable.onnx")
    emb = model.encode(textured(h, w))
    pts = np.array([[w // 3, h // 2], [w - 15, 12], [17, h - 20]])
    logits, iou = model.predict(emb, pts)
    assert logits.shape == (3, 3, h, w) and iou.shape == (3, 3)
    vv, uu = np.mgrid[0:h, 0:w]
    for (u, v), lg in zip(pts, logits):
        d = np.hypot(uu - u, vv - v)
        for c, r in enumerate(STABLE):
            mask = lg[c] > 0
            # exactly the disc around the prompt pixel, in original-image pixels
            assert np.all(mask[d < r - 0.01]) and not np.any(mask[d > r + 0.01])
            if r < min(u, v, w - 1 - u, h - 1 - v):
                cu, cv = centroid(mask)
                assert abs(cu - u) < 1e-6 and abs(cv - v) < 1e-6


def test_upsample_to(mdir):
    h, w = 120, 160
    model = sam(mdir, dec="dec_stable.onnx", upsample_to=(240, 320))
    emb = model.encode(textured(h, w))
    assert emb.model_size == (240, 320) and emb.image_size == (h, w)
    logits, _ = model.predict(emb, [[60, 50]])
    assert logits.shape == (1, 3, h, w)
    mask = logits[0, 2] > 0  # radius 20.5 model pixels = 10.25 image pixels
    cu, cv = centroid(mask)
    assert abs(cu - 60) < 0.3 and abs(cv - 50) < 0.3
    assert abs(mask.sum() - np.pi * 10.25 ** 2) < 0.05 * np.pi * 10.25 ** 2


def test_four_token_output_keeps_multimask_tokens(mdir):
    model = sam(mdir, dec="dec4.onnx")
    emb = model.encode(textured(120, 160))
    logits, iou = model.predict(emb, [[80, 60]])
    assert logits.shape[1] == 3
    areas = (logits[0] > 0).sum(axis=(1, 2))
    assert areas.tolist() == [disc_area(r) for r in STABLE]
    np.testing.assert_allclose(iou[0], [0.8, 0.9, 0.99], atol=0.01)


# ---------------------------------------------------------------- utilities
def test_stability_scores():
    logits = np.array([[[3.0, 0.5, -0.5, -3.0]]])  # > +1: 1 px; > -1: 3 px
    np.testing.assert_allclose(stability_scores(logits), [1 / 3])
    assert stability_scores(np.full((1, 2, 2), -5.0))[0] == 0.0


def test_box_nms():
    boxes = np.array([[0, 0, 9, 9], [1, 0, 10, 9], [0, 0, 9, 9], [50, 50, 60, 60]])
    scores = np.array([0.5, 0.9, 0.7, 0.1])
    keep = box_nms(boxes, scores, 0.8)  # box 1 (best) suppresses 0 and 2 (IoU 0.82)
    assert list(keep) == [1, 3]
    assert list(box_nms(boxes, scores, 0.9)) == [1, 2, 3]  # 2 is a duplicate of 0 (IoU 1)
    regions = [np.array([5 * 20 + 3, 7 * 20 + 8])]
    assert mask_boxes(regions, 20).tolist() == [[3, 5, 8, 7]]


# ------------------------------------------------------------ selection rules
def run(model, prompts, h=120, w=160, **cfg):
    cfg.setdefault("num_active_prompts", 0)
    gen = SamMaskGenerator(model, SamMaskGeneratorConfig(**cfg))
    return gen.segment_with_prompts(textured(h, w), cam(h, w), np.asarray(prompts))


PROMPTS = [[30, 30], [90, 40], [130, 90], [50, 95]]


def test_unstable_candidate_never_chosen(mdir):
    model = sam(mdir)  # candidate 0: smallest, highest IoU, but unstable
    emb = model.encode(textured(120, 160))
    logits, _ = model.predict(emb, PROMPTS)
    stab = stability_scores(logits)
    assert np.all(stab[:, 0] < 0.9) and np.all(stab[:, 1:] >= 0.9)
    seg = run(model, PROMPTS)
    assert len(seg) == 4 and seg.meta["dropped_stability"] == 0
    for i, (u, v) in enumerate(PROMPTS):
        k = list(seg.anchors).index(v * 160 + u)
        expect = np.flatnonzero(logits[i, 1] > 0)  # the 10.5 px disc, not the 4 px one
        np.testing.assert_array_equal(seg.regions[k], expect)
        np.testing.assert_allclose(seg.scores[k], 0.9 + 1e-4 * u, atol=1e-5)


def test_all_unstable_dropped(mdir):
    seg = run(sam(mdir, dec="dec_unstable.onnx"), PROMPTS)
    assert len(seg) == 0
    assert seg.meta["dropped_stability"] == 4 and seg.meta["queries"] == 4


def test_smallest_kept_candidate_chosen(mdir):
    model = sam(mdir, dec="dec_stable.onnx")  # all stable; IoU favours the largest
    seg = run(model, PROMPTS)
    assert len(seg) == 4
    for r in seg.regions:
        assert r.size == disc_area(5.5)


def test_prompt_outside_dropped(mdir):
    seg = run(sam(mdir, dec="dec_offset.onnx"), PROMPTS)
    assert len(seg) == 0 and seg.meta["dropped_prompt_outside"] == 4
    # the chosen (smallest stable) disc misses the prompt although larger ones contain it
    model = sam(mdir, dec="dec_offset_small.onnx")
    logits, _ = model.predict(model.encode(textured(120, 160)), PROMPTS)
    assert all(logits[i, 2, v, u] > 0 for i, (u, v) in enumerate(PROMPTS))
    seg = run(model, PROMPTS)
    assert len(seg) == 0 and seg.meta["dropped_prompt_outside"] == 4


def test_nms_removes_near_duplicates_keeping_higher_iou(mdir):
    model_big = sam(mdir)  # chosen disc: radius 10
    prompts = [[50, 60], [51, 60], [100, 30], [105, 30]]
    seg = run(model_big, prompts)
    # 21x21 boxes 1 px apart: IoU 0.91 > 0.8 -> the u=50 one (lower IoU) goes;
    # 5 px apart: IoU 0.62 -> both stay
    assert seg.meta["removed_nms"] == 1 and len(seg) == 3
    anchors = set(seg.anchors.tolist())
    assert 60 * 160 + 51 in anchors and 60 * 160 + 50 not in anchors
    assert {30 * 160 + 100, 30 * 160 + 105} <= anchors
    assert np.all(np.diff(seg.scores) <= 0)  # ranked by predicted IoU


def test_active_prompts_fill_uncovered_area(mdir):
    model = sam(mdir)
    h, w = 120, 160
    gen = SamMaskGenerator(model, SamMaskGeneratorConfig(num_prompts=6, num_active_prompts=40,
                                                         seed=3))
    seg = gen.segment(textured(h, w), cam(h, w))
    meta = seg.meta
    n0 = meta["num_initial"]
    assert meta["initial_queries"] == 6 and meta["active_prompts"] == 40
    assert meta["queries"] == 46 and n0 + meta["num_active"] == len(seg)
    covered0 = np.zeros(h * w, bool)
    for r in seg.regions[:n0]:
        covered0[r] = True
    act = meta["active_prompts_uv"]
    assert len(act) == 40 and len(np.unique(act[:, 1] * w + act[:, 0])) == 40
    assert not covered0[act[:, 1] * w + act[:, 0]].any()  # only uncovered pixels
    assert set(seg.anchors[n0:].tolist()) <= set((act[:, 1] * w + act[:, 0]).tolist())
    assert meta["coverage_final"] > meta["coverage_initial"] + 0.1
    assert meta["coverage_initial"] == pytest.approx(covered0.mean())
    assert meta["coverage_final"] == pytest.approx((seg.coverage() > 0).mean())
    for r, a in zip(seg.regions, seg.anchors):
        assert a in r  # every anchor is its own prompt, inside its mask


def test_active_prompt_grid_jitter():
    unc = np.zeros((100, 100), bool)
    unc[:, 60:] = True
    rng = np.random.default_rng(0)
    pts = SamMaskGenerator.active_prompts(unc, 25, 3.0, rng)
    assert len(pts) == 25 and np.all(pts[:, 0] >= 60)
    # roughly a grid: no two prompts closer than ~ spacing - 2*jitter
    d = np.linalg.norm(pts[:, None] - pts[None], axis=-1) + np.eye(25) * 1e9
    assert d.min() >= 2
    assert len(SamMaskGenerator.active_prompts(np.zeros((10, 10), bool), 5, 3.0, rng)) == 0


def test_deterministic_by_seed(mdir):
    model = sam(mdir)
    cfg = SamMaskGeneratorConfig(num_prompts=20, num_active_prompts=10, seed=7)
    img, c = textured(120, 160), cam(120, 160)
    a = SamMaskGenerator(model, cfg).segment(img, c)
    b = SamMaskGenerator(model, cfg).segment(img, c)
    other = SamMaskGenerator(model, dataclasses.replace(cfg, seed=8)).segment(img, c)
    assert len(a) == len(b) > 0
    np.testing.assert_array_equal(a.anchors, b.anchors)
    np.testing.assert_array_equal(a.scores, b.scores)
    assert all(np.array_equal(x, y) for x, y in zip(a.regions, b.regions))
    np.testing.assert_array_equal(a.meta["active_prompts_uv"], b.meta["active_prompts_uv"])
    assert set(a.anchors.tolist()) != set(other.anchors.tolist())


def test_default_config_is_design():
    cfg = SamMaskGeneratorConfig()
    assert (cfg.num_prompts, cfg.num_active_prompts, cfg.stability_threshold,
            cfg.stability_offset, cfg.nms_iou) == (300, 100, 0.90, 1.0, 0.8)
    assert SamOnnxConfig().mask_threshold == 0.0 and SamOnnxConfig().input_size == 1024


def test_keep_all_candidates(mdir):
    model = sam(mdir, dec="dec_stable.onnx")
    prompts = [[40, 40], [120, 80]]
    seg = run(model, prompts, keep_all_candidates=True)
    assert len(seg) == 6 and seg.meta["keep_all_candidates"]
    sizes = sorted(r.size for r in seg.regions)
    assert sizes == sorted(2 * [disc_area(r) for r in STABLE])
    # the unstable candidate stays out even when keeping all
    seg = run(sam(mdir), prompts, keep_all_candidates=True)
    assert len(seg) == 4 and seg.meta["dropped_stability"] == 2


def test_protocol_and_segment_defaults(mdir):
    gen = SamMaskGenerator(sam(mdir), SamMaskGeneratorConfig(num_prompts=30,
                                                             num_active_prompts=10))
    assert isinstance(gen, Segmenter)
    seg = gen.segment(textured(60, 80), cam(60, 80))
    assert seg.height == 60 and seg.width == 80 and len(seg) > 0
    assert seg.meta["candidates_per_query"] == 3


# ------------------------------------------------------------- EfficientSAM
def test_efficientsam_adapter_matches_sam_contract(mdir):
    esam = SegmentModel(SamOnnxConfig(flavour="efficientsam",
                                      encoder_path=str(mdir / "esam_enc.onnx"),
                                      decoder_path=str(mdir / "esam_dec.onnx"),
                                      prompt_batch_size=3))
    assert esam.max_prompts_per_call == 3
    h, w = 90, 160
    img = textured(h, w)
    emb = esam.encode(img)
    assert emb.embedding.shape == (1, 256, 64, 64)
    pts = np.array([[20, 20], [80, 45], [150, 80], [5, 85], [100, 10]])
    logits, iou = esam.predict(emb, pts)
    assert logits.shape == (5, 3, h, w) and iou.shape == (5, 3)
    for (u, v), lg in zip(pts, logits):
        assert lg[1, v, u] > 0
    ref = sam(mdir)
    cfg = dict(num_prompts=25, num_active_prompts=10, seed=1)
    a = SamMaskGenerator(esam, SamMaskGeneratorConfig(**cfg)).segment(img, cam(h, w))
    b = SamMaskGenerator(ref, SamMaskGeneratorConfig(**cfg)).segment(img, cam(h, w))
    np.testing.assert_array_equal(a.anchors, b.anchors)
    assert all(np.array_equal(x, y) for x, y in zip(a.regions, b.regions))


# --------------------------------------------------------------- bad inputs
def test_missing_model_file(tmp_path, mdir):
    missing = tmp_path / "nope.onnx"
    with pytest.raises(FileNotFoundError, match="nope.onnx"):
        SegmentModel(SamOnnxConfig(encoder_path=str(missing), decoder_path=str(mdir / "dec.onnx")))
    with pytest.raises(FileNotFoundError, match="nope.onnx"):
        NormalModel(NormalOnnxConfig(model_path=str(missing)))
    with pytest.raises(ValueError, match="encoder_path and decoder_path"):
        SegmentModel(SamOnnxConfig())


def test_wrong_decoder_input_names(mdir):
    with pytest.raises(ValueError) as exc:
        sam(mdir, dec="dec_badnames.onnx")
    msg = str(exc.value)
    assert "point_coords" in msg and "'points'" in msg and "expected" in msg and "found" in msg


def test_wrong_flavour_contract(mdir):
    with pytest.raises(ValueError, match="batched_point_coords"):
        SegmentModel(SamOnnxConfig(flavour="efficientsam", encoder_path=str(mdir / "esam_enc.onnx"),
                                   decoder_path=str(mdir / "dec.onnx")))


def test_not_an_onnx_file(tmp_path, mdir):
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not a model")
    with pytest.raises(ValueError, match="bad.onnx"):
        SegmentModel(SamOnnxConfig(encoder_path=str(bad), decoder_path=str(mdir / "dec.onnx")))


def test_bad_images_and_prompts(mdir):
    model = sam(mdir)
    gen = SamMaskGenerator(model, SamMaskGeneratorConfig(num_prompts=5, num_active_prompts=0))
    img = textured(60, 80)
    img[3, 4, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        gen.segment(img, cam(60, 80))
    with pytest.raises(ValueError, match="expected"):
        gen.segment(textured(60, 80), cam(61, 80))
    with pytest.raises(ValueError, match="inside"):
        gen.segment_with_prompts(textured(60, 80), cam(60, 80), np.array([[80, 3]]))
    with pytest.raises(ValueError):
        SamOnnxConfig(flavour="sam2")
    with pytest.raises(ValueError):
        SamMaskGeneratorConfig(nms_iou=0.0)


# ------------------------------------------------------------------ normals
def normal_field(h, w):
    """A smooth, towards-the-camera unit normal field in spgeo's convention."""
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    n = np.stack([0.6 * (u / w - 0.5), 0.5 * (v / h - 0.5), -np.ones_like(u)], -1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(a * b, -1), -1, 1)))


@pytest.fixture(scope="module")
def nmodels(tmp_path_factory):
    d = tmp_path_factory.mktemp("normals")
    B.normal_model(d / "plain.onnx")
    B.normal_model(d / "dyn.onnx", input_size=None)
    B.normal_model(d / "imnet255.onnx", mean=MEAN, std=STD, scale=255.0)
    B.normal_model(d / "kappa.onnx", confidence=7.5)
    B.normal_model(d / "conf_out.onnx", confidence=2.0, confidence_output="normal_confidence")
    B.normal_model(d / "nhwc_rgb.onnx", output_layout="NHWC", raw_rgb=True)
    B.normal_model(d / "square.onnx", input_size=(48, 48))
    B.normal_model(d / "nhwc_in.onnx", input_layout="NHWC")
    return d


def nm(path, **kw):
    kw.setdefault("input_size", (48, 64))
    kw.setdefault("mean", (0.0, 0.0, 0.0))
    kw.setdefault("std", (1.0, 1.0, 1.0))
    return NormalModel(NormalOnnxConfig(model_path=str(path), **kw))


@pytest.mark.parametrize("convention", ["x right, y up, z towards viewer", "opengl", "dsine",
                                        "x left, y down, z forward",
                                        "x down, y right, z forward, normals away from camera"])
def test_normal_convention_conversion(nmodels, convention):
    h, w = 120, 160
    M = parse_convention(convention)
    model = nm(nmodels / "plain.onnx", convention=convention)
    assert isinstance(model, NormalEstimator) and model.uses_depth is False
    # constant normal: exact
    n_true = np.array([0.3, -0.4, -np.sqrt(0.75)])
    img = B.encode_normals(np.broadcast_to(M.T @ n_true, (h, w, 3)))
    out = model.estimate(img, cam(h, w))
    assert out.shape == (h, w, 3) and out.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(out, axis=-1), 1.0, atol=1e-5)
    assert angle_deg(out, n_true).max() < 0.5
    # smooth field through 48x64 and back
    field = normal_field(h, w)
    out = model.estimate(B.encode_normals(field @ M), cam(h, w))
    assert np.median(angle_deg(out, field)) < 0.5 and angle_deg(out, field).max() < 3.0


def test_named_presets_and_matrix():
    np.testing.assert_array_equal(parse_convention("x right, y up, z towards viewer"),
                                  parse_convention("opengl"))
    np.testing.assert_array_equal(parse_convention("spgeo"), np.eye(3))
    # facing wall (0,0,-1) in spgeo is (0,0,+1) for an outward model
    assert (parse_convention("dsine") @ np.array([0, 0, 1.0]))[2] == -1
    with pytest.raises(ValueError):
        parse_convention("x right, y right, z forward")
    with pytest.raises(ValueError):
        parse_convention("x sideways, y down, z forward")
    with pytest.raises(ValueError, match="orthogonal"):
        NormalOnnxConfig(model_to_spgeo=((1, 0, 0), (0, 1, 0), (0, 1, 1)))
    assert len({tuple(m.ravel()) for m in signed_permutations()}) == 48


def test_normals_explicit_matrix_and_imagenet_255(nmodels):
    h, w = 60, 80
    M = np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 1.0]])
    model = NormalModel(NormalOnnxConfig(model_path=str(nmodels / "imnet255.onnx"),
                                         input_size=(48, 64), input_range="0-255",
                                         mean=tuple(MEAN), std=tuple(STD),
                                         model_to_spgeo=tuple(map(tuple, M))))
    field = normal_field(h, w)
    out = model.estimate(B.encode_normals(field @ M), cam(h, w))
    assert np.median(angle_deg(out, field)) < 0.5


def test_confidence_channel(nmodels):
    h, w = 60, 80
    img = B.encode_normals(normal_field(h, w))
    pred = nm(nmodels / "kappa.onnx").predict(img)
    assert pred.confidence.shape == (h, w)
    np.testing.assert_allclose(pred.confidence, 7.5, atol=1e-4)
    assert np.median(angle_deg(pred.normals, normal_field(h, w))) < 0.5
    pred = nm(nmodels / "conf_out.onnx", confidence_output_name="normal_confidence").predict(img)
    np.testing.assert_allclose(pred.confidence, 2.0, atol=1e-4)
    assert nm(nmodels / "plain.onnx").predict(img).confidence is None


def test_nhwc_rgb01_output_and_dynamic_size(nmodels):
    h, w = 60, 80
    field = normal_field(h, w)
    img = B.encode_normals(field)
    out = nm(nmodels / "nhwc_rgb.onnx", output_layout="NHWC",
             output_encoding="rgb01").estimate(img, cam(h, w))
    assert np.median(angle_deg(out, field)) < 0.5
    out = nm(nmodels / "dyn.onnx", input_size=None).estimate(img, cam(h, w))
    assert angle_deg(out, field).max() < 0.2
    out = nm(nmodels / "nhwc_in.onnx", layout="NHWC").estimate(img, cam(h, w))
    assert np.median(angle_deg(out, field)) < 0.5
    with pytest.raises(ValueError, match="NCHW 3-channel"):
        nm(nmodels / "nhwc_in.onnx")


def test_letterbox(nmodels):
    h, w = 60, 80
    field = normal_field(h, w)
    model = nm(nmodels / "square.onnx", input_size=(48, 48), resize_mode="letterbox")
    out = model.estimate(B.encode_normals(field), cam(h, w))
    assert out.shape == (h, w, 3)
    assert np.median(angle_deg(out, field)) < 1.0
    # stretching a non-square image into a square input still maps pixels back
    out = nm(nmodels / "square.onnx", input_size=(48, 48)).estimate(B.encode_normals(field),
                                                                     cam(h, w))
    assert np.median(angle_deg(out, field)) < 1.0


def test_check_convention_on_plane(nmodels):
    room, gt = render_synthetic_room(PinholeCamera(100, 100, 79.5, 59.5, 160, 120))
    assert room.shape == (120, 160, 3) and np.all(np.isfinite(gt))
    # the synthetic room has floor, ceiling, walls, back wall and a slanted panel
    assert len(np.unique(gt.reshape(-1, 3), axis=0)) == 6
    M_true = parse_convention("x left, y up, z towards viewer")
    model = nm(nmodels / "dyn.onnx", input_size=None)
    scores = check_convention_on_plane(model, image=B.encode_normals(gt @ M_true), normals_gt=gt)
    assert len(scores) == 48
    np.testing.assert_array_equal(np.array(scores[0].model_to_spgeo), M_true)
    assert scores[0].score_deg < 0.5 and scores[0].mean_deg < 0.5 and scores[1].score_deg > 20
    assert [s.score_deg for s in scores] == sorted(s.score_deg for s in scores)
    # default synthetic room with a 48x64 model: runs and ranks all candidates
    scores = check_convention_on_plane(nm(nmodels / "plain.onnx"))
    assert len(scores) == 48


def test_normal_bad_inputs(nmodels, tmp_path):
    with pytest.raises(ValueError, match=r"expected the single input 'rgb'.*\['image'\]"):
        nm(nmodels / "plain.onnx", input_name="rgb")
    with pytest.raises(ValueError, match="predicted_normal"):
        nm(nmodels / "plain.onnx", output_name="predicted_normal")
    with pytest.raises(ValueError, match="48x64"):
        nm(nmodels / "plain.onnx", input_size=(480, 640))
    model = nm(nmodels / "plain.onnx")
    img = B.encode_normals(normal_field(30, 40))
    img[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        model.estimate(img, cam(30, 40))
    with pytest.raises(ValueError):
        model.estimate(B.encode_normals(normal_field(30, 40)), cam(31, 40))
    with pytest.raises(ValueError):
        NormalOnnxConfig(layout="CHW")
    with pytest.raises(ValueError):
        NormalModel.from_path(nmodels / "plain.onnx", preset="nope")


# ------------------------------------------------------------------ end to end
def test_onnx_frontend_end_to_end_primitives(mdir, nmodels):
    """make_frontend('onnx') with contract-following models: SAM discs become
    primitives anchored at their prompts, and the normal network's output
    (a tilted plane, encoded in the image) integrates to that plane's depth."""
    from analytic import plane, scale_fitted_rel_error
    from spgeo.frontend import FrontEndConfig, make_frontend
    from spgeo.frontend.mask_generator import SamMaskGeneratorConfig

    h, w = 120, 160
    c = cam(h, w)
    z, n_true = plane(c, [0.3, -0.2, -1.0], -2.0)
    img = B.encode_normals(n_true)          # the test normal model decodes the image as normals
    fe = make_frontend(
        "onnx", FrontEndConfig(),
        sam=dict(family=None, encoder=mdir / "enc.onnx", decoder=mdir / "dec_stable.onnx",
                 encoder_input_name="x",
                 generator_config=SamMaskGeneratorConfig(num_prompts=20, num_active_prompts=10)),
        normals=dict(name_or_path=nmodels / "plain.onnx", input_size=(48, 64),
                     mean=(0.0, 0.0, 0.0), std=(1.0, 1.0, 1.0)))
    assert fe.uses_depth is False
    prims = fe.primify(img, c)
    assert len(prims) >= 10
    meta = prims.meta["segmenter_meta"]
    assert meta["dropped_prompt_outside"] == 0
    for prim in prims:
        u, v = prim.anchor_uv
        assert prim.mask[v, u]
        # every primitive is a disc of the chosen (smallest stable) radius around its prompt
        assert prim.size <= disc_area(STABLE[0]) + 1
    depth_err = []
    for prim in prims:
        ld = np.full(c.shape, np.nan)
        ld.reshape(-1)[prim.pixels] = prim.log_depth
        depth_err.append(np.median(scale_fitted_rel_error(ld, z, prim.mask)))
    assert np.median(depth_err) < 2e-3
