"""Logging while a progress bar runs: each message on a line of its own, not glued onto the bar."""

from __future__ import annotations

import contextlib
import logging
import re
import sys

from ogscene3d.progress import progress

log = logging.getLogger("ogscene3d.test_progress")


def _segments(text: str) -> list[str]:
    """What a terminal would show on separate lines (a carriage return starts the line over)."""
    return [s for s in re.split(r"[\r\n]", text) if s.strip()]


@contextlib.contextmanager
def console_logging():
    """A console handler on the root logger, as the CLI's logging.basicConfig installs, on the stderr that
    capsys has in place while the test runs (not yet while fixtures are set up)."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    root.addHandler(handler)
    try:
        yield handler
    finally:
        root.removeHandler(handler)


def test_warnings_logged_inside_a_bar_get_their_own_line(capsys):
    with console_logging() as handler:
        with progress(range(3), desc="mapping", total=3) as frames:
            for i in frames:
                log.warning("falling back to the classical segmenter (%d)", i)
                frames.set_postfix(kf=i)
        # the handler is the console's again once the bar is closed
        assert handler in logging.getLogger().handlers
    err = capsys.readouterr().err
    lines = _segments(err)
    messages = [s for s in lines if "falling back" in s]
    assert len(messages) == 3
    for s in messages:
        assert s.startswith("WARNING ogscene3d.test_progress: falling back"), repr(s)
        assert "mapping:" not in s
    assert any("mapping: 100%" in s for s in lines)


def test_without_logging_setup_warnings_still_show_on_their_own_line(capsys, monkeypatch):
    root = logging.getLogger()
    monkeypatch.setattr(root, "handlers", [])
    with progress(range(2), desc="track") as frames:
        for _ in frames:
            log.warning("frame skipped")
            log.info("not shown: below the last-resort level")
    err = capsys.readouterr().err
    messages = [s for s in _segments(err) if "frame skipped" in s]
    assert messages == ["frame skipped", "frame skipped"]
    assert "not shown" not in err
    assert root.handlers == []


def test_disabled_bar_passes_the_items_through(capsys):
    with progress(iter([1, 2]), desc="x", disable=True) as items:
        assert list(items) == [1, 2]
    assert "x:" not in capsys.readouterr().err


# ------------------------------------------------------------------------------------- the run-time estimate


class _Mapper:
    def __init__(self, device: str) -> None:
        self.device = device


class _Frame:
    width, height = 1200, 680


def test_the_second_keyframe_gives_the_runs_estimate_and_on_a_cpu_what_to_change(caplog):
    from ogscene3d.progress import RunTimeEstimate

    est = RunTimeEstimate(frames=2000, keyframe_every=5, scale=1.0, opt_iters=10)
    with caplog.at_level(logging.INFO, logger="ogscene3d.progress"):
        # the first keyframe (kernels compiling, no earlier keyframe to optimise with) says nothing yet
        est.keyframe(_Mapper("cpu"), _Frame(), 20.0)
        assert est.said is None and not caplog.records
        est.keyframe(_Mapper("cpu"), _Frame(), 120.0)
        est.keyframe(_Mapper("cpu"), _Frame(), 1.0)  # said once, from the first two keyframes
    (record,) = caplog.records
    assert record.levelno == logging.WARNING
    text = record.getMessage()
    assert "the first keyframes took 20.0 s and 120.0 s on cpu at 1200x680" in text
    # 20 s + 399 x 120 s
    assert "the run's 400 keyframes will take about 13 h 18 min" in text
    # the largest scale in steps of 0.05 that fits 10 minutes (0.086 here), but not below 0.25
    assert "map on a GPU (--device cuda)" in text
    assert "--set data.scale=0.25 (16x fewer pixels: about 50 min)" in text
    assert "--set mapping.optimize.iters=3" in text


def test_a_scale_just_below_one_names_its_fraction_of_fewer_pixels(caplog):
    from ogscene3d.progress import RunTimeEstimate

    est = RunTimeEstimate(frames=20, keyframe_every=1, scale=1.0, opt_iters=10)
    with caplog.at_level(logging.INFO, logger="ogscene3d.progress"):
        est.keyframe(_Mapper("cpu"), _Frame(), 30.0)
        est.keyframe(_Mapper("cpu"), _Frame(), 35.0)  # 30 s + 19 x 35 s, 11.6 min: 0.9 brings it under 10
    text = caplog.records[0].getMessage()
    assert "--set data.scale=0.9 (1.2x fewer pixels: about 9 min)" in text


def test_a_short_or_gpu_run_is_only_told_its_estimate(caplog):
    from ogscene3d.progress import RunTimeEstimate

    with caplog.at_level(logging.INFO, logger="ogscene3d.progress"):
        cpu = RunTimeEstimate(frames=60, keyframe_every=2)
        gpu = RunTimeEstimate(frames=2000, keyframe_every=0)
        for seconds in (4.0, 2.9):
            cpu.keyframe(_Mapper("cpu"), _Frame(), seconds)
        for seconds in (30.0, 2.0):  # the first keyframe's kernel compilation is not the run's rate
            gpu.keyframe(_Mapper("cuda:0"), _Frame(), seconds)
    assert [r.getMessage() for r in caplog.records] == [cpu.said, gpu.said]
    assert all(r.levelno == logging.INFO for r in caplog.records)
    assert cpu.said.endswith("the run's 30 keyframes will take about 88 s") and "to go faster" not in cpu.said
    assert "up to 2000 keyframes (by camera motion) will take about 67 min" in gpu.said
    assert "to go faster" not in gpu.said


def test_a_run_of_one_keyframe_is_told_nothing(caplog):
    from ogscene3d.progress import RunTimeEstimate

    est = RunTimeEstimate(frames=3, keyframe_every=5)
    with caplog.at_level(logging.INFO, logger="ogscene3d.progress"):
        est.keyframe(_Mapper("cpu"), _Frame(), 3.0)
    assert est.said is None and not caplog.records
