"""runs/graph_json.py: the up vector a scene graph was built with (graph.json's ``up``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ogscene3d.errors import DataError
from ogscene3d.runs import graph_up, read_graph_json
from ogscene3d.up_axis import PROVISIONAL_UP


def test_graph_up_reads_the_graphs_up_as_a_unit_vector(tmp_path):
    p = tmp_path / "graph.json"
    p.write_text(json.dumps({"nodes": [], "edges": [], "up": [0, 0, 2]}))
    assert np.allclose(graph_up(read_graph_json(p)), [0.0, 0.0, 1.0])


def test_graph_up_of_a_graph_without_one_is_the_default_given():
    assert graph_up({"nodes": []}) is None
    assert np.allclose(graph_up({"nodes": []}, default=PROVISIONAL_UP), PROVISIONAL_UP)


@pytest.mark.parametrize("bad", [[0, 0, 0], [1, 2], [0, float("nan"), 1], "z"])
def test_graph_up_names_the_file_for_a_bad_up(bad):
    with pytest.raises(DataError, match=r"run/graph\.json: 'up' must be a finite non-zero 3-vector"):
        graph_up({"up": bad}, "run/graph.json")
