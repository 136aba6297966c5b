"""Viewer pieces without a browser: colours, snapshot math, run reading, scene layers, live session, CLI."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from viewer_runs import _write_run, make_scene

from ogscene3d.colors import confidence_colors, label_colors, turbo
from ogscene3d.errors import ConfigError, DataError
from ogscene3d.gaussians import GaussianMap
from ogscene3d.runs.graph_json import read_graph_json
from ogscene3d.viewer.runs import load_run
from ogscene3d.viewer.scene import SceneLayers, ViewerSettings, labelled_nodes, legend_html, node_text
from ogscene3d.viewer.snapshot import (
    MapSnapshot,
    covariances,
    decimate_indices,
    quat_to_rotmat,
    rotmat_to_wxyz,
    snapshot_from_mapper,
)

# ------------------------------------------------------------------------------ colours


def test_label_colors_stable_distinct_and_grey_for_unlabeled():
    labels = np.array([0, 1, 2, 3, 0, -1, 1000, 1001], dtype=np.int32)
    c = label_colors(labels)
    assert c.shape == (8, 3) and c.dtype == np.float32
    assert np.all((c >= 0) & (c <= 1))
    np.testing.assert_array_equal(c[0], c[4])  # same label, same colour
    np.testing.assert_array_equal(label_colors(np.array([1000]))[0], c[6])  # independent of the batch
    assert np.allclose(c[5], 0.62)  # unlabeled -> grey
    # neighbouring labels differ clearly
    for a, b in [(0, 1), (1, 2), (2, 3), (6, 7)]:
        assert np.abs(c[a] - c[b]).max() > 0.1
    with pytest.raises(ValueError):
        label_colors(np.array([0.5]))


def test_turbo_and_confidence_colors():
    ends = turbo(np.array([0.0, 1.0, np.nan, 2.0, 0.1, 0.5, 0.9]))
    assert ends.shape == (7, 3)
    assert ends[4, 2] > 2 * ends[4, 0]  # low confidence is blue
    assert ends[5, 1] > ends[5, 0] and ends[5, 1] > ends[5, 2]  # middle is green
    assert ends[6, 0] > 2 * ends[6, 2]  # high confidence is red
    np.testing.assert_allclose(ends[2], ends[0])  # NaN -> 0
    np.testing.assert_allclose(ends[3], ends[1])  # clipped
    cc = confidence_colors(np.array([0.9, 0.9]), np.array([3, -1]))
    assert np.allclose(cc[1], 0.62) and not np.allclose(cc[0], 0.62)


# ------------------------------------------------------------------------------ snapshot math


def test_covariances_have_the_scales_as_principal_axes():
    rng = np.random.default_rng(1)
    q = rng.normal(size=(50, 4))
    s = rng.uniform(0.01, 0.3, size=(50, 3))
    R = quat_to_rotmat(q)
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-9)
    cov = covariances(q, s).astype(np.float64)
    np.testing.assert_allclose(cov, cov.transpose(0, 2, 1), atol=1e-7)
    # Σ R_k = s_k² R_k: the columns of R are eigenvectors with eigenvalues s².
    np.testing.assert_allclose(cov @ R, R * (s**2)[:, None, :], atol=1e-6)
    # a quaternion and its negation are the same rotation; zero quaternion -> identity
    np.testing.assert_allclose(quat_to_rotmat(-q), R, atol=1e-12)
    np.testing.assert_allclose(quat_to_rotmat(np.zeros((1, 4)))[0], np.eye(3))
    # wxyz convention: 90 degrees about z maps x to y
    qz = np.array([[np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)]])
    np.testing.assert_allclose(quat_to_rotmat(qz)[0] @ [1.0, 0, 0], [0, 1.0, 0], atol=1e-12)


def test_rotmat_to_wxyz_round_trip():
    rng = np.random.default_rng(2)
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    R = quat_to_rotmat(q)
    for i in range(len(q)):
        back = quat_to_rotmat(rotmat_to_wxyz(R[i])[None])[0]
        np.testing.assert_allclose(back, R[i], atol=1e-9)


def test_decimate_indices_is_a_deterministic_uniform_subset():
    assert decimate_indices(10, 10) is None
    idx = decimate_indices(10_000, 1000)
    assert idx is not None and len(idx) == 1000 and len(np.unique(idx)) == 1000
    assert np.all(np.diff(idx) > 0) and idx.max() < 10_000
    np.testing.assert_array_equal(idx, decimate_indices(10_000, 1000))
    # spread over the whole range (each tenth gets some)
    assert np.bincount(idx // 1000, minlength=10).min() > 50
    with pytest.raises(ValueError):
        decimate_indices(5, 0)


def test_snapshot_validates_shapes_and_drops_non_finite():
    snap = make_scene(10, objects=2)
    assert len(snap) == 20 and snap.total_gaussians == 20 and snap.image_size == (160, 120)
    with pytest.raises(ValueError, match="quats"):
        MapSnapshot(
            snap.means,
            snap.quats[:5],
            snap.scales,
            snap.opacities,
            snap.colors,
            snap.labels,
            snap.confidences,
        )
    with pytest.raises(ValueError, match="image"):
        MapSnapshot(
            snap.means,
            snap.quats,
            snap.scales,
            snap.opacities,
            snap.colors,
            snap.labels,
            snap.confidences,
            image=np.zeros((4, 4), np.uint8),
        )
    snap.means[3, 1] = np.nan
    snap.scales[7, 0] = np.inf
    clean = snap.finite()
    assert len(clean) == 18 and np.isfinite(clean.means).all() and np.isfinite(clean.scales).all()


# ------------------------------------------------------------------------------ runs


class FakeMapper:
    """The Mapper's public surface, with a trivial map update: each frame adds a blob of Gaussians."""

    def __init__(self, per_frame: int = 50, fail_at: int | None = None) -> None:
        self.map = GaussianMap("cpu")
        self.frames_seen = 0
        self.keyframe_count = 0
        self.per_frame = per_frame
        self.fail_at = fail_at
        self.finalized = False
        self.saved: list[Path] = []
        self.graph = None

        class _T:
            def as_dict(inner):
                return {"ms_per_keyframe": {"init": 1.0, "optimize": 9.0}, "counts": {"labels": 2}}

        self.timings = _T()

    def process(self, frame) -> bool:
        if self.fail_at is not None and self.frames_seen == self.fail_at:
            raise RuntimeError("synthetic failure")
        self.frames_seen += 1
        g = torch.Generator().manual_seed(self.frames_seen)
        m = self.per_frame
        self.map.append(
            torch.randn(m, 3, generator=g) * 0.2 + torch.tensor(frame.pose[:3, 3], dtype=torch.float32),
            torch.rand(m, 3, generator=g),
            torch.full((m, 3), -3.0),
            labels=torch.full((m,), self.frames_seen % 2, dtype=torch.int32),
            confidences=torch.full((m,), 0.7),
        )
        self.keyframe_count += 1
        if self.keyframe_count == 2:
            self.graph = {
                "version": 1,
                "nodes": [{"id": 0, "tag": "chair", "center": [0.0, 0.0, 0.0]}],
                "edges": [],
            }
        return True

    def finalize(self) -> None:
        self.finalized = True

    def save(self, out_dir) -> Path:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        self.map.export_ply(out / "gaussians.ply")
        (out / "graph.json").write_text(json.dumps(self.graph or {"version": 1, "nodes": [], "edges": []}))
        self.saved.append(out)
        return out


