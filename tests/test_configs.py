"""`spgeo.configs` (`--set` / `--config` overrides, the changed-fields repr) and `spgeo eval` dispatch."""
import importlib.util
import json
import re
from dataclasses import dataclass, field
from typing import Optional, Tuple

import pytest

from spgeo.cli import build_parser, main
from spgeo.configs import (ConfigError, apply_overrides, config_class, config_to_dict,
                           load_config_file, parse_assignments, parse_value, resolve_config)
from spgeo.odometry import OdometryConfig


@dataclass(frozen=True)
class Inner:
    tol: float = 1e-3
    iters: int = 10


@dataclass(frozen=True)
class Outer:
    name: str = "a"
    size: Tuple[int, int] = (1, 2)
    flag: bool = False
    sigma: Optional[float] = None
    inner: Inner = field(default_factory=Inner)


def test_parse_value_literals_else_strings():
    assert parse_value("1e-4") == 1e-4 and parse_value(" 7 ") == 7
    assert parse_value("None") is None and parse_value("True") is True
    # TOML's booleans too (issue 42: --set landmarks.enabled=true was refused)
    assert parse_value("true") is True and parse_value(" FALSE ") is False
    assert parse_value("'true'") == "true"
    assert parse_value("(1, 2)") == (1, 2) and parse_value("'x'") == "x"
    assert parse_value("classical") == "classical" and parse_value("a b") == "a b"
    assert parse_assignments(["a=1", "b.c = x", "a=2"]) == {"a": 2, "b.c": "x"}
    for bad in ("a", "=1", "a..b=1"):
        with pytest.raises(ConfigError):
            parse_assignments([bad])


def test_apply_overrides_nested_and_types():
    cfg = apply_overrides(Outer(), ["inner.tol=1e-4", "name=b", "size=[3, 4]", "sigma=0.5",
                                    "inner.iters=3"])
    assert cfg == Outer(name="b", size=(3, 4), sigma=0.5, inner=Inner(1e-4, 3))
    assert Outer() == Outer()        # the input is not modified (frozen copies)
    assert apply_overrides(Outer(), ["inner.tol=1"]).inner.tol == 1.0    # int -> float field
    assert apply_overrides(Outer(), {"inner": {"iters": 5}}).inner.iters == 5
    assert apply_overrides(Outer(), {"inner.iters": 6}).inner.iters == 6
    for bad in (["inner.iters=1.5"], ["flag=1"], ["name=3"], ["size=7"], ["name=None"],
                ["inner=3"], ["name.x=1"]):
        with pytest.raises(ConfigError):
            apply_overrides(Outer(), bad)


def test_unknown_field_names_it_and_lists_valid_fields():
    with pytest.raises(ConfigError) as exc:
        apply_overrides(Outer(), ["inner.bogus=1"])
    msg = str(exc.value)
    assert "'inner.bogus'" in msg and "inner.tol" in msg and "inner.iters" in msg
    with pytest.raises(ConfigError, match="valid fields: name, size, flag, sigma, inner"):
        apply_overrides(Outer(), ["nope=1"])


def test_route_to_nested_config():
    from spgeo.apps.vo_run import VORunConfig

    cfg = apply_overrides(VORunConfig(), ["tracker.relative_cost_tol=1e-4", "window=7",
                                          "frontend=depth"], route="odometry")
    assert cfg.frontend == "depth" and cfg.odometry.window == 7
    assert cfg.odometry.tracker.relative_cost_tol == 1e-4
    assert cfg.odometry == apply_overrides(OdometryConfig(), ["window=7",
                                                             "tracker.relative_cost_tol=1e-4"])
    with pytest.raises(ConfigError, match="'windw'"):
        apply_overrides(VORunConfig(), ["windw=7"], route="odometry")
    with pytest.raises(ConfigError, match="resolution"):        # the config's own check
        apply_overrides(VORunConfig(), ["resolution=(0, 120)"], route="odometry")


