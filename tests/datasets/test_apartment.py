"""Synthetic apartments: rooms of distinct types with their furniture, the room of every instance, doorways,
a camera that walks from room to room, and the scene folder's room ground truth."""

import json

import numpy as np
import pytest

from ogscene3d.cli import main
from ogscene3d.datasets import load_instances, make_synthetic_scene, open_dataset
from ogscene3d.datasets.apartment import (
    DOOR_WIDTH,
    ROOM_TYPES,
    apartment_camera,
    build_apartment,
    rooms_entered,
)
from ogscene3d.datasets.procedural import STRUCTURAL_CLASSES
from ogscene3d.datasets.synthetic import apartment_trajectory

CUES = {
    "bedroom": {"bed"},
    "bathroom": {"toilet", "bathtub"},
    "living room": {"sofa"},
    "kitchen": {"refrigerator", "stove"},
    "office": {"desk"},
}


@pytest.mark.parametrize("seed", range(10))
def test_rooms_of_distinct_types_with_their_furniture(seed):
    apt = build_apartment(seed)
    assert 2 <= len(apt.rooms) <= 5
    kinds = [r.type for r in apt.rooms]
    assert len(set(kinds)) == len(kinds) and set(kinds) <= set(ROOM_TYPES)
    assert set(apt.instance_room) == {o.instance_id for o in apt.objects}
    assert len(apt.doors) == len(apt.rooms) - 1
    for r in apt.rooms:
        mine = [o for o in apt.objects if apt.instance_room[o.instance_id] == r.id]
        classes = [o.class_name for o in mine]
        assert classes.count("floor") == 1 and classes.count("ceiling") == 1 and classes.count("wall") == 4
        assert CUES[r.type] & set(classes), (r.type, classes)
        # every instance lies in its room's interior (walls and floor reach 5 cm beyond it)
        for o in apt.zup_objects:
            if apt.instance_room[o.instance_id] != r.id:
                continue
            lo, hi = o.aabb
            assert np.all(lo[:2] >= r.zup_min - 0.051) and np.all(hi[:2] <= r.zup_max + 0.051), o.class_name
    # supports stay in the room: nothing rests on another room's furniture
    for o in apt.objects:
        if o.support is not None:
            assert apt.instance_room[o.support] == apt.instance_room[o.instance_id]
    assert all(r[1] in ("on", "in", "attached to", "above", "next to") for r in apt.relations)


def test_the_same_seed_gives_the_same_apartment():
    a, b, c = build_apartment(3), build_apartment(3), build_apartment(4)
    assert np.array_equal(a.vertices, b.vertices) and a.instance_room == b.instance_room
    assert len(a.vertices) != len(c.vertices) or not np.array_equal(a.vertices, c.vertices)


def test_doorways_are_open_in_both_walls():
    apt = build_apartment(0)
    for ra, rb, xy in apt.doors:
        # no part of any object blocks the doorway between 0.1 m and 2 m height
        for o in apt.zup_objects:
            for p in o.parts:
                lo, hi = p.aabb
                inside = (
                    lo[0] < xy[0] + 0.06
                    and hi[0] > xy[0] - 0.06
                    and lo[1] < xy[1] + DOOR_WIDTH / 2 - 0.01
                    and hi[1] > xy[1] - DOOR_WIDTH / 2 + 0.01
                    and lo[2] < 2.0
                    and hi[2] > 0.1
                )
                assert not inside, (o.class_name, ra, rb)


@pytest.mark.parametrize("seed", [0, 4, 9])
def test_the_camera_walks_from_room_to_room_clear_of_furniture(seed):
    apt = build_apartment(seed)
    poses = apartment_trajectory(apt, 50, seed)
    assert len(poses) == 50 * len(apt.rooms)
    R = poses[:, :3, :3]
    assert np.allclose(R @ R.transpose(0, 2, 1), np.eye(3), atol=1e-9)
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    assert steps.max() <= 0.35 + 1e-9
    cosang = np.einsum("nij,nij->n", R[1:], R[:-1])  # trace(R_i^T R_{i+1})
    assert np.rad2deg(np.arccos(np.clip((cosang - 1) / 2, -1, 1))).max() <= 20.0 + 1e-6
    entered = rooms_entered(apt, poses)
    assert list(entered) == [r.id for r in apt.rooms] and entered[apt.rooms[0].id] == 0
    assert list(entered.values()) == sorted(entered.values())
    xyz, _, _ = apartment_camera(apt, 50, seed)
    boxes = [p.aabb for o in apt.zup_objects if o.class_name not in STRUCTURAL_CLASSES for p in o.parts]
    for lo, hi in boxes:
        if lo[2] > 2.0:
            continue
        gap = np.maximum(np.maximum(lo[:2] - xyz[:, :2], xyz[:, :2] - hi[:2]), 0.0)
        assert np.linalg.norm(gap, axis=1).min() > 0.3


def test_too_few_frames_name_how_many_are_needed():
    apt = build_apartment(0)
    with pytest.raises(ValueError, match=r"needs at least \d+ frames per room"):
        apartment_camera(apt, 5, 0)


@pytest.mark.slow
def test_apartment_scene_folder_has_rooms(tmp_path, capsys):
    out = tmp_path / "apt"
    assert main(["synth", "--out", str(out), "--layout", "apartment", "--seed", "5", "--frames", "30",
                 "--size", "48x36"]) == 0  # fmt: skip
    assert "(60 frames, an apartment," in capsys.readouterr().out
    gt = load_instances(out / "gt" / "instances.json")
    apt = build_apartment(5)
    assert set(gt["rooms"]) == {r.id for r in apt.rooms}
    assert {k: v["type"] for k, v in gt["rooms"].items()} == {r.id: r.type for r in apt.rooms}
    assert all(v["room"] == apt.instance_room[k] for k, v in gt["instances"].items())
    assert [v["first_frame"] for v in gt["rooms"].values()][0] == 0
    assert json.loads((out / "scene.json").read_text())["layout"] == "apartment"
    ds = open_dataset(out)
    assert len(ds) == 60 and ds.kind == "synthetic"
    # the same arguments reuse the folder (another layout would not: it is part of scene.json)
    stamp = (out / "traj.txt").stat().st_mtime_ns
    make_synthetic_scene(out, 5, 30, 48, 36, layout="apartment")
    assert (out / "traj.txt").stat().st_mtime_ns == stamp
    with pytest.raises(ValueError, match="layout"):
        make_synthetic_scene(tmp_path / "x", 0, 4, 48, 36, layout="castle")
