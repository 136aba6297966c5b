"""The central range check of every numeric setting (config.RANGES, config.LIST_CHECKS: views of the rules on
the fields; check_config)."""

import copy
import dataclasses
import math
import re
import types
import typing
from pathlib import Path

import pytest

from ogscene3d.cli import main
from ogscene3d.config import LIST_CHECKS, RANGES, Config, check_config, load_config
from ogscene3d.errors import ConfigError

CONFIGS = sorted((Path(__file__).resolve().parents[1] / "configs").glob("*.yaml"))


def _fields(cls=Config, prefix=""):
    """(dotted key, type) of every leaf field of the Config dataclasses."""
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        if isinstance(tp, type) and dataclasses.is_dataclass(tp):
            yield from _fields(tp, f"{prefix}{f.name}.")
        else:
            yield prefix + f.name, tp


def _split_optional(tp):
    """(the type without None, whether None is allowed)."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1 and len(args) < len(typing.get_args(tp)):
            return args[0], True
    return tp, False


def _with(key, value):
    cfg = Config()
    node = cfg
    *path, name = key.split(".")
    for part in path:
        node = getattr(node, part)
    setattr(node, name, value)
    return cfg


def _default(key):
    node = Config()
    for part in key.split("."):
        node = getattr(node, part)
    return node


def _outside(key):
    """Values just outside the range of ``key`` (one per finite bound)."""
    rng = RANGES[key]
    out = []
    if rng.lo is not None:
        if rng.lo_open:
            out.append(int(rng.lo) if rng.integer else float(rng.lo))
        else:
            out.append(int(rng.lo) - 1 if rng.integer else math.nextafter(rng.lo, -math.inf))
    if rng.hi is not None:
        if rng.hi_open:
            out.append(int(rng.hi) if rng.integer else float(rng.hi))
        else:
            out.append(int(rng.hi) + 1 if rng.integer else math.nextafter(rng.hi, math.inf))
    return out


def _numeric_list(tp) -> bool:
    return typing.get_origin(tp) is list and typing.get_args(tp)[0] in (int, float)


def _members(tp) -> tuple:
    """The members of a union type; ``(tp,)`` for any other."""
    return typing.get_args(tp) if typing.get_origin(tp) in (typing.Union, types.UnionType) else (tp,)


def test_every_numeric_setting_has_a_range():
    numeric, lists = {}, set()
    for key, tp in _fields():
        base, optional = _split_optional(tp)
        if base in (int, float):
            numeric[key] = (base, optional)
        elif any(_numeric_list(t) for t in _members(base)):
            lists.add(key)  # a numeric list, or a choice or one (graph.up_axis: auto or a 3-vector)
    missing = sorted(set(numeric) - set(RANGES))
    assert not missing, f"numeric settings without an entry in config.RANGES: {missing}"
    stale = sorted(set(RANGES) - set(numeric))
    assert not stale, f"config.RANGES entries for no numeric setting: {stale}"
    for key, (base, optional) in numeric.items():
        assert RANGES[key].integer == (base is int), key
        assert RANGES[key].optional == optional, key
    assert lists == set(LIST_CHECKS), "numeric list settings and the check= on fields differ"
    assert len(RANGES) >= 120


def test_defaults_and_shipped_configs_pass():
    check_config(Config())
    for key in RANGES:
        assert RANGES[key].contains(_default(key)), key
    assert CONFIGS
    for path in CONFIGS:
        load_config(path)


@pytest.mark.parametrize("key", sorted(RANGES))
def test_each_bound_is_enforced(key):
    rng = RANGES[key]
    values = _outside(key)
    assert values or not rng.integer, f"{key}: an integer setting without bounds"
    for value in values:
        with pytest.raises(ConfigError, match=rf"^{re.escape(key)} must be .*, got "):
            check_config(_with(key, value))
    # a closed bound itself is allowed
    for bound, is_open in ((rng.lo, rng.lo_open), (rng.hi, rng.hi_open)):
        if bound is not None and not is_open:
            assert rng.contains(int(bound) if rng.integer else float(bound)), key
    if rng.integer:
        with pytest.raises(ConfigError, match=key):
            check_config(_with(key, _default(key) + 0.5 if _default(key) is not None else 1.5))
    else:
        for bad in (math.nan, math.inf, -math.inf):
            with pytest.raises(ConfigError, match=key):
                check_config(_with(key, bad))
    with pytest.raises(ConfigError, match=key):
        check_config(_with(key, True))  # a bool is no number
    if rng.optional:
        check_config(_with(key, None))
    else:
        with pytest.raises(ConfigError, match=key):
            check_config(_with(key, None))


def test_messages_name_key_value_and_range():
    with pytest.raises(ConfigError, match=r"^mapping\.refine\.tau_high must be in \[0, 1\], got 2\.0$"):
        check_config(_with("mapping.refine.tau_high", 2.0))
    with pytest.raises(ConfigError, match=r"mapping\.refine\.tau_high must be in \[0, 1\], got nan"):
        load_config(None, ["mapping.refine.tau_high=.nan"])
    with pytest.raises(ConfigError, match=r"mapping\.optimize\.iters must be an integer >= 0 .*got -3"):
        load_config(None, ["mapping.optimize.iters=-3"])
    with pytest.raises(ConfigError, match=r"mapping\.init\.opacity must be in \(0, 1\)"):
        load_config(None, ["mapping.init.opacity=1"])
    # 0 = off / no limit stays allowed
    zeros = ["mapping.checkpoint_every", "data.max_depth", "tracking.max_width", "mapping.max_pose_step",
             "mapping.optimize.iters", "mapping.refine.every", "mapping.optimize.memory_frames"]  # fmt: skip
    load_config(None, [f"{key}=0" for key in zeros])


@pytest.mark.parametrize(
    "key, bad",
    [
        ("data.intrinsics", [500.0, 500.0, 320.0]),
        ("data.intrinsics", [0.0, 500.0, 320.0, 240.0]),
        ("data.intrinsics", [500.0, math.nan, 320.0, 240.0]),
        ("data.intrinsics", [500.0, 500.0, math.inf, 240.0]),
        ("segmentation.sam_score_range", [0.9, 0.8]),
        ("segmentation.sam_score_range", [0.5, math.nan]),
        ("segmentation.sam_score_range", [0.5]),
        ("segmentation.conf_range", [0.5, 1.5]),
        ("segmentation.conf_range", [math.nan, 1.0]),
        ("graph.up_axis", [0.0, 0.0, 0.0]),
        ("graph.up_axis", [0.0, math.inf, 0.0]),
        ("graph.up_axis", [0.0, 1.0]),
        ("graph.up_axis", "up"),
        ("tracking.iterations", []),
        ("tracking.iterations", [20, 0, 5]),
        ("tracking.iterations", [20, 2.5]),
    ],
)
def test_list_settings(key, bad):
    with pytest.raises(ConfigError, match=rf"^{re.escape(key)} .*got "):
        check_config(_with(key, bad))


def test_list_settings_pass_when_sensible():
    check_config(_with("data.intrinsics", [500.0, 480.0, 320.0, 240.0]))
    check_config(_with("data.intrinsics", None))
    check_config(_with("segmentation.conf_range", [1.0, 0.5]))
    check_config(_with("graph.up_axis", [0.0, 0.0, 2.0]))
    check_config(_with("graph.up_axis", "auto"))
    check_config(_with("tracking.iterations", [7]))


def test_cross_field_rules():
    with pytest.raises(ConfigError, match=r"mapping\.refine\.tau_low must be <= mapping\.refine\.tau_high"):
        load_config(None, ["mapping.refine.tau_low=0.8"])
    load_config(None, ["mapping.refine.tau_low=0.7"])
    with pytest.raises(ConfigError, match="no frame would become a keyframe"):
        load_config(None, ["mapping.keyframe_every=0"])
    load_config(None, ["mapping.keyframe_every=0", "mapping.keyframe_rotation_deg=5"])
    with pytest.raises(ConfigError, match=r"data\.min_depth must be < data\.max_depth"):
        load_config(None, ["data.min_depth=3", "data.max_depth=2"])
    load_config(None, ["data.min_depth=3"])  # max_depth 0: no limit
    with pytest.raises(ConfigError, match=r"tracking\.depth_min must be < tracking\.depth_max"):
        load_config(None, ["tracking.depth_min=5"])


def test_mapper_checks_a_config_built_in_python():
    from ogscene3d.mapping.mapper import Mapper

    cfg = Config()
    cfg.graph.enabled = False
    bad = copy.deepcopy(cfg)
    bad.mapping.refine.tau_high = 2.0
    with pytest.raises(ConfigError, match=r"mapping\.refine\.tau_high must be in \[0, 1\], got 2\.0"):
        Mapper(bad, "cpu")
    bad = copy.deepcopy(cfg)
    bad.mapping.association.knn_radius = 0.0
    match = r"mapping\.association\.knn_radius must be a finite number > 0, got 0\.0"
    with pytest.raises(ConfigError, match=match):
        Mapper(bad, "cpu")
    Mapper(cfg, "cpu")


def test_cli_refuses_an_out_of_range_override_before_any_work(tmp_path, capsys):
    out = tmp_path / "o"
    code = main(["run", "--out", str(out), "--no-progress", "--set", "mapping.optimize.iters=-3"])
    assert code == 2
    err = capsys.readouterr().err
    assert "mapping.optimize.iters must be an integer >= 0" in err and "got -3" in err
    assert not out.exists()


def test_a_config_file_that_is_not_utf8_is_one_clear_line(tmp_path, capsys):
    bad = tmp_path / "latin1.yaml"
    bad.write_bytes("mapping:\n  opt_iters: 5  # r\xe9glage\n".encode("latin-1"))
    with pytest.raises(ConfigError, match=rf"config file '{re.escape(str(bad))}' is not UTF-8 text"):
        load_config(bad)
    # before: a UnicodeDecodeError traceback and exit 1
    out = tmp_path / "o"
    assert main(["run", "--config", str(bad), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "latin1.yaml" in err[0] and "not UTF-8" in err[0], err
    assert not out.exists()


def test_every_setting_and_section_has_a_doc():
    from ogscene3d.config import sections, settings

    undocumented = [s.key for s in settings() if len(s.doc) < 8]
    assert not undocumented, f"settings without a doc: {undocumented}"
    assert all(doc for _, _, doc in sections())


@pytest.mark.parametrize(
    "key", ["data.kind", "data.on_bad_frame", "segmentation.backend", "mapping.ablation", "tracking.poses",
            "graph.captioner.kind", "graph.query_embedding", "segmentation.execution_provider"],
)  # fmt: skip
def test_choices_come_from_the_literal_and_are_checked(key):
    from ogscene3d.config import choices

    allowed = choices(key)
    assert len(allowed) >= 2 and _default(key) in allowed
    pattern = rf"^{re.escape(key)} must be one of \[.*\], got 'bogus'$"
    with pytest.raises(ConfigError, match=pattern):
        check_config(_with(key, "bogus"))  # a Config built in Python
    with pytest.raises(ConfigError, match=pattern):
        load_config(None, [f"{key}=bogus"])  # a YAML value or --set
    load_config(None, [f"{key}={allowed[-1]}"])


def test_consumers_accept_exactly_the_literal_choices():
    """The choices a consumer checks itself (a section built in Python never passes check_config) are the
    field's Literal: either read from it, or equal to it."""
    from ogscene3d.config import choices
    from ogscene3d.datasets.base import DEPTH_FORMATS
    from ogscene3d.datasets.loader import READERS
    from ogscene3d.mapping.mapper import ABLATIONS
    from ogscene3d.mapping.pose_jump import ACTIONS
    from ogscene3d.segmentation.simulated import NOISE_LEVELS
    from ogscene3d.tracking import METHODS, POSE_SOURCES

    assert ABLATIONS == choices("mapping.ablation")
    assert ACTIONS == choices("mapping.on_pose_jump")
    assert METHODS == choices("tracking.method") and POSE_SOURCES == choices("tracking.poses")
    assert set(READERS) | {"auto"} == set(choices("data.kind"))
    assert set(DEPTH_FORMATS) | {"auto"} == set(choices("data.depth_format"))
    assert set(NOISE_LEVELS) == set(choices("segmentation.simulated_noise"))
    assert set(NOISE_LEVELS) == set(choices("synthetic.noise"))


