"""run-batch / eval-batch: scenes files, summaries, the sequential executor and a local Ray instance."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import pytest
from layout_scenes import garble_pixels

from ogscene3d.batch import (
    EvalOptions,
    SceneSpec,
    Task,
    aggregate,
    execute,
    format_table,
    read_scenes_file,
    run_batch,
)
from ogscene3d.cli import main
from ogscene3d.errors import ConfigError, DataError

CONFIG = str(Path(__file__).resolve().parents[1] / "configs" / "synthetic.yaml")

# Tiny scenes: 6 frames of 64x48, 3 keyframes, one Adam step, no scene graph (a few seconds each).
TINY = [
    "synthetic.frames=6",
    "synthetic.width=64",
    "synthetic.height=48",
    "mapping.keyframe_every=2",
    "mapping.optimize.iters=1",
    "mapping.optimize.memory_frames=1",
    "graph.enabled=false",
]


# ------------------------------------------------------------------------------------------ scenes files
def test_text_scenes_file(tmp_path: Path) -> None:
    (tmp_path / "data" / "room0").mkdir(parents=True)
    f = tmp_path / "scenes.txt"
    f.write_text(
        f"# my scenes\ndata/room0\n\nsynthetic:3   # a generated room\n{tmp_path}/other/room0\nsynthetic: 7\n"
    )
    specs = read_scenes_file(f)
    assert [s.name for s in specs] == ["room0", "synthetic_3", "room0_2", "synthetic_7"]
    assert specs[0].data == str((tmp_path / "data" / "room0").resolve())  # relative to the scenes file
    assert specs[1].data is None and specs[1].synthetic_seed == 3
    assert specs[2].data == str(tmp_path / "other" / "room0")
    assert specs[3].synthetic_seed == 7
    assert specs[1].describe() == "synthetic:3"


def test_yaml_scenes_file(tmp_path: Path) -> None:
    f = tmp_path / "scenes.yaml"
    f.write_text(
        "scenes:\n"
        "  - synthetic:1\n"
        "  - {path: rooms/a, name: kitchen, gt: gt/a.ply, segments: seg/a, "
        "set: [mapping.association.tau_p=0.2]}\n"
        "  - {synthetic: 2, set: {mapping: {optimize: {iters: 4}}, graph: {enabled: false}}}\n"
    )
    s1, s2, s3 = read_scenes_file(f)
    assert (s1.name, s1.synthetic_seed) == ("synthetic_1", 1)
    assert s2.name == "kitchen" and s2.data == str(tmp_path / "rooms" / "a")
    assert s2.gt == str(tmp_path / "gt" / "a.ply") and s2.segments == str(tmp_path / "seg" / "a")
    assert s2.overrides == ("mapping.association.tau_p=0.2",)
    assert set(s3.overrides) == {"mapping.optimize.iters=4", "graph.enabled=false"}


@pytest.mark.parametrize(
    ("suffix", "text", "error", "match"),
    [
        (".txt", "synthetic:abc\n", ConfigError, "seed must be an integer"),
        (".txt", "# nothing\n\n", DataError, "lists no scene"),
        (".yaml", "- {path: a, synthetic: 1}\n", ConfigError, "exactly one of"),
        (".yaml", "- {path: a, colour: red}\n", ConfigError, "unknown key"),
        (".yaml", "- {path: a, name: x}\n- {path: b, name: x}\n", ConfigError, "more than once"),
        (".yaml", "- {path: a, name: ../up}\n", ConfigError, "plain folder name"),
        (".yaml", "scenes: 3\n", DataError, "expected a list"),
        (".yaml", "- [a, b]\n", ConfigError, "expected a path"),
        (".yaml", "- {path: a, set: [novalue]}\n", ConfigError, "key=value"),
        (".yaml", "- {path: a\n", DataError, "invalid YAML"),
    ],
)
def test_bad_scenes_files(tmp_path: Path, suffix: str, text: str, error: type, match: str) -> None:
    f = tmp_path / f"scenes{suffix}"
    f.write_text(text)
    with pytest.raises(error, match=match):
        read_scenes_file(f)


def test_scene_spec_validation() -> None:
    with pytest.raises(ConfigError, match="exactly one of"):
        SceneSpec("a")
    with pytest.raises(ConfigError, match="exactly one of"):
        SceneSpec("a", data="/x", synthetic_seed=1)
    with pytest.raises(ConfigError, match="plain folder name"):
        SceneSpec("a/b", synthetic_seed=1)


def test_missing_scenes_file(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="not found"):
        read_scenes_file(tmp_path / "nope.txt")


# -------------------------------------------------------------------------------------------- summaries
def test_aggregate_and_table() -> None:
    recs = [
        {"name": "a", "status": "ok", "frames": 10, "semantic_3d": {"hovsg": {"miou": 0.2}}},
        {"name": "b", "status": "ok", "frames": 20, "semantic_3d": {"hovsg": {"miou": 0.4}}},
        {"name": "c", "status": "ok", "frames": 30, "semantic_3d": {"hovsg": {"miou": float("nan")}}},
        {"name": "d", "status": "failed", "error": "DataError: broken", "frames": 1000},
    ]
    agg = aggregate(recs, ["frames", "semantic_3d.hovsg.miou", "gaussians"])
    assert agg["frames"]["n"] == 3 and agg["frames"]["mean"] == pytest.approx(20.0)
    assert agg["frames"]["std"] == pytest.approx(10.0)  # sample std of 10, 20, 30
    m = agg["semantic_3d.hovsg.miou"]
    assert m["n"] == 2 and m["mean"] == pytest.approx(0.3) and m["std"] == pytest.approx(math.sqrt(0.02))
    assert agg["gaussians"] == {"mean": None, "std": None, "n": 0}
    one = aggregate(recs[:1], ["frames"])["frames"]
    assert one == {"mean": 10.0, "std": 0.0, "n": 1}

    cols = [("frames", "frames", "d"), ("semantic_3d.hovsg.miou", "mIoU", "%")]
    table = format_table(recs, cols, aggregate(recs, [k for k, _, _ in cols])).splitlines()
    assert table[0].split() == ["scene", "status", "frames", "mIoU"]
    assert table[2].split() == ["a", "ok", "10", "20.00"]
    assert table[4].split() == ["c", "ok", "30", "-"]
    assert table[5].split() == ["d", "failed", "1000", "-"]
    assert table[7].split() == ["mean", "3/4", "ok", "20.00", "30.00"]
    assert table[8].split() == ["std", "10.00", "14.14"]
    assert table[9] == "failed: d: DataError: broken"


def test_unknown_executor_and_missing_ray(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(ConfigError, match="executor must be one of"):
        execute([], executor="dask")  # type: ignore[arg-type]
    # Without Ray installed the error names the extra to install.
    monkeypatch.setitem(__import__("sys").modules, "ray", None)
    with pytest.raises(ConfigError, match=r'pip install "ogscene3d\[ray\]"'):
        execute([Task("x", dict, ())], executor="ray")


def test_bad_override_fails_before_any_scene(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="unknown config key"):
        run_batch([SceneSpec("a", synthetic_seed=0)], tmp_path / "out", overrides=["mapping.nope=1"])
    assert not (tmp_path / "out" / "a").exists()


# --------------------------------------------------------------------------------------- whole batches
@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A pre-generated synthetic scene (seed 1) given to the batches as a plain dataset folder."""
    from ogscene3d.datasets import make_synthetic_scene

    return make_synthetic_scene(tmp_path_factory.mktemp("data") / "seed1", 1, 6, 64, 48)


