r"""The paper's ablation (Tab. "Ablation study") on synthetic seeds, rooms and long scans: per seed, averaged.

Each seed's scene (``--layout room``: the 60-frame procedural room; ``scan``: a 300-frame long scan,
``datasets/long_scan.py``; ``both``) is mapped with ``mapping.ablation`` = naive (KNN-majority labels, no
confidence, no refinement, no long-term), local (local 3D optimization only: the paper's row a),
local+global (+ global 3D refinement: row b), full (+ long-term global optimization: row c), by
:func:`ogscene3d.mapping.ablation.run_ablation`, and the same frames' segments are clustered offline by the
strong yardstick (``yardstick.py``: view consensus of all frames' segments with a separation rule).

Scores, on the GT points that some frame of the sequence saw (``gt/points.ply`` ``observed``), per row and
per seed:

* **instance mIoU**: scene labels matched one to one to GT instances (Hungarian, on IoU), mean over the GT
  instances, walls and floor included (``_instances.py``);
* **class mIoU / F-mIoU**: HOV-SG protocol (k=5 nearest Gaussians vote per GT point, wall/floor/ceiling
  left out of the means), scene labels named by majority overlap with the GT instances (an oracle naming,
  the same for every row, so differences come from the mapping alone);
* **labels**: scene labels in the final map (clusters, for the yardstick);
* **unlabelled**: the share of the observed GT points whose nearest Gaussian (voxel, for the yardstick)
  carries no label;
* **% of the yardstick**: the row's instance mIoU over the yardstick's, per seed;
* **% at its points**: the row's instance mIoU over that of the yardstick's labels taken at the row's own
  Gaussians (``yardstick.at_points``): the yardstick scores every voxel a frame saw, several times as many
  points as the map has, and this share leaves that out and compares the labelling alone;
* **recovered**: of the objects whose first view's segments got them wrong (absorbed into a surface, merged
  with their support or the floor, cut or missed), how many end with a matched label of IoU >= 0.5;
* **objects lost by repair**: the objects that the local row labels with IoU >= 0.5 and that end below 0.25
  in a later row (listed: seed, object, class, IoU local -> row).

Spread = sample standard deviation over seeds (ddof=1); the paired column gives the per-seed difference of
instance mIoU to the previous row and on how many seeds it is positive. ``--segments perfect`` maps every
object cleanly segmented in every frame (ids reshuffled per frame: simulated-SAM level "none"). The scene
graph is off (it does not change the semantic map). Long scans map with ``mapping.max_pose_step`` 1.6 m /
65 degrees (the check only warns; their jumps are meant). ``--reuse`` keeps the rows an earlier run of the
same settings mapped into OUT (a stopped run goes on; scores and yardstick are computed again).

    python benchmarks/ablation.py --seeds 0,1 --device cpu --set mapping.optimize.iters=1   # quick look
    python benchmarks/ablation.py --seeds 0-9 --layout both --device cpu --set mapping.optimize.iters=1 \
        --out abl
    python benchmarks/ablation.py --seeds 0-9 --segments perfect --ablations naive,full --no-yardstick

Writes OUT/ablation.json and OUT/ablation_<layout>.png (grouped bars of instance mIoU / class F-mIoU /
recovered %, error bars = ±1 std, dots = seeds). Paper, Replica (a/b/c class mIoU): 22.98 / 25.35 / 36.07.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import positive_int, run_main  # noqa: E402
from _instances import (  # noqa: E402
    class_scores,
    instance_scores,
    lost_objects,
    recovered,
    unlabelled_share,
    wrong_first_views,
)

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
LAYOUTS = ("room", "scan")
SCAN_FRAMES = 300
# the long scans' jumps (up to 1.5 m / 60 degrees) are meant: the pose-jump check (warn only) stays quiet
SCAN_OVERRIDES = ("mapping.max_pose_step=1.6", "mapping.max_pose_step_deg=65")
# (key, column title): the plotted metrics, fractions shown in %
METRICS = (("inst", "inst mIoU"), ("fcls", "class F-mIoU"), ("rec", "recovered %"))
# every per-seed number of a row that the summary averages (fractions)
SCALARS = ("inst", "cls", "fcls", "unlabelled", "rec", "of_yardstick", "of_yardstick_here")
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


def _stats(values: list) -> dict:
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
    """{row: {metric: stats with "values" per seed, "labels", "recovered", "paired_inst": stats of the
    per-seed instance-mIoU difference to the previous mapping row, with "positive" seeds}} over seeds."""
    out: dict[str, dict] = {}
    prev = None
    for row in rows:
        r: dict = {}
        for key in SCALARS:
            vals = [per_seed[s][row].get(key) for s in per_seed]
            r[key] = {**_stats(vals), "values": vals}
        labels = [per_seed[s][row].get("labels") for s in per_seed]
        r["labels"] = {**_stats(labels), "values": labels}
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


def lost_by_repair(per_seed: dict[int, dict[str, dict]], rows: list[str], names: dict) -> dict[str, list]:
    """{row: [(seed, object id, class, IoU in local, IoU in the row)]} for the rows after local."""
    out: dict[str, list] = {}
    if "local" not in rows:
        return out
    for row in rows[rows.index("local") + 1 :]:
        if row == YARDSTICK:
            continue
        out[row] = []
        for s, res in per_seed.items():
            before = {int(k): v for k, v in res["local"]["iou_per_instance"].items()}
            after = {int(k): v for k, v in res[row]["iou_per_instance"].items()}
            for i in lost_objects(before, after):
                out[row].append((s, i, names.get(s, {}).get(i, "?"), before[i], after.get(i, 0.0)))
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
    rows = [["row", "inst mIoU", "class mIoU", "class F-mIoU", "labels", "unlabelled %",
             "% of yardstick (min)", "% at its points (min)", "recovered", "Δinst vs prev (paired)",
             "seeds > 0"]]  # fmt: skip
    for name, r in summary.items():
        rec = [x for x in r["recovered"] if x is not None]
        rec_text = f"{sum(a for a, _ in rec)}/{sum(b for _, b in rec)}" if rec else "-"
        paired = r.get("paired_inst")
        ys, here = r["of_yardstick"], r["of_yardstick_here"]
        rows.append(
            [
                name,
                _pm(r["inst"]),
                _pm(r["cls"]),
                _pm(r["fcls"]),
                f"{r['labels']['mean']:.0f}" if r["labels"]["mean"] is not None else "-",
                _pm(r["unlabelled"], digits=1),
                f"{100 * ys['mean']:.1f} ({100 * ys['min']:.1f})" if ys["mean"] is not None else "-",
                f"{100 * here['mean']:.1f} ({100 * here['min']:.1f})" if here["mean"] is not None else "-",
                rec_text,
                _pm(paired) if paired else "",
                f"{paired['positive']}/{n}" if paired else "",
            ]
        )
    return _table(rows)


def format_per_seed(per_seed: dict[int, dict[str, dict]], rows: list[str]) -> str:
    """Per seed and row: instance mIoU / class F-mIoU / labels / unlabelled % / % of the yardstick."""
    table = [["seed", *rows]]
    for s, res in per_seed.items():
        cells = [str(s)]
        for row in rows:
            m = res[row]
            ys = f"{100 * m['of_yardstick']:.0f}%" if m.get("of_yardstick") is not None else "-"
            cells.append(f"{100 * m['inst']:.1f} / {100 * m['fcls']:.1f} / {m['labels']} / "
                         f"{100 * m['unlabelled']:.1f} / {ys}")  # fmt: skip
        table.append(cells)
    return _table(table)


def format_lost(lost: dict[str, list]) -> str:
    lines = []
    for row, items in lost.items():
        lines.append(f"{row}: {len(items)} object(s) lost by repair (local IoU >= 0.5, {row} < 0.25)")
        for s, i, cls, a, b in items:
            lines.append(f"  seed {s}, object {i} ({cls}): {a:.2f} -> {b:.2f}")
    return "\n".join(lines)


def plot_summary(
    summary: dict, title: str, subtitle: str, width: int = 1000, height: int = 540
) -> np.ndarray:
    """Grouped bars (instance mIoU, class F-mIoU, recovered %) per row with ±1 std error bars and per-seed
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


