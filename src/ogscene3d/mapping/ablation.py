"""The paper's ablation (Tab. "Ablation study") on any scene with ground truth: map the same sequence with
the naive baseline, local only, + global refinement and + long-term, and score each run's 3D semantic
segmentation with the evaluation protocols of ``ogscene3d.eval`` (HOV-SG by default).

Each run is a session of :mod:`ogscene3d.mapping.session`, as ``ogscene3d run`` makes it: its folder records
the run's id and the data it mapped, so ``ogscene3d eval RUN`` finds the ground truth and ``run --resume``
the frames.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..config import Config
from ..eval.run_eval import evaluate_run
from .mapper import ABLATIONS, Mapper
from .session import mapping_session


def map_sequence(
    config: Config,
    data: str | Path | Any,
    out_dir: str | Path,
    device: str | None = None,
    max_frames: int | None = None,
    progress: bool = False,
) -> Mapper:
    """Map the sequence ``data`` (a dataset folder, or a dataset opened from one: its folder, read again
    with ``config.data``), finalize and save to ``out_dir``, in a session as ``ogscene3d run`` makes it
    (:func:`ogscene3d.mapping.session.mapping_session`). ``config`` is changed: it records the data (and
    ``device``, when given).

    Raises:
        KeyboardInterrupt: Ctrl-C or SIGTERM stopped the run (the map so far is saved, for ``--resume``).
    """
    if device is not None:
        config.device = device
    folder = data if isinstance(data, str | Path) else data.root  # (a Path's own .root is "/")
    with mapping_session(config, out_dir, folder, command="ablation", max_frames=max_frames) as s:
        summary = s.run(progress=progress)
    if summary.status == "stopped":
        raise KeyboardInterrupt(f"{out_dir}: stopped after {summary.read} frames")
    return s.mapper


def run_ablation(
    config: Config,
    data: str | Path,
    gt: str | Path,
    out_root: str | Path,
    ablations: Sequence[str] = ABLATIONS,
    device: str | None = None,
    protocols: Sequence[str] = ("hovsg",),
    max_frames: int | None = None,
    gt_points: Sequence[str] = ("observed",),
) -> dict[str, dict]:
    """Map ``data`` once per ablation into ``out_root/<ablation>`` and evaluate against ``gt``.

    Returns {ablation: {protocol: {"miou", "fmiou", "macc"} (in [0,1]), "seconds", "gaussians",
    "labels"}}; the protocol entries score the GT points chosen by ``gt_points[0]`` ("observed" or "all",
    see :func:`ogscene3d.eval.evaluate_run`), and every choice is also under "<protocol>/<choice>".
    Scene labels are named by majority overlap with the GT instances (an oracle naming that is the same
    for every ablation, so differences come from the mapping alone).
    """
    results: dict[str, dict] = {}
    for abl in ablations:
        if abl not in ABLATIONS:
            raise ValueError(f"unknown ablation {abl!r}; expected one of {ABLATIONS}")
        cfg = copy.deepcopy(config)
        cfg.mapping.ablation = abl
        cfg.graph.enabled = False  # the graph does not change the semantic map
        out = Path(out_root) / abl.replace("+", "_")
        t0 = time.perf_counter()
        mapper = map_sequence(cfg, data, out, device, max_frames)
        seconds = time.perf_counter() - t0
        row: dict = {
            "seconds": seconds,
            "gaussians": len(mapper.map),
            "labels": int(mapper.timings.counts.get("labels", 0)),
        }
        for i, gp in enumerate(gt_points):
            ev = evaluate_run(out, gt, protocols=tuple(protocols), mapping="overlap", gt_points=gp)  # type: ignore[arg-type]
            for proto, m in ev.semantic.items():
                scores = {"miou": m.miou, "fmiou": m.fmiou, "macc": m.macc}
                row[f"{proto}/{gp}"] = scores
                if i == 0:
                    row[proto] = scores
        results[abl] = row
    return results


def format_ablation(results: dict[str, dict], protocol: str = "hovsg") -> str:
    """A text table of ``run_ablation``'s results (percent)."""
    lines = [
        f"{'ablation':<14}{'mIoU':>8}{'F-mIoU':>8}{'mAcc':>8}{'Gaussians':>11}{'labels':>8}{'time s':>8}"
    ]
    for abl, r in results.items():
        m = r.get(protocol, {})
        pct = lambda v: f"{100 * v:8.2f}" if v is not None else f"{'-':>8}"  # noqa: E731
        lines.append(
            f"{abl:<14}{pct(m.get('miou'))}{pct(m.get('fmiou'))}{pct(m.get('macc'))}"
            f"{r['gaussians']:>11}{r['labels']:>8}{r['seconds']:>8.1f}"
        )
    return "\n".join(lines)
