"""``ogscene3d eval``: evaluate a run directory against ground truth (3D semantics, scene graph, trajectory).

Score RUN_DIR (gaussians.ply, graph.json) against ground truth GT: a synthetic scene directory (found
automatically for runs of synthetic scenes), its gt/ folder, a labelled PLY (x, y, z, class[, instance]) with
a class-name table, a ScanNet scene folder (*_vh_clean_2.labels.ply, NYU40; label-filt/ for 2D), an original
Replica scene folder (habitat/mesh_semantic.ply + info_semantic.json, as HOV-SG scores Replica), or an RGB-D
sequence whose frames carry class maps but which has no 3D ground truth (label-fusion: scored in 2D only).
Prints a table and writes metrics.json and a per-class IoU bar chart into the run directory.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from ..errors import DataError, OGSceneError
from ..eval.options import add_eval_arguments, eval_options_from_args
from ..runs import METRICS, write_metrics
from .options import add_command


def add_parser(subparsers: Any) -> None:
    p = add_command(subparsers, __doc__, run)
    p.add_argument("run_dir", metavar="RUN_DIR", type=Path, help="run directory written by the mapper")
    p.add_argument(
        "--gt",
        type=Path,
        default=None,
        help="ground truth: scene dir, gt/ folder, labelled PLY, ScanNet scene folder, Replica scene folder "
        "(or its habitat/mesh_semantic.ply) or a sequence with per-frame class maps (default: the scene "
        "the run was made from, RUN_DIR/scene or config.yaml's data.path, when it holds one of these)",
    )
    add_eval_arguments(p, defaults={"num_views": 3})
    p.add_argument(
        "--traj",
        nargs=2,
        metavar=("EST", "GT"),
        type=Path,
        default=None,
        help="also report ATE RMSE between two trajectories, same poses in order: files (4x4/3x4 rows or "
        "TUM), or for GT the dataset folder the run read (its poses of the run's frames; e.g. --traj "
        "RUN_DIR/traj.txt DATA after a run with --poses odometry); without semantic ground truth, the ATE "
        "alone is reported",
    )
    p.add_argument("--device", default="cpu", help="rendering device for --views (cpu, cuda, cuda:0)")
    p.add_argument("--align", default="se3", choices=["se3", "sim3", "none"], help="trajectory alignment")
    p.add_argument(
        "--out", type=Path, default=None, help="where to write metrics.json and PNGs (default RUN_DIR)"
    )


def _pct(x: Any) -> str:
    return "   n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:6.2f}"


def run(args: argparse.Namespace) -> int:
    try:
        return _run(args)
    except OGSceneError:
        raise
    except ValueError as e:
        # The library validates its inputs with ValueError; on the command line they are input errors.
        raise OGSceneError(str(e)) from e


def _mapping_line(report: dict[str, Any]) -> str:
    """The label mapping, flagged when it looked at the ground truth to name the scene labels."""
    m = report["label_mapping"]
    # Overlap naming reads the GT classes, so its scores measure segmentation, not naming.
    oracle = " (oracle: names scene labels from the GT)" if m["method"] == "overlap" else ""
    if m.get("space") == "2d":
        oracle += f" from the rendered frames {m['frames']}"
    return (
        f"label mapping: {m['method']}{oracle}, "
        f"{m['num_mapped_labels']}/{m['num_scene_labels']} scene labels named"
    )


def _views_kind_line(v: dict[str, Any]) -> str:
    """Which kind of frames the 2D block scored: held out from the run, or frames of the mapped sequence."""
    if v.get("held_out"):
        r = v["run_frames"]
        where = (
            "outside the mapped range: extrapolated views"
            if v["extrapolated"]
            else "novel views between mapped frames"
        )
        return (
            f"held-out views {v['frames']}: frames the run did not map ({where}; it mapped {r['num_mapped']} "
            f"frames, {r['first']}..{r['last']}, {r['selection']})"
        )
    mapped = v.get("scored_frames_mapped")
    known = "" if mapped is None else f", {len(mapped)} of the {len(v['frames'])} mapped by the run"
    return f"views {v['frames']}: frames of the mapped sequence{known}, not held out (see --held-out)"


def _gaussians_line(report: dict[str, Any]) -> str:
    unlabelled = report.get("unlabelled_fraction", 0.0)
    if not report.get("has_3d_ground_truth", True):
        return (
            f"{report['num_gaussians_evaluated']} Gaussians ({100 * unlabelled:.1f}% unlabelled); "
            "no 3D ground truth: 2D only (rendered frames vs their class maps)"
        )
    return (
        f"{report['num_gaussians_evaluated']} Gaussians ({100 * unlabelled:.1f}% unlabelled: no vote under "
        f"hovsg, misses under conceptgraphs), {report['num_gt_points']} GT points"
    )


def _run(args: argparse.Namespace) -> int:
    from ..eval.metrics import format_metrics_table
    from ..eval.plots import write_iou_chart
    from ..eval.readers import find_ground_truth
    from ..eval.run_eval import evaluate_run

    options = eval_options_from_args(args)
    if not args.run_dir.is_dir():
        raise DataError(f"{args.run_dir}: no such run directory (RUN_DIR is the --out of ogscene3d run)")
    # Read the trajectories first so that a bad file fails before the (longer) map evaluation.
    traj = None if args.traj is None else _trajectories(args.traj, args.run_dir)
    gt_path = args.gt
    if gt_path is None:
        gt_path = find_ground_truth(args.run_dir)
        if gt_path is None and traj is not None:
            return _trajectory_only(args, traj)
        if gt_path is None:
            raise DataError(
                f"{args.run_dir}: no --gt given and no ground truth found (a synthetic scene with gt/ in "
                "RUN_DIR/scene or config.yaml data.path, or a data.path holding a ScanNet labels PLY or "
                "frames with class maps)"
            )
    result = evaluate_run(
        args.run_dir,
        gt_path,
        options,
        out_dir=None if not options.plots else (args.out or args.run_dir),
        device=args.device,
    )
    report = result.report
    if traj is not None:
        report["trajectory"] = _ate(traj, args.align)

    out = args.out or args.run_dir
    print(f"run: {args.run_dir}   ground truth: {report['ground_truth']}")
    print(_mapping_line(report))
    print(_gaussians_line(report))
    gp = report["gt_points"]
    if gp is not None and gp["points"] == "observed":
        print(
            f"scored on the {gp['num_scored']} labelled GT points some frame saw "
            f"({100 * gp['observed_fraction']:.0f}% of all; --gt-points all scores every point)"
        )
    for name, metrics in result.semantic.items():
        print()
        print(format_metrics_table(metrics))
        if options.plots:
            report["semantic_3d"][name]["bar_chart"] = write_iou_chart(out, name, metrics).name
    v = report.get("semantic_2d")
    if v:
        print()
        print(format_metrics_table(result.views, per_class=not report["has_3d_ground_truth"]))
        print(f"frames scored: {', '.join(v['frame_names'])} ({v['dataset_kind']} {v['source']})")
        print(_views_kind_line(v))
        if v["pictures"]:
            print(f"pictures: {', '.join(v['pictures'])}")
    g = report.get("scene_graph")
    if g:
        print()
        print(f"scene graph: {g['protocol']}")
        print(
            f"relation recall {_pct(g['recall'])}   edge recall {_pct(g['edge_recall'])}   "
            f"({g['num_recalled']}/{g['num_gt']} triplets; {g['num_unmatched_endpoint']} unmatched endpoint, "
            f"{g['num_no_edge']} no edge, {g['num_wrong_relation']} wrong relation; "
            f"{g['num_matched_nodes']} nodes matched)"
        )
    _print_rooms_and_queries(report)
    _finish(report, out)
    return 0


def _print_rooms_and_queries(report: dict[str, Any]) -> None:
    """The room segmentation and query accuracy lines (when the report has them)."""
    r = report.get("rooms")
    if r:
        print()
        print(f"rooms: {r['protocol']}")
        print(
            f"room precision {_pct(r['precision'])}   recall {_pct(r['recall'])}   (matched per room: "
            f"{_pct(r['matched_precision'])} / {_pct(r['matched_recall'])}; {r['num_gt_rooms']} GT rooms, "
            f"{r['num_pred_rooms']} predicted; types right: {r.get('types_correct', 'n/a')})"
        )
        for gid, row in r["per_room"].items():
            settle = row.get("settle_frames")
            when = "" if settle is None else f", node {settle:+d} frames after the room was entered"
            pred = row["pred_room"]
            name = f"#{pred} {r['pred_types'].get(str(pred), '')}" if pred is not None else "none"
            print(
                f"  GT room {gid} ({row.get('gt_type') or '?'}): precision {_pct(row['precision'])} recall "
                f"{_pct(row['recall'])} (room {name}{when})"
            )
    q = report.get("queries")
    if q:
        print()
        print(f"queries: {q['protocol']}")
        cells = [
            f"{k} {_pct(v['top1_accuracy'])} ({v['top1']}/{v['queries']}, {v['answerable']} answerable)"
            for k, v in q["per_kind"].items()
            if v["queries"]
        ]
        print("top-1   " + "   ".join(cells))


def _finish(report: dict[str, Any], out: Path) -> None:
    """Print the trajectory line and the notes, and write metrics.json."""
    t = report.get("trajectory")
    if t:
        print()
        print(
            f"trajectory: ATE RMSE {t['ate_rmse_m']:.4f} m after {t['alignment']} alignment "
            f"({t['num_poses']} poses{_left_out(t)})"
        )
    for note in report.get("notes", []):
        print(f"note: {note}")
    path = write_metrics(Path(out) / METRICS, report)
    print(f"\nwrote {path}")


def _trajectories(paths: list[Path], run_dir: Path) -> tuple[Any, Any, int]:
    """(estimated, ground truth, poses left out) for ``--traj EST GT``: GT a file, or the dataset folder
    the run read, whose frames without a valid pose are left out of both."""
    import numpy as np

    from ..eval.trajectory import dataset_trajectory, read_trajectory

    est = read_trajectory(paths[0])
    if not paths[1].is_dir():
        return est, read_trajectory(paths[1]), 0
    gt = dataset_trajectory(paths[1], run_dir)
    if len(gt) != len(est):
        raise DataError(
            f"{paths[0]} has {len(est)} poses, but the run read {len(gt)} frames of {paths[1]}: --traj with "
            "a dataset folder pairs the run's traj.txt with the frames the run read (give a GT trajectory "
            "file to pair another one)"
        )
    keep = [i for i, g in enumerate(gt) if g is not None]
    if len(keep) < 3:
        raise DataError(
            f"{paths[1]}: {len(keep)} of the run's {len(gt)} frames have a valid pose; ATE needs 3"
        )
    return est[keep], np.stack([gt[i] for i in keep]), len(gt) - len(keep)


def _ate(traj: tuple[Any, Any, int], align: str) -> dict[str, Any]:
    from ..eval.trajectory import ate

    t = ate(traj[0], traj[1], align).to_dict()  # type: ignore[arg-type]
    if traj[2]:
        t["num_left_out"] = traj[2]
    return t


def _left_out(t: dict[str, Any]) -> str:
    n = t.get("num_left_out", 0)
    return f"; {n} frames without a valid dataset pose left out" if n else ""


def _trajectory_only(args: argparse.Namespace, traj: tuple[Any, Any, int]) -> int:
    """``--traj`` for a run with no semantic ground truth (e.g. a 7-Scenes run under odometry)."""
    report: dict[str, Any] = {
        "run_dir": str(args.run_dir),
        "ground_truth": None,
        "trajectory": _ate(traj, args.align),
        "notes": ["no semantic ground truth found (--gt): trajectory only"],
    }
    print(f"run: {args.run_dir}   ground truth: none (trajectory only)")
    _finish(report, args.out or args.run_dir)
    return 0
