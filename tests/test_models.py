"""Model cache: directory, registry, verified download (file:// URLs, offline), CLI, factories."""
from __future__ import annotations

import argparse
import hashlib

import numpy as np
import pytest

import onnx_builders as B
from spgeo import models
from spgeo.camera import PinholeCamera
from spgeo.frontend import from_cache
from spgeo.frontend.base import Segmenter
from spgeo.frontend.onnx_depth import DEPTH_PRESETS
from spgeo.frontend.onnx_normals import NORMAL_PRESETS, NormalModel
from spgeo.frontend.mask_generator import SamMaskGeneratorConfig
from spgeo.frontend.onnx_sam import SAM_PRESETS, SegmentModel
from spgeo.cli.models import add_cli
from spgeo.models import ModelDownloadError, ModelEntry


@pytest.fixture
def cache(tmp_path, monkeypatch):
    d = tmp_path / "cache"
    monkeypatch.setenv("SPGEO_MODEL_DIR", str(d))
    return d


def make_file(tmp_path, name="m.onnx", data=b"onnx-bytes" * 1000):
    p = tmp_path / name
    p.write_bytes(data)
    return p, hashlib.sha256(data).hexdigest()


def entry(url, sha, size=None, name="toy", kind="normals", filename="toy.onnx"):
    return ModelEntry(name, kind, url, sha, size, "MIT", "generic-480x640", filename=filename)


def test_model_dir_env_override(tmp_path, monkeypatch):
    monkeypatch.setenv("SPGEO_MODEL_DIR", str(tmp_path / "x"))
    assert models.model_dir() == tmp_path / "x"
    assert not (tmp_path / "x").exists()
    assert models.model_dir(create=True).is_dir()
    monkeypatch.delenv("SPGEO_MODEL_DIR")
    default = models.model_dir()
    assert default.name == "models" and default.parent.name.lower().startswith("spgeo")


def test_registry_is_consistent():
    reg = models.REGISTRY
    assert len(reg) >= 10
    families = set()
    for name, e in reg.items():
        assert e.name == name and e.kind in models.KINDS
        assert e.url.startswith("https://") and e.filename.endswith(".onnx")
        assert e.licence and e.source
        presets = {"normals": NORMAL_PRESETS, "depth": DEPTH_PRESETS}.get(e.kind, SAM_PRESETS)
        assert e.preset in presets
        if e.kind.startswith("sam-"):
            families.add(name.rsplit("-", 1)[0])
    for fam in families:
        assert f"{fam}-encoder" in reg and f"{fam}-decoder" in reg
    assert len({e.filename for e in reg.values()}) == len(reg)
    with pytest.raises(KeyError, match="known models"):
        models.get_entry("nope")
    with pytest.raises(ValueError):
        ModelEntry("x", "weights", "https://a/b.onnx", None, None, "MIT", "p")


def test_fetch_verified_file_url(tmp_path, cache):
    src, sha = make_file(tmp_path)
    reg = {"toy": entry(src.as_uri(), sha, src.stat().st_size)}
    path, present = models.model_path("toy", reg)
    assert path == cache / "toy.onnx" and not present
    out = models.fetch_model("toy", registry=reg, progress=False)
    assert out == path and out.read_bytes() == src.read_bytes()
    assert models.model_path("toy", reg)[1]
    # present: no download (the source may change or vanish)
    src.write_bytes(b"changed")
    assert models.fetch_model("toy", registry=reg, progress=False).read_bytes() != b"changed"
    assert [p.name for p in cache.iterdir()] == ["toy.onnx"]  # no temp leftovers
    listing = models.list_models(reg)
    assert listing[0][0].name == "toy" and listing[0][2]


def test_fetch_sha_mismatch_rejected(tmp_path, cache):
    src, _ = make_file(tmp_path)
    reg = {"toy": entry(src.as_uri(), "0" * 64)}
    with pytest.raises(ValueError, match="sha256 mismatch.*expected 0{64}"):
        models.fetch_model("toy", registry=reg, progress=False)
    assert not any(cache.iterdir())  # nothing installed, temp file removed
    reg = {"toy": entry(src.as_uri(), hashlib.sha256(src.read_bytes()).hexdigest(), size=3)}
    with pytest.raises(ValueError, match="expected 3"):
        models.fetch_model("toy", registry=reg, progress=False)
    assert not any(cache.iterdir())


def test_force_redownload(tmp_path, cache):
    src, sha = make_file(tmp_path)
    reg = {"toy": entry(src.as_uri(), sha)}
    models.fetch_model("toy", registry=reg, progress=False)
    (cache / "toy.onnx").write_bytes(b"corrupt")
    models.fetch_model("toy", registry=reg, progress=False, force=True)
    assert (cache / "toy.onnx").read_bytes() == src.read_bytes()


def test_unverified_needs_opt_in(tmp_path, cache):
    src, sha = make_file(tmp_path)
    reg = {"toy": entry(src.as_uri(), None)}
    with pytest.raises(ValueError, match="allow_unverified"):
        models.fetch_model("toy", registry=reg, progress=False)
    out = models.fetch_model("toy", registry=reg, progress=False, allow_unverified=True)
    assert out.read_bytes() == src.read_bytes()
    assert (cache / "toy.onnx.sha256").read_text().split()[0] == sha