def _row_dir(seed_out: Path, abl: str) -> Path:
    return seed_out / abl.replace("+", "_")


def _fingerprint(cfg, abl: str, scene: Path) -> str:
    """What a reused row must have been mapped with: the settings and the scene's parameters."""
    seg, mapping = dataclasses.asdict(cfg.segmentation), dataclasses.asdict(cfg.mapping)
    doc = {"ablation": abl, "mapping": mapping, "seg": seg, "scene": (scene / "scene.json").read_text()}
    return hashlib.sha1(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


def map_rows(cfg, scene: Path, seed_out: Path, ablations: list[str], device, reuse: bool) -> dict[str, dict]:
    """Map the scene once per row (``run_ablation``), or take a row an earlier run mapped with the same
    settings (``reuse``). -> {row: {"hovsg": {miou, fmiou, macc}, "seconds", "gaussians", "labels"}}."""
    out: dict[str, dict] = {}
    for abl in ablations:
        record = _row_dir(seed_out, abl) / "ablation_row.json"
        key = _fingerprint(cfg, abl, scene)
        if reuse and record.is_file():
            saved = json.loads(record.read_text())
            if saved.get("fingerprint") == key:
                out[abl] = saved
                continue
        res = run_ablation(cfg, scene, scene, seed_out, [abl], device, ("hovsg",))[abl]
        res["fingerprint"] = key
        record.write_text(json.dumps(json_safe(res), indent=1) + "\n")
        out[abl] = res
    return out


def score_seed(
    scene: Path, seed_out: Path, res: dict[str, dict], yardstick: bool, depth_snap: float | None = None
) -> dict:
    """Every row's scores (see the module docstring), the yardstick's (on the segments moved onto the depth
    edges by ``depth_snap``, as the rows' mapper moved them), and the objects of wrong first views."""
    gt = load_ground_truth(scene)
    wrong = wrong_first_views(scene)
    rows: dict[str, dict] = {}
    means: dict[str, np.ndarray] = {}
    for abl, r in res.items():
        run = read_run(_row_dir(seed_out, abl))
        means[abl] = run.means
        inst = instance_scores(run.means, run.labels, gt)
        rows[abl] = {
            "inst": inst["miou"],
            "cls": r["hovsg"]["miou"],
            "fcls": r["hovsg"]["fmiou"],
            "labels": int(r["labels"]),
            "unlabelled": unlabelled_share(run.means, run.labels, gt),
            "recovered": recovered(inst["iou"], wrong),
            "iou_per_instance": inst["iou"],
            "seconds": r["seconds"],
            "gaussians": r["gaussians"],
        }
    if yardstick:
        from yardstick import _frames, at_points, strong_consensus

        t0 = time.perf_counter()
        pts, lab = strong_consensus(_frames(scene, depth_snap))
        inst = instance_scores(pts, lab, gt)
        cls, fcls = class_scores(pts, lab, gt)
        rows[YARDSTICK] = {
            "inst": inst["miou"],
            "cls": cls,
            "fcls": fcls,
            "labels": int(len(np.unique(lab[lab >= 0]))),
            "unlabelled": unlabelled_share(pts, lab, gt),
            "recovered": recovered(inst["iou"], wrong),
            "iou_per_instance": inst["iou"],
            "seconds": time.perf_counter() - t0,
        }
        # the rows of a seed share their Gaussians (the geometry places them; only the labels differ): the
        # yardstick's labels there are scored once per distinct set, not once per row
        here: dict[bytes, float] = {}
        for abl, m in means.items():
            key = np.ascontiguousarray(m).tobytes()
            if key not in here:
                here[key] = instance_scores(m, at_points(pts, lab, m), gt)["miou"]
            rows[abl]["yardstick_here"] = here[key]
    ys = rows.get(YARDSTICK, {}).get("inst")
    for r in rows.values():
        a, b = r["recovered"]
        r["rec"] = a / b if b else None
        r["of_yardstick"] = r["inst"] / ys if ys else None
        here = r.get("yardstick_here")
        r["of_yardstick_here"] = r["inst"] / here if here else None
    rows["wrong_first_views"] = {str(k): v for k, v in wrong.items()}  # type: ignore[assignment]
    rows["classes"] = {str(i): gt.class_names[c] for i, c in gt.instance_classes.items()}  # type: ignore
    return rows


def report(per_seed: dict[int, dict], title: str, out: Path, layout: str, subtitle: str) -> dict:
    """Print the tables of one layout, write its plot; -> its summary and lost objects."""
    first = next(iter(per_seed.values()))
    rows = [r for r in (*ABLATIONS, YARDSTICK) if r in first]
    summary = summarize(per_seed, rows)
    names = {s: {int(k): v for k, v in res.get("classes", {}).items()} for s, res in per_seed.items()}
    lost = lost_by_repair(per_seed, rows, names)
    print(title)
    print("per seed (inst mIoU / class F-mIoU / labels / unlabelled % / % of the yardstick's inst mIoU):")
    print(format_per_seed(per_seed, rows))
    print("mean ± sample std over seeds:")
    print(format_summary(summary))
    print(format_lost(lost))
    img = plot_summary({k: {m: v[m] for m, _ in METRICS} for k, v in summary.items()}, title, subtitle)
    png = write_png(out / f"ablation_{layout}.png", img)
    print(f"wrote {png}")
    return {"summary": summary, "lost_by_repair": lost}


def report_partial(path: Path, out: Path) -> int:
    """The tables and plots of the seeds a stopped run finished (``ablation_partial.json``)."""
    raw = json.loads(path.read_text())
    out.mkdir(parents=True, exist_ok=True)
    for layout, seeds in raw.items():
        per_seed = {int(k): v for k, v in seeds.items()}
        if not per_seed:
            continue
        title = f"{layout}: {len(per_seed)} seeds finished ({', '.join(map(str, per_seed))}), from {path}"
        report(per_seed, title, out, layout, str(path))
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", default="0,1,2", help="e.g. 0,1,2 or 0-4 (default 0,1,2)")
    ap.add_argument("--layout", default="room", choices=[*LAYOUTS, "both"], help="rooms, long scans or both")
    default_cfg = ROOT / "configs" / "synthetic.yaml"
    ap.add_argument("--config", default=str(default_cfg) if default_cfg.is_file() else None)
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument(
        "--frames", type=positive_int, default=None, help="frames per room (default: the config's)"
    )
    ap.add_argument(
        "--scan-frames", type=positive_int, default=SCAN_FRAMES, help=f"frames per scan ({SCAN_FRAMES})"
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
    ap.add_argument("--reuse", action="store_true", help="keep rows OUT holds that were mapped the same way")
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
    layouts = list(LAYOUTS) if args.layout == "both" else [args.layout]
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    protocol_text = (
        "class (F-)mIoU: HOV-SG, k=5 nearest Gaussians vote per GT point, "
        f"{'/'.join(HOVSG_DEFAULT_IGNORE)} left out; instance mIoU: Hungarian 1:1 labels to GT instances"
    )
    partial: dict[str, dict] = {}
    report_doc: dict = {"version": 3, "protocol_description": protocol_text, "gt_points": "observed",
                        "label_naming": "majority overlap with GT instances (oracle), same for every row",
                        "unlabelled": "share of observed GT points whose nearest Gaussian carries no label",
                        "statistics": "mean, sample std (ddof=1), min, max over seeds; paired_inst = "
                        "per-seed difference of instance mIoU to the previous mapping row", "seeds": seeds,
                        "segments": args.segments, "layouts": {}}  # fmt: skip
    t_all = time.perf_counter()
    for layout in layouts:
        overrides = list(args.overrides) + [f"synthetic.layout={layout}"]
        frames = args.frames if layout == "room" else args.scan_frames
        if frames is not None:
            overrides.append(f"synthetic.frames={frames}")
        if layout == "scan":
            overrides = list(SCAN_OVERRIDES) + overrides
        if args.size is not None:
            w, h = (int(v) for v in args.size.lower().split("x"))
            overrides += [f"synthetic.width={w}", f"synthetic.height={h}"]
        noise = "none" if args.segments == "perfect" else args.noise
        if noise is not None:
            overrides.append(f"synthetic.noise={noise}")
        cfg = load_config(args.config, overrides)
        s = cfg.synthetic
        per_seed: dict[int, dict[str, dict]] = {}
        for seed in seeds:
            scene = configured_scene(out / "scenes" / f"{layout}_{seed}", dataclasses.replace(s, seed=seed))
            seed_out = out / f"{layout}_{seed}"
            print(
                f"{layout} {seed}: mapping {len(ablations)} rows of {scene} ...", file=sys.stderr, flush=True
            )
            res = map_rows(cfg, scene, seed_out, ablations, args.device, args.reuse)
            snap = cfg.segmentation.depth_snap
            per_seed[seed] = score_seed(scene, seed_out, res, not args.no_yardstick, snap)
            for row, m in per_seed[seed].items():
                if row in ("wrong_first_views", "classes"):
                    continue
                print(
                    f"  {row:<13} inst mIoU {100 * m['inst']:.2f}  F-mIoU {100 * m['fcls']:.2f}  labels "
                    f"{m['labels']}  unlabelled {100 * m['unlabelled']:.1f} %  ({m['seconds']:.1f} s)",
                    file=sys.stderr,
                    flush=True,
                )
            # written after every seed: a run stopped early keeps the seeds it finished
            partial[layout] = per_seed
            (out / "ablation_partial.json").write_text(json.dumps(json_safe(partial), indent=1) + "\n")
        segments_text = "perfect segments" if args.segments == "perfect" else f"simulated SAM '{s.noise}'"
        title = f"{layout}s: {len(seeds)} seeds ({s.frames} frames {s.width}x{s.height}, {segments_text})"
        print()
        doc = report(per_seed, title, out, layout, protocol_text)
        report_doc["layouts"][layout] = {
            "synthetic": {"layout": layout, "frames": s.frames, "width": s.width, "height": s.height,
                          "noise": s.noise},
            "overrides": overrides,
            **doc,
            "per_seed": {str(k): v for k, v in per_seed.items()},
        }  # fmt: skip
    print(f"paper, Replica (class mIoU a/b/c): {' / '.join(f'{v[0]:.2f}' for v in PAPER_REPLICA.values())}")
    print(f"total {time.perf_counter() - t_all:.0f} s on {args.device or 'auto'}")
    (out / "ablation.json").write_text(json.dumps(json_safe(report_doc), indent=2) + "\n")
    print(f"wrote {out / 'ablation.json'}")
    return 0


if __name__ == "__main__":
    run_main(main)
