r"""The paper's ablation (Tab. "Ablation study") on several synthetic seeds: mean and spread, and a plot.

Each seed's procedural room is mapped four times with ``mapping.ablation`` = naive (KNN-majority labels, no
confidence, no refinement, no long-term), local (local 3D optimization only: the paper's row a), local+global
(+ global 3D refinement: row b), full (+ long-term global optimization: row c), by
:func:`ogscene3d.mapping.ablation.run_ablation`. Protocol: 3D semantic segmentation of the Gaussian centres
against the room's ground-truth point cloud, HOV-SG protocol by default (k=5 nearest Gaussians vote for every
GT point, counted on GT points, wall/floor/ceiling left out of the means); scene labels are named by majority
overlap with the GT instances (an oracle naming, the same for every ablation, so differences come from the
mapping alone). The headline table scores the GT points that some frame of the sequence saw (``gt/points.ply``
``observed``; about half of a room: the ceiling, the floor under furniture and the backs of objects are never
in view, and their points would only be voted on by whatever Gaussians happen to be nearest); the table over
all GT points follows it. The scene graph is off (it does not change the semantic map). Spread = sample
standard deviation over seeds (ddof=1); the paired column gives the per-seed difference to the previous row,
which is what the ablation claims.

    python benchmarks/ablation.py --seeds 0,1,2 --device cpu --frames 24 --size 96x72 \
        --set mapping.opt_iters=1
    python benchmarks/ablation.py --seeds 0-4 --device cuda   # the synthetic config's 60 frames, 160x120

Writes OUT/ablation.json and OUT/ablation.png (grouped bars of mIoU / F-mIoU / mAcc, error bars = ±1 std, dots
= seeds). Paper, Replica (a/b/c mIoU): 22.98 / 25.35 / 36.07.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import positive_int, run_main  # noqa: E402

from ogscene3d.batch import json_safe  # noqa: E402
from ogscene3d.config import load_config  # noqa: E402
from ogscene3d.datasets import configured_scene  # noqa: E402
from ogscene3d.device import resolve_device  # noqa: E402
from ogscene3d.eval.protocols import CONCEPTGRAPHS_DEFAULT_IGNORE, HOVSG_DEFAULT_IGNORE  # noqa: E402
from ogscene3d.mapping.ablation import run_ablation  # noqa: E402
from ogscene3d.mapping.mapper import ABLATIONS  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
METRICS = (("miou", "mIoU"), ("fmiou", "F-mIoU"), ("macc", "mAcc"))
PAPER_REPLICA = {
    "local": (22.98, 35.15, 42.85),
    "local+global": (25.35, 38.16, 49.02),
    "full": (36.07, 42.22, 55.16),
}


def parse_seeds(text: str) -> list[int]:
    """ "0,1,2" or "0-4" (inclusive) or a mix: "0-2,7"."""
    seeds: list[int] = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        if "-" in part[1:]:
            a, b = part.split("-", 1) if not part.startswith("-") else (part, "")
            seeds += list(range(int(a), int(b) + 1))
        else:
            seeds.append(int(part))
    if not seeds:
        raise ValueError(f"--seeds: no seed in {text!r}")
    return seeds


def _stats(values: list[float]) -> dict:
    v = [x for x in values if x is not None and math.isfinite(x)]
    if not v:
        return {"mean": None, "std": None, "min": None, "max": None, "n": 0}
    a = np.asarray(v, dtype=np.float64)
    return {
        "mean": float(a.mean()),
        "std": float(a.std(ddof=1)) if a.size > 1 else 0.0,
        "min": float(a.min()),
        "max": float(a.max()),
        "n": int(a.size),
    }


def summarize(per_seed: dict[int, dict[str, dict]], ablations: list[str], protocol: str) -> dict:
    """{ablation: {metric: stats, "paired_miou": stats of the difference to the previous ablation,
    "gaussians", "seconds"}} over seeds."""
    out: dict[str, dict] = {}
    prev = None
    for abl in ablations:
        row: dict = {}
        for key, _ in METRICS:
            vals = [per_seed[s][abl][protocol][key] for s in per_seed]
            row[key] = {**_stats(vals), "values": vals}
        if prev is not None:
            diffs = []
            for s in per_seed:
                a, b = per_seed[s][abl][protocol]["miou"], per_seed[s][prev][protocol]["miou"]
                diffs.append(None if a is None or b is None else a - b)
            row["paired_miou"] = _stats(diffs)
        row["gaussians"] = _stats([per_seed[s][abl]["gaussians"] for s in per_seed])
        row["seconds"] = _stats([per_seed[s][abl]["seconds"] for s in per_seed])
        out[abl] = row
        prev = abl
    return out


def _pm(st: dict, scale: float = 100.0, digits: int = 2) -> str:
    if st["mean"] is None:
        return "-"
    return f"{scale * st['mean']:.{digits}f} ± {scale * st['std']:.{digits}f}"


def format_summary(summary: dict, protocol: str) -> str:
    header = [
        "ablation",
        "mIoU",
        "F-mIoU",
        "mAcc",
        "ΔmIoU vs prev (paired)",
        "mIoU per seed",
        "Gaussians",
        "s",
    ]
    rows = [header]
    for abl, r in summary.items():
        per = " ".join("-" if v is None else f"{100 * v:.1f}" for v in r["miou"]["values"])
        rows.append(
            [
                abl,
                _pm(r["miou"]),
                _pm(r["fmiou"]),
                _pm(r["macc"]),
                _pm(r["paired_miou"]) if "paired_miou" in r else "",
                per,
                f"{r['gaussians']['mean']:.0f}",
                f"{r['seconds']['mean']:.1f}",
            ]
        )
    widths = [max(len(row[i]) for row in rows) for i in range(len(header))]
    lines = [
        "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(row, widths)))
        for row in rows
    ]
    lines.insert(1, "-" * len(lines[0]))
    return "\n".join(lines)


def plot_summary(summary: dict, title: str, subtitle: str, width: int = 960, height: int = 540) -> np.ndarray:
    """Grouped bars (mIoU, F-mIoU, mAcc in %) per ablation with ±1 std error bars and per-seed dots;
    uint8 RGB [H, W, 3] drawn with OpenCV."""
    img = np.full((height, width, 3), 255, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    left, right, top, bottom = 70, 20, 70, 60
    x0, x1, y0, y1 = left, width - right, top, height - bottom
    colors = [(66, 133, 244), (52, 168, 83), (251, 188, 5)]  # RGB per metric
    vmax = 100.0
    all_vals = [
        100 * v for r in summary.values() for k, _ in METRICS for v in r[k]["values"] if v is not None
    ]
    tops = [
        100 * (r[k]["mean"] + r[k]["std"])
        for r in summary.values()
        for k, _ in METRICS
        if r[k]["mean"] is not None
    ]
    hi = max([*all_vals, *tops, 1.0])
    vmax = min(100.0, max(10.0, math.ceil(hi / 10.0) * 10.0))

    def ypix(v: float) -> int:
        return int(round(y1 - (y1 - y0) * min(max(v, 0.0), vmax) / vmax))

    cv2.putText(img, title, (x0, 28), font, 0.65, (0, 0, 0), 2, cv2.LINE_AA)
    cv2.putText(img, subtitle, (x0, 52), font, 0.42, (60, 60, 60), 1, cv2.LINE_AA)
    for t in np.arange(0, vmax + 1e-6, 10.0):
        y = ypix(t)
        cv2.line(img, (x0, y), (x1, y), (225, 225, 225), 1)
        cv2.putText(img, f"{t:.0f}", (x0 - 34, y + 5), font, 0.45, (80, 80, 80), 1, cv2.LINE_AA)
    cv2.line(img, (x0, y0), (x0, y1), (0, 0, 0), 1)
    cv2.line(img, (x0, y1), (x1, y1), (0, 0, 0), 1)
    cv2.putText(img, "%", (x0 - 34, y0 - 10), font, 0.45, (80, 80, 80), 1, cv2.LINE_AA)

    n = len(summary)
    group_w = (x1 - x0) / max(n, 1)
    bar_w = int(group_w * 0.8 / len(METRICS))
    for g, (abl, r) in enumerate(summary.items()):
        gx = x0 + g * group_w + group_w * 0.1
        for j, (key, _) in enumerate(METRICS):
            st = r[key]
            if st["mean"] is None:
                continue
            bx = int(gx + j * bar_w)
            cv2.rectangle(img, (bx + 2, ypix(100 * st["mean"])), (bx + bar_w - 2, y1), colors[j], -1)
            cx = bx + bar_w // 2
            lo, hi_ = ypix(100 * (st["mean"] - st["std"])), ypix(100 * (st["mean"] + st["std"]))
            cv2.line(img, (cx, lo), (cx, hi_), (0, 0, 0), 2)
            for y in (lo, hi_):
                cv2.line(img, (cx - 6, y), (cx + 6, y), (0, 0, 0), 2)
            for v in st["values"]:
                if v is not None:
                    cv2.circle(img, (cx, ypix(100 * v)), 3, (40, 40, 40), -1, cv2.LINE_AA)
            label = f"{100 * st['mean']:.1f}"
            (tw, _), _ = cv2.getTextSize(label, font, 0.38, 1)
            cv2.putText(
                img, label, (cx - tw // 2, max(y0 - 2, hi_ - 6)), font, 0.38, (0, 0, 0), 1, cv2.LINE_AA
            )
        (tw, _), _ = cv2.getTextSize(abl, font, 0.55, 1)
        cv2.putText(
            img, abl, (int(gx + group_w * 0.4 - tw / 2), y1 + 24), font, 0.55, (0, 0, 0), 1, cv2.LINE_AA
        )
    lx = x1 - 3 * 110
    for j, (_, name) in enumerate(METRICS):
        cv2.rectangle(img, (lx + j * 110, height - 26), (lx + j * 110 + 14, height - 12), colors[j], -1)
        cv2.putText(img, name, (lx + j * 110 + 20, height - 13), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    note = "bars: mean, whiskers: +/-1 std, dots: seeds"
    cv2.putText(img, note, (x0, height - 13), font, 0.42, (60, 60, 60), 1, cv2.LINE_AA)
    return img


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", default="0,1,2", help="e.g. 0,1,2 or 0-4 (default 0,1,2)")
    default_cfg = ROOT / "configs" / "synthetic.yaml"
    ap.add_argument("--config", default=str(default_cfg) if default_cfg.is_file() else None)
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument(
        "--frames", type=positive_int, default=None, help="frames per scene (default: the config's)"
    )
    ap.add_argument("--size", default=None, help="WxH (default: the config's)")
    ap.add_argument("--noise", default=None, help="simulated-SAM noise: none | low | default | high")
    ap.add_argument("--ablations", default=",".join(ABLATIONS), help=f"subset of {','.join(ABLATIONS)}")
    ap.add_argument("--protocol", default="hovsg", choices=["hovsg", "conceptgraphs"])
    ap.add_argument(
        "--gt-points",
        default="observed",
        choices=["observed", "all"],
        help="GT points of the headline table: those some frame saw (default) or all; both are reported",
    )
    ap.add_argument("--device", default=None, help="cpu, cuda (default: config, else CUDA if present)")
    ap.add_argument("--out", type=Path, default=Path("ablation_out"), help="runs, scenes, JSON and PNG")
    args = ap.parse_args(argv)

    if args.device is not None:
        resolve_device(args.device)  # no CUDA GPU for --device cuda: say so before any scene is made
    seeds = parse_seeds(args.seeds)
    ablations = [a.strip() for a in args.ablations.split(",") if a.strip()]
    for a in ablations:
        if a not in ABLATIONS:
            ap.error(f"unknown ablation {a!r}; expected some of {ABLATIONS}")
    overrides = list(args.overrides)
    if args.frames is not None:
        overrides.append(f"synthetic.frames={args.frames}")
    if args.size is not None:
        w, h = (int(v) for v in args.size.lower().split("x"))
        overrides += [f"synthetic.width={w}", f"synthetic.height={h}"]
    if args.noise is not None:
        overrides.append(f"synthetic.noise={args.noise}")
    cfg = load_config(args.config, overrides)
    s = cfg.synthetic
    out = args.out
    out.mkdir(parents=True, exist_ok=True)

    per_seed: dict[int, dict[str, dict]] = {}
    t_all = time.perf_counter()
    for seed in seeds:
        scene = configured_scene(out / "scenes" / f"seed_{seed}", dataclasses.replace(s, seed=seed))
        print(f"seed {seed}: mapping {len(ablations)} ablations of {scene} ...", file=sys.stderr, flush=True)
        choices = [args.gt_points] + [g for g in ("observed", "all") if g != args.gt_points]
        res = run_ablation(
            cfg,
            scene,
            scene,
            out / f"seed_{seed}",
            ablations,
            args.device,
            (args.protocol,),
            gt_points=choices,
        )
        per_seed[seed] = res
        for abl in ablations:
            m = res[abl][args.protocol]
            print(f"  {abl:<13} mIoU {100 * m['miou']:.2f}  ({res[abl]['seconds']:.1f} s)", file=sys.stderr)
    protocol_text = {
        "hovsg": "HOV-SG: k=5 nearest Gaussians vote per GT point, counted on GT points, "
        f"{'/'.join(HOVSG_DEFAULT_IGNORE)} left out of the means",
        "conceptgraphs": "ConceptGraphs: each Gaussian takes its nearest GT point's class, counted on "
        f"Gaussians, {'/'.join(CONCEPTGRAPHS_DEFAULT_IGNORE)} left out",
    }[args.protocol]
    summary = summarize(per_seed, ablations, args.protocol)
    other = "all" if args.gt_points == "observed" else "observed"
    summary_other = summarize(per_seed, ablations, f"{args.protocol}/{other}")
    points_text = {
        "observed": "GT points seen by some frame (gt/points.ply 'observed')",
        "all": "all GT points, including surfaces no frame sees (HOV-SG on a full mesh)",
    }
    print()
    print(
        f"ablation on {len(seeds)} synthetic seeds ({s.frames} frames {s.width}x{s.height}, "
        f"noise {s.noise}), mean ± sample std over seeds, in %"
    )
    print(f"protocol: {protocol_text}; labels named by majority overlap with GT instances (oracle)")
    print(f"scored on {points_text[args.gt_points]}:")
    print(format_summary(summary, args.protocol))
    print(f"scored on {points_text[other]}:")
    print(format_summary(summary_other, f"{args.protocol}/{other}"))
    print(f"paper, Replica (mIoU a/b/c): {' / '.join(f'{v[0]:.2f}' for v in PAPER_REPLICA.values())}")
    print(f"total {time.perf_counter() - t_all:.0f} s on {args.device or cfg.device or 'auto'}")

    img = plot_summary(
        summary,
        f"Ablation on {len(seeds)} synthetic seeds ({s.frames} frames, {s.width}x{s.height})",
        f"{protocol_text}; {args.gt_points} GT points; oracle label naming",
    )
    png = out / "ablation.png"
    ok, buf = cv2.imencode(".png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    if not ok:
        raise RuntimeError(f"could not encode {png}")
    png.write_bytes(buf.tobytes())
    report = {
        "version": 1,
        "protocol": args.protocol,
        "protocol_description": protocol_text,
        "gt_points": args.gt_points,
        "gt_points_description": points_text,
        "label_naming": "majority overlap with GT instances (oracle), same for every ablation",
        "statistics": "mean, sample std (ddof=1), min, max over seeds; paired_miou = per-seed difference to "
        "the previous ablation",
        "seeds": seeds,
        "synthetic": {"frames": s.frames, "width": s.width, "height": s.height, "noise": s.noise},
        "overrides": overrides,
        "summary": summary,
        f"summary_{other}_gt_points": summary_other,
        "per_seed": {str(k): v for k, v in per_seed.items()},
    }
    (out / "ablation.json").write_text(json.dumps(json_safe(report), indent=2) + "\n")
    print(f"wrote {out / 'ablation.json'} and {png}")
    return 0


if __name__ == "__main__":
    run_main(main)