@pytest.fixture(scope="module")
def sequential_batch(tmp_path_factory: pytest.TempPathFactory, tiny_scene: Path):
    """``ogscene3d run-batch --eval`` (sequential) on synthetic:0, the seed-1 folder and a missing folder."""
    root = tmp_path_factory.mktemp("seq")
    scenes = root / "scenes.yaml"
    scenes.write_text(
        "- synthetic:0\n"
        f"- {{path: {tiny_scene}, name: seed1, gt: {tiny_scene}}}\n"
        "- {path: does/not/exist, name: broken}\n"
    )
    out = root / "out"
    argv = ["run-batch", str(scenes), "--out", str(out), "--config", CONFIG, "--eval"]
    for ov in TINY:
        argv += ["--set", ov]
    code = main(argv)
    return code, out


def test_run_batch_sequential(sequential_batch, tiny_scene: Path) -> None:
    code, out = sequential_batch
    assert code == 1  # one scene failed, the others are there
    summary = json.loads((out / "run_batch.json").read_text())
    assert summary["executor"] == "sequential" and summary["command"] == "run-batch"
    recs = {r["name"]: r for r in summary["scenes"]}
    assert [r["name"] for r in summary["scenes"]] == ["synthetic_0", "seed1", "broken"]
    assert recs["broken"]["status"] == "failed" and "does/not/exist" in recs["broken"]["error"]
    for name in ("synthetic_0", "seed1"):
        r = recs[name]
        assert r["status"] == "ok", r
        assert r["frames"] == 6 and r["keyframes"] == 3 and r["gaussians"] > 100 and r["labels"] > 3
        run = out / name
        for f in ("gaussians.ply", "map.npz", "graph.json", "timings.json", "config.yaml", "metrics.json"):
            assert (run / f).is_file(), f
        hs = r["semantic_3d"]["hovsg"]
        assert "counted on GT points" in hs["protocol"]
        # simulated SAM on a furnished room: clearly better than chance, not perfect
        assert 0.05 < hs["miou"] < 1.0 and 0.0 < hs["macc"] <= 1.0
        metrics = json.loads((run / "metrics.json").read_text())
        assert metrics["semantic_3d"]["hovsg"]["miou"] == pytest.approx(hs["miou"])
    assert (out / "synthetic_0" / "scene" / "gt" / "instances.json").is_file()  # generated in place
    assert Path(recs["seed1"]["gt"]) == tiny_scene.resolve()
    assert Path(recs["synthetic_0"]["gt"]) == (out / "synthetic_0" / "scene").resolve()
    agg = summary["aggregate"]["semantic_3d.hovsg.miou"]
    vals = [recs[n]["semantic_3d"]["hovsg"]["miou"] for n in ("synthetic_0", "seed1")]
    assert agg["n"] == 2 and agg["mean"] == pytest.approx(sum(vals) / 2)
    assert agg["std"] == pytest.approx(abs(vals[0] - vals[1]) / math.sqrt(2))