def test_tracking_validator_is_the_field_rules():
    from ogscene3d.config import TrackingConfig
    from ogscene3d.tracking import validate_tracking_config

    # the same wording as check_config, not a second set of ranges
    with pytest.raises(ConfigError, match=r"^tracking\.min_fitness must be in \[0, 1\], got 1\.5$"):
        validate_tracking_config(TrackingConfig(min_fitness=1.5))
    with pytest.raises(ConfigError, match=r"^tracking\.depth_min must be < tracking\.depth_max"):
        validate_tracking_config(TrackingConfig(depth_min=6.0))


def test_a_retired_key_in_an_older_runs_config_is_dropped_not_refused(tmp_path):
    # graph.*.backoff_s went with the openai client (it has its own backoff); a run's config.yaml written
    # before still holds it, and must still load for --resume and eval
    old = tmp_path / "config.yaml"
    old.write_text("graph:\n  captioner:\n    backoff_s: 1.0\n  relations:\n    backoff_s: 2.0\n")
    cfg = load_config(old)
    assert not hasattr(cfg.graph.captioner, "backoff_s")
    with pytest.raises(ConfigError, match="unknown config key"):
        load_config(None, ["graph.captioner.no_such_key=1"])


def test_the_retired_evidence_rules_of_an_older_run_load_with_a_notice(tmp_path, caplog):
    # the repair rules that mapping.evidence.enabled replaced (issue 39): an older run's config.yaml
    # holds them
    old = tmp_path / "config.yaml"
    old.write_text(
        "mapping:\n  evidence_split: true\n  evidence_partition_apart: 0.25\n  evidence_veto: false\n"
    )
    with caplog.at_level("INFO", logger="ogscene3d.config"):
        cfg = load_config(old)
    assert cfg.mapping.evidence.enabled and not hasattr(cfg.mapping, "evidence_split")
    notes = [r.getMessage() for r in caplog.records if "no longer used" in r.getMessage()]
    assert len(notes) == 3 and all("mapping.evidence, one evidence model" in n for n in notes)
