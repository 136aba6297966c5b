"""Storeys and rooms segmented from hand-built point clouds (floor plans with walls and doorways), kept
across updates, typed from their objects, and stored in graph.json / GraphML."""

import json

import numpy as np
import pytest
from graph_scenes import blob_map, box_surface, plane, to_world, walls_with_doors

from ogscene3d.config import GraphConfig, RoomsConfig
from ogscene3d.errors import DataError
from ogscene3d.graph import MeanConfidence, SceneGraph
from ogscene3d.graph.captioner import HeuristicCaptioner
from ogscene3d.graph.rooms import (
    RoomMap,
    RuleRoomTyper,
    assign_rooms,
    find_floors,
    read_rooms,
    room_type_of,
    segment_rooms,
)

UPS = [(0.0, 0.0, 1.0), (0.0, -1.0, 0.0)]


def room_points(x0, x1, y0, y1, rng, H=2.6, doors=(), z=0.0, furniture=True):
    """Floor, walls (doorways open) and some furniture of one room, its floor at height ``z`` (z-up)."""
    pts = [plane([x0, y0, 0.0], [x1, y1, 0.0], rng, 400.0), walls_with_doors(x0, x1, y0, y1, H, rng, doors)]
    if furniture:  # a cabinet against a wall and a table in the middle: furniture must not split the room
        pts.append(box_surface([x0, y0, 0.0], [x0 + 0.8, y0 + 0.45, 0.8], rng, 800.0))
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        pts.append(box_surface([cx - 0.5, cy - 0.4, 0.7], [cx + 0.5, cy + 0.4, 0.75], rng, 800.0))
    return np.concatenate(pts) + [0.0, 0.0, z]


def two_rooms(rng, H=2.6, z=0.0, door=True):
    """Rooms [0, 4] x [0, 4] and [4.1, 7.6] x [0, 4] (walls back to back), joined by a doorway at y = 2."""
    doors_a = [("+x", 2.0)] if door else []
    doors_b = [("-x", 2.0)] if door else []
    a = room_points(0.0, 4.0, 0.0, 4.0, rng, H, doors_a, z)
    b = room_points(4.1, 7.6, 0.0, 4.0, rng, H, doors_b, z)
    return a, b


@pytest.mark.parametrize("up", UPS)
def test_two_rooms_joined_by_a_doorway_are_two_rooms(up):
    rng = np.random.default_rng(0)
    a, b = two_rooms(rng)
    pts = to_world(np.concatenate([a, b]), up)
    seg = segment_rooms(pts, np.asarray(up), RoomsConfig())
    assert len(seg.floors) == 1 and abs(seg.floors[0].height) < 0.05
    assert len(seg.room_cells) == 2
    areas = sorted(seg.room_area)
    assert areas[0] == pytest.approx(3.5 * 4.0, rel=0.15) and areas[1] == pytest.approx(16.0, rel=0.15)
    # every point of each room lands in that room: its walls too (they lie outside the outlines)
    rm = RoomMap(RoomsConfig())
    rm.update(0, pts, np.asarray(up), {})
    which = assign_rooms(pts, np.asarray(up), rm.floors, list(rm.rooms.values()))
    wa, wb = which[: len(a)], which[len(a) :]
    ra, rb = np.bincount(wa[wa >= 0]).argmax(), np.bincount(wb[wb >= 0]).argmax()
    assert ra != rb
    assert (wa == ra).mean() > 0.97 and (wb == rb).mean() > 0.97


def test_an_opening_wider_than_a_door_makes_one_room():
    """An open-plan space: the dividing wall stops 1.6 m short of the far wall (wider than door_width)."""
    rng = np.random.default_rng(1)
    pts = [plane([0, 0, 0], [8, 4, 0], rng, 400.0), walls_with_doors(0, 8, 0, 4, 2.6, rng)]
    pts.append(plane([4, 0, 0], [4, 2.4, 2.6], rng, 300.0))  # the partial wall
    seg = segment_rooms(np.concatenate(pts), np.array([0, 0, 1.0]), RoomsConfig())
    assert len(seg.room_cells) == 1
    seg = segment_rooms(np.concatenate(pts), np.array([0, 0, 1.0]), RoomsConfig(door_width=1.8))
    assert len(seg.room_cells) == 2  # a wider door_width reads the 1.6 m opening as a doorway


def test_a_single_room_scan_is_one_room_and_a_tiny_map_none():
    rng = np.random.default_rng(2)
    pts = room_points(0, 5, 0, 4, rng)
    seg = segment_rooms(pts, np.array([0, 0, 1.0]), RoomsConfig())
    assert len(seg.room_cells) == 1
    # a few Gaussians, or none: storeys at most, no room, no error
    for few in (pts[:30], np.zeros((0, 3))):
        seg = segment_rooms(few, np.array([0, 0, 1.0]), RoomsConfig())
        assert seg.room_cells == []
    rm = RoomMap(RoomsConfig())
    rm.update(0, np.zeros((0, 3)), np.array([0, 0, 1.0]), {})
    assert rm.rooms == {} and rm.to_dict() == {"floors": [], "rooms": []}


