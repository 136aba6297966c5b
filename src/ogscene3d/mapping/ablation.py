"""The paper's ablation (Tab. "Ablation study") on any scene with ground truth: map the same sequence with
the naive baseline, local only, + global refinement and + long-term, and score each run's 3D semantic
segmentation with the evaluation protocols of ``ogscene3d.eval`` (HOV-SG by default).
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from ..config import Config
from ..runs import run_directory
from .engine import MappingEngine
from .mapper import ABLATIONS, Mapper


def map_sequence(
    config: Config,
    frames,
    out_dir: str | Path,
    device: str | None = None,
    progress: Callable | None = None,
) -> Mapper:
    """Map every frame of ``frames`` (an iterable of Frame), finalize and save to ``out_dir`` (locked for
    the run, as every run directory is: :mod:`ogscene3d.mapping.engine`)."""
    mapper = Mapper(config, device)
    with run_directory(out_dir, "ablation"):
        MappingEngine(mapper, out_dir, getattr(frames, "root", "")).run(
            frames if progress is None else progress(frames)
        )
    return mapper


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
    from ..datasets import open_dataset
    from ..eval.run_eval import evaluate_run

    results: dict[str, dict] = {}
    for abl in ablations:
        if abl not in ABLATIONS:
            raise ValueError(f"unknown ablation {abl!r}; expected one of {ABLATIONS}")
        cfg = copy.deepcopy(config)
        cfg.mapping.ablation = abl
        cfg.graph.enabled = False  # the graph does not change the semantic map
        ds = open_dataset(data, max_frames=max_frames, config=cfg.data)
        out = Path(out_root) / abl.replace("+", "_")
        t0 = time.perf_counter()
        mapper = map_sequence(cfg, ds, out, device)
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
