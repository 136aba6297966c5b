r"""Issue 39's cost target: the semantic stages per keyframe late in a long scan against early in it.

The semantic stages (local association, the evidence, the long-term step, the refinement and the duplicate
merge) should cost what a view sees, not what the stream has seen: at the 300th frame at most 2x their cost
at the 60th. The mapper's ``timings.json`` keeps each keyframe's time per module (``per_keyframe_ms``,
``per_keyframe_cpu_ms``, ``per_keyframe_frame``); this reads it for the full row of long scans and compares
the mean per keyframe over a window of keyframes ending at each of the two frames (``--window`` keyframes,
by default 12: two rounds of the 6-keyframe schedule of the long-term step and the refinement, so that a
window holds the same number of each).

Stages: ``local`` (its time includes ``merge``, shown apart but not added twice), ``evidence``,
``longterm``, ``refine``; "semantic" is their sum. CPU time (the process's, every thread) is the headline:
on a shared machine it moves less than wall time; wall time is printed beside it. Where the run noted the
Gaussians each keyframe's view sees (``per_keyframe_counts``' ``visible_gaussians``, by the evidence stage),
their mean over each window is printed too, and the semantic stages' cost per thousand of them: a cost that
follows what a view sees keeps that ratio near 1 however the views grow. Where it noted the memory views each
long-term pass judged (``memory_views``), their count over each window is printed: the long-term step and
the evidence's revisits cost per memory view, and the memory holds fewer early in a scan.

A window of 12 keyframes is a short measurement, and a shared machine moves it between runs of the same map.
Runs of one scene (the same directory name of the scene they mapped, as the ablation's ``scenes/scan_N`` and
``--rounds`` lay them out) are rounds of it: each scene's ratio is then the median of its rounds' ratios, and
the summary is over scenes (docs/consistency.md, "Cost along a scan").

    python benchmarks/semantic_growth.py RUN_DIR [RUN_DIR ...]          # runs mapped already (full row)
    python benchmarks/semantic_growth.py --seeds 0-2 --device cpu --set mapping.optimize.iters=1 --out growth
    python benchmarks/semantic_growth.py --seeds 0-9 --rounds 3 ...     # each scan mapped three times
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import positive_int, run_main  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("local", "merge", "evidence", "longterm", "refine")
VISIBLE = "visible_gaussians"
MEMORY = "memory_views"
PER_VISIBLE = ("visible", "per_1k_visible")
SUMMED = ("local", "evidence", "longterm", "refine")  # merge runs inside local
TARGET = 2.0


def window_cost(timings: dict, frame: int, window: int, kind: str = "per_keyframe_cpu_ms") -> dict | None:
    """Mean milliseconds per keyframe of each stage (and "semantic", their sum) over the ``window``
    keyframes ending at the last keyframe at or before ``frame``; None when the run has not got so far."""
    frames = np.asarray(timings.get("per_keyframe_frame", []))
    series = timings.get(kind, {})
    if frames.size == 0 or frames[0] > frame:
        return None
    end = int(np.searchsorted(frames, frame, side="right"))  # keyframes up to and including the frame
    if end < window:
        return None
    out = {s: float(np.mean(series.get(s, [0.0] * len(frames))[end - window : end])) for s in STAGES}
    out["semantic"] = sum(out[s] for s in SUMMED)
    seen = timings.get("per_keyframe_counts", {}).get(VISIBLE)
    if seen:
        out["visible"] = float(np.mean(seen[end - window : end]))
        out["per_1k_visible"] = 1000 * out["semantic"] / out["visible"] if out["visible"] > 0 else None
    judged = timings.get("per_keyframe_counts", {}).get(MEMORY)
    if judged:
        out[MEMORY] = float(np.sum(judged[end - window : end]))
    out["keyframes"] = (int(frames[end - window]), int(frames[end - 1]))
    return out


def growth(timings: dict, early: int, late: int, window: int) -> dict:
    """{"cpu": {early: costs, late: costs, "ratio": {stage: late / early}}, "wall": ...}."""
    out = {}
    for name, kind in (("cpu", "per_keyframe_cpu_ms"), ("wall", "per_keyframe_ms")):
        a, b = window_cost(timings, early, window, kind), window_cost(timings, late, window, kind)
        if a is None or b is None:
            raise SystemExit(f"the run has no {window} keyframes up to frame {late} (or {early})")
        ratio = {s: (b[s] / a[s] if a[s] > 0 else None) for s in (*STAGES, "semantic")}
        ratio.update({s: b[s] / a[s] for s in (*PER_VISIBLE, MEMORY) if a.get(s) and b.get(s) is not None})
        out[name] = {"early": a, "late": b, "ratio": ratio}
    return out


def _row(label: str, g: dict) -> list[str]:
    cpu, wall = g["cpu"], g["wall"]
    cells = [label]
    for s in (*STAGES, "semantic"):
        r = cpu["ratio"][s]
        cells.append(f"{cpu['early'][s]:.1f} -> {cpu['late'][s]:.1f} ({r:.2f}x)" if r else "-")
    cells.append(f"{wall['ratio']['semantic']:.2f}x" if wall["ratio"]["semantic"] else "-")
    for s, fmt in zip(PER_VISIBLE, (".0f", ".1f")):
        r = cpu["ratio"].get(s)
        cells.append(f"{cpu['early'][s]:{fmt}} -> {cpu['late'][s]:{fmt}} ({r:.2f}x)" if r else "-")
    early, late = cpu["early"].get(MEMORY), cpu["late"].get(MEMORY)
    cells.append(f"{early:.0f} -> {late:.0f}" if early is not None and late is not None else "-")
    return cells


def _map_scans(args) -> list[Path]:
    from ablation import SCAN_OVERRIDES, parse_seeds

    from ogscene3d.config import load_config
    from ogscene3d.datasets import configured_scene
    from ogscene3d.mapping.ablation import run_ablation

    overrides = [*SCAN_OVERRIDES, *args.overrides, "synthetic.layout=scan", f"synthetic.frames={args.frames}"]
    cfg = load_config(args.config, overrides)
    seeds = parse_seeds(args.seeds)
    scenes = {
        seed: configured_scene(
            args.out / "scenes" / f"scan_{seed}", dataclasses.replace(cfg.synthetic, seed=seed)
        )
        for seed in seeds
    }
    runs = []
    # one run at a time, a round after the other: no two runs share the machine
    for r in range(args.rounds):
        base = args.out / f"round_{r}" if args.rounds > 1 else args.out
        for seed in seeds:
            scene = scenes[seed]
            run_ablation(cfg, scene, scene, base / f"scan_{seed}", ["full"], args.device, ("hovsg",))
            runs.append(base / f"scan_{seed}" / "full")
    return runs


def scene_of(run: Path) -> str:
    """The name of the scene directory that ``run`` mapped (its ``config.yaml``'s ``data.path``); the run
    directory itself where it has no such record."""
    from ogscene3d.runs import recorded_data_path

    path = recorded_data_path(run)
    return path.name if path is not None else str(run)


def by_scene(results: dict[str, dict], scenes: dict[str, str]) -> dict[str, dict]:
    """Per scene, over its runs (rounds of one scene; ``results`` of :func:`growth` per run, ``scenes`` the
    scene of each run): their semantic CPU ratios and the median ratio, and the median CPU ms a keyframe of
    each stage in each window ("early", "late")."""
    out: dict[str, dict] = {}
    for run, g in results.items():
        out.setdefault(scenes[run], {"runs": {}, "of": []})
        out[scenes[run]]["runs"][run] = g["cpu"]["ratio"]["semantic"]
        out[scenes[run]]["of"].append(g["cpu"])
    for g in out.values():
        of = g.pop("of")
        g["median"] = float(np.median(list(g["runs"].values())))
        for w in ("early", "late"):
            g[w] = {k: float(np.median([c[w][k] for c in of])) for k in ("semantic", "evidence", "longterm")}
        # what the views see is the same in every round (one map): the cost per thousand of them
        seen = [of[0][w].get("visible") for w in ("early", "late")]
        if all(seen) and g["early"]["semantic"] > 0:
            g["per_1k_visible"] = (g["late"]["semantic"] / seen[1]) / (g["early"]["semantic"] / seen[0])
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="*", type=Path, help="run directories (their timings.json)")
    ap.add_argument("--seeds", default=None, help="map the full row of these long scans first (e.g. 0-2)")
    ap.add_argument("--rounds", type=positive_int, default=1, help="map each of --seeds this many times (1)")
    ap.add_argument("--frames", type=positive_int, default=300, help="frames per scan (300)")
    ap.add_argument("--early", type=positive_int, default=60, help="the early frame (60)")
    ap.add_argument("--late", type=positive_int, default=300, help="the late frame (300)")
    ap.add_argument("--window", type=positive_int, default=12, help="keyframes per window (12)")
    default_cfg = ROOT / "configs" / "synthetic.yaml"
    ap.add_argument("--config", default=str(default_cfg) if default_cfg.is_file() else None)
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--device", default=None, help="cpu, cuda (default: config, else CUDA if present)")
    ap.add_argument("--out", type=Path, default=Path("growth_out"), help="scenes and runs of --seeds")
    args = ap.parse_args(argv)
    if args.rounds > 1 and not args.seeds:
        ap.error("--rounds maps --seeds that many times: give --seeds")
    runs = list(args.runs) + (_map_scans(args) if args.seeds else [])
    if not runs:
        ap.error("give run directories or --seeds")
    results = {}
    table = [["run", *(f"{s} ms/kf" for s in STAGES), "semantic ms/kf", "semantic wall", "visible Gaussians",
              "semantic ms per 1k visible", "memory views judged"]]  # fmt: skip
    for run in runs:
        path = run / "timings.json"
        if not path.is_file():
            raise SystemExit(f"{path}: missing (a run directory of ogscene3d run or the ablation)")
        g = growth(json.loads(path.read_text()), args.early, args.late, args.window)
        results[str(run)] = g
        table.append(_row(str(run), g))
    ratios = [g["cpu"]["ratio"]["semantic"] for g in results.values()]
    from ablation import _table

    print(f"semantic stages, CPU ms per keyframe over {args.window} keyframes up to frame {args.early} -> "
          f"up to frame {args.late} (ratio); target <= {TARGET}x")  # fmt: skip
    print(_table(table))
    print(f"semantic ratio: mean {np.mean(ratios):.2f}x, max {np.max(ratios):.2f}x over {len(ratios)} run(s)")
    scenes = by_scene(results, {str(run): scene_of(run) for run in runs})
    if len(scenes) < len(results):
        for name, g in scenes.items():
            each = ", ".join(f"{r:.2f}" for r in sorted(g["runs"].values()))
            ms = ", ".join(f"{k} {g['early'][k]:.1f} -> {g['late'][k]:.1f}" for k in g["early"])
            n = len(g["runs"])
            per = f"; per 1k visible {g['per_1k_visible']:.2f}x" if g.get("per_1k_visible") else ""
            print(f"  {name}: {g['median']:.2f}x (median of {n} run(s): {each}); median ms: {ms}{per}")
        med = [g["median"] for g in scenes.values()]
        within = sum(m <= TARGET for m in med)
        seen = [g["per_1k_visible"] for g in scenes.values() if g.get("per_1k_visible")]
        per_seen = f"; per 1k visible, mean {np.mean(seen):.2f}x" if seen else ""
        print(f"semantic ratio, median of each scene's runs: mean {np.mean(med):.2f}x, "
              f"max {np.max(med):.2f}x, {within}/{len(med)} scene(s) within {TARGET}x{per_seen}")  # fmt: skip
    per = [g["cpu"]["ratio"].get("per_1k_visible") for g in results.values()]
    per = [r for r in per if r is not None]
    if per:
        print(f"semantic ms per 1k visible Gaussians: mean {np.mean(per):.2f}x, max {np.max(per):.2f}x over "
              f"{len(per)} run(s)")  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    doc = {"early": args.early, "late": args.late, "window": args.window, "target": TARGET, "runs": results,
           "scenes": scenes}  # fmt: skip
    (args.out / "semantic_growth.json").write_text(json.dumps(doc, indent=2) + "\n")
    print(f"wrote {args.out / 'semantic_growth.json'}")
    return 0


if __name__ == "__main__":
    run_main(main)