def test_eval_batch_matches_run_batch(sequential_batch, capsys: pytest.CaptureFixture) -> None:
    code, out = sequential_batch
    capsys.readouterr()
    assert main(["eval-batch", str(out), "--protocol", "both", "--no-plots"]) == 1
    printed = capsys.readouterr().out
    assert "mIoU HS" in printed and "mIoU CG" in printed and "broken" in printed
    ev = json.loads((out / "eval_batch.json").read_text())
    run = {r["name"]: r for r in json.loads((out / "run_batch.json").read_text())["scenes"]}
    recs = {r["name"]: r for r in ev["scenes"]}
    assert recs["broken"]["status"] == "not mapped"
    assert set(ev["protocols"]) == {"hovsg", "conceptgraphs"}
    for name in ("synthetic_0", "seed1"):
        assert recs[name]["status"] == "ok"
        # the same evaluation of the same run gives the same numbers
        assert recs[name]["semantic_3d"]["hovsg"]["miou"] == pytest.approx(
            run[name]["semantic_3d"]["hovsg"]["miou"]
        )
        assert 0.0 < recs[name]["semantic_3d"]["conceptgraphs"]["miou"] <= 1.0
    assert recs["seed1"]["gt"] == run["seed1"]["gt"]  # explicit gt from the scenes file


def test_eval_batch_passes_the_conceptgraphs_voxel_size(
    sequential_batch, capsys: pytest.CaptureFixture
) -> None:
    _, out = sequential_batch
    protocols = {}
    for size in ("0", "0.05"):
        main(["eval-batch", str(out), "--protocol", "conceptgraphs", "--no-plots", "--cg-voxel-size", size])
        ev = json.loads((out / "eval_batch.json").read_text())
        rec = {r["name"]: r for r in ev["scenes"]}["seed1"]
        protocols[size] = rec["semantic_3d"]["conceptgraphs"]["protocol"]
    assert "not resampled" in protocols["0"] and "0.05 m voxel" in protocols["0.05"]
    capsys.readouterr()
    assert main(["eval-batch", str(out), "--no-plots", "--cg-voxel-size", "-1"]) == 2
    assert "--cg-voxel-size must be >= 0" in capsys.readouterr().err


