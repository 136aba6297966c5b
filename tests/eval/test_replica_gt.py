"""Replica's own semantic ground truth (``habitat/mesh_semantic.ply`` + ``info_semantic.json``), read as
HOV-SG reads it: one point per face corner, the class of the face's object."""

import json
import logging

import numpy as np
import pytest
from eval_runs import GAUSSIAN_DTYPE, _main, _write_ply

from ogscene3d.errors import DataError
from ogscene3d.eval import evaluate_run, load_ground_truth
from ogscene3d.eval.metrics import resolve_ignore

CLASSES = [
    {"id": 1, "name": "chair"},
    {"id": 2, "name": "table"},
    {"id": 3, "name": "wall"},
    {"id": 4, "name": "wall-plug"},
    {"id": 5, "name": "indoor-plant"},
    {"id": 6, "name": "floor"},
]


def write_semantic_ply(path, vertices, faces, object_ids, object_id_type="ushort", text=False):
    """Replica's layout: float x y z nx ny nz, uchar red green blue; faces ``list uchar int
    vertex_indices`` and an integer ``object_id``. Faces of mixed sizes are written too (a general file)."""
    vertices = np.asarray(vertices, np.float32)
    v = np.zeros(
        len(vertices),
        [(n, "<f4") for n in ("x", "y", "z", "nx", "ny", "nz")]
        + [(c, "u1") for c in ("red", "green", "blue")],
    )
    v["x"], v["y"], v["z"] = vertices.T
    v["nz"] = 1.0
    head = (
        f"ply\nformat {'ascii' if text else 'binary_little_endian'} 1.0\ncomment Replica-like\n"
        f"element vertex {len(v)}\n"
        + "".join(f"property float {n}\n" for n in ("x", "y", "z", "nx", "ny", "nz"))
        + "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        + f"element face {len(faces)}\nproperty list uchar int vertex_indices\n"
        + (f"property {object_id_type} object_id\n" if object_ids is not None else "")
        + "end_header\n"
    )
    oid_dt = {"ushort": "<u2", "int": "<i4", "uint": "<u4"}[object_id_type]
    with open(path, "wb") as fh:
        fh.write(head.encode())
        if text:
            for r in v:
                fh.write((" ".join(str(x) for x in r) + "\n").encode())
            for i, f in enumerate(faces):
                oid = "" if object_ids is None else f" {object_ids[i]}"
                fh.write((f"{len(f)} " + " ".join(map(str, f)) + oid + "\n").encode())
            return
        fh.write(v.tobytes())
        for i, f in enumerate(faces):
            fh.write(np.array([len(f)], "u1").tobytes() + np.asarray(f, "<i4").tobytes())
            if object_ids is not None:
                fh.write(np.array([object_ids[i]], oid_dt).tobytes())


def write_info(path, objects, classes=CLASSES):
    objs = [{"id": o, "class_id": c, "class_name": "?", "oriented_bbox": {}} for o, c in objects]
    path.write_text(json.dumps({"classes": classes, "objects": objs, "id_to_label": []}))


@pytest.fixture
def two_quads(tmp_path):
    """Quads A (object 11, chair) and B (object 12, wall) share the edge 1-4; quad C has object 99, which
    info_semantic.json does not list."""
    scene = tmp_path / "room_0"
    (scene / "habitat").mkdir(parents=True)
    verts = [[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0], [3, 0, 0], [3, 1, 0]]
    faces = [[0, 1, 4, 3], [1, 2, 5, 4], [2, 6, 7, 5]]
    write_semantic_ply(scene / "habitat" / "mesh_semantic.ply", verts, faces, [11, 12, 99])
    write_info(scene / "habitat" / "info_semantic.json", [(11, 1), (12, 3), (13, 2)])
    (scene / "mesh.ply").write_bytes(b"")  # the textured mesh beside habitat/: not ground truth
    return scene


