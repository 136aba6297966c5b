"""Moved config keys (config.MOVED): the endpoint settings that each LLM component of the graph repeated are
one section, ``graph.endpoint``; YAML files and run folders written before still load, with one notice."""

import logging
from pathlib import Path

import pytest

from ogscene3d.config import MOVED, Config, EndpointConfig, load_config, save_config
from ogscene3d.errors import ConfigError
from ogscene3d.graph.scenegraph import SceneGraph

RUN_FOLDER = Path(__file__).parent / "data" / "run_folder_03e44a8" / "run"

OLD_YAML = """
graph:
  captioner: {kind: openai, base_url: http://vlm:8000/v1, model: qwen-vl, api_key_env: "", timeout_s: 5}
  relations: {kind: llm, base_url: http://vlm:8000/v1, model: qwen, max_retries: 0}
  rooms: {typer: llm, api_key_env: ""}
  query: {kind: llm, base_url: http://127.0.0.1:8000/v1}
"""


def _moved_notices(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if "moved to" in r.getMessage()]


def test_an_old_yaml_loads_its_endpoint_keys_into_graph_endpoint_with_one_notice(tmp_path, caplog):
    p = tmp_path / "old.yaml"
    p.write_text(OLD_YAML)
    with caplog.at_level(logging.INFO, logger="ogscene3d.config"):
        cfg = load_config(p)
    ep = cfg.graph.endpoint
    # a value beyond the default is the endpoint's; the defaults (query.base_url) say nothing
    assert ep == EndpointConfig(base_url="http://vlm:8000/v1", api_key_env="", timeout_s=5.0, max_retries=0)
    assert (cfg.graph.captioner.model, cfg.graph.relations.model, cfg.graph.rooms.model) == (
        "qwen-vl",
        "qwen",
        "",
    )
    (notice,) = _moved_notices(caplog)
    assert "graph.captioner.{base_url,api_key_env,timeout_s}" in notice and "graph.query.base_url" in notice
    assert notice.endswith("moved to graph.endpoint (read there; update the file)")
    # written back, the config holds the new keys only and loads without a notice
    caplog.clear()
    save_config(cfg, tmp_path / "new.yaml")
    with caplog.at_level(logging.INFO, logger="ogscene3d.config"):
        assert load_config(tmp_path / "new.yaml") == cfg
    assert (
        not _moved_notices(caplog)
        and "base_url" not in (tmp_path / "new.yaml").read_text().split("captioner")[1]
    )


def test_the_components_call_the_shared_endpoint_with_their_own_model():
    sets = ["graph.endpoint.base_url=http://llm:1/v1", "graph.endpoint.model=shared",
            "graph.captioner.kind=openai", "graph.captioner.model=vision",
            "graph.relations.kind=llm", "graph.rooms.typer=llm", "graph.query.kind=llm"]  # fmt: skip
    cfg = load_config(None, sets)
    g = SceneGraph(cfg.graph)
    clients = {
        "captioner": g.captioner.client,
        "relations": g.relations.client,
        "rooms": g.room_map.typer.client,
        "query": g._llm_query.client,
    }
    assert {k: c.model for k, c in clients.items()} == {
        "captioner": "vision", "relations": "shared", "rooms": "shared", "query": "shared"
    }  # fmt: skip
    assert {c.base_url for c in clients.values()} == {"http://llm:1/v1"}


def test_old_keys_that_disagree_are_an_error_unless_the_new_key_is_given():
    old = ["graph.captioner.base_url=http://a:1/v1", "graph.relations.base_url=http://b:1/v1"]
    match = r"graph\.captioner\.base_url=.*graph\.relations\.base_url=.*differ.*set graph\.endpoint\.base_url"
    with pytest.raises(ConfigError, match=match):
        load_config(None, old)
    cfg = load_config(None, [*old, "graph.endpoint.base_url=http://c:1/v1"])
    assert cfg.graph.endpoint.base_url == "http://c:1/v1"  # the new key wins
    # the same value twice (30 and 30.0 alike) is no conflict
    cfg = load_config(None, ["graph.captioner.timeout_s=12", "graph.relations.timeout_s=12.0"])
    assert cfg.graph.endpoint.timeout_s == 12.0