def test_storeys_from_heights():
    rng = np.random.default_rng(3)
    ground = np.concatenate(
        [room_points(0, 5, 0, 4, rng, H=2.6), plane([0, 0, 2.6], [5, 4, 2.6], rng, 300.0)]
    )
    upper = room_points(0, 5, 0, 4, rng, H=2.5, z=2.9)  # over a 0.3 m slab
    floors = find_floors(np.concatenate([ground, upper])[:, 2], RoomsConfig())
    assert [round(f.height, 1) for f in floors] == [0.0, 2.9]
    assert floors[0].top == pytest.approx(2.8, abs=0.06) and floors[1].top is None
    # one storey with its ceiling seen: the ceiling is no floor (nothing stands on it)
    assert len(find_floors(ground[:, 2], RoomsConfig())) == 1
    seg = segment_rooms(np.concatenate([ground, upper]), np.array([0, 0, 1.0]), RoomsConfig())
    assert sorted(seg.room_floor) == [0, 1]


def test_room_ids_stay_while_the_map_grows():
    """The first room keeps its id and first_seen as it grows; the next room gets a new id."""
    rng = np.random.default_rng(4)
    a, b = two_rooms(rng)
    up = np.array([0, 0, 1.0])
    rm = RoomMap(RoomsConfig())
    part = a[(a[:, 0] < 2.5)]  # half of room A explored
    rm.update(3, part, up, {}, frame=6)
    assert len(rm.rooms) == 1
    (rid,) = rm.rooms
    rm.update(7, np.concatenate([a, b[b[:, 0] < 5.5]]), up, {}, frame=14)
    rm.update(11, np.concatenate([a, b]), up, {}, frame=22)
    assert len(rm.rooms) == 2 and rid in rm.rooms
    assert rm.rooms[rid].first_seen == 3 and rm.rooms[rid].first_frame == 6
    (other,) = set(rm.rooms) - {rid}
    assert rm.rooms[other].first_seen in (7, 11) and rm.rooms[other].last_updated == 11
    # loaded back from graph.json (outlines only), the next update keeps the ids
    again = RoomMap(RoomsConfig())
    again.load(json.loads(json.dumps(rm.to_dict())), "test", up)
    again.update(15, np.concatenate([a, b]), up, {})
    assert set(again.rooms) == set(rm.rooms)


def test_objects_go_in_the_room_holding_most_of_them_and_name_it():
    rng = np.random.default_rng(5)
    a, b = two_rooms(rng)
    up = np.array([0, 0, 1.0])
    bed = box_surface([0.5, 2.5, 0.0], [2.0, 3.9, 0.5], rng, 500.0)
    stove = box_surface([6.8, 3.3, 0.0], [7.5, 3.9, 0.9], rng, 500.0)
    fridge = box_surface([4.2, 3.2, 0.0], [4.9, 3.9, 1.8], rng, 500.0)
    rm = RoomMap(RoomsConfig())
    objects = {
        1: (bed, "bed"),
        2: (stove, "stove"),
        3: (fridge, "fridge"),
        4: (np.array([[50.0, 0, 0]]), "cup"),
    }
    rm.update(0, np.concatenate([a, b, bed, stove, fridge]), up, objects)
    assert set(rm.object_room) == {1, 2, 3}  # the far-away cup is in no room
    assert rm.object_room[2] == rm.object_room[3] != rm.object_room[1]
    assert rm.rooms[rm.object_room[1]].type == "bedroom"
    assert rm.rooms[rm.object_room[2]].type == "kitchen" and rm.rooms[rm.object_room[2]].type_source == "rule"
    assert (
        "refrigerator" in rm.rooms[rm.object_room[2]].type_reason
        or "fridge" in rm.rooms[rm.object_room[2]].type_reason
    )


def test_rule_typer():
    t = RuleRoomTyper()
    assert t.describe(["bed", "pillow", "lamp"])[0] == "bedroom"
    assert t.describe(["couch", "television"])[0] == "living room"  # synonyms count
    assert t.describe(["toilet", "sink"])[0] == "bathroom"
    assert t.describe(["desk", "monitor", "chair"])[0] == "office"
    assert t.describe(["pillow"])[0] == "room"  # a weak cue names no room
    assert t.describe(["cabinet", "cabinet"])[0] == "room"  # nor a generic word for furniture
    assert t.describe([])[0] == "room"
    assert room_type_of("Lounge") == "living room" and room_type_of("study") == "office"
    assert room_type_of("garage") is None