def test_points_repeat_each_vertex_per_face_with_its_face_class(two_quads):
    gt = load_ground_truth(two_quads)
    assert gt.points.shape == (12, 3)
    # face after face, each of its corners: the shared vertices 1 and 4 appear once per face
    assert gt.points[:, 0].tolist() == [0, 1, 1, 0, 1, 2, 2, 1, 2, 3, 3, 2]
    names = [gt.class_names[c] for c in gt.classes]
    assert names == ["chair"] * 4 + ["wall"] * 4 + ["background"] * 4  # object 99: not listed
    assert gt.class_ids == [0, 1, 2, 3, 4, 5, 6] and gt.class_names[0] == "background"
    assert gt.instances.tolist() == [11] * 4 + [12] * 4 + [99] * 4
    idx = gt.class_names.index
    assert gt.instance_classes == {11: idx("chair"), 12: idx("wall"), 99: idx("background")}
    assert gt.relations == [] and gt.observed is None and gt.has_3d
    # Replica's 2D class ids translate through the same table
    assert gt.class_index_of_ids([3, 0, 7]).tolist() == [idx("wall"), 0, -1]


def test_scene_folder_habitat_folder_and_ply_give_the_same_ground_truth(two_quads):
    a = load_ground_truth(two_quads)
    for p in (two_quads / "habitat", two_quads / "habitat" / "mesh_semantic.ply"):
        b = load_ground_truth(p)
        np.testing.assert_array_equal(a.points, b.points)
        np.testing.assert_array_equal(a.classes, b.classes)
        np.testing.assert_array_equal(a.instances, b.instances)
        assert a.class_names == b.class_names and b.source.endswith("mesh_semantic.ply")


def test_mixed_face_sizes_and_ascii_take_the_general_reader(tmp_path, two_quads):
    from ogscene3d.eval.replica_gt import read_face_mesh

    fast = read_face_mesh(two_quads / "habitat" / "mesh_semantic.ply")
    assert fast.fast_path and fast.face_sizes.tolist() == [4, 4, 4]
    hab = tmp_path / "mixed" / "habitat"
    hab.mkdir(parents=True)
    verts = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0]]
    write_semantic_ply(hab / "mesh_semantic.ply", verts, [[0, 1, 2, 3], [1, 4, 2]], [11, 12], "int")
    write_info(hab / "info_semantic.json", [(11, 1), (12, 2)])
    mesh = read_face_mesh(hab / "mesh_semantic.ply")
    assert not mesh.fast_path and mesh.face_sizes.tolist() == [4, 3]
    gt = load_ground_truth(hab.parent)
    assert gt.points[:, 0].tolist() == [0, 1, 1, 0, 1, 2, 1]
    assert [gt.class_names[c] for c in gt.classes] == ["chair"] * 4 + ["table"] * 3
    txt = tmp_path / "text" / "habitat"
    txt.mkdir(parents=True)
    write_semantic_ply(txt / "mesh_semantic.ply", verts, [[0, 1, 2, 3]], [12], text=True)
    write_info(txt / "info_semantic.json", [(12, 2)])
    gt = load_ground_truth(txt / "mesh_semantic.ply")
    assert [gt.class_names[c] for c in gt.classes] == ["table"] * 4


def test_missing_info_json_or_object_ids_are_errors_naming_the_file(tmp_path, two_quads, caplog):
    (two_quads / "habitat" / "info_semantic.json").unlink()
    with pytest.raises(DataError, match=r"habitat/info_semantic\.json: missing"):
        load_ground_truth(two_quads)
    hab = tmp_path / "noid" / "habitat"
    hab.mkdir(parents=True)
    write_semantic_ply(hab / "mesh_semantic.ply", [[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 1, 2]], None)
    write_info(hab / "info_semantic.json", [(1, 1)])
    with pytest.raises(
        DataError, match=r"noid/habitat/mesh_semantic\.ply: face property 'object_id' missing"
    ):
        load_ground_truth(hab)
    write_semantic_ply(hab / "mesh_semantic.ply", [[0, 0, 0]], [[0, 1, 2]], [1])
    with pytest.raises(DataError, match=r"mesh_semantic\.ply: face vertex indices outside \[0, 1\)"):
        load_ground_truth(hab)
    (hab / "info_semantic.json").write_text(json.dumps({"classes": CLASSES}))
    with pytest.raises(DataError, match=r"info_semantic\.json: expected an 'objects' list"):
        load_ground_truth(hab)
    # an object whose class is not in the table is void, and said so
    write_semantic_ply(hab / "mesh_semantic.ply", [[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 1, 2]], [1])
    write_info(hab / "info_semantic.json", [(1, 77)])
    with caplog.at_level(logging.WARNING):
        gt = load_ground_truth(hab)
    assert gt.classes.tolist() == [-1, -1, -1] and "class_id (77)" in caplog.text


