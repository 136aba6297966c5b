"""Run-directory and ground-truth readers: formats accepted and clear errors for bad files."""

import json

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from ogscene3d.errors import DataError
from ogscene3d.eval.readers import load_ground_truth, read_class_table, read_graph_json, read_run


def _ply(path, **fields):
    n = len(next(iter(fields.values())))
    arr = np.zeros(
        n, dtype=[(k, "<i4" if np.asarray(v).dtype.kind in "iu" else "<f4") for k, v in fields.items()]
    )
    for k, v in fields.items():
        arr[k] = v
    PlyData([PlyElement.describe(arr, "vertex")], byte_order="<").write(str(path))


def test_class_table_formats(tmp_path):
    for data in (
        ["wall", "chair"],
        {"0": "wall", "1": "chair"},
        {"classes": {"0": {"name": "wall"}, "1": "chair"}},
    ):
        (tmp_path / "t.json").write_text(json.dumps(data))
        assert read_class_table(tmp_path / "t.json") == {0: "wall", 1: "chair"}
    (tmp_path / "t.json").write_text("{oops")
    with pytest.raises(DataError, match="invalid JSON"):
        read_class_table(tmp_path / "t.json")
    (tmp_path / "t.json").write_text(json.dumps({"x": "wall"}))
    with pytest.raises(DataError, match="not 'id': name"):
        read_class_table(tmp_path / "t.json")


def test_flat_instances_json_and_instance_field(tmp_path):
    gt = tmp_path / "gt"
    gt.mkdir()
    _ply(gt / "pts.ply", x=[0.0, 1.0, 2.0, 3.0], y=[0.0] * 4, z=[0.0] * 4, object_id=[5, 5, 6, 7])
    (gt / "instances.json").write_text(
        json.dumps({"5": {"class": "table"}, "6": "cup", "relations": [[6, "on", 5]]})
    )
    g = load_ground_truth(tmp_path)
    assert g.class_names == ["cup", "table"] and g.class_ids is None
    assert g.classes.tolist() == [1, 1, 0, -1]  # instance 7 is unknown: void
    assert g.instances.tolist() == [5, 5, 6, -1] and g.relations == [(6, "on", 5)]
    (gt / "instances.json").write_text(json.dumps({"5": {"class": "table"}, "relations": [[6, "on", 5]]}))
    with pytest.raises(DataError, match="unknown instance"):
        load_ground_truth(tmp_path)


def test_ground_truth_errors(tmp_path):
    with pytest.raises(DataError, match="not found"):
        load_ground_truth(tmp_path / "missing.ply")
    (tmp_path / "bad.ply").write_bytes(
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n"
    )
    with pytest.raises(DataError, match="bad.ply"):
        load_ground_truth(tmp_path / "bad.ply", classes=tmp_path / "c.json")
    _ply(tmp_path / "nocls.ply", x=[0.0], y=[0.0], z=[0.0])
    with pytest.raises(DataError, match="no class field"):
        load_ground_truth(tmp_path / "nocls.ply")
    _ply(tmp_path / "nan.ply", x=[np.nan], y=[0.0], z=[0.0], label=[1])
    with pytest.raises(DataError, match="NaN"):
        load_ground_truth(tmp_path / "nan.ply")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(DataError, match="no labelled point cloud"):
        load_ground_truth(empty)


def test_run_reader(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    _ply(run / "gaussians.ply", x=[0.0, 1.0], y=[0.0, 0.0], z=[0.0, 0.0], opacity=[0.0, 50.0], label=[3, -1])
    r = read_run(run)
    assert r.labels.tolist() == [3, -1] and r.graph is None
    np.testing.assert_allclose(r.opacities, [0.5, 1.0])
    np.testing.assert_array_equal(r.confidences, [1.0, 1.0])  # absent field: every label fully trusted
    (run / "graph.json").write_text(json.dumps({"nodes": [{"id": 3}], "edges": [{"source": 3}]}))
    with pytest.raises(DataError, match="every edge needs"):
        read_run(run)
    with pytest.raises(DataError, match="not valid JSON"):
        (run / "graph.json").write_text("[")
        read_graph_json(run / "graph.json")
    _ply(run / "gaussians.ply", x=[0.0], y=[0.0], z=[0.0])
    with pytest.raises(DataError, match="'label' missing"):
        read_run(run)
