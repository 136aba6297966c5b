import json
from pathlib import Path

import numpy as np
import pytest
import torch
from mapping_scenes import F, H, W, _config, _frame

from ogscene3d.config import load_config
from ogscene3d.errors import ConfigError, DataError, OGSceneError
from ogscene3d.frame import Frame
from ogscene3d.mapping.keyframes import KeyframeSelector
from ogscene3d.mapping.mapper import Mapper


def test_labels_stay_consistent_across_frames(device):
    m = Mapper(_config("mapping.ablation=local"), device)
    for i, ids in enumerate([(1, 2), (7, 3), (2, 9)]):  # per-frame ids are arbitrary
        assert m.process(_frame(i, ids))
    gm = m.map
    labels = gm.labels.cpu()
    assert len(gm) > 0 and int(gm.origin_kf.max()) >= 1  # later keyframes added the newly seen strip
    assert sorted(torch.unique(labels).tolist()) == [0, 1]
    left = gm.means[:, 0].cpu() < -0.05
    right = gm.means[:, 0].cpu() > 0.05
    assert len(set(labels[left].tolist())) == 1 and len(set(labels[right].tolist())) == 1
    assert labels[left][0] != labels[right][0]
    # matched observations raised the confidences above their initial rescaled SAM scores
    assert float(gm.confidences[left].max()) > 0.5 + 0.5 * (0.97 - 0.88) / 0.12 + 1e-3
    c = m.timings.as_dict()["counts"]
    assert c["keyframes"] == 3 and c["segments_matched"] == 4 and c["segments_novel"] == 2


def test_naive_confidences_are_one(device):
    m = Mapper(_config("mapping.ablation=naive"), device)
    for i in range(2):
        m.process(_frame(i))
    assert torch.all(m.map.confidences[m.map.labels >= 0] == 1.0)


def test_keyframe_rule():
    sel = KeyframeSelector(every=3)
    assert [sel(np.eye(4)) for _ in range(7)] == [True, False, False, True, False, False, True]
    sel = KeyframeSelector(every=0, translation=0.1)
    poses = [np.eye(4) for _ in range(4)]
    for i, p in enumerate(poses):
        p[0, 3] = 0.06 * i
    assert [sel(p) for p in poses] == [True, False, True, False]
    with pytest.raises(ValueError):
        KeyframeSelector(every=0)


def test_save_and_resume(tmp_path, device):
    cfg = _config("mapping.ablation=local+global", "mapping.refine.every=2")
    m = Mapper(cfg, device)
    for i in range(2):
        m.process(_frame(i))
    m.save(tmp_path)
    for name in ("gaussians.ply", "map.npz", "graph.json", "timings.json", "config.yaml"):
        assert (tmp_path / name).is_file(), name
    timings = json.loads((tmp_path / "timings.json").read_text())
    assert timings["calls"]["refine"] == 1 and timings["counts"]["keyframes"] == 2
    graph = json.loads((tmp_path / "graph.json").read_text())
    assert graph["version"] == 1 and {n["label"] for n in graph["nodes"]} == {0, 1}

    r = Mapper(cfg, device)
    r.load_checkpoint(tmp_path / "map.npz")
    assert (r.frames_seen, r.keyframe_count, len(r.memory)) == (2, 2, len(m.memory))
    torch.testing.assert_close(r.map.means, m.map.means)
    assert r.map.next_label == m.map.next_label
    r.process(_frame(2, (4, 5)))
    m.process(_frame(2, (4, 5)))
    assert torch.equal(r.map.labels, m.map.labels)


def test_geometry_only_without_segments(device):
    m = Mapper(_config("segmentation.backend=none"), device)
    m.process(_frame(0, with_segments=False))
    assert len(m.map) > 0 and torch.all(m.map.labels == -1)


def test_frames_without_segments_fall_back_to_the_classical_segmenter(device):
    m = Mapper(_config(), device)  # backend "precomputed", but the frame has none
    m.process(_frame(0, with_segments=False))
    assert type(m.segmenter).__name__ == "ClassicalSegmenter"
    assert len(m.map) > 0 and bool((m.map.labels >= 0).any())