def _with_comments(src, dst, n):
    """``src`` with ``n`` comment lines after its first comment (one of them naming end_header, which only
    the end_header line itself may end the header on)."""
    data = src.read_bytes()
    at = data.index(b"comment Replica-like\n") + len(b"comment Replica-like\n")
    extra = b"comment this line mentions end_header but does not end it\n"
    extra += b"".join(b"comment padding line %06d of a long header\n" % i for i in range(n))
    dst.parent.mkdir(parents=True, exist_ok=True)
    dst.write_bytes(data[:at] + extra + data[at:])
    (dst.parent / "info_semantic.json").write_bytes((src.parent / "info_semantic.json").read_bytes())
    return len(data[:at] + extra) + data[at:].index(b"end_header\n") + len(b"end_header\n")


@pytest.mark.parametrize("text", [False, True])
def test_a_header_longer_than_64_kib_reads_as_without_its_comments(tmp_path, text):
    from ogscene3d.eval.replica_gt import read_face_mesh

    verts = [[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0], [3, 0, 0], [3, 1, 0]]
    short = tmp_path / "short" / "habitat" / "mesh_semantic.ply"
    short.parent.mkdir(parents=True)
    write_semantic_ply(short, verts, [[0, 1, 4, 3], [1, 2, 5, 4], [2, 6, 7, 5]], [11, 12, 99], text=text)
    write_info(short.parent / "info_semantic.json", [(11, 1), (12, 3)])
    long = tmp_path / "long" / "habitat" / "mesh_semantic.ply"
    header_bytes = _with_comments(short, long, 3000)
    assert header_bytes > 1 << 17  # past the 64 KiB the header parser used to read
    a, b = read_face_mesh(short), read_face_mesh(long)
    assert a.fast_path == b.fast_path == (not text)
    for field in ("vertices", "face_sizes", "indices", "object_ids"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    ga, gb = load_ground_truth(short.parent.parent), load_ground_truth(long.parent.parent)
    np.testing.assert_array_equal(ga.points, gb.points)
    np.testing.assert_array_equal(ga.classes, gb.classes)
    np.testing.assert_array_equal(ga.instances, gb.instances)
    assert ga.class_names == gb.class_names
    assert [gb.class_names[c] for c in gb.classes] == ["chair"] * 4 + ["wall"] * 4 + ["background"] * 4


def test_truncated_or_missing_ply_header_is_an_error_naming_the_file(tmp_path, two_quads, monkeypatch):
    from ogscene3d.eval import replica_gt

    ply = two_quads / "habitat" / "mesh_semantic.ply"
    data = ply.read_bytes()
    cut = tmp_path / "cut" / "mesh_semantic.ply"
    cut.parent.mkdir()
    cut.write_bytes(data[: data.index(b"end_header")])  # ends inside the header
    with pytest.raises(DataError, match=r"cut/mesh_semantic\.ply: truncated PLY header: the file ends after"):
        replica_gt.read_face_mesh(cut)
    cut.write_bytes(data[: data.index(b"end_header") + 7])  # "end_hea": not the end_header line
    with pytest.raises(DataError, match=r"cut/mesh_semantic\.ply: truncated PLY header"):
        replica_gt.read_face_mesh(cut)
    cut.write_bytes(b"\x00\x01binary" * 100)
    with pytest.raises(DataError, match=r"cut/mesh_semantic\.ply: not a PLY file"):
        replica_gt.read_face_mesh(cut)
    # a header past the bound is refused without reading on to the end of the file
    long = tmp_path / "long" / "habitat" / "mesh_semantic.ply"
    header_bytes = _with_comments(ply, long, 200)
    monkeypatch.setattr(replica_gt, "MAX_HEADER_BYTES", header_bytes - 1)
    with pytest.raises(
        DataError,
        match=rf"long/habitat/mesh_semantic\.ply: no 'end_header' line in the first "
        rf"{header_bytes - 1} bytes",
    ):
        replica_gt.read_face_mesh(long)
    monkeypatch.setattr(replica_gt, "MAX_HEADER_BYTES", header_bytes)
    assert replica_gt.read_face_mesh(long).object_ids.tolist() == [11, 12, 99]


def test_hovsg_replica_preset_ignores_hovsgs_classes(two_quads):
    gt = load_ground_truth(two_quads)
    idx, unknown = resolve_ignore(["preset:hovsg-replica"], gt.class_names)
    # HOV-SG: -1, 0 and every name containing wall/floor/ceiling/door/window/background
    assert sorted(gt.class_names[i] for i in idx) == [
        "background",
        "floor",
        "indoor-plant",
        "wall",
        "wall-plug",
    ]
    assert unknown == []


def _mesh_scene(tmp_path):
    """A 1 m x 0.5 m floor of 5 cm quads: chair (object 1) where x < 0.5, table (2) where x >= 0.5, a wall
    (3) along y >= 0.45 and an unlisted object (40) at the far corner."""
    n_x, n_y, q = 20, 10, 0.05
    ys, xs = np.meshgrid(np.arange(n_y + 1) * q, np.arange(n_x + 1) * q, indexing="ij")
    verts = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    faces, oids = [], []
    for j in range(n_y):
        for i in range(n_x):
            a = j * (n_x + 1) + i
            faces.append([a, a + 1, a + n_x + 2, a + n_x + 1])
            oids.append(3 if j == n_y - 1 else 40 if (i, j) == (n_x - 1, 0) else 1 if i < n_x // 2 else 2)
    scene = tmp_path / "Replica" / "room_0"
    (scene / "habitat").mkdir(parents=True)
    write_semantic_ply(scene / "habitat" / "mesh_semantic.ply", verts, faces, oids)
    write_info(scene / "habitat" / "info_semantic.json", [(1, 1), (2, 2), (3, 3)])
    return scene


def test_eval_cli_scores_a_run_lying_on_the_replica_mesh(tmp_path, monkeypatch, capsys):
    scene = _mesh_scene(tmp_path)
    # Gaussians on the mesh every 1 cm: label 7 (tag chair) where x < 0.5, 8 (table) elsewhere, 9 (wall)
    xs, ys = np.meshgrid(np.arange(0.0, 1.0, 0.01) + 0.005, np.arange(0.0, 0.5, 0.01) + 0.005)
    run = tmp_path / "run"
    run.mkdir()
    g = np.zeros(xs.size, dtype=GAUSSIAN_DTYPE)
    g["x"], g["y"] = xs.ravel(), ys.ravel()
    g["opacity"], g["rot_0"], g["confidence"] = 4.0, 1.0, 0.9
    g["label"] = np.where(ys.ravel() >= 0.45, 9, np.where(xs.ravel() < 0.5, 7, 8))
    _write_ply(run / "gaussians.ply", g)
    nodes = [{"id": i, "label": i, "tag": t} for i, t in ((7, "chair"), (8, "table"), (9, "wall"))]
    (run / "graph.json").write_text(json.dumps({"version": 1, "nodes": nodes, "edges": []}))
    argv = ["eval", str(run), "--gt", str(scene), "--ignore", "preset:hovsg-replica", "--no-plots"]
    assert _main(argv, monkeypatch) == 0
    out = capsys.readouterr().out
    assert "protocol: hovsg" in out
    report = json.loads((run / "metrics.json").read_text())
    h = report["semantic_3d"]["hovsg"]
    assert sorted(h["ignored_classes"]) == ["background", "floor", "indoor-plant", "wall", "wall-plug"]
    per = {c["name"]: c for c in h["per_class"]}
    assert sorted(n for n, c in per.items() if c["evaluated"]) == ["chair", "table"]
    # support counts face corners: 9 rows of 10 quads each (the table's less the unlisted object's quad)
    assert per["chair"]["support"] == 4 * 90 and per["table"]["support"] == 4 * 89
    assert per["wall"]["support"] == 4 * 20 and per["background"]["support"] == 4
    assert per["chair"]["iou"] > 0.8 and per["table"]["iou"] > 0.8
    assert h["miou"] == pytest.approx((per["chair"]["iou"] + per["table"]["iou"]) / 2)
    assert report["label_mapping"]["method"] == "text"
    res = evaluate_run(run, scene, protocols=["hovsg"], ignore=["preset:hovsg-replica"], mapping="overlap")
    assert res.label_to_class == {7: 1, 8: 2, 9: 3}  # named through the object ids (instances)
