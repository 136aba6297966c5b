"""The ablation benchmark's instance scores and the offline view-consensus yardstick, on hand-built cases."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from ogscene3d.eval.readers import GroundTruth

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
_instances = pytest.importorskip("_instances")
yardstick = pytest.importorskip("yardstick")


def three_boxes() -> GroundTruth:
    """Three instances of 100 points each, 1 m apart on x: a floor (1), a table (2), a cup (3)."""
    rng = np.random.default_rng(0)
    pts = np.concatenate([rng.uniform(0, 0.3, (100, 3)) + [x, 0, 0] for x in (0.0, 1.0, 2.0)])
    inst = np.repeat([1, 2, 3], 100)
    return GroundTruth(
        points=pts, classes=inst - 1, class_names=["floor", "table", "cup"], instances=inst,
        instance_classes={1: 0, 2: 1, 3: 2},
    )  # fmt: skip


def test_instance_miou_hungarian():
    gt = three_boxes()
    exact = _instances.instance_scores(gt.points, gt.instances * 10, gt)
    assert exact["miou"] == pytest.approx(1.0)
    assert exact["matched"] == {1: 10, 2: 20, 3: 30}
    # table and cup under one label: one of them matched (IoU 0.5), the other unmatched (0)
    merged = np.where(gt.instances == 3, 2, gt.instances)
    m = _instances.instance_scores(gt.points, merged, gt)
    assert m["miou"] == pytest.approx((1.0 + 0.5 + 0.0) / 3, abs=0.02)
    # the floor split in two labels by x: its best half matches, the other half is a false positive
    split = gt.instances.copy()
    split[(gt.instances == 1) & (gt.points[:, 0] > 0.15)] = 9
    s = _instances.instance_scores(gt.points, split, gt)
    assert 0.3 < s["iou"][1] < 0.7 and s["iou"][2] == pytest.approx(1.0)
    assert _instances.recovered(s["iou"], {2: "absorbed/merged", 7: "cut/missed"}) == (1, 1)  # 7 unscored
    unmatched = 3 if m["iou"][2] > 0 else 2
    assert _instances.recovered(m["iou"], {unmatched: "absorbed/merged"}) == (0, 1)


def test_class_miou_names_labels_by_overlap():
    gt = three_boxes()
    assert _instances.class_miou(gt.points, gt.instances + 5, gt, which="all") == pytest.approx(1.0)


def test_consensus_edges_and_components():
    # 4 masks over 5 frames: containers per frame (-2 not seen, -1 seen but in no mask)
    cont = np.array(
        [
            [7, 7, 8, -2, 9],  # mask 0
            [7, 7, 8, -1, 9],  # mask 1: always with mask 0 -> consensus 1
            [7, 5, 6, 4, 3],  # mask 2: with mask 0 in 1 of 4 shared frames
            [-2, -2, -2, -2, 3],  # mask 3: one shared frame only (< MIN_VIEWS)
        ]
    )
    edges = yardstick.consensus_edges(cont, 0.9)
    assert edges.tolist() == [[0, 1]]
    assert yardstick.consensus_edges(cont, 0.25).tolist() == [[0, 1], [0, 2], [1, 2]]
    comp = yardstick._components(4, edges)
    assert comp[0] == comp[1] and len({comp[1], comp[2], comp[3]}) == 3


def test_voxels_go_to_the_most_specific_claim():
    """A cup's voxel is covered by the table's cluster in 2 frames and by the cup's in 2: the smaller cup
    cluster wins; a table voxel only the table covers stays table."""
    cup = np.array([0.01, 0.01, 0.01])
    table = np.array([0.51, 0.01, 0.01])
    points = np.array([cup, cup, cup, cup, table, table, table, table, table])
    cluster = np.array([0, 0, 1, 1, 0, 0, 0, 0, 0])  # 0: table (7 points), 1: cup (2)
    frame = np.array([0, 1, 2, 3, 0, 1, 2, 3, 4])
    centres, lab = yardstick.assign_voxels(points, cluster, frame)
    at = {tuple(np.floor(c / yardstick.VOXEL).astype(int)): int(v) for c, v in zip(centres, lab)}
    assert at[tuple(np.floor(cup / yardstick.VOXEL).astype(int))] == 1
    assert at[tuple(np.floor(table / yardstick.VOXEL).astype(int))] == 0
