"""Per-module wall and CPU time of a mapping run, and its counters (``timings.json``)."""

from __future__ import annotations

import time
from contextlib import contextmanager

import torch


class Counters:
    """A stage's counters (a dataclass of ints and floats): ``as_dict`` gives them to ``Timings.add``."""

    def as_dict(self) -> dict[str, float]:
        return dict(self.__dict__)


class Timings:
    """Accumulated wall time (s) and call counts per module, plus free-form counters, and each keyframe's
    time per module (``per_keyframe``: how a module's cost grows along the stream)."""

    def __init__(self, device: torch.device) -> None:
        self.device = device
        self.seconds: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self.counts: dict[str, float] = {}
        # per keyframe of the stream: its frame index and the wall and CPU seconds of each module in its
        # process (CPU time: the process's, all threads; steadier than wall time on a shared machine)
        self.per_keyframe: list[dict] = []
        self._keyframe: dict | None = None

    def begin_keyframe(self, frame_index: int) -> None:
        """The sections from here to :meth:`end_keyframe` make a new row of ``per_keyframe``."""
        self._keyframe = {"frame": int(frame_index), "wall": {}, "cpu": {}, "counts": {}}
        self.per_keyframe.append(self._keyframe)

    def end_keyframe(self) -> None:
        self._keyframe = None

    @contextmanager
    def section(self, name: str):
        sync = self.device.type == "cuda"
        if sync:
            torch.cuda.synchronize(self.device)
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            if sync:
                torch.cuda.synchronize(self.device)
            dt = time.perf_counter() - t0
            self.seconds[name] = self.seconds.get(name, 0.0) + dt
            self.calls[name] = self.calls.get(name, 0) + 1
            if self._keyframe is not None:
                wall, cpu = self._keyframe["wall"], self._keyframe["cpu"]
                wall[name] = wall.get(name, 0.0) + dt
                cpu[name] = cpu.get(name, 0.0) + time.process_time() - c0

    def add(self, name: str, value: float = 1) -> None:
        self.counts[name] = self.counts.get(name, 0) + value

    def note(self, name: str, value: float) -> None:
        """A quantity of the current keyframe (the Gaussians its view sees), beside its times: written as
        ``per_keyframe_counts``, so that a module's cost can be read against what the keyframe saw."""
        if self._keyframe is not None:
            self._keyframe["counts"][name] = value

    def state(self) -> dict:
        return {
            "seconds": self.seconds,
            "calls": self.calls,
            "counts": self.counts,
            "per_keyframe": self.per_keyframe,
        }

    def load_state(self, state: dict) -> None:
        self.seconds = {str(k): float(v) for k, v in state.get("seconds", {}).items()}
        self.calls = {str(k): int(v) for k, v in state.get("calls", {}).items()}
        self.counts = {str(k): v for k, v in state.get("counts", {}).items()}
        self.per_keyframe = [
            {"frame": int(row["frame"]), "wall": dict(row["wall"]), "cpu": dict(row["cpu"]),
             "counts": dict(row.get("counts", {}))}  # (a checkpoint written before they were kept)
            for row in state.get("per_keyframe", [])
        ]
        self._keyframe = None

    def as_dict(self) -> dict:
        kf = max(1, int(self.counts.get("keyframes", 0)))
        return {
            "seconds": {k: round(v, 6) for k, v in self.seconds.items()},
            "calls": dict(self.calls),
            "ms_per_keyframe": {k: round(1000 * v / kf, 3) for k, v in self.seconds.items()},
            "counts": {k: (int(v) if float(v).is_integer() else v) for k, v in self.counts.items()},
            # each keyframe's frame index, and per module its wall and CPU milliseconds in each keyframe in
            # order (0: it did not run there); the end of stream's passes (finalize) are in "seconds" only
            "per_keyframe_frame": [row["frame"] for row in self.per_keyframe],
            "per_keyframe_ms": self._series("wall"),
            "per_keyframe_cpu_ms": self._series("cpu"),
            # per quantity noted (``note``), its value in each keyframe (0: not noted there)
            "per_keyframe_counts": self._columns("counts", 0),
        }

    def _columns(self, kind: str, missing: float) -> dict[str, list[float]]:
        """Per name in the keyframes' ``kind`` dicts, its value in each keyframe (``missing``: absent)."""
        names = sorted({n for row in self.per_keyframe for n in row[kind]})
        return {n: [row[kind].get(n, missing) for row in self.per_keyframe] for n in names}

    def _series(self, kind: str) -> dict[str, list[float]]:
        return {n: [round(1000 * v, 3) for v in vals] for n, vals in self._columns(kind, 0.0).items()}

    def table(self) -> str:
        """A per-module timing table (text)."""
        kf = max(1, int(self.counts.get("keyframes", 0)))
        rows = [f"{'module':<14}{'calls':>7}{'total s':>10}{'ms/keyframe':>13}"]
        for k, v in sorted(self.seconds.items(), key=lambda kv: -kv[1]):
            rows.append(f"{k:<14}{self.calls.get(k, 0):>7}{v:>10.2f}{1000 * v / kf:>13.1f}")
        return "\n".join(rows)

    def document(self, ablation: str, finalized: bool) -> dict:
        """``timings.json``: :meth:`as_dict` with the run's device, ablation and whether it was finalized
        (False: the map of a stopped run, which ``--resume`` goes on from)."""
        doc = self.as_dict()
        doc["device"] = str(self.device)
        doc["ablation"] = ablation
        doc["finalized"] = finalized
        return doc