def _frames(n: int):
    from ogscene3d.frame import Frame

    out = []
    for i in range(n):
        pose = np.eye(4)
        pose[0, 3] = 0.3 * i
        out.append(
            Frame(
                i,
                np.full((12, 16, 3), 40 * i % 255, np.uint8),
                np.ones((12, 16), np.float32),
                np.array([[10, 0, 8], [0, 10, 6], [0, 0, 1]], np.float32),
                pose,
            )
        )
    return out


def test_snapshot_from_mapper_decimates_and_activates():
    mapper = FakeMapper(per_frame=300)
    for f in _frames(4):
        mapper.process(f)
    full = snapshot_from_mapper(mapper, budget=10_000)
    assert len(full) == 1200 and full.total_gaussians == 1200
    np.testing.assert_allclose(full.scales, np.exp(-3.0), rtol=1e-6)
    np.testing.assert_allclose(full.opacities, 0.5, rtol=1e-6)  # default logit 0
    np.testing.assert_allclose(full.means, mapper.map.means.numpy())
    assert full.graph["nodes"][0]["tag"] == "chair"
    assert full.timings == {"init": 1.0, "optimize": 9.0}
    assert full.counts["keyframes"] == 4 and full.counts["labels"] == 2
    small = snapshot_from_mapper(mapper, budget=100, frame=_frames(1)[0])
    assert len(small) == 100 and small.total_gaussians == 1200
    idx = decimate_indices(1200, 100)
    np.testing.assert_allclose(small.means, full.means[idx])
    np.testing.assert_array_equal(small.labels, full.labels[idx])
    assert small.image is not None and small.image_size == (16, 12)


def test_load_run_reads_the_mapper_ply_and_graph(tmp_path):
    gm = GaussianMap("cpu")
    rng = np.random.default_rng(3)
    n = 64
    colors = rng.uniform(0.05, 0.95, (n, 3)).astype(np.float32)
    log_scales = np.log(rng.uniform(0.01, 0.1, (n, 3))).astype(np.float32)
    opac = rng.uniform(0.1, 0.9, n).astype(np.float32)
    quats = rng.normal(size=(n, 4)).astype(np.float32)
    labels = rng.integers(-1, 5, n).astype(np.int32)
    conf = rng.uniform(0, 1, n).astype(np.float32)
    gm.append(
        torch.from_numpy(rng.normal(size=(n, 3)).astype(np.float32)),
        torch.from_numpy(colors),
        torch.from_numpy(log_scales),
        labels=torch.from_numpy(labels),
        confidences=torch.from_numpy(conf),
        quats=torch.from_numpy(quats),
        opacity_logits=torch.logit(torch.from_numpy(opac)),
    )
    gm.export_ply(tmp_path / "gaussians.ply")
    scene = make_scene(5)
    (tmp_path / "graph.json").write_text(json.dumps(scene.graph))
    (tmp_path / "timings.json").write_text(
        json.dumps({"ms_per_keyframe": {"optimize": 12.5}, "counts": {"keyframes": 7}})
    )
    (tmp_path / "config.yaml").write_text("graph:\n  up_axis: [0.0, -2.0, 0.0]\n")
    snap, info = load_run(tmp_path)
    np.testing.assert_allclose(snap.means, gm.means.numpy(), atol=1e-6)
    np.testing.assert_allclose(snap.colors, colors, atol=1e-5)
    np.testing.assert_allclose(snap.scales, np.exp(log_scales), rtol=1e-5)
    np.testing.assert_allclose(snap.opacities, opac, atol=1e-5)
    np.testing.assert_allclose(
        np.abs(np.sum(snap.quats * quats, 1)) / np.linalg.norm(quats, axis=1), 1.0, atol=1e-5
    )
    np.testing.assert_array_equal(snap.labels, labels)
    np.testing.assert_allclose(snap.confidences, conf)
    assert len(snap.graph["nodes"]) == 3 and len(snap.graph["edges"]) == 2
    assert snap.timings == {"optimize": 12.5} and snap.counts["keyframes"] == 7
    np.testing.assert_allclose(info.up, [0.0, -1.0, 0.0])


