"""The session builder (mapping/session.py): run, run-batch, live and the ablation build their sessions there,
so an ablation run folder records its run id and the data it mapped as `run` does, and `eval` finds its
ground truth (issue 40)."""

from __future__ import annotations

import pytest

from ogscene3d.config import load_config
from ogscene3d.runs import RunFolder, read_config, read_run_id, recorded_data_path

FAST = ["mapping.optimize.iters=1", "graph.enabled=false"]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from ogscene3d.datasets import make_synthetic_scene

    return make_synthetic_scene(tmp_path_factory.mktemp("data") / "scene", 1, 3, 48, 36, progress=False)


def test_an_ablation_run_records_its_id_and_data_and_eval_finds_its_ground_truth(scene, tmp_path, capsys):
    from ogscene3d.cli import main
    from ogscene3d.eval import find_ground_truth
    from ogscene3d.mapping.ablation import run_ablation

    cfg = load_config("synthetic", FAST)
    res = run_ablation(cfg, scene, scene, tmp_path / "abl", ["local"], device="cpu")
    assert res["local"]["gaussians"] > 0
    run = tmp_path / "abl" / "local"
    assert read_run_id(run) is not None
    assert recorded_data_path(run) == scene.resolve()
    assert read_config(run).device == "cpu" and read_config(run).mapping.ablation == "local"
    assert find_ground_truth(run) == scene.resolve()
    assert main(["eval", str(run), "--no-plots"]) == 0  # no --gt: found from config.yaml's data.path
    assert "mIoU" in capsys.readouterr().out
    assert RunFolder(run).metrics.is_file()


def test_open_session_without_data_generates_the_synthetic_scene_in_the_run_folder(tmp_path):
    from ogscene3d.mapping.session import mapping_session

    cfg = load_config("synthetic", [*FAST, "synthetic.frames=2", "synthetic.width=48", "synthetic.height=36"])
    out = tmp_path / "run"
    with mapping_session(cfg, out, None, command="run") as session:
        assert session.data == RunFolder(out).scene and session.start == 0 and session.total == 2
        assert cfg.data.path == str(RunFolder(out).scene.resolve())  # recorded for eval and --resume
        summary = session.run()
    assert summary.status == "finished" and summary.read == 2
    assert recorded_data_path(out) == RunFolder(out).scene.resolve()