@pytest.fixture(scope="module")
def local_ray():
    ray = pytest.importorskip("ray")
    if ray.is_initialized():
        ray.shutdown()
    ray.init(num_cpus=2, include_dashboard=False, logging_level="ERROR", log_to_driver=False)
    try:
        yield ray
    finally:
        ray.shutdown()


def test_run_batch_ray(local_ray, sequential_batch, tiny_scene: Path, tmp_path: Path) -> None:
    _, seq_out = sequential_batch
    seq = {r["name"]: r for r in json.loads((seq_out / "run_batch.json").read_text())["scenes"]}
    specs = [
        SceneSpec("synthetic_0", synthetic_seed=0),
        SceneSpec("seed1", data=str(tiny_scene), gt=str(tiny_scene)),
        SceneSpec("broken", data=str(tmp_path / "missing")),
    ]
    res = run_batch(
        specs,
        tmp_path / "out",
        config=CONFIG,
        overrides=TINY,
        executor="ray",
        evaluate=EvalOptions(plots=False),
    )
    assert local_ray.is_initialized()  # an existing connection is used and left alone
    recs = {r["name"]: r for r in res.records}
    assert [r["name"] for r in res.records] == ["synthetic_0", "seed1", "broken"]
    assert res.num_failed == 1 and recs["broken"]["status"] == "failed"
    assert "missing" in recs["broken"]["error"]
    for name in ("synthetic_0", "seed1"):
        r = recs[name]
        assert r["status"] == "ok" and r["device"] == "cpu" and r["pid"] != os.getpid()
        assert (r["frames"], r["keyframes"]) == (seq[name]["frames"], seq[name]["keyframes"])
        # same data and config in another process: the same map up to float reduction order
        assert abs(r["gaussians"] - seq[name]["gaussians"]) <= 0.05 * seq[name]["gaussians"]
        assert 0.05 < r["semantic_3d"]["hovsg"]["miou"] < 1.0
        assert (tmp_path / "out" / name / "metrics.json").is_file()
    assert json.loads(res.summary_path.read_text())["executor"] == "ray"


def test_ray_worker_crash_is_recorded(local_ray) -> None:
    # A worker that dies (segfault, OOM kill) fails its scene only; the other task's record comes back.
    def crash(*_args, device=None):
        os._exit(3)

    def fine(value, device=None):
        return {"name": "fine", "status": "ok", "value": value, "device": device}

    out = execute([Task("dies", crash, ()), Task("fine", fine, (7,))], executor="ray")
    assert out[0]["name"] == "dies" and out[0]["status"] == "failed"
    assert "WorkerCrashedError" in out[0]["error"]
    assert out[1] == {"name": "fine", "status": "ok", "value": 7, "device": "cpu"}


def test_a_bad_frame_keeps_the_scenes_map_so_far(tmp_path: Path, tiny_scene: Path) -> None:
    import shutil

    scene = tmp_path / "scene"
    shutil.copytree(tiny_scene, scene)
    garble_pixels(scene / "results" / "depth000004.png")  # keyframes 0 and 2 come before it
    scenes = tmp_path / "scenes.txt"
    scenes.write_text(f"{scene}\n")
    argv = ["run-batch", str(scenes), "--out", str(tmp_path / "out"), "--config", CONFIG]
    for ov in TINY:
        argv += ["--set", ov]
    assert main(argv) == 2  # every scene failed
    rec = json.loads((tmp_path / "out" / "run_batch.json").read_text())["scenes"][0]
    assert rec["status"] == "failed" and "depth000004.png" in rec["error"]
    run = tmp_path / "out" / rec["name"]
    assert (run / "map.npz").is_file()
    # its config.yaml (the data and the batch's settings) is there too: `run --resume --out` goes on with it
    import yaml

    saved = yaml.safe_load((run / "config.yaml").read_text())
    assert saved["data"]["path"] == str(scene.resolve()) and saved["mapping"]["optimize"]["iters"] == 1