def test_load_run_errors_name_the_file(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        load_run(tmp_path / "nope")
    with pytest.raises(DataError, match="no gaussians.ply"):
        load_run(tmp_path)
    (tmp_path / "gaussians.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 10\n")
    with pytest.raises(DataError, match="gaussians.ply"):
        load_run(tmp_path)
    bad = tmp_path / "graph.json"
    bad.write_text('{"nodes": [{"id": 1, "center": [0, 0, 0]}], "edges": [{"source": 1, "target": 2}]}')
    with pytest.raises(DataError, match="edge 0"):
        read_graph_json(bad, centers=True)
    bad.write_text('{"nodes": [{"id": 1, "center": [0, 0]}]}')
    with pytest.raises(DataError, match="bad center"):
        read_graph_json(bad, centers=True)
    bad.write_text("{not json")
    with pytest.raises(DataError, match="graph.json"):
        read_graph_json(bad, centers=True)


def test_load_run_tolerates_bad_optional_files(tmp_path, caplog):
    """map.npz and timings.json only add the camera path and the timings panel: when they are truncated
    or of the wrong shape, browsing goes on with a warning naming the file."""
    import logging

    run = _write_run(tmp_path / "run", make_scene(10))
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, 0, 3] = [2.0, 0.0, 1.0]
    np.savez(run / "map.npz", mem_pose=poses, mem_keyframe=np.array([4, 0, 2]))
    snap, _ = load_run(run)
    np.testing.assert_allclose(snap.trajectory[:, 0, 3], [0.0, 1.0, 2.0])  # keyframe order
    data = (run / "map.npz").read_bytes()
    for name, content in [
        ("map.npz", data[: len(data) // 2]),  # a run cut short mid-write
        ("timings.json", "[1, 2]"),
    ]:
        (run / name).write_bytes(content) if isinstance(content, bytes) else (run / name).write_text(content)
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="ogscene3d.viewer.runs"):
            snap, _ = load_run(run)
        assert name in caplog.text
    assert len(snap.trajectory) == 0 and snap.counts == {"gaussians": 30}
    (run / "timings.json").write_text('{"counts": [1], "ms_per_keyframe": {"optimize": 3.0}}')
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="ogscene3d.viewer.runs"):
        snap, _ = load_run(run)
    assert "'counts'" in caplog.text and snap.timings == {"optimize": 3.0}


@pytest.mark.parametrize(
    "node,match",
    [
        ({"id": 1, "center": ["a", "b", "c"]}, "node 1 has a bad center"),
        ({"id": 1, "center": [None, 0, 0]}, "node 1 has a bad center"),
        ({"id": 1, "center": [float("nan"), 0, 0]}, "node 1 has a non-finite center"),
        ({"id": 1, "center": [float("inf"), 0, 0]}, "non-finite center"),
        ({"id": [1], "center": [0, 0, 0]}, "node 0 field 'id' must be an integer"),
        ({"id": "1", "center": [0, 0, 0]}, "field 'id'"),
    ],
)
def test_read_graph_json_rejects_bad_node_fields(tmp_path, node, match):
    bad = tmp_path / "graph.json"
    bad.write_text(json.dumps({"nodes": [node], "edges": []}))
    with pytest.raises(DataError, match=match) as exc:
        read_graph_json(bad, centers=True)
    assert str(bad) in str(exc.value)


def test_read_graph_json_rejects_unhashable_edge_ends(tmp_path):
    bad = tmp_path / "graph.json"
    bad.write_text(
        json.dumps({"nodes": [{"id": 1, "center": [0, 0, 0]}], "edges": [{"source": [1], "target": 1}]})
    )
    with pytest.raises(DataError, match="edge 0"):
        read_graph_json(bad, centers=True)


# ------------------------------------------------------------------------------ scene layers


@pytest.fixture(scope="module")
def server():
    import viser

    srv = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    yield srv
    srv.stop()


def test_node_text():
    assert node_text({"id": 3, "tag": "chair", "caption": "a red chair"}) == "chair"
    assert node_text({"id": 3, "tag": "", "caption": "one two three four five"}) == "one two three four..."
    assert node_text({"id": 3}) == "#3"


def test_labelled_nodes_keep_the_largest_of_a_cluster_and_the_chosen_ones():
    nodes = {
        0: {"id": 0, "center": [0.0, 0, 0], "num_gaussians": 50},
        1: {"id": 1, "center": [0.1, 0, 0], "num_gaussians": 500},  # next to 0, larger
        2: {"id": 2, "center": [0.15, 0, 0], "num_gaussians": 10},
        3: {"id": 3, "center": [2.0, 0, 0], "num_gaussians": 5},  # alone
    }
    assert labelled_nodes(nodes, 0.5) == {1, 3}
    # the selected node or a Find match is labelled, and takes its neighbourhood's place
    assert labelled_nodes(nodes, 0.5, always={2}) == {2, 3}
    assert labelled_nodes(nodes, 0.0) == {0, 1, 2, 3}


def test_legend_lists_the_semantic_colours_of_the_graph_nodes():
    graph = make_scene(5, objects=3).graph
    html = legend_html("semantic", graph)
    for n in graph["nodes"]:
        r, g, b = label_colors(np.array([n["id"]]))[0] * 255
        assert f"rgb({round(r)},{round(g)},{round(b)})" in html and f"{n['tag']} (#{n['id']})" in html
    assert "unlabelled" in html
    assert "linear-gradient" in legend_html("confidence", graph) and legend_html("rgb", graph) == ""
    assert "<script>" not in legend_html(
        "semantic", {"nodes": [{"id": 1, "tag": "<script>", "center": [0, 0, 0]}]}
    )


def test_drawable_graph_drops_malformed_entries():
    from ogscene3d.viewer.scene import drawable_graph

    g = {
        "version": 1,
        "nodes": [
            {"id": 1, "center": [0, 0, 0]},
            {"id": 2, "center": [0, float("nan"), 0]},
            {"id": "x", "center": [0, 0, 0]},
            {"center": [1, 1, 1]},
            {"id": 3, "center": [1, 2]},
            {"id": 4, "center": [1, 2, 3]},
        ],
        "edges": [
            {"source": 1, "target": 4, "relation": "on"},
            {"source": 1, "target": 2},
            {"source": "a", "target": 4},
            {"target": 4},
        ],
    }
    out = drawable_graph(g)
    assert [n["id"] for n in out["nodes"]] == [1, 4] and out["edges"] == [g["edges"][0]]
    assert drawable_graph(None) is None and drawable_graph([1, 2]) is None


def test_layers_switch_between_splats_and_points_by_budget(server):
    layers = SceneLayers(server)
    snap = make_scene(200)  # 600 Gaussians
    st = ViewerSettings(max_splats=1000, max_points=250)
    layers.update_bounds(snap)
    layers.update_map(snap, st, None)
    assert layers.shown_kind == "splats" and layers.shown_gaussians == 600
    handle = layers._gauss_handle
    assert handle.buffer.shape == (600, 8)
    layers.update_map(snap, ViewerSettings(max_splats=500, max_points=250), None)  # auto -> points, decimated
    assert layers.shown_kind == "points" and layers.shown_gaussians == 250
    assert layers._gauss_handle is not handle and handle._impl.removed
    layers.update_map(snap, ViewerSettings(render="splats", max_splats=100), None)
    assert layers.shown_kind == "splats" and layers.shown_gaussians == 100
    layers.update_map(snap.subset(np.zeros(len(snap), bool)), st, None)
    assert layers.shown_gaussians == 0 and layers._gauss_handle is None


