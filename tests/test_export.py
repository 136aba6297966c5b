"""``ogscene3d export``: coloured point clouds other tools read, per-node clouds, GraphML with boxes."""

from __future__ import annotations

import numpy as np
import pytest
from viewer_runs import BLUE, GREEN, _write_run, make_scene

from ogscene3d.cli import main
from ogscene3d.colors import label_colors
from ogscene3d.errors import DataError
from ogscene3d.export import export_run, node_file_name


@pytest.fixture
def run_dir(tmp_path):
    return _write_run(tmp_path / "run", make_scene(50, objects=3))


def test_open3d_reads_the_colours_labels_and_confidences(run_dir):
    import open3d as o3d
    from plyfile import PlyData

    res = export_run(run_dir, colors="rgb")
    assert res.cloud == run_dir / "export" / "points_rgb.ply"
    pc = o3d.io.read_point_cloud(str(res.cloud))
    assert pc.has_colors() and len(pc.points) == 150
    colors = np.asarray(pc.colors)
    assert np.isclose(colors, GREEN, atol=1 / 255).all(axis=1).sum() == 100  # objects 0 and 2
    assert np.isclose(colors, BLUE, atol=1 / 255).all(axis=1).sum() == 50
    # the standard names and types CloudCompare and MeshLab look for
    v = PlyData.read(str(res.cloud))["vertex"]
    types = {p.name: p.val_dtype for p in v.properties}
    assert types["red"] == types["green"] == types["blue"] == "u1"
    assert types["label"] == "i4" and types["confidence"] == "f4"
    snap = make_scene(50, objects=3)
    np.testing.assert_array_equal(v["label"], snap.labels)
    np.testing.assert_allclose(v["confidence"], snap.confidences, rtol=1e-6)
    # the source gaussians.ply is what Open3D shows grey
    assert not o3d.io.read_point_cloud(str(run_dir / "gaussians.ply")).has_colors()


def test_semantic_colours_are_the_viewers_label_colours(run_dir, tmp_path):
    import open3d as o3d

    res = export_run(run_dir, tmp_path / "out", colors="semantic", nodes=False, graphml=False)
    pc = o3d.io.read_point_cloud(str(res.cloud))
    labels = make_scene(50, objects=3).labels
    np.testing.assert_allclose(np.asarray(pc.colors), label_colors(labels), atol=0.5 / 255 + 1e-6)
    assert res.nodes == {} and res.graphml is None


def test_one_cloud_per_node_and_graphml_with_boxes(run_dir):
    import networkx as nx
    import open3d as o3d

    res = export_run(run_dir)
    assert sorted(res.nodes) == [0, 1, 2]
    assert res.nodes[1].name == "node_0001_table.ply" and res.nodes[1].parent.name == "nodes"
    for nid, path in res.nodes.items():
        pc = o3d.io.read_point_cloud(str(path))
        assert len(pc.points) == 50 and pc.has_colors()
        assert abs(np.asarray(pc.points)[:, 0].mean() - 1.2 * nid) < 0.2  # the node's own Gaussians
    G = nx.read_graphml(res.graphml, node_type=int)
    assert sorted(G.nodes) == [0, 1, 2] and G.number_of_edges() == 2
    assert [G.nodes[1][f"bbox_min_{a}"] for a in "xyz"] == pytest.approx([0.7, -0.5, -0.5])
    assert [G.nodes[1][f"bbox_max_{a}"] for a in "xyz"] == pytest.approx([1.7, 0.5, 0.5])


def test_node_file_names():
    assert node_file_name(3, "Coffee table / low") == "node_0003_coffee_table_low.ply"
    assert node_file_name(12, "") == "node_0012.ply"


def test_missing_files_are_clear_errors(tmp_path, run_dir):
    with pytest.raises(DataError, match="does not exist"):
        export_run(tmp_path / "nope")
    (run_dir / "graph.json").unlink()
    with pytest.raises(DataError, match="no graph.json"):
        export_run(run_dir)
    res = export_run(run_dir, nodes=False, graphml=False)  # the cloud alone needs no graph
    assert res.cloud.is_file()


def test_cli_export(run_dir, tmp_path, capsys):
    out = tmp_path / "exp"
    assert (
        main(["export", str(run_dir), "--out", str(out), "--colors", "semantic", "--min-opacity", "0.5"]) == 0
    )
    printed = capsys.readouterr().out
    assert f"wrote {out / 'points_semantic.ply'}" in printed and "3 node clouds" in printed
    assert (out / "graph.graphml").is_file() and len(list((out / "nodes").glob("*.ply"))) == 3
    # every Gaussian of the test scene is 0.95 opaque: a higher threshold leaves an empty cloud
    assert main(["export", str(run_dir), "--out", str(out), "--min-opacity", "0.99", "--no-nodes"]) == 0
    from plyfile import PlyData

    assert len(PlyData.read(str(out / "points_rgb.ply"))["vertex"]) == 0
    assert main(["export", str(run_dir), "--no-cloud", "--no-nodes", "--no-graphml"]) == 2
    assert "nothing to export" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["export", str(run_dir), "--min-opacity", "2"])