def test_bad_input(device):
    with pytest.raises(ConfigError, match="ablation"):
        Mapper(_config("mapping.ablation=everything"), device)
    m = Mapper(_config(), device)
    f = _frame(0)
    f.pose = None
    with pytest.raises(DataError, match="no camera pose.*--poses odometry"):
        m.process(f)
    with pytest.raises(DataError, match="map.npz"):
        m.load_checkpoint(Path("/nonexistent/map.npz"))


def test_negative_segment_ids_are_no_segment(device):
    """-1 for background (a common segmenter convention) means no segment, as 0 does: the same map."""
    ref = Mapper(_config(), device)
    ref.process(_frame(0))
    f = _frame(0)
    f.segments = f.segments.copy()
    f.segments[:, :3] = 0
    g = _frame(0)
    g.segments = f.segments.copy()
    g.segments[:, :3] = -1
    maps = []
    for frame in (f, g):
        m = Mapper(_config(), device)
        m.process(frame)
        maps.append(m.map)
    assert torch.equal(maps[0].labels, maps[1].labels) and torch.equal(maps[0].means, maps[1].means)
    assert sorted(torch.unique(maps[1].labels).tolist()) == [-1, 0, 1]


class _Segmenter:
    def __init__(self, ids):
        self.ids = ids

    def __call__(self, rgb, depth=None):
        from ogscene3d.segmentation.base import Segmentation

        return Segmentation(self.ids, {1: 0.95})