def test_layers_color_modes_and_query_dimming(server):
    layers = SceneLayers(server)
    snap = make_scene(50)
    layers.update_map(snap, ViewerSettings(color_mode="semantic"), None)
    rgba = layers._gauss_handle.rgbs.astype(float) / 255
    np.testing.assert_allclose(rgba, label_colors(snap.labels), atol=1 / 255 + 1e-6)
    layers.update_map(snap, ViewerSettings(color_mode="confidence"), None)
    np.testing.assert_allclose(
        layers._gauss_handle.rgbs.astype(float) / 255,
        confidence_colors(snap.confidences),
        atol=1 / 255 + 1e-6,
    )
    layers.update_map(snap, ViewerSettings(color_mode="rgb"), {1})
    rgb = layers._gauss_handle.rgbs.astype(float) / 255
    hit = snap.labels == 1
    np.testing.assert_allclose(rgb[hit], snap.colors[hit], atol=1 / 255 + 1e-6)
    assert np.abs(rgb[~hit] - snap.colors[~hit]).max() > 0.3  # others dimmed


def test_layers_graph_updates_only_what_changed(server):
    layers = SceneLayers(server)
    snap = make_scene(20, objects=4)
    st = ViewerSettings()
    layers.update_graph(snap.graph, st, set())
    assert layers.shown_nodes == 4 and layers.shown_edges == 3
    handles = dict(layers._node_handles)
    segments = layers._edge_segments
    assert layers._edge_labels == []  # relation labels only for a selected node, or on demand
    layers.update_graph(json.loads(json.dumps(snap.graph)), st, set())  # same content: nothing re-created
    assert all(layers._node_handles[k] is handles[k] for k in handles)
    assert layers._edge_segments is segments
    layers.update_graph(snap.graph, st, set(), selected=1)  # node 1 has two relations
    assert sorted(h.position[0] for h in layers._edge_labels) == pytest.approx([0.6, 1.8])
    assert layers._edge_segments is segments
    layers.update_graph(snap.graph, ViewerSettings(show_edge_labels=True), set())
    assert len(layers._edge_labels) == 3
    # a node changes its tag, another disappears (with its edges), a query matches one
    g = json.loads(json.dumps(snap.graph))
    g["nodes"][0]["tag"] = "armchair"
    g["nodes"] = g["nodes"][:3]
    g["edges"] = g["edges"][:2]
    layers.update_graph(g, st, {1})
    assert layers.shown_nodes == 3 and layers.shown_edges == 2 and layers._edge_segments is not segments
    assert handles[3][0]._impl.removed and layers._node_handles[0][0] is handles[0][0]
    assert layers._node_handles[0][0].text == "armchair"
    assert layers._node_handles[1][0].text.endswith("table") and layers._node_handles[1][0].text.startswith(
        "★"
    )
    assert layers._highlight_handle is not None and layers._highlight_handle.points.shape == (12, 2, 3)
    layers.update_graph(None, st, set())
    assert layers.shown_nodes == 0 and layers.shown_edges == 0 and layers._highlight_handle is None


def test_layers_camera_trajectory_and_frustum(server):
    layers = SceneLayers(server)
    snap = make_scene(10)
    st = ViewerSettings()
    layers.update_camera(snap, st)
    assert layers._traj_handle.points.shape == (4, 2, 3)
    assert layers._frustum is not None
    np.testing.assert_allclose(layers._frustum.position, snap.pose[:3, 3])
    np.testing.assert_allclose(layers._frustum.fov, 2 * np.arctan(60 / 100))
    traj = layers._traj_handle
    layers.update_camera(snap, st)
    assert layers._traj_handle is traj  # unchanged trajectory is not re-sent


def test_layers_leave_no_scene_node_behind_for_removed_graph_nodes(server):
    # Node ids are scene labels: a live graph keeps dropping ids (merged labels) and adding new ones.
    # Each node's label and marker sit under /graph/nodes/<id>; that frame must go with the node, or the
    # server keeps (and replays to every browser that connects) one frame per id ever shown.
    layers = SceneLayers(server)
    snap = make_scene(5, objects=3)
    names = server.scene._handle_from_node_name
    for shift in range(1000, 1020):
        g = json.loads(json.dumps(snap.graph))
        for n in g["nodes"]:
            n["id"] += shift
        for e in g["edges"]:
            e["source"] += shift
            e["target"] += shift
        layers.update_graph(g, ViewerSettings(), set())
    assert layers.shown_nodes == 3
    ours = [k for k in names if k.startswith("/graph/nodes/") and int(k.split("/")[3]) >= 1000]
    assert {k for k in ours if k.count("/") == 3} == {f"/graph/nodes/{i}" for i in (1019, 1020, 1021)}
    layers.update_graph(None, ViewerSettings(), set())
    assert not [k for k in names if k.startswith("/graph/nodes/") and int(k.split("/")[3]) >= 1000]


def test_layers_resend_a_new_camera_image_even_at_a_freed_images_address(server):
    # A new frame's image can be allocated where the last shown (and since freed) one was: the frustum
    # must still show the new image (an id() comparison took it for the old one).
    layers = SceneLayers(server)
    base = make_scene(5)
    img = np.zeros((360, 480, 3), np.uint8)  # wider than 240 px: the frustum gets a subsampled copy
    layers.update_camera(dataclasses.replace(base, image=img), ViewerSettings())
    assert layers._frustum.image.max() == 0
    for value in (50, 100, 150, 200):
        del img
        img = np.full((360, 480, 3), value, np.uint8)
        layers.update_camera(dataclasses.replace(base, image=img), ViewerSettings())
        assert layers._frustum.image.min() == value


# ------------------------------------------------------------------------------ viewer + session