def test_toml_config_file_and_set_overrides_it(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text('name = "t"\nsize = [5, 6]\n[inner]\ntol = 0.25\niters = 4\n')
    assert load_config_file(path) == {"name": "t", "size": [5, 6],
                                      "inner": {"tol": 0.25, "iters": 4}}
    cfg = resolve_config(Outer(), str(path), ["inner.iters=9"])
    assert cfg == Outer(name="t", size=(5, 6), inner=Inner(0.25, 9))
    assert config_to_dict(cfg) == {"name": "t", "size": [5, 6], "flag": False, "sigma": None,
                                   "inner": {"tol": 0.25, "iters": 9}}
    (tmp_path / "bad.toml").write_text("name = \n")
    for bad in (tmp_path / "bad.toml", tmp_path / "missing.toml", tmp_path / "c.ini"):
        with pytest.raises(ConfigError):
            load_config_file(bad)


def test_yaml_config_file(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("inner:\n  iters: 2\n")
    if importlib.util.find_spec("yaml") is None:
        with pytest.raises(ConfigError, match="PyYAML"):
            load_config_file(path)
    else:
        assert resolve_config(Outer(), str(path)).inner.iters == 2


@pytest.mark.parametrize("argv, text", [
    (["demo", "--set", "bogus=1"], "unknown field 'bogus' of DemoConfig"),
    (["demo", "--set", "vo_frames"], "FIELD=VALUE"),
    (["demo", "--config", "missing.toml"], "config file not found"),
    (["vo", "--dataset", "tum", "x", "--out", "o", "--set", "window=abc"],
     "'odometry.window' expects an integer"),
    (["sfm", "--ref", "a", "--views", "b", "--intrinsics", "1,1,1,1", "--out", "o",
      "--set", "levls=2"], "unknown field 'levls' of SfMConfig"),
    (["complete", "--rgb", "a", "--sparse", "b", "--intrinsics", "1,1,1,1", "--out", "o.png",
      "--set", "method=3"], "'method' expects a string"),
])
def test_cli_config_errors_exit_2(tmp_path, monkeypatch, capsys, argv, text):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"spgeo {argv[0]}: error:") and text in err[0]


def test_demo_effective_config(tmp_path, monkeypatch):
    """Options < --set; --config < explicit options (checked on the parsed config only)."""
    from spgeo.cli.demo import _demo_config

    path = tmp_path / "demo.toml"
    path.write_text('synthetic_seed = 3\nvo_frontends = ["classical"]\nout_dir = "x"\n')
    args = build_parser().parse_args(["demo", "--config", str(path), "--out", "y", "--no-vo",
                                      "--set", "vo_frames=10"])
    cfg = _demo_config(args)
    assert (cfg.synthetic_seed, cfg.vo_frontends, cfg.out_dir, cfg.vo, cfg.vo_frames) == \
        (3, ("classical",), "y", False, 10)
    args = build_parser().parse_args(["demo", "--seed", "2", "--set", "synthetic_seed=5"])
    assert _demo_config(args).synthetic_seed == 5
    assert json.dumps(config_to_dict(cfg))


def test_eval_help_lists_protocols(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["eval", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for name in ("colmap", "colmap_vo", "feature_vo", "vo_compare", "tum_fr1", "vo_synthetic",
                 "sfm_real", "completion_7scenes", "void", "scannet", "bench_vo"):
        assert f"\n    {name}" in out
    assert "metrics" not in out.split("PROTOCOL", 2)[-1].split("options")[0].split()


def test_eval_dispatches_argv(monkeypatch):
    import spgeo.evaluation.vo.tum_fr1 as mod

    seen = []
    monkeypatch.setattr(mod, "main", lambda argv: seen.append(argv) or 3)
    assert main(["eval", "tum_fr1", "--frames", "1:2", "-v", "pos"]) == 3
    assert seen == [["--frames", "1:2", "-v", "pos"]]
    assert main(["eval", "tum_fr1", "--help"]) == 3 and seen[-1] == ["--help"]


def test_eval_protocol_help_exits_cleanly(capsys):
    assert main(["eval", "vo_synthetic", "--help"]) == 0
    assert "usage: spgeo eval vo_synthetic" in capsys.readouterr().out


def test_config_repr_shows_only_changed_fields():
    @config_class
    @dataclass(frozen=True)
    class Shown:
        a: int = 1
        b: Tuple[int, int] = (1, 2)
        inner: Inner = field(default_factory=Inner)

    assert repr(Shown()) == "Shown()"
    assert repr(Shown(a=2)) == "Shown(a=2)"
    changed = Shown(inner=Inner(iters=3))
    assert repr(changed) == "Shown(inner=Inner(tol=0.001, iters=3))"
    assert apply_overrides(Shown(), ["b=(3, 4)"]).b == (3, 4)


def test_feature_options_of_feature_retry_and_loop_closure():
    """The VO's feature retry and loop closure hold a FeatureOptions (the feature part
    of TwoViewConfig), with their own counts; ``--set`` reaches its fields."""
    from spgeo.twoview import FeatureOptions, TwoViewConfig

    cfg = OdometryConfig()
    assert cfg.feature_retry.features == FeatureOptions(max_features=1500)
    assert cfg.loop_closure.recognition.features == FeatureOptions(max_features=1000)
    assert TwoViewConfig(features="orb", ratio=0.7).feature_options == FeatureOptions(
        features="orb", ratio=0.7)
    cfg = apply_overrides(cfg, ["feature_retry.features.max_features=900",
                                "loop_closure.recognition.features.features=orb"])
    assert cfg.feature_retry.features.max_features == 900
    assert cfg.loop_closure.recognition.features.features == "orb"
    with pytest.raises(ConfigError, match="backend"):          # a TwoViewConfig field
        apply_overrides(cfg, ["feature_retry.features.backend=pycolmap"])
    for bad in ({"features": "surf"}, {"max_features": 4}, {"ratio": 1.5}):
        with pytest.raises(ValueError, match="FeatureOptions"):
            FeatureOptions(**bad)


def test_set_accepts_toml_booleans_as_the_cli_does():
    """``--set landmarks.enabled=true`` (issue 42) sets the nested bool, as TOML's
    ``enabled = true`` does; a bool field still refuses a string."""
    from spgeo.vo import OdometryConfig

    cfg = apply_overrides(OdometryConfig(), ["landmarks.enabled=false",
                                             "loop_closure.enabled=TRUE"])
    assert cfg.landmarks.enabled is False and cfg.loop_closure.enabled is True
    with pytest.raises(ConfigError, match="True or False"):
        apply_overrides(OdometryConfig(), ["landmarks.enabled=yes"])


@pytest.mark.parametrize("make", ["vo", "sfm", "complete", "demo"])
def test_dump_config_reads_back_equal(make, tmp_path, capsys):
    """`spgeo CMD --dump-config FILE` writes TOML that --config and resolve_config read
    back to the defaults (None fields are comments), with no other argument given."""
    from spgeo.apps.demo import DemoConfig
    from spgeo.apps.vo_run import VORunConfig
    from spgeo.completion import CompletionConfig
    from spgeo.sfm import SfMConfig

    cls = {"vo": VORunConfig, "sfm": SfMConfig, "complete": CompletionConfig,
           "demo": DemoConfig}[make]
    path = tmp_path / "defaults.toml"
    with pytest.raises(SystemExit) as exit_:
        main([make, "--dump-config", str(path)])
    assert exit_.value.code == 0 and str(path) in capsys.readouterr().out
    assert resolve_config(cls(), path) == cls()
    with pytest.raises(SystemExit):
        main([make, "--dump-config"])
    assert capsys.readouterr().out == path.read_text()


@pytest.mark.parametrize("make", ["vo", "sfm", "complete", "demo"])
def test_dump_config_says_what_every_field_means(make, capsys):
    """Every field of every dumped config has a meaning in its class's docstring
    (``Attributes:``), and the dump writes it as a comment right above the field
    or table (a new field without one fails here)."""
    from spgeo.apps.demo import DemoConfig
    from spgeo.apps.vo_run import VORunConfig
    from spgeo.completion import CompletionConfig
    from spgeo.config_docs import missing_meanings
    from spgeo.sfm import SfMConfig

    cls = {"vo": VORunConfig, "sfm": SfMConfig, "complete": CompletionConfig,
           "demo": DemoConfig}[make]
    assert missing_meanings(cls()) == []
    with pytest.raises(SystemExit):
        main([make, "--dump-config"])
    lines = capsys.readouterr().out.splitlines()
    value = re.compile(r"^(# )?[A-Za-z_]\w* = |^\[[\w.]+\]$")
    fields = [i for i, line in enumerate(lines) if value.match(line)
              and not line.startswith("# ") or "(TOML cannot write it" in line]
    assert len(fields) > 3
    for i in fields:
        above = lines[i - 1]
        assert above.startswith("# ") and not value.match(above), (lines[i], above)
        assert len(above) <= 88
    if make == "vo":
        text = "\n".join(lines)
        assert "# keyframes kept in the smoother (default 5, >= 2)\nwindow = 5" in text
        assert ("# the rotation from the latest keyframe exceeds this (degrees, > 0; default 15)."
                "\nmax_rotation_deg = 15.0") in text


def test_field_meanings_from_the_attributes_section():
    """The docstring parser behind the dump: entries, shared entries (``a, b:``),
    continuation lines, a base class's entries, the first clause, plain markup."""
    from spgeo.config_docs import field_meanings, short_meaning

    @dataclass
    class Base:
        """Base.

        Attributes:
            size: ``(w, h)`` in pixels (e.g. 4.5 or
                :class:`~spgeo.camera.PinholeCamera`); default None.  More.
        """

        size: Optional[Tuple[int, int]] = None

    @dataclass
    class Child(Base):
        """Child.

        Attributes:
            lo, hi: bounds in metres.
            ratio: ... of the first one.  Then more.

        Raises nothing.
        """

        lo: float = 0.0
        hi: float = 1.0
        ratio: float = 0.5

    meanings = field_meanings(Child)
    assert sorted(meanings) == ["hi", "lo", "ratio", "size"]
    assert meanings["lo"] == meanings["hi"] == "bounds in metres."
    assert short_meaning(meanings["size"]) == "(w, h) in pixels (e.g. 4.5 or PinholeCamera)"
    assert short_meaning(meanings["ratio"]) == "... of the first one."


def test_config_round_trip_dump_edit_load_cli_and_python(tmp_path):
    """One file for both: the vo dump, edited, sets the same odometry from the
    command line (`_run_config`) and from Python (VORunConfig and OdometryConfig)."""
    from spgeo.apps.vo_run import VORunConfig
    from spgeo.cli.vo import _run_config

    path = tmp_path / "vo.toml"
    with pytest.raises(SystemExit):
        main(["vo", "--dump-config", str(path)])
    text = path.read_text().replace("\nwindow = 5\n", "\nwindow = 7\n")
    text = text.replace("\nprogress = true\n", "\nprogress = false\n")
    head, sep, tail = text.partition("[odometry.landmarks]\n")
    path.write_text(head + sep + tail.replace("\nenabled = true", "\nenabled = false", 1))
    args = build_parser().parse_args(["vo", "--dataset", "tum", "x", "--out", "y",
                                      "--config", str(path)])
    cli = _run_config(args)
    assert (cli.odometry.window, cli.progress, cli.odometry.landmarks.enabled) == (7, False, False)
    assert resolve_config(VORunConfig(), path) == cli
    assert resolve_config(OdometryConfig(), path) == cli.odometry   # its [odometry] table
    flat = tmp_path / "flat.toml"      # no tables: run fields and odometry fields side by side
    flat.write_text("progress = false\nwindow = 7\n")
    assert resolve_config(VORunConfig(), flat).odometry.window == 7
    assert resolve_config(OdometryConfig(), flat.parent / "vo.toml").window == 7


def test_wrong_type_at_construction_names_field_and_type():
    from spgeo.configs import ConfigTypeError
    from spgeo.vo import TrackerConfig

    with pytest.raises(ConfigTypeError, match=r"OdometryConfig\.window expects an integer, "
                                              r"got '7' \(str\)"):
        OdometryConfig(window="7")
    with pytest.raises(TypeError, match=r"OdometryConfig\.tracker expects a TrackerConfig"):
        OdometryConfig(tracker={"max_iterations": 3})
    with pytest.raises(TypeError, match=r"OdometryConfig\.resolution expects a tuple or None"):
        OdometryConfig(resolution="320x240")
    import numpy as np

    assert OdometryConfig(window=np.int64(7), resolution=(320, 240)).window == 7
    assert TrackerConfig() == TrackerConfig(**{})      # defaults satisfy their own types