def test_offline_message(tmp_path, cache):
    reg = {"toy": entry((tmp_path / "absent.onnx").as_uri(), "a" * 64),
           "net": entry("http://127.0.0.1:9/model.onnx", "a" * 64, filename="net.onnx")}
    for name, fname in (("toy", "toy.onnx"), ("net", "net.onnx")):
        with pytest.raises(ModelDownloadError) as exc:
            models.fetch_model(name, registry=reg, progress=False, timeout=5)
        msg = str(exc.value)
        assert "no network / could not download" in msg
        assert str(cache / fname) in msg and "manually" in msg and "a" * 64 in msg
    assert not any(p.suffix == ".part" for p in cache.iterdir())


def test_register_local_and_resolve(tmp_path, cache):
    src, sha = make_file(tmp_path)
    reg = {"toy": entry("https://example.invalid/toy.onnx", sha)}
    with pytest.raises(FileNotFoundError, match="spgeo models fetch toy"):
        models.resolve_model("toy", reg)
    assert models.register_local("toy", src, registry=reg) == cache / "toy.onnx"
    assert models.resolve_model("toy", reg) == (cache / "toy.onnx", reg["toy"])
    assert models.resolve_model(src, reg) == (src, None)  # any local file works
    with pytest.raises(FileNotFoundError, match="nope.onnx"):
        models.resolve_model(tmp_path / "nope.onnx", reg)
    bad = {"toy": entry("https://example.invalid/toy.onnx", "1" * 64)}
    with pytest.raises(ValueError, match="sha256 mismatch"):
        models.register_local("toy", src, registry=bad)


def _parser():
    parser = argparse.ArgumentParser(prog="spgeo")
    sub = parser.add_subparsers(dest="command")
    add_cli(sub)
    return parser


def test_cli_list_and_path(cache, capsys):
    parser = _parser()
    args = parser.parse_args(["models", "list"])
    assert args.func(args) == 0
    out = capsys.readouterr().out
    assert str(cache) in out and "sam-vit-h-encoder" in out and "efficientsam-vitt-decoder" in out

    args = parser.parse_args(["models", "path", "efficientsam-vitt-encoder"])
    assert args.func(args) == 3       # finished, flagged: not in the cache
    assert "(missing)" in capsys.readouterr().out
    cache.mkdir(parents=True)
    (cache / "efficient_sam_vitt_encoder.onnx").write_bytes(b"x")
    assert args.func(args) == 0
    assert capsys.readouterr().out.strip() == str(cache / "efficient_sam_vitt_encoder.onnx")

    args = parser.parse_args(["models", "path", "nope"])
    assert args.func(args) == 2 and "unknown model" in capsys.readouterr().err


def test_cli_fetch_arguments(cache, capsys):
    parser = _parser()
    args = parser.parse_args(["models", "fetch", "metric3d-vit-small", "--force",
                              "--no-progress"])
    assert args.force and not args.allow_unverified and args.name == "metric3d-vit-small"
    assert args.func(args) == 2  # no published sha256 and no --allow-unverified: no download
    assert "--allow-unverified" in capsys.readouterr().err
    args = parser.parse_args(["models", "fetch", "x", "--allow-unverified"])
    assert args.allow_unverified
    with pytest.raises(SystemExit):
        parser.parse_args(["models"])


def test_factories_from_cache_and_paths(tmp_path, cache):
    d = tmp_path / "m"
    d.mkdir()
    enc = B.efficientsam_encoder(d / "e.onnx")
    dec = B.efficientsam_decoder(d / "d.onnx")
    reg = {
        "toy-encoder": ModelEntry("toy-encoder", "sam-encoder", "https://x.invalid/e.onnx",
                                  models.sha256_file(enc), None, "MIT", "efficientsam",
                                  filename="toy_enc.onnx"),
        "toy-decoder": ModelEntry("toy-decoder", "sam-decoder", "https://x.invalid/d.onnx",
                                  models.sha256_file(dec), None, "MIT", "efficientsam",
                                  filename="toy_dec.onnx"),
    }
    models.register_local("toy-encoder", enc, registry=reg)
    models.register_local("toy-decoder", dec, registry=reg)
    model = from_cache.sam_model_from_cache("toy", registry=reg, prompt_batch_size=4)
    assert isinstance(model, SegmentModel) and model.config.flavour == "efficientsam"
    assert model.max_prompts_per_call == 4
    gen = from_cache.sam_frontend_from_cache(
        "toy", registry=reg, generator_config=SamMaskGeneratorConfig(num_prompts=10,
                                                                     num_active_prompts=5))
    assert isinstance(gen, Segmenter)
    cam = PinholeCamera(50, 50, 39.5, 29.5, 80, 60)
    seg = gen.segment(np.random.default_rng(0).uniform(0, 1, (60, 80, 3)).astype(np.float32), cam)
    assert seg.meta["queries"] == 15
    # explicit paths (no registry entry): preset must be given or defaults to sam-official
    with pytest.raises(ValueError, match="point_coords"):
        from_cache.sam_model_from_cache(None, encoder=enc, decoder=dec, registry=reg)
    assert from_cache.sam_model_from_cache(None, encoder=enc, decoder=dec, preset="efficientsam",
                                           registry=reg).config.flavour == "efficientsam"
    nfile = B.normal_model(d / "n.onnx", input_size=(480, 640))
    nmodel = from_cache.normal_model_from_cache(nfile)
    assert isinstance(nmodel, NormalModel) and nmodel.config.input_size == (480, 640)
    with pytest.raises(FileNotFoundError, match="spgeo models fetch"):
        from_cache.normal_model_from_cache("metric3d-vit-small-fp16")