class FakeBrowser:
    """A websocket client that joins a viewer as a browser does (viser counts a browser as connected
    once it reports its camera) and drains what the server sends; the browser test covers real ones."""

    def __init__(self, url: str) -> None:
        import msgspec
        import viser
        from viser import _messages
        from websockets.sync.client import connect

        self.ws = connect(
            url.replace("http", "ws", 1), subprotocols=[f"viser-v{viser.__version__}"], max_size=None
        )
        camera = _messages.ViewerCameraMessage(
            (1.0, 0.0, 0.0, 0.0),
            (0.0, 0.0, 3.0),
            1.0,
            0.01,
            100.0,
            480,
            640,
            (0.0, 0.0, 0.0),
            (0.0, 0.0, 1.0),
        )
        self.ws.send(msgspec.msgpack.encode(camera.as_serializable_dict()))
        self.received = 0
        self._thread = threading.Thread(target=self._drain, daemon=True)
        self._thread.start()

    def _drain(self) -> None:
        try:
            for _ in self.ws:
                self.received += 1
        except Exception:  # noqa: BLE001 - the connection closed
            pass

    def close(self) -> None:
        self.ws.close()
        self._thread.join(10)


@pytest.fixture
def open_browser():
    """``open_browser(viewer)`` connects a FakeBrowser and returns its view once the viewer has it."""
    browsers: list[FakeBrowser] = []

    def open_(viewer):
        before = {v.client_id for v in viewer.views}
        browsers.append(FakeBrowser(viewer.url))
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            new = [v for v in viewer.views if v.client_id not in before]
            if new:
                return new[0]
            time.sleep(0.02)
        raise AssertionError("the fake browser did not connect")

    yield open_
    for b in browsers:
        b.close()


def test_publish_never_waits_on_a_stuck_viewer(open_browser):
    from ogscene3d.viewer.app import LiveViewer

    viewer = LiveViewer(port=0, max_rate_hz=50)
    view = open_browser(viewer)
    release = threading.Event()
    entered = threading.Event()
    real_push = view.push

    def stuck_push(snap, dirty):
        entered.set()
        release.wait(30)
        real_push(snap, dirty)

    view.push = stuck_push
    try:
        viewer.publish(make_scene(10, seed=0))
        assert entered.wait(10)
        for i in range(50):  # the push thread is blocked; publishing must still return at once
            viewer.publish(make_scene(10, seed=i + 1, objects=2))
        final = make_scene(30, seed=99, objects=2)
        viewer.publish(final)
        release.set()
        assert viewer.wait_until(lambda s: s["gaussians"] == 60 and s["nodes"] == 2, timeout=20)
        assert viewer.stats["errors"] == 0
        # only the newest snapshot was drawn after the stuck one: two map pushes in all
        assert viewer.stats["map_pushes"] == 2
    finally:
        release.set()
        viewer.close()


def test_unchanged_layers_are_not_resent(open_browser):
    from ogscene3d.viewer.app import LiveViewer

    with LiveViewer(port=0, max_rate_hz=50) as viewer:
        view = open_browser(viewer)
        snap = make_scene(20)
        viewer.publish(snap)
        assert viewer.wait_until(lambda s: s["nodes"] == 3 and s["map_pushes"] == 1, timeout=20)
        frustum = view.layers._frustum
        pose = snap.pose.copy()
        pose[:3, 3] += [0.5, 0.0, 0.0]
        n = viewer.stats["pushes"]
        # the camera moved, the map (same map_rev) and the graph (same content) did not
        viewer.publish(dataclasses.replace(snap, pose=pose, graph=json.loads(json.dumps(snap.graph))))
        assert viewer.wait_until(lambda s: s["pushes"] > n, timeout=20)
        assert viewer.stats["map_pushes"] == 1 and viewer.stats["graph_pushes"] == 1
        assert view.layers._frustum is frustum
        np.testing.assert_allclose(frustum.position, pose[:3, 3])
        viewer.publish(dataclasses.replace(snap, map_rev=snap.map_rev + 1))
        assert viewer.wait_until(lambda s: s["map_pushes"] == 2, timeout=20)


def test_snapshots_without_map_rev_are_compared_by_identity_not_a_reusable_id(open_browser):
    from ogscene3d.viewer.app import LiveViewer

    with LiveViewer(port=0) as viewer:
        view = open_browser(viewer)
        # push is called here directly, as the push thread does (nothing is published, so it idles)
        snap = dataclasses.replace(make_scene(20), map_rev=None)
        view.push(snap, set())
        for seed in range(1, 5):
            # a new map of the same size, built after the shown one was dropped: CPython may give it the
            # shown snapshot's id(), which must not make the viewer take it for the map already shown
            del snap
            snap = dataclasses.replace(make_scene(20, seed=seed), map_rev=None)
            view.push(snap, set())
            assert viewer.stats["map_pushes"] == 1 + seed
            np.testing.assert_allclose(view.layers._gauss_handle.centers, snap.means)
        view.push(snap, set())  # the same snapshot again (e.g. a GUI change): the map is not re-sent
        assert viewer.stats["map_pushes"] == 5
        # Gaussians with NaN are dropped before drawing; the map is still the same snapshot, not re-sent
        means = snap.means.copy()
        means[0] = np.nan
        bad = dataclasses.replace(snap, means=means)
        view.push(bad, set())
        assert viewer.stats["map_pushes"] == 6 and view.layers.shown_gaussians == 59
        for _ in range(3):
            view.push(bad, set())
        assert viewer.stats["map_pushes"] == 6