def test_a_run_folder_written_before_loads(caplog):
    with caplog.at_level(logging.INFO, logger="ogscene3d.config"):
        cfg = load_config(RUN_FOLDER / "config.yaml")
    assert cfg.graph.endpoint == EndpointConfig()
    assert len(_moved_notices(caplog)) == 1


def test_every_moved_key_lands_on_a_setting():
    from ogscene3d.config import settings

    keys = {s.key for s in settings(Config)}
    assert MOVED and set(MOVED.values()) <= keys and not set(MOVED) & keys


OLD_MAPPING_YAML = """
mapping:
  keyframe_every: 2
  pixels_per_gaussian: 9
  knn_radius: 0.03
  opt_iters: 3
  merge_duplicates: false
  refine_every: 4
  longterm_views: 3
  evidence: false
  evidence_cell: 0.08
"""


def test_an_old_yaml_loads_its_flat_mapping_keys_into_their_sections_with_one_notice(tmp_path, caplog):
    p = tmp_path / "old.yaml"
    p.write_text(OLD_MAPPING_YAML)
    with caplog.at_level(logging.INFO, logger="ogscene3d.config"):
        cfg = load_config(p)
    m = cfg.mapping
    assert (m.keyframe_every, m.init.pixels_per_gaussian, m.association.knn_radius, m.optimize.iters) == (
        2, 9, 0.03, 3
    )  # fmt: skip
    assert not m.merge.enabled and m.refine.every == 4 and m.longterm.views == 3
    assert not m.evidence.enabled and m.evidence.cell == 0.08  # the old switch is the section's enabled
    (notice,) = _moved_notices(caplog)
    assert "mapping.{pixels_per_gaussian,knn_radius," in notice and "opt_iters" in notice
    assert "mapping.init" in notice and "mapping.optimize" in notice and "mapping.evidence" in notice
    caplog.clear()
    save_config(cfg, tmp_path / "new.yaml")
    with caplog.at_level(logging.INFO, logger="ogscene3d.config"):
        assert load_config(tmp_path / "new.yaml") == cfg
    assert not _moved_notices(caplog) and "opt_iters" not in (tmp_path / "new.yaml").read_text()


def test_old_mapping_overrides_keep_working_and_the_new_key_wins():
    cfg = load_config(None, ["mapping.opt_iters=2", "mapping.tau_low=0.2", "mapping.merge_novel=false"])
    assert cfg.mapping.optimize.iters == 2 and cfg.mapping.refine.tau_low == 0.2
    assert not cfg.mapping.merge.novel
    cfg = load_config(None, ["mapping.opt_iters=2", "mapping.optimize.iters=5"])
    assert cfg.mapping.optimize.iters == 5
    # the old rule across two settings now names the new keys
    with pytest.raises(ConfigError, match=r"mapping\.refine\.tau_low must be <= mapping\.refine\.tau_high"):
        load_config(None, ["mapping.tau_low=0.8"])


def test_the_old_evidence_switch_over_a_file_with_an_evidence_section(tmp_path):
    p = tmp_path / "new.yaml"
    p.write_text("mapping:\n  evidence:\n    cell: 0.08\n")
    cfg = load_config(p, ["mapping.evidence=false"])
    assert not cfg.mapping.evidence.enabled and cfg.mapping.evidence.cell == 0.08  # merged, not replaced
    assert load_config(p, ["mapping.evidence.enabled=false"]) == cfg
    p.write_text("mapping:\n  evidence: false\n")
    cfg = load_config(p, ["mapping.evidence.cell=0.08"])
    assert not cfg.mapping.evidence.enabled and cfg.mapping.evidence.cell == 0.08


def test_every_flat_mapping_key_of_the_old_layout_has_moved():
    """Each leaf of MappingConfig before the sections (the run folder of 03e44a8 holds them all) is a
    setting today, or moved, or retired."""
    import yaml

    from ogscene3d.config import RETIRED, settings

    old = yaml.safe_load((RUN_FOLDER / "config.yaml").read_text())["mapping"]
    keys = {s.key for s in settings(Config)}
    for name in old:
        key = f"mapping.{name}"
        assert key in keys or key in MOVED or key in RETIRED, key
    assert sum(f"mapping.{n}" in MOVED for n in old) == 47  # all but the 8 left at the top and the retired
