"""Model cache: directory, registry, verified download (file:// URLs, offline), CLI, factories;
user models (register_model, registry.json, `spgeo models register`)."""
from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

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


# ------------------------------------------------------------------ user models
def test_register_model_and_resolve(tmp_path, cache):
    src, sha = make_file(tmp_path, "mine.onnx")
    entry_ = models.register_model("my-depth", src, kind="depth", preset="fastdepth",
                                   licence="MIT", notes="test")
    assert entry_.local_path == str(src.resolve()) and entry_.sha256 == sha
    assert entry_.size == src.stat().st_size and entry_.preset == "fastdepth"
    assert models.get_entry("my-depth") == entry_
    assert models.resolve_model("my-depth") == (src.resolve(), entry_)
    assert models.model_path("my-depth") == (src.resolve(), True)
    assert models.fetch_model("my-depth", progress=False) == src.resolve()  # nothing to fetch
    listed = {e.name: (p, present) for e, p, present in models.list_models()}
    assert listed["my-depth"] == (src.resolve(), True) and "sam-vit-h-encoder" in listed
    assert [p.name for p in cache.iterdir()] == [models.USER_REGISTRY_FILE]
    # defaults by kind; registering a user name again replaces it
    assert models.register_model("my-n", src, kind="normals").preset == "generic-480x640"
    assert models.register_model("my-depth", src).preset == "generic-depth-518"
    assert "generic-480x640" in NORMAL_PRESETS and "generic-depth-518" in DEPTH_PRESETS
    assert sorted(models.user_models()) == ["my-depth", "my-n"]
    # an explicit registry= mapping is used alone
    assert "my-depth" not in {e.name for e, _, _ in models.list_models(models.REGISTRY)}
    with pytest.raises(ValueError, match="is a user model"):
        models.register_local("my-depth", src)


def test_register_model_refusals(tmp_path, cache):
    src, sha = make_file(tmp_path, "mine.onnx")
    with pytest.raises(ValueError, match="'efficientsam-vitt-encoder' is a built-in"):
        models.register_model("efficientsam-vitt-encoder", src)
    for bad in ("", "a/b", "-x", "two words"):
        with pytest.raises(ValueError, match="bad model name"):
            models.register_model(bad, src)
    with pytest.raises(ValueError, match="kind must be one of"):
        models.register_model("m", src, kind="sam-encoder")
    with pytest.raises(FileNotFoundError, match="nope.onnx"):
        models.register_model("m", tmp_path / "nope.onnx")
    assert not cache.exists()  # nothing written
    models.register_model("m", src)
    src.write_bytes(b"changed weights")
    new_sha = hashlib.sha256(b"changed weights").hexdigest()
    for call in (lambda: models.resolve_model("m"),
                 lambda: from_cache.metric_depth_from_cache("m"),
                 lambda: models.fetch_model("m", progress=False)):
        with pytest.raises(ValueError) as exc:
            call()
        msg = str(exc.value)
        assert str(src.resolve()) in msg and sha in msg and new_sha in msg
    src.unlink()
    with pytest.raises(FileNotFoundError, match="mine.onnx"):
        models.resolve_model("m")
    (cache / models.USER_REGISTRY_FILE).write_text("{not json")
    with pytest.raises(ValueError, match="registry.json.*not a readable"):
        models.get_entry("m")


def test_user_registry_written_atomically(tmp_path, cache, monkeypatch):
    src, _ = make_file(tmp_path, "mine.onnx")
    models.register_model("a", src)
    where = cache / models.USER_REGISTRY_FILE
    before = where.read_text()
    data = json.loads(before)
    assert data["models"]["a"]["sha256"] == models.sha256_file(src)
    calls = []

    def failing_replace(tmp, dest):
        calls.append((tmp, dest))
        raise OSError("disk full")

    monkeypatch.setattr(models.os, "replace", failing_replace)
    with pytest.raises(OSError, match="disk full"):
        models.register_model("b", src)
    (tmp, dest), = calls
    assert dest == where and Path(tmp).parent == cache
    assert where.read_text() == before  # the old registry is intact, the temp file removed
    assert [p.name for p in cache.iterdir()] == [models.USER_REGISTRY_FILE]


def test_cli_register(tmp_path, cache, capsys):
    src, sha = make_file(tmp_path, "mine.onnx")
    parser = _parser()
    args = parser.parse_args(["models", "register", "fd", str(src), "--preset", "fastdepth"])
    assert args.func(args) == 0
    out = capsys.readouterr().out
    assert "fd" in out and sha in out and "fastdepth" in out
    args = parser.parse_args(["models", "list"])
    assert args.func(args) == 0
    line = [s for s in capsys.readouterr().out.splitlines() if s.startswith("* fd ")]
    assert len(line) == 1 and "user:" in line[0] and str(src.resolve()) in line[0]
    args = parser.parse_args(["models", "path", "fd"])
    assert args.func(args) == 0 and capsys.readouterr().out.strip() == str(src.resolve())
    for argv, err in [(["sam-vit-b-encoder", str(src)], "built-in"),
                      (["x", str(src), "--preset", "nope"], "unknown depth preset 'nope'"),
                      (["x", str(src), "--kind", "normals", "--preset", "fastdepth"],
                       "unknown normals preset"),
                      (["x", str(tmp_path / "nope.onnx")], "nope.onnx")]:
        args = parser.parse_args(["models", "register", *argv])
        assert args.func(args) == 2
        captured = capsys.readouterr()
        assert err in captured.err and captured.err.count("\n") == 1 and not captured.out
    with pytest.raises(SystemExit):
        parser.parse_args(["models", "register", "x", str(src), "--kind", "sam-encoder"])
    src.write_bytes(b"other")
    args = parser.parse_args(["models", "fetch", "fd"])
    assert args.func(args) == 2 and "sha256 mismatch" in capsys.readouterr().err
    (cache / models.USER_REGISTRY_FILE).write_text("[]")
    args = parser.parse_args(["models", "list"])
    assert args.func(args) == 2 and "registry.json" in capsys.readouterr().err