def test_gui_query_and_selection_update_the_panels(open_browser):
    from ogscene3d.viewer.app import LiveViewer

    with LiveViewer(port=0, max_rate_hz=50) as viewer:
        view = open_browser(viewer)
        viewer.publish(make_scene(20))
        assert viewer.wait_until(lambda s: s["nodes"] == 3, timeout=20)
        assert "| gaussians | 60 |" in view._md_counts.content
        assert "optimize" in view._md_timings.content
        n = viewer.stats["pushes"]
        view._txt_query.value = "Table"  # what typing in the browser does; whole words, as graph -q
        assert viewer.wait_until(lambda s: s["pushes"] > n and "1 match" in view._md_matches.content, 20)
        assert "table" in view._md_matches.content
        assert view._dd_node.options == ("(none)", "#1 table")  # the node list follows the query
        n = viewer.stats["pushes"]
        view._on_node_pick("#1 table")  # picking it in the GUI list
        assert viewer.wait_until(lambda s: s["pushes"] > n and "caption" in view._md_selected.content, 20)
        assert "a test object number 1" in view._md_selected.content
        assert "next to" in view._md_selected.content
        assert len(view.layers._edge_labels) == 2  # the selected node's relations are labelled
        n = viewer.stats["pushes"]
        view.select_node(0)  # a click on a node marker
        assert viewer.wait_until(lambda s: s["pushes"] > n and "sofa" in view._md_selected.content, 20)
        assert view._dd_node.value == "(none)"  # node 0 does not match "table": not in the list
        n = viewer.stats["pushes"]
        view._txt_query.value = "#2"  # a node by id
        assert viewer.wait_until(
            lambda s: s["pushes"] > n and view._dd_node.options == ("(none)", "#2 lamp"), 20
        )
        n = viewer.stats["pushes"]
        view._txt_query.value = ""
        assert viewer.wait_until(lambda s: s["pushes"] > n and len(view._dd_node.options) == 4, 20)
        assert view._dd_node.value == "#0 sofa"
        n = viewer.stats["map_pushes"]
        view._dd_color.value = "Semantic label"
        assert viewer.wait_until(lambda s: s["map_pushes"] > n, 20)
        assert view.settings.color_mode == "semantic"
        assert "sofa (#0)" in view._html_legend.content
        n = viewer.stats["map_pushes"]
        view._dd_render.value = "Points"
        view._sl_point.value = 2.5
        assert viewer.wait_until(lambda s: s["render"] == "points" and s["map_pushes"] > n, 20)
        assert viewer.wait_until(lambda s: view.layers._gauss_handle.point_size == 0.025, 20)


def test_each_browser_keeps_its_own_gui_state(open_browser):
    """A second browser opens with the start settings, not with what the first one chose, and its
    choices do not change the first one's scene."""
    from ogscene3d.viewer.app import LiveViewer

    with LiveViewer(port=0, max_rate_hz=50) as viewer:
        first = open_browser(viewer)
        snap = make_scene(20)
        viewer.publish(snap)
        assert viewer.wait_until(lambda s: s["nodes"] == 3, timeout=20)
        first._dd_color.value = "Semantic label"
        first._txt_query.value = "lamp"
        assert viewer.wait_until(lambda s: "1 match" in first._md_matches.content, 20)
        second = open_browser(viewer)
        assert viewer.wait_until(lambda s: second.layers.shown_gaussians == 60, 20)
        assert second.settings.color_mode == "rgb" and second._dd_color.value == "RGB"
        assert second._txt_query.value == "" and second._md_matches.content == ""
        np.testing.assert_allclose(
            second.layers._gauss_handle.rgbs[:, :3] / 255, snap.colors, atol=1 / 255 + 1e-6
        )
        np.testing.assert_allclose(
            first.layers._gauss_handle.rgbs[:, :3] / 255, label_colors(snap.labels), atol=0.76
        )  # semantic, with the non-matching nodes dimmed
        assert first.layers._highlight_handle is not None and second.layers._highlight_handle is None
        n = viewer.stats["map_pushes"]
        second._dd_color.value = "Confidence"
        assert viewer.wait_until(lambda s: s["map_pushes"] > n, 20)
        assert first.settings.color_mode == "semantic" and first._dd_color.value == "Semantic label"
        assert "lamp" in first._md_matches.content


def test_first_camera_sees_the_whole_map_from_outside(open_browser):
    from ogscene3d.viewer.app import LiveViewer, fit_camera

    up = np.array([0.0, 0.0, 1.0])
    fov = np.deg2rad(75)
    eye, target = fit_camera(np.zeros(3), 4.0, up, fov, view_dir=np.array([0.0, 1.0, 0.0]))
    np.testing.assert_allclose(target, 0.0, atol=1e-12)
    # outside the 4 m sphere, where it fits the field of view with some margin
    assert 2.0 / np.sin(fov / 2) < np.linalg.norm(eye) < 1.3 * 2.0 / np.sin(fov / 2)
    assert abs(eye[0]) < 1e-9 and eye[1] < 0 and eye[2] > 0  # behind the first view direction, above
    # a wide canvas whose right third is under the GUI panel: the map is centred in the left two thirds
    eye2, target2 = fit_camera(
        np.zeros(3), 4.0, up, fov, np.array([0.0, 1.0, 0.0]), aspect=2.0, covered=1 / 3
    )
    fwd = (target2 - eye2) / np.linalg.norm(target2 - eye2)
    rel = -eye2  # the map's centre seen from the camera
    x = (rel @ np.array([1.0, 0.0, 0.0])) / (rel @ fwd)  # its horizontal image coordinate, tan units
    half_w = np.tan(fov / 2) * 2.0
    assert (x / half_w + 1) / 2 == pytest.approx((1 - 1 / 3) / 2)  # middle of the uncovered part
    with LiveViewer(port=0, max_rate_hz=50, up="+z") as viewer:
        view = open_browser(viewer)
        snap = make_scene(200)
        viewer.publish(snap)
        assert viewer.wait_until(lambda s: s["gaussians"] == 600, timeout=20)
        assert viewer.wait_until(lambda s: view.camera_placed, timeout=20)
        lo, hi = np.percentile(snap.means, [2, 98], axis=0)
        for cam_pos, look_at in (
            (view.client.camera.position, view.client.camera.look_at),
            (viewer.server.initial_camera.position, viewer.server.initial_camera.look_at),
        ):
            # the target is the map's centre, slid sideways only (the fake browser is 640 px wide: no panel
            # allowance; the server-wide initial camera has none either)
            np.testing.assert_allclose(look_at, 0.5 * (lo + hi), atol=1e-6)
            assert not np.all((cam_pos > snap.means.min(axis=0)) & (cam_pos < snap.means.max(axis=0)))
            assert np.linalg.norm(cam_pos - look_at) >= 0.5 * np.linalg.norm(hi - lo)