def test_scene_graph_rooms_in_json_graphml_and_old_files(tmp_path):
    import networkx as nx

    rng = np.random.default_rng(6)
    a, b = two_rooms(rng)
    up = [0.0, -1.0, 0.0]
    room_pts = to_world(np.concatenate([a, b]), up)
    g = SceneGraph(GraphConfig(), captioner=HeuristicCaptioner(), node_confidence=MeanConfidence())
    bed = to_world(box_surface([0.5, 2.5, 0.0], [2.0, 3.9, 0.5], rng, 2000.0), up)
    means = np.concatenate([room_pts, bed])
    labels = np.concatenate([np.full(len(room_pts), -1), np.full(len(bed), 7)]).astype(np.int32)
    g.update(11, means, labels, np.full(len(means), 0.8))
    assert len(g.rooms) == 2 and len(g.floors) == 1
    assert g.nodes[7].room in g.rooms and 7 in g.rooms[g.nodes[7].room].objects
    path = tmp_path / "graph.json"
    g.save(path)
    doc = json.loads(path.read_text())
    assert {r["id"] for r in doc["rooms"]} == set(g.rooms) and doc["up"] == up
    assert all(len(r["outline"]) >= 1 and len(r["outline"][0][0]) == 3 for r in doc["rooms"])
    h = SceneGraph.load(path)
    assert h.to_json() == g.to_json()
    gml = tmp_path / "g.graphml"
    h.save_graphml(gml)
    G = nx.read_graphml(gml)
    kinds = nx.get_node_attributes(G, "kind")
    assert sorted(kinds.values()).count("room") == 2 and sorted(kinds.values()).count("floor") == 1
    rid = g.nodes[7].room
    assert G.edges["7", f"room_{rid}"]["relation"] == "in"
    assert G.edges[f"room_{rid}", "floor_0"]["relation"] == "in"
    # a graph.json written before rooms existed still loads (no rooms)
    del doc["rooms"], doc["floors"], doc["up"]
    old = SceneGraph.from_json(doc)
    assert old.rooms == {} and set(old.nodes) == set(g.nodes)
    with pytest.raises(DataError, match="room #0"):
        SceneGraph.from_json({**json.loads(path.read_text()), "rooms": [{"id": 1}]})


def test_rooms_update_between_graph_updates():
    """Rooms update every rooms.update_every keyframes, before the graph's first update too."""
    cfg = GraphConfig()
    cfg.rooms.update_every = 4
    g = SceneGraph(cfg, captioner=HeuristicCaptioner(), node_confidence=MeanConfidence())
    ran = [kf for kf in range(12) if g.update(kf, *blob_map([0, 1]))]
    assert ran == [3, 7, 11] and g.num_updates == 1  # the graph's own update at 11 updates the rooms too
    off = GraphConfig()
    off.rooms.enabled = False
    g = SceneGraph(off, captioner=HeuristicCaptioner(), node_confidence=MeanConfidence())
    assert [kf for kf in range(12) if g.is_due(kf)] == [11] and "rooms" not in g.to_json()


def test_a_large_map_is_read_through_a_subset():
    rng = np.random.default_rng(8)
    a, b = two_rooms(rng)
    pts = np.concatenate([a, b])
    full, sub = RoomMap(RoomsConfig()), RoomMap(RoomsConfig(max_points=20_000))
    full.update(0, pts, np.array([0, 0, 1.0]), {})
    sub.update(0, pts, np.array([0, 0, 1.0]), {})
    assert len(pts) > 40_000 and len(sub.rooms) == len(full.rooms) == 2
    for rid, r in full.rooms.items():
        assert sub.rooms[rid].num_gaussians == pytest.approx(r.num_gaussians, rel=0.05)
        assert sub.rooms[rid].area == pytest.approx(r.area, rel=0.05)


def test_an_llm_typer_is_asked_only_when_the_update_may():
    """Room updates between graph updates keep the model's room types (and ask the rule for new rooms)."""
    from ogscene3d.graph.rooms import LLMRoomTyper

    class Client:
        calls = 0

        def chat(self, messages, max_tokens=None):
            Client.calls += 1
            return '{"type": "bedroom", "reason": "a bed"}'

    rng = np.random.default_rng(9)
    a, b = two_rooms(rng)
    up = np.array([0, 0, 1.0])
    bed = box_surface([0.5, 2.5, 0.0], [2.0, 3.9, 0.5], rng, 500.0)
    rm = RoomMap(RoomsConfig(), typer=LLMRoomTyper(Client()))
    rm.update(0, np.concatenate([a, b, bed]), up, {1: (bed, "bed")}, ask_model=False)
    assert Client.calls == 0 and {r.type_source for r in rm.rooms.values()} == {"rule"}
    rm.update(1, np.concatenate([a, b, bed]), up, {1: (bed, "bed")})
    assert Client.calls == 1  # the room with the bed (the empty one needs no model)
    typed = rm.rooms[rm.object_room[1]]
    assert (typed.type, typed.type_source) == ("bedroom", "llm")
    rm.update(2, np.concatenate([a, b, bed]), up, {1: (bed, "big bed")}, ask_model=False)
    assert Client.calls == 1 and rm.rooms[typed.id].type_source == "llm"


def test_read_rooms_takes_the_graphs_up_from_graph_up():
    up, floors, rooms = read_rooms({"nodes": [], "edges": [], "up": [0, -3, 0]})
    assert np.allclose(up, [0.0, -1.0, 0.0]) and floors == [] and rooms == []
    assert read_rooms({"nodes": [], "edges": []})[0] is None
    with pytest.raises(DataError, match="shown graph: 'up'"):
        read_rooms({"up": [0, 0, 0]}, "the shown graph")
