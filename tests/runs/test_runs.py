"""The run folder's owner (ogscene3d.runs): a folder written before the package existed still resumes, and
each file kind has one reader that every consumer shares.

``data/run_folder_03e44a8`` was written by main at 03e44a8, before ``ogscene3d.runs``: the tiny Replica-layout
scene of ``mapping_scenes._replica_scene`` (3 frames, 32x24, with segments) in ``scene/``, and in ``run/``
``ogscene3d run`` of its first two frames (``mapping_scenes._common`` with ``--max-frames 2``).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from ogscene3d.cli import main
from ogscene3d.errors import DataError
from ogscene3d.runs import RunFolder, read_gaussians_ply, read_graph_json, read_run_id, recorded_data_path

FIXTURE = Path(__file__).resolve().parents[1] / "data" / "run_folder_03e44a8"


@pytest.fixture
def old_run(tmp_path):
    shutil.copytree(FIXTURE, tmp_path / "old")
    return tmp_path / "old" / "scene", tmp_path / "old" / "run"


def test_a_run_folder_written_before_the_runs_package_resumes(old_run, capsys):
    scene, run = old_run
    folder = RunFolder(run)
    run_id = read_run_id(run)
    assert run_id is not None and json.loads(folder.timings.read_text())["counts"]["frames"] == 2
    # the scene moved (the recorded data.path is where main wrote it): the same frames, found by their bytes
    assert recorded_data_path(run) != scene
    argv = ["run", "--resume", "--out", str(run), "--data", str(scene), "--segments", str(scene / "segs"),
            "--device", "cpu", "--no-progress"]  # fmt: skip
    assert main(argv) == 0
    assert "read 1 frames: 1 mapped (3 keyframes in all)" in capsys.readouterr().out
    counts = json.loads(folder.timings.read_text())["counts"]
    assert counts["frames"] == 3 and counts["keyframes"] == 3
    assert read_run_id(run) == run_id  # a resume goes on with its map's id
    assert recorded_data_path(run) == scene.resolve()  # config.yaml now records where the frames are
    # its flat mapping keys (before the sections) were read at their new place and are written there
    saved = yaml.safe_load(folder.config.read_text())["mapping"]
    assert saved["optimize"]["iters"] == 1 and saved["association"]["knn_radius"] == 0.1
    assert "opt_iters" not in saved and "knn_radius" not in saved
    assert main(argv) == 0  # finished: nothing to do
    assert "nothing to do" in capsys.readouterr().out


def test_the_readers_of_gaussians_ply_agree(old_run):
    """The mapper's GaussianMap.read_ply, the viewer and eval read gaussians.ply through one reader."""
    from ogscene3d.eval import read_run
    from ogscene3d.gaussians import GaussianMap
    from ogscene3d.viewer.runs import load_run

    _, run = old_run
    ply = read_gaussians_ply(RunFolder(run).gaussians)
    gm = GaussianMap.read_ply(RunFolder(run).gaussians)
    snap, _ = load_run(run)
    ev = read_run(run)
    assert len(ply) == len(gm) == snap.total_gaussians == len(ev.means) > 0
    np.testing.assert_array_equal(gm.means.numpy(), ply.means)
    np.testing.assert_array_equal(snap.means, ply.means)
    np.testing.assert_array_equal(ev.means, ply.means.astype(np.float64))
    np.testing.assert_array_equal(ev.labels, ply.labels)
    np.testing.assert_array_equal(snap.opacities, ev.opacities)
    np.testing.assert_allclose(gm.opacities.numpy(), ev.opacities, rtol=1e-6)
    # and the writer writes back the same file
    out = RunFolder(run).path / "again.ply"
    gm.export_ply(out)
    assert out.read_bytes() == RunFolder(run).gaussians.read_bytes()


def test_the_gaussians_reader_names_what_it_lacks(tmp_path):
    from plyfile import PlyData, PlyElement

    p = tmp_path / "g.ply"
    vert = np.zeros(2, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("label", "<f4")])
    vert["label"] = [1.0, 2.5]
    PlyData([PlyElement.describe(vert, "vertex")]).write(str(p))
    with pytest.raises(DataError, match="lacks the 3DGS properties"):
        read_gaussians_ply(p)
    with pytest.raises(DataError, match="'label' must hold whole numbers"):
        read_gaussians_ply(p, ["x", "y", "z", "label"])
    with pytest.raises(DataError, match="does not exist"):
        read_gaussians_ply(tmp_path / "none.ply")


def test_graph_json_centres_are_checked_where_asked(tmp_path):
    p = tmp_path / "graph.json"
    p.write_text(json.dumps({"nodes": [{"id": 1, "tag": "chair"}], "edges": []}))
    assert read_graph_json(p)["nodes"][0]["tag"] == "chair"  # eval scores a graph by ids and tags
    with pytest.raises(DataError, match="node 0 lacks 'id' or 'center'"):
        read_graph_json(p, centers=True)  # the viewer places each node at its centre
    p.write_text(json.dumps({"nodes": [{"id": 1, "center": [0, 0, float("nan")]}]}))
    with pytest.raises(DataError, match="non-finite center"):
        read_graph_json(p)