def test_live_session_maps_pauses_saves_and_finishes(open_browser, tmp_path):
    from ogscene3d.viewer.app import LiveViewer
    from ogscene3d.viewer.live import LiveSession

    mapper = FakeMapper(per_frame=40)
    with LiveViewer(port=0, max_rate_hz=100) as viewer:
        view = open_browser(viewer)
        session = LiveSession(mapper, _frames(6), viewer, budget=100, out_dir=tmp_path / "run")
        viewer.set_control(session)
        session.set_paused(True)
        session.start()
        time.sleep(0.5)
        assert mapper.frames_seen == 0 and not session.done  # paused before the first frame
        assert viewer.wait_until(lambda s: view._btn_pause.label == "Resume mapping", timeout=10)
        assert "(paused)" in view._md_status.content and not view._btn_pause.disabled
        view._toggle_pause()  # the GUI button
        assert not session.paused
        assert session.join(30) and session.error is None
        assert mapper.frames_seen == 6 and mapper.finalized
        assert session.saved_to == tmp_path / "run" and (tmp_path / "run" / "gaussians.ply").is_file()
        assert viewer.wait_until(lambda s: s["gaussians"] == 100 and s["nodes"] == 1, timeout=20)
        # mapping is over: nothing to pause any more
        assert viewer.wait_until(lambda s: view._btn_pause.disabled, timeout=10)
        assert view._btn_pause.label == "Mapping finished"
        view._toggle_pause()
        assert not session.paused
        latest = viewer._latest
        assert (
            latest.total_gaussians == 240
            and len(latest.trajectory) == 6
            and latest.status.startswith("finished")
        )
        view._txt_out.value = str(tmp_path / "again")
        view._on_save()  # the GUI's save button, after mapping
        assert (tmp_path / "again" / "gaussians.ply").is_file()
        assert view._md_save.content.startswith("Saved to") and not view._btn_save.disabled
        mapper.save = lambda out: (_ for _ in ()).throw(OSError("disk full"))
        view._on_save()
        assert "Save failed" in view._md_save.content and "disk full" in view._md_save.content


def test_live_session_reports_mapping_errors():
    from ogscene3d.viewer.app import LiveViewer
    from ogscene3d.viewer.live import LiveSession

    mapper = FakeMapper(fail_at=2)
    with LiveViewer(port=0) as viewer:
        session = LiveSession(mapper, _frames(5), viewer).start()
        assert session.join(30)
        assert isinstance(session.error, RuntimeError) and session.status.startswith("error")
        assert viewer._latest is not None and viewer._latest.total_gaussians == 100  # the map so far is shown


# ------------------------------------------------------------------------------ CLI


def test_cli_argument_errors(tmp_path, capsys):
    from ogscene3d.commands.live import main

    assert main([]) == 2
    assert "nothing to show" in capsys.readouterr().err
    assert main([str(tmp_path), "--synthetic"]) == 2
    assert "not both" in capsys.readouterr().err
    assert main([str(tmp_path / "missing"), "--port", "0"]) == 2
    assert "does not exist" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--rate", "0"])