@pytest.mark.parametrize(
    "ids, match",
    [
        (np.ones((H // 2, W // 2), np.int32), r"_Segmenter gave segment ids of shape \(12, 16\)"),
        (np.ones((W, H), np.int32), r"shape \(32, 24\), the image is \(24, 32\)"),
        (np.ones((H, W), np.float32), "dtype float32"),
    ],
)
def test_a_segmenters_bad_output_is_named(ids, match):
    m = Mapper(_config(), "cpu", segmenter=_Segmenter(ids))
    with pytest.raises(DataError, match=match):
        m.process(_frame(0, with_segments=False))


def test_depth_in_millimetres_warns(caplog):
    f = _frame(0)
    f.depth = f.depth * 1000.0
    m = Mapper(_config(), "cpu")
    with caplog.at_level("WARNING", logger="ogscene3d.mapping.mapper"):
        m.process(f)
        m.process(_frame(1))
    warned = [r.message for r in caplog.records if "implausible" in r.message]
    assert len(warned) == 1 and "frame 0 (f0): median depth 2e+03 m" in warned[0]
    assert "metres" in warned[0]


@pytest.mark.parametrize(
    "override, match",
    [
        ("graph.captioner.kind=opnai", "graph.captioner.kind"),
        ("graph.relations.kind=llm", "no model name configured"),
    ],
)
def test_a_mistake_in_the_graph_settings_stops_the_mapper_before_any_frame(override, match):
    with pytest.raises((ConfigError, OGSceneError), match=match):
        Mapper(load_config(None, [override]), "cpu")
    # with the graph off its settings do not matter
    Mapper(load_config(None, [override, "graph.enabled=false"]), "cpu")


def test_full_ablation_runs_longterm_and_refinement(device):
    cfg = _config("mapping.ablation=full", "mapping.refine.every=2", "mapping.longterm.every=2")
    m = Mapper(cfg, device)
    for i, ids in enumerate([(1, 2), (3, 4), (5, 6), (7, 8)]):
        m.process(_frame(i, ids))
    m.finalize()
    t = m.timings.as_dict()
    assert t["calls"]["longterm"] == 3 and t["calls"]["refine"] == 3  # keyframes 2, 4 and finalize
    # each keyframe's time per module; the end of stream's passes only in the totals
    series = t["per_keyframe_ms"]
    assert t["per_keyframe_frame"] == [0, 1, 2, 3] and len(t["per_keyframe_cpu_ms"]["local"]) == 4
    assert len(series["local"]) == 4 and all(v > 0 for v in series["local"])
    assert [v > 0 for v in series["longterm"]] == [False, True, False, True]
    assert sum(series["refine"]) < 1000 * t["seconds"]["refine"]
    assert t["counts"]["longterm_updated"] > 0
    # the memory views each keyframe's long-term pass judged (the finalize pass only in the total)
    judged = t["per_keyframe_counts"]["memory_views"]
    assert judged[0] == judged[2] == 0 and 1 <= judged[1] <= judged[3] <= cfg.mapping.longterm.views
    assert judged[1] + judged[3] < t["counts"]["longterm_views"]
    assert sorted(torch.unique(m.map.labels).tolist()) == [0, 1]
    assert bool(((m.map.confidences >= 0) & (m.map.confidences <= 1)).all())


def test_scene_graph_is_fed(tmp_path, device):
    cfg = load_config(
        None,
        ["mapping.optimize.iters=1", "mapping.association.knn_radius=0.1", "graph.init_keyframes=2",
         "graph.update_every=1",
         "graph.min_gaussians=5"],
    )  # fmt: skip
    m = Mapper(cfg, device)
    for i in range(3):
        m.process(_frame(i, (1 + i, 5 + i)))
    m.finalize()
    m.save(tmp_path)
    assert m.timings.counts.get("graph_errors", 0) == 0
    # the final graph update is timed with the per-keyframe ones, the final pruning on its own
    assert m.timings.calls["graph"] == 3 + 1 and m.timings.calls["prune"] == 1
    graph = json.loads((tmp_path / "graph.json").read_text())
    assert {n["id"] for n in graph["nodes"]} == {0, 1}


@pytest.mark.parametrize("up, warns", [("[0,-1,0]", False), ("[0,0,1]", True)])
def test_an_up_axis_far_from_the_cameras_up_warns(up, warns, caplog):
    """_frame's cameras are upright OpenCV cameras (world up -y): a z-up setting is named, with the fix."""
    cfg = _config(
        "graph.enabled=true", "graph.init_keyframes=1", "graph.min_gaussians=5", f"graph.up_axis={up}"
    )
    m = Mapper(cfg, "cpu")
    with caplog.at_level("WARNING", logger="ogscene3d.mapping.mapper"):
        m.process(_frame(0))
    warned = [r.message for r in caplog.records if "graph.up_axis" in r.message]
    assert bool(warned) == warns
    if warns:
        assert "90 deg" in warned[0] and "-y-up, set --set graph.up_axis=[0,-1,0]" in warned[0]


def test_detector_class_names_become_node_tags(tmp_path):
    """Segments a detector named (Frame.segment_names, from precomputed segments or a sam+detector
    segmenter) name the scene labels they were given: the offline captions take them as tags."""
    cfg = load_config(
        None,
        ["mapping.optimize.iters=1", "mapping.association.knn_radius=0.1", "graph.init_keyframes=2",
         "graph.update_every=1",
         "graph.min_gaussians=5"],
    )  # fmt: skip
    m = Mapper(cfg, "cpu")
    for i in range(3):
        f = _frame(i, (1 + i, 5 + i))
        f.segment_names = {1 + i: "sofa"} if i != 1 else {1 + i: "sofa", 5 + i: "lamp"}  # the right one once
        m.process(f)
    m.finalize()
    m.save(tmp_path)
    nodes = json.loads((tmp_path / "graph.json").read_text())["nodes"]
    by_tag = {n["tag"]: n for n in nodes}
    assert set(by_tag) == {"sofa", "lamp"}
    assert all(n["caption_source"] == "detector" for n in nodes)
    assert by_tag["sofa"]["caption"].startswith("sofa (detector class); ")
    left = m.map.means[:, 0].cpu() < -0.05
    assert by_tag["sofa"]["id"] == int(m.map.labels.cpu()[left][0])
    # the votes go on after a resume: the next update names the nodes as before
    r = Mapper(cfg, "cpu")
    r.load_checkpoint(tmp_path / "map.npz")
    r.process(_frame(3, (4, 8)))
    r.finalize()
    assert sorted((n.tag, n.caption_source) for n in r.graph.nodes.values()) == [
        ("lamp", "detector"),
        ("sofa", "detector"),
    ]


def test_checkpoint_state_and_write_order(tmp_path, monkeypatch, caplog):
    m = Mapper(_config("mapping.checkpoint_every=1"), "cpu")
    m.set_checkpoint_dir(tmp_path)
    m.process(_frame(0))
    m.rng.random(5)
    # a full disk at a periodic checkpoint: a warning, and mapping goes on
    real = Mapper.save_checkpoint
    monkeypatch.setattr(Mapper, "save_checkpoint", lambda self, p: (_ for _ in ()).throw(OSError(28, "full")))
    with caplog.at_level("WARNING", logger="ogscene3d.mapping.mapper"):
        assert m.process(_frame(1))
    assert any("checkpoint not written" in r.message for r in caplog.records)
    assert m.timings.counts["checkpoint_errors"] == 1

    def first(self, path):
        # the resumable state (config.yaml, map.npz) comes before every export (#31: a full disk at the
        # final save left gaussians.ply and no map.npz); a finished map whose exports are missing or older
        # gets them written again by `run --resume` (test_mapping_cli)
        assert (tmp_path / "config.yaml").is_file()
        assert not {p.name for p in tmp_path.iterdir()} & {"gaussians.ply", "graph.json", "timings.json"}
        real(self, path)

    monkeypatch.setattr(Mapper, "save_checkpoint", first)
    m.finalize()
    m.save(tmp_path)
    r = Mapper(_config(), "cpu")
    r.load_checkpoint(tmp_path / "map.npz")
    assert r.rng.random() == m.rng.random()  # the random stream goes on where it was


def test_resume_keeps_the_scene_graph(tmp_path):
    cfg = load_config(
        None,
        ["mapping.optimize.iters=1", "mapping.association.knn_radius=0.1", "graph.init_keyframes=2",
         "graph.update_every=2",
         "graph.min_gaussians=5", "graph.background=false"],
    )  # fmt: skip
    m = Mapper(cfg, "cpu")
    for i in range(3):
        m.process(_frame(i, (1 + i, 5 + i)))
    m.save_checkpoint(tmp_path / "map.npz")
    saved = m.graph.to_json()
    assert saved["nodes"] and m.graph.num_updates == 1
    r = Mapper(cfg, "cpu")
    r.load_checkpoint(tmp_path / "map.npz")
    assert r.graph is not None and r.graph.to_json() == saved
    assert r.graph.is_due(3) and not r.graph.is_due(2)  # the schedule goes on: updates at keyframes 1, 3, ...
    r.process(_frame(3, (4, 8)))
    assert r.graph.num_updates == 2
    assert {n["id"]: n["first_seen"] for n in saved["nodes"]}.items() <= {
        n.id: n.first_seen for n in r.graph.nodes.values()
    }.items()


def test_odometry_poses_replace_the_dataset_poses(tmp_path):
    pytest.importorskip("open3d")  # the RGB-D odometry; absent only on bare benchmark machines
    from ogscene3d.datasets import make_synthetic_scene, open_dataset

    # 60 frames spread the default trajectory (~5 m) at ~9 cm per frame; map the first 6
    scene = make_synthetic_scene(tmp_path / "scene", seed=0, frames=60, width=96, height=72, progress=False)
    cfg = _config("tracking.poses=odometry", "mapping.optimize.iters=1")
    m = Mapper(cfg, "cpu")
    frames = list(open_dataset(scene, max_frames=6))
    gt = [f.pose.copy() for f in frames]
    for f in frames:
        m.process(f)
    assert m.timings.calls["tracking"] == len(frames)
    tracked = [i for i, f in enumerate(frames) if not np.allclose(f.pose, gt[i])]
    # the first frame keeps its pose (it anchors the trajectory); later ones are estimated, close to truth
    assert np.allclose(frames[0].pose, gt[0])
    assert len(tracked) >= 1
    for i in tracked:
        assert np.linalg.norm(frames[i].pose[:3, 3] - gt[i][:3, 3]) < 0.05
    assert len(m.map) > 0


def test_resumed_odometry_goes_on_in_the_same_trajectory(tmp_path):
    """A sequence without poses: odometry anchors at the identity, and a run resumed from the checkpoint
    tracks the next frames in the same coordinates as the uninterrupted run (the tracker's keyframe is in
    the checkpoint), not from a new anchor."""
    pytest.importorskip("open3d")
    from ogscene3d.datasets import make_synthetic_scene, open_dataset

    scene = make_synthetic_scene(tmp_path / "scene", seed=0, frames=60, width=96, height=72, progress=False)
    ds = open_dataset(scene, max_frames=6)

    def posed_by_odometry(i: int) -> Frame:
        frame = ds[i]
        frame.pose = None
        return frame

    cfg = _config("tracking.poses=odometry", "mapping.optimize.iters=1")
    whole = Mapper(cfg, "cpu")
    for i in range(4):
        whole.process(posed_by_odometry(i))
    whole.save(tmp_path / "run")
    resumed = Mapper(cfg, "cpu")
    resumed.load_checkpoint(tmp_path / "run" / "map.npz")
    assert resumed.next_index == 4
    for i in (4, 5):
        a, b = posed_by_odometry(i), posed_by_odometry(i)
        whole.process(a)
        resumed.process(b)
        assert b.pose is not None and not np.allclose(b.pose, np.eye(4), atol=1e-3)
        np.testing.assert_allclose(b.pose, a.pose, atol=1e-4)


def test_odometry_resumed_from_a_checkpoint_without_tracker_state_warns(tmp_path, caplog):
    m = Mapper(_config(), "cpu")
    for i in range(2):
        m.process(_frame(i))
    m.save(tmp_path)
    with caplog.at_level("WARNING", logger="ogscene3d.mapping.mapper"):
        Mapper(_config("tracking.poses=odometry"), "cpu").load_checkpoint(tmp_path / "map.npz")
    assert any("no tracker state" in r.message for r in caplog.records)


def _gap_frame(i: int) -> Frame:
    """``_frame``'s wall without depth within 35 cm of x = 0, so that its two objects lie apart in space (the
    test's r_search is 30 cm: Gaussians here are 17 cm apart); the first view's segment holds both (a first
    view that merged an object with its neighbour)."""
    f = _frame(i, (1, 1) if i == 0 else (1, 2))
    u = (np.arange(W) + 0.5 - W / 2) / F * 2.0 + 0.2 * i
    f.depth[:, np.abs(u) < 0.35] = 0.0
    f.segments[:, np.abs(u) < 0.35] = 0
    return f


@pytest.mark.parametrize("evidence", [True, False])
def test_the_evidence_gives_two_objects_a_first_view_merged_labels_of_their_own(device, evidence):
    cfg = _config(
        "mapping.ablation=full", "mapping.refine.every=2", "mapping.longterm.every=2",
        "mapping.refine.r_search=0.3",
        f"mapping.evidence.enabled={str(evidence).lower()}",
    )  # fmt: skip
    m = Mapper(cfg, device)
    for i in range(6):
        m.process(_gap_frame(i))
    m.finalize()
    gm = m.map
    x, labels = gm.means[:, 0].cpu(), gm.labels.cpu()
    left, right = labels[x < -0.35], labels[x > 0.35]
    assert left.numel() and right.numel()
    assert len(set(left.tolist())) == 1 and len(set(right.tolist())) == 1
    assert (left[0] != right[0]) == evidence
    counts = m.timings.as_dict()["counts"]
    assert (counts.get("evidence_new_labels", 0) >= 1) == evidence
