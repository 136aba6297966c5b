r"""The paper's ablation (Tab. "Ablation study") on several synthetic seeds: per seed, averaged, plotted.

Each seed's procedural room is mapped four times with ``mapping.ablation`` = naive (KNN-majority labels, no
confidence, no refinement, no long-term), local (local 3D optimization only: the paper's row a), local+global
(+ global 3D refinement: row b), full (+ long-term global optimization: row c), by
:func:`ogscene3d.mapping.ablation.run_ablation`, and the same frames' segments are clustered offline by the
yardstick (``yardstick.py``: view-consensus clustering of all frames at once, as MaskClustering does).

Scores, on the GT points that some frame of the sequence saw (``gt/points.ply`` ``observed``):

* **instance mIoU**: scene labels matched one to one to GT instances (Hungarian, on IoU), mean over the GT
  instances, walls and floor included (``_instances.py``); the headline figure of issue 26;
* **class mIoU**: HOV-SG protocol (k=5 nearest Gaussians vote per GT point, wall/floor/ceiling left out of
  the means), scene labels named by majority overlap with the GT instances (an oracle naming, the same for
  every row, so differences come from the mapping alone);
* **recovered**: of the objects whose first view's segments got them wrong (absorbed into a surface, merged
  with their support, cut or missed), how many end with a matched label of IoU >= 0.5.

Spread = sample standard deviation over seeds (ddof=1); the paired column gives the per-seed difference of
instance mIoU to the previous row and on how many seeds it is positive. ``--segments perfect`` maps every
object cleanly segmented in every frame (ids reshuffled per frame: simulated-SAM level "none"). The scene
graph is off (it does not change the semantic map).

    python benchmarks/ablation.py --seeds 0,1 --device cpu --frames 30            # quick look
    python benchmarks/ablation.py --seeds 0-9 --device cpu --frames 30 --out ablation_out
    python benchmarks/ablation.py --seeds 0-9 --segments perfect --ablations naive,full --no-yardstick

Writes OUT/ablation.json and OUT/ablation.png (grouped bars of instance mIoU / class mIoU / recovered %,
error bars = ±1 std, dots = seeds). Paper, Replica (a/b/c class mIoU): 22.98 / 25.35 / 36.07.
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
from _instances import class_miou, instance_scores, recovered, wrong_first_views  # noqa: E402

from ogscene3d.batch import json_safe  # noqa: E402
from ogscene3d.config import load_config  # noqa: E402
from ogscene3d.datasets import configured_scene  # noqa: E402
from ogscene3d.device import resolve_device  # noqa: E402
from ogscene3d.eval.plots import write_png  # noqa: E402
from ogscene3d.eval.protocols import HOVSG_DEFAULT_IGNORE  # noqa: E402
from ogscene3d.eval.readers import load_ground_truth, read_run  # noqa: E402
from ogscene3d.mapping.ablation import run_ablation  # noqa: E402
from ogscene3d.mapping.mapper import ABLATIONS  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
YARDSTICK = "yardstick"
# (key, column title, is a fraction shown in %)
METRICS = (("inst", "inst mIoU"), ("cls", "class mIoU"), ("rec", "recovered %"))
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


def summarize(per_seed: dict[int, dict[str, dict]], rows: list[str]) -> dict:
    """{row: {metric: stats with "values" per seed, "paired_inst": stats of the per-seed instance-mIoU
    difference to the previous mapping row, with "positive" seeds}} over seeds."""
    out: dict[str, dict] = {}
    prev = None
    for row in rows:
        r: dict = {}
        for key, _ in METRICS:
            vals = [per_seed[s][row][key] for s in per_seed]
            r[key] = {**_stats(vals), "values": vals}
        r["recovered"] = [per_seed[s][row]["recovered"] for s in per_seed]
        if prev is not None:
            diffs = []
            for s in per_seed:
                a, b = per_seed[s][row]["inst"], per_seed[s][prev]["inst"]
                diffs.append(None if a is None or b is None else a - b)
            r["paired_inst"] = {**_stats(diffs), "positive": sum(d is not None and d > 0 for d in diffs)}
        out[row] = r
        if row != YARDSTICK:
            prev = row
    return out


def _pm(st: dict, scale: float = 100.0, digits: int = 2) -> str:
    if st["mean"] is None:
        return "-"
    return f"{scale * st['mean']:.{digits}f} ± {scale * st['std']:.{digits}f}"


def _table(rows: list[list[str]]) -> str:
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = [
        "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(row, widths)))
        for row in rows
    ]
    lines.insert(1, "-" * len(lines[0]))
    return "\n".join(lines)


def format_summary(summary: dict) -> str:
    """The averaged table: mean ± std per metric, paired instance-mIoU gain over the previous row."""
    n = len(next(iter(summary.values()))["inst"]["values"])
    rows = [["row", "inst mIoU", "class mIoU", "recovered", "Δinst vs prev (paired)", "seeds > 0"]]
    for name, r in summary.items():
        rec = [x for x in r["recovered"] if x is not None]
        rec_text = f"{sum(a for a, _ in rec)}/{sum(b for _, b in rec)}" if rec else "-"
        paired = r.get("paired_inst")
        rows.append(
            [
                name,
                _pm(r["inst"]),
                _pm(r["cls"]),
                rec_text,
                _pm(paired) if paired else "",
                f"{paired['positive']}/{n}" if paired else "",
            ]
        )
    return _table(rows)


def format_per_seed(per_seed: dict[int, dict[str, dict]], rows: list[str]) -> str:
    """Per seed: instance mIoU / class mIoU / recovered of every row."""
    table = [["seed", *rows]]
    for s, res in per_seed.items():
        cells = [str(s)]
        for row in rows:
            m = res[row]
            rec = m["recovered"]
            cells.append(
                f"{100 * m['inst']:.1f} / {100 * m['cls']:.1f} / " + (f"{rec[0]}/{rec[1]}" if rec else "-")
            )
        table.append(cells)
    return _table(table)


def plot_summary(
    summary: dict, title: str, subtitle: str, width: int = 1000, height: int = 540
) -> np.ndarray:
    """Grouped bars (instance mIoU, class mIoU, recovered %) per row with ±1 std error bars and per-seed
    dots; uint8 RGB [H, W, 3] drawn with OpenCV (written with ``ogscene3d.eval.plots.write_png``)."""
    img = np.full((height, width, 3), 255, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    left, right, top, bottom = 70, 20, 86, 60  # room above 100 for a mean whose seed reached it
    x0, x1, y0, y1 = left, width - right, top, height - bottom
    colors = [(66, 133, 244), (52, 168, 83), (251, 188, 5)]  # RGB per metric
    vmax = 100.0

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
    n = len(summary)
    group_w = (x1 - x0) / max(n, 1)
    bar_w = int(group_w * 0.8 / len(METRICS))
    for g, (name, r) in enumerate(summary.items()):
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
            for v in st["values"]:
                if v is not None:
                    cv2.circle(img, (cx, ypix(100 * v)), 3, (40, 40, 40), -1, cv2.LINE_AA)
            # the mean above the bar's error bar and every seed's dot, on white: readable over the dots
            top = min([hi_, *(ypix(100 * v) - 3 for v in st["values"] if v is not None)])
            label = f"{100 * st['mean']:.1f}"
            (tw, th), _ = cv2.getTextSize(label, font, 0.38, 1)
            ty = max(62 + th, top - 6)  # under the subtitle
            white = (255, 255, 255)
            cv2.rectangle(img, (cx - tw // 2 - 2, ty - th - 2), (cx + tw // 2 + 2, ty + 2), white, -1)
            cv2.putText(img, label, (cx - tw // 2, ty), font, 0.38, (0, 0, 0), 1, cv2.LINE_AA)
        (tw, _), _ = cv2.getTextSize(name, font, 0.55, 1)
        cv2.putText(
            img, name, (int(gx + group_w * 0.4 - tw / 2), y1 + 24), font, 0.55, (0, 0, 0), 1, cv2.LINE_AA
        )
    lx = x1 - 3 * 130
    for j, (_, name) in enumerate(METRICS):
        cv2.rectangle(img, (lx + j * 130, height - 26), (lx + j * 130 + 14, height - 12), colors[j], -1)
        cv2.putText(img, name, (lx + j * 130 + 20, height - 13), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    note = "mean, +/-1 std, dots: seeds"
    cv2.putText(img, note, (x0, height - 13), font, 0.42, (60, 60, 60), 1, cv2.LINE_AA)
    return img


def score_seed(scene: Path, seed_out: Path, ablations: list[str], res: dict, yardstick: bool) -> dict:
    """Instance mIoU, class mIoU and recovered objects of every mapping row (and the yardstick)."""
    gt = load_ground_truth(scene)
    wrong = wrong_first_views(scene)
    rows: dict[str, dict] = {}
    for abl in ablations:
        run = read_run(seed_out / abl.replace("+", "_"))
        inst = instance_scores(run.means, run.labels, gt)
        rows[abl] = {
            "inst": inst["miou"],
            "cls": res[abl]["hovsg"]["miou"],
            "recovered": recovered(inst["iou"], wrong),
            "iou_per_instance": inst["iou"],
            "seconds": res[abl]["seconds"],
            "gaussians": res[abl]["gaussians"],
        }
    if yardstick:
        from yardstick import _frames, view_consensus

        t0 = time.perf_counter()
        pts, lab = view_consensus(_frames(scene))
        inst = instance_scores(pts, lab, gt)
        rows[YARDSTICK] = {
            "inst": inst["miou"],
            "cls": class_miou(pts, lab, gt),
            "recovered": recovered(inst["iou"], wrong),
            "iou_per_instance": inst["iou"],
            "seconds": time.perf_counter() - t0,
        }
    for r in rows.values():
        a, b = r["recovered"]
        r["rec"] = a / b if b else None
    rows["wrong_first_views"] = {str(k): v for k, v in wrong.items()}  # type: ignore[assignment]
    return rows


def report_partial(path: Path, out: Path) -> int:
    """The tables and plot of the seeds a stopped run finished (``ablation_partial.json``)."""
    raw = json.loads(path.read_text())
    per_seed = {int(k): v for k, v in raw.items()}
    if not per_seed:
        raise SystemExit(f"{path}: no finished seed")
    first = next(iter(per_seed.values()))
    rows = [r for r in (*ABLATIONS, YARDSTICK) if r in first]
    summary = summarize(per_seed, rows)
    print(f"{len(per_seed)} seeds finished ({', '.join(map(str, per_seed))}), from {path}; in %")
    print("per seed (inst mIoU / class mIoU / recovered after a wrong first view):")
    print(format_per_seed(per_seed, rows))
    print("mean ± sample std over seeds:")
    print(format_summary(summary))
    out.mkdir(parents=True, exist_ok=True)
    img = plot_summary(summary, f"Ablation, {len(per_seed)} seeds", str(path))
    png = write_png(out / "ablation.png", img)
    print(f"wrote {png}")
    return 0


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
    ap.add_argument(
        "--noise", default=None, help="simulated-SAM level (segmentation/simulated.py NOISE_LEVELS)"
    )
    ap.add_argument(
        "--segments",
        default="simulated",
        choices=["simulated", "perfect"],
        help="perfect: every object clean in every frame, ids reshuffled per frame (noise 'none')",
    )
    ap.add_argument("--ablations", default=",".join(ABLATIONS), help=f"subset of {','.join(ABLATIONS)}")
    ap.add_argument("--no-yardstick", action="store_true", help="skip the offline view-consensus yardstick")
    ap.add_argument("--device", default=None, help="cpu, cuda (default: config, else CUDA if present)")
    ap.add_argument("--out", type=Path, default=Path("ablation_out"), help="runs, scenes, JSON and PNG")
    ap.add_argument(
        "--from-partial",
        type=Path,
        default=None,
        metavar="JSON",
        help="only report the seeds an earlier run finished (its ablation_partial.json)",
    )
    args = ap.parse_args(argv)
    if args.from_partial is not None:
        return report_partial(args.from_partial, args.out)

    if args.device is not None:
        resolve_device(args.device)  # no CUDA GPU for --device cuda: say so before any scene is made
    seeds = parse_seeds(args.seeds)
    ablations = [a.strip() for a in args.ablations.split(",") if a.strip()]
    for a in ablations:
        if a not in ABLATIONS:
            ap.error(f"unknown ablation {a!r}; expected some of {ABLATIONS}")
    if args.segments == "perfect" and args.noise not in (None, "none"):
        ap.error("--segments perfect is noise 'none'; leave --noise out")
    overrides = list(args.overrides)
    if args.frames is not None:
        overrides.append(f"synthetic.frames={args.frames}")
    if args.size is not None:
        w, h = (int(v) for v in args.size.lower().split("x"))
        overrides += [f"synthetic.width={w}", f"synthetic.height={h}"]
    noise = "none" if args.segments == "perfect" else args.noise
    if noise is not None:
        overrides.append(f"synthetic.noise={noise}")
    cfg = load_config(args.config, overrides)
    s = cfg.synthetic
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    rows = ablations + ([] if args.no_yardstick else [YARDSTICK])

    per_seed: dict[int, dict[str, dict]] = {}
    t_all = time.perf_counter()
    for seed in seeds:
        scene = configured_scene(out / "scenes" / f"seed_{seed}", dataclasses.replace(s, seed=seed))
        print(f"seed {seed}: mapping {len(ablations)} ablations of {scene} ...", file=sys.stderr, flush=True)
        res = run_ablation(cfg, scene, scene, out / f"seed_{seed}", ablations, args.device, ("hovsg",))
        per_seed[seed] = score_seed(scene, out / f"seed_{seed}", ablations, res, not args.no_yardstick)
        for row in rows:
            m = per_seed[seed][row]
            print(
                f"  {row:<13} inst mIoU {100 * m['inst']:.2f}  class mIoU {100 * m['cls']:.2f}  "
                f"recovered {m['recovered'][0]}/{m['recovered'][1]}  ({m['seconds']:.1f} s)",
                file=sys.stderr,
                flush=True,
            )
        # written after every seed: a run stopped early keeps the seeds it finished
        (out / "ablation_partial.json").write_text(json.dumps(json_safe(per_seed), indent=1) + "\n")
    protocol_text = (
        "class mIoU: HOV-SG, k=5 nearest Gaussians vote per GT point, "
        f"{'/'.join(HOVSG_DEFAULT_IGNORE)} left out; instance mIoU: Hungarian 1:1 labels to GT instances"
    )
    summary = summarize(per_seed, rows)
    segments_text = "perfect segments" if args.segments == "perfect" else f"simulated SAM '{s.noise}'"
    print()
    print(
        f"ablation on {len(seeds)} synthetic seeds ({s.frames} frames {s.width}x{s.height}, "
        f"{segments_text}), observed GT points, in %"
    )
    print(protocol_text)
    print("per seed (inst mIoU / class mIoU / recovered after a wrong first view):")
    print(format_per_seed(per_seed, rows))
    print("mean ± sample std over seeds:")
    print(format_summary(summary))
    print(f"paper, Replica (class mIoU a/b/c): {' / '.join(f'{v[0]:.2f}' for v in PAPER_REPLICA.values())}")
    print(f"total {time.perf_counter() - t_all:.0f} s on {args.device or cfg.device or 'auto'}")

    img = plot_summary(
        summary,
        f"Ablation, {len(seeds)} synthetic seeds ({s.frames} frames, {s.width}x{s.height}, {segments_text})",
        protocol_text,
    )
    png = write_png(out / "ablation.png", img)
    report = {
        "version": 2,
        "protocol_description": protocol_text,
        "gt_points": "observed",
        "label_naming": "majority overlap with GT instances (oracle), same for every row",
        "statistics": "mean, sample std (ddof=1), min, max over seeds; paired_inst = per-seed difference of "
        "instance mIoU to the previous mapping row",
        "seeds": seeds,
        "synthetic": {"frames": s.frames, "width": s.width, "height": s.height, "noise": s.noise},
        "segments": args.segments,
        "overrides": overrides,
        "summary": summary,
        "per_seed": {str(k): v for k, v in per_seed.items()},
    }
    (out / "ablation.json").write_text(json.dumps(json_safe(report), indent=2) + "\n")
    print(f"wrote {out / 'ablation.json'} and {png}")
    return 0


if __name__ == "__main__":
    run_main(main)