def test_cli_browse_prints_the_bound_url_and_serves(tmp_path):
    import socket
    import urllib.request

    run = _write_run(tmp_path / "run", make_scene(50))
    # Occupy a port so that the viewer has to take another one and report it.
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen(1)
    port = busy.getsockname()[1]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "ogscene3d.commands.live", str(run), "--port", str(port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    try:
        url = None
        lines = []
        deadline = time.monotonic() + 60
        while url is None and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if "open http://" in line:
                url = line.split("open ", 1)[1].split()[0]
        assert url is not None, "".join(lines)
        assert url.startswith("http://127.0.0.1:") and int(url.rsplit(":", 1)[1]) != port
        assert "150 Gaussians, 3 graph nodes" in "".join(lines)
        with urllib.request.urlopen(url, timeout=10) as r:
            assert r.status == 200 and b"<html" in r.read().lower()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0
    finally:
        busy.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.parametrize("port", ["70000", "-5", "http"])
def test_cli_rejects_ports_outside_the_tcp_range(port, capsys):
    from ogscene3d.commands.live import main

    with pytest.raises(SystemExit) as exc:
        main(["run", "--port", port])
    assert exc.value.code == 2 and "--port" in capsys.readouterr().err


def test_check_bindable_follows_viser_port_search():
    import socket

    from ogscene3d.viewer.app import check_bindable

    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen(1)
    port = busy.getsockname()[1]
    try:
        assert check_bindable("127.0.0.1", port) > port  # viser moves on to the next free port
    finally:
        busy.close()
    assert check_bindable("127.0.0.1", 0) == 0
    with pytest.raises(ConfigError, match="0 to 65535"):
        check_bindable("127.0.0.1", 70000)
    with pytest.raises(ConfigError, match="192.0.2.1"):
        check_bindable("192.0.2.1", 8080)  # TEST-NET address: not this machine's


def _ipv6_loopback() -> bool:
    import socket

    try:
        with socket.socket(socket.AF_INET6) as s:
            s.bind(("::1", 0))
        return True
    except OSError:
        return False


@pytest.mark.skipif(not _ipv6_loopback(), reason="no IPv6 loopback")
def test_url_of_an_ipv6_host_is_bracketed():
    import urllib.request

    from ogscene3d.viewer.app import LiveViewer

    with LiveViewer(host="::1", port=0) as viewer:
        assert viewer.url == f"http://[::1]:{viewer.port}"  # was http://::1:PORT, which no browser opens
        with urllib.request.urlopen(viewer.url, timeout=10) as r:
            assert r.status == 200


def test_cli_unbindable_host_is_a_clean_error_not_a_hang(tmp_path):
    """viser binds on its own thread; when that fails the main thread used to wait forever."""
    run = _write_run(tmp_path / "run", make_scene(10))
    proc = subprocess.run(
        [sys.executable, "-m", "ogscene3d.commands.live", str(run), "--host", "192.0.2.1", "--port", "0"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert "ogscene3d-live: error: cannot serve the viewer on 192.0.2.1" in proc.stderr


def test_node_details_name_the_caption_source():
    from ogscene3d.viewer.app import caption_line

    assert caption_line({"caption": "a mug", "caption_source": "vlm-text"}) == (
        "caption (VLM, prose reply instead of JSON): a mug"
    )
    assert caption_line({"caption": "a mug", "caption_source": "vlm"}) == "caption (VLM): a mug"
    assert caption_line({"caption": "a mug"}) == "caption: a mug"


def test_cli_rejects_bad_settings():
    from ogscene3d.commands.live import _settings, build_parser

    args = build_parser().parse_args(["x", "--max-splats", "5"])
    assert _settings(args).max_splats == 5
    args.color = "heat"
    with pytest.raises(ConfigError, match="color mode"):
        _settings(args)


def test_cli_screenshot_without_chromium_is_a_clear_error(monkeypatch, tmp_path, capsys):
    import ogscene3d.commands.live as live
    from ogscene3d.commands.live import main

    monkeypatch.setattr(live, "find_chromium", lambda: None)
    run = _write_run(tmp_path / "run", make_scene(10))
    assert main([str(run), "--port", "0", "--screenshot", str(tmp_path / "x.png")]) == 2
    assert "needs chromium" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()


def test_aborted_browser_handshakes_are_not_logged_as_errors():
    """A speculative browser connection closed before its request (EOF under the handshake error) is
    dropped from the websockets server's log; any other handshake failure, or other message, is kept."""
    import logging

    from ogscene3d.viewer.app import _DropAbortedHandshakes

    def record(msg: str, exc: BaseException | None) -> logging.LogRecord:
        info = (type(exc), exc, None) if exc is not None else None
        return logging.LogRecord("websockets.server", logging.ERROR, __file__, 1, msg, (), info)

    def chained(cause: BaseException) -> BaseException:
        outer = ValueError("did not receive a valid HTTP request")
        outer.__cause__ = RuntimeError("connection closed while reading HTTP request line")
        outer.__cause__.__cause__ = cause
        return outer

    keep = _DropAbortedHandshakes().filter
    assert not keep(record("opening handshake failed", chained(EOFError("stream ends after 0 bytes"))))
    assert keep(record("opening handshake failed", chained(ValueError("bad header"))))
    assert keep(record("opening handshake failed", None))
    assert keep(record("connection handler failed", chained(EOFError())))


def test_find_box_and_graph_query_are_one_function():
    """The viewer's Find gives the nodes ``ogscene3d graph -q`` gives (SceneGraph.query), synonyms too."""
    from ogscene3d.graph import SceneGraph
    from ogscene3d.viewer.app import LiveViewer

    graph = make_scene(5, objects=4).graph
    g = SceneGraph.from_json(graph)
    with LiveViewer(port=0) as viewer:
        for q in ("couch", "table", "object", "#3", "giraffe"):
            assert viewer.find(graph, q) == ([n.id for n in g.query(q)], g.ask(q).message)
        assert viewer.find(graph, "couch")[0] == [0]  # the sofa, by synonym (a substring match finds none)
        assert "no known object, relation or room term" in viewer.find(graph, "giraffe")[1]
        ids, error = viewer.find({"version": 1, "nodes": [{"id": 1, "center": [0, 0, 0]}], "edges": []}, "x")
        assert ids == [] and "Find is unavailable" in error and "bbox_min" in error


def test_node_panel_gives_the_captions_size_and_the_box_apart():
    from ogscene3d.viewer.app import node_details

    node = {
        "id": 4,
        "tag": "gray object",
        "caption": "medium gray object, about 78 cm (geometric heuristic)",
        "caption_source": "heuristic",
        "center": [0, 0, 0],
        "extent": [0.78, 0.5, 0.31],
        "bbox_min": [0, 0, 0],
        "bbox_max": [1.41, 0.9, 1.02],
    }
    text = node_details({"nodes": [node], "edges": []}, 4)
    assert "size: 0.78 x 0.50 x 0.31 m" in text and "box: 1.41 x 0.90 x 1.02 m" in text
    assert "about 78 cm" in text
    assert "size:" not in node_details({"nodes": [{k: v for k, v in node.items() if k != "extent"}]}, 4)
    assert node_details(None, None).startswith("*Pick")


def _rooms_graph(snap: MapSnapshot) -> dict:
    """``snap``'s graph with two rooms: x < 1.8 (the first two objects) and x > 1.9 (the third)."""
    from ogscene3d.graph.rooms import RoomNode

    def room(i, kind, x0, x1, objects):
        # on the floor at y = 1 (height -1 along the world up -y), under the objects
        corners = np.array([[x0, 1, -1], [x1, 1, -1], [x1, 1, 1], [x0, 1, 1]], dtype=np.float64)
        return RoomNode(i, 0, [corners], (x1 - x0) * 2, corners.mean(0), corners.min(0), corners.max(0),
                        type=kind, objects=objects).to_dict()  # fmt: skip

    return {
        **snap.graph,
        "up": [0.0, -1.0, 0.0],
        "floors": [{"id": 0, "height": -1.0, "top": None}],
        "rooms": [room(1, "kitchen", -0.6, 1.8, [0, 1]), room(2, "office", 1.9, 3.0, [2])],
    }


def test_rooms_outlines_room_colours_and_legend(server):
    from ogscene3d.colors import room_colors

    snap = make_scene(50)
    graph = _rooms_graph(snap)
    layers = SceneLayers(server)
    st = ViewerSettings(color_mode="room")
    layers.update_map(snap, st, None, graph, np.array([0.0, -1.0, 0.0]))
    rgb = layers._gauss_handle.rgbs.astype(float) / 255
    first, third = snap.means[:, 0] < 1.5, snap.means[:, 0] > 2.1
    np.testing.assert_allclose(rgb[first], np.tile(room_colors(np.array([1])), (first.sum(), 1)), atol=0.01)
    np.testing.assert_allclose(rgb[third], np.tile(room_colors(np.array([2])), (third.sum(), 1)), atol=0.01)
    layers.update_rooms(graph, st)
    assert layers.shown_rooms == 2 and len(layers._room_handles) == 4  # outline + label per room
    handles = list(layers._room_handles)
    layers.update_rooms(json.loads(json.dumps(graph)), st)  # same rooms: nothing re-sent
    assert layers._room_handles == handles
    layers.apply_visibility(dataclasses.replace(st, show_rooms=False))
    assert not any(h.visible for h in layers._room_handles)
    html = legend_html("room", graph)
    assert "kitchen (room #1, 2 objects)" in html and "office" in html and "in no room" in html
    assert "no rooms yet" in legend_html("room", snap.graph)
    layers.update_rooms({**graph, "rooms": [{"id": "bad"}]}, st)  # malformed rooms: none drawn, no error
    assert layers.shown_rooms == 0


def test_find_answers_relations_and_rooms():
    from ogscene3d.viewer.app import LiveViewer

    graph = _rooms_graph(make_scene(5, objects=3))
    with LiveViewer(port=0) as viewer:
        assert viewer.find(graph, "office") == ([2], "")  # a room stands for the nodes in it
        assert viewer.find(graph, "table in the kitchen")[0][0] == 1
        answer, error = viewer.answer(graph, "lamp in the office")
        assert error == "" and answer.hits[0].id == 2 and "room #2 'office'" in answer.hits[0].reason
