"""runs/record.py: the up vector a run was configured with (config.yaml's ``graph.up_axis``)."""

from __future__ import annotations

import logging

import numpy as np

from ogscene3d.runs import recorded_up


def _config(tmp_path, up_axis: str) -> None:
    (tmp_path / "config.yaml").write_text(f"graph:\n  up_axis: {up_axis}\n")


def test_recorded_up_is_the_configured_vector_made_unit(tmp_path):
    _config(tmp_path, "[0, 0, 5]")
    assert np.allclose(recorded_up(tmp_path), [0.0, 0.0, 1.0])


def test_recorded_up_auto_is_the_cameras_up(tmp_path):
    _config(tmp_path, "auto")
    assert recorded_up(tmp_path) is None  # no cameras: no up
    poses = np.repeat(np.eye(4)[None], 3, axis=0)  # upright OpenCV cameras: up is -y
    assert np.allclose(recorded_up(tmp_path, poses), [0.0, -1.0, 0.0])


def test_recorded_up_without_a_config_or_a_readable_value_is_none(tmp_path, caplog):
    assert recorded_up(tmp_path) is None
    _config(tmp_path, "[0, 0, 0]")
    with caplog.at_level(logging.WARNING):
        assert recorded_up(tmp_path) is None
    assert "no readable graph.up_axis" in caplog.text
