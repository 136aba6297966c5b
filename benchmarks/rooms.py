r"""Rooms and queries on synthetic apartments: room segmentation, how soon rooms appear, query accuracy, and
what the room update costs.

Per seed: the apartment of ``configs/apartment.yaml`` (``synthetic.layout: apartment``, simulated segments
and detector names at the config's noise level) is generated, mapped with the scene graph on, and evaluated
with ``ogscene3d.eval.evaluate_run``:

* rooms, as HOV-SG scores them (``ogscene3d.eval.rooms``): precision of every predicted room and recall of
  every ground-truth room on the bird's-eye view, their means, and per GT room its matched room's precision
  and recall; ``settle``: frames from the camera's first frame in a room to the first frame its node
  existed (negative: seen through a doorway first);
* queries generated from the ground truth (``ogscene3d.eval.queries``), answered offline: top-1 success per
  kind (object; object + relation + object; object + room);
* cost: the seconds the room updates took (``SceneGraph.timings["graph_rooms"]``: the segmentation, the
  object assignment and the typing, every ``graph.rooms.update_every`` keyframes and at every graph update)
  against the run's mapping seconds, both per keyframe, in the same run (a ratio: the machine's load
  cancels).

The pooled lines give the means over all rooms of all seeds (precision over predicted rooms, recall over
GT rooms), the lowest rooms (what a mean hides), and the query accuracy over all queries. No timed asserts:
this only reports.

    python benchmarks/rooms.py --seeds 0-9 --out /tmp/rooms-bench
    python benchmarks/rooms.py --seeds 0-9 --out /tmp/rooms-bench --reuse      # reprint finished seeds
    python benchmarks/rooms.py --seeds 0-9 --out /tmp/rooms-bench --reuse --rescore   # evaluate them again
    python benchmarks/rooms.py --seeds 0 --set synthetic.frames=40 --out /tmp/rooms-quick --json out.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import print_table, run_main  # noqa: E402

from ogscene3d.batch import json_safe  # noqa: E402

KINDS = ("object", "relation", "room")


def _seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b or a) + 1))
    return out


def map_and_score(seed: int, out: Path, config: str, overrides: list[str], device: str | None) -> dict:
    """Generate, map and evaluate one apartment; the record of ``rooms_seed.json``."""
    from ogscene3d.config import load_config
    from ogscene3d.mapping.session import mapping_session, synthetic_scene

    cfg = load_config(config, [*overrides, *([f"device={device}"] if device else [])])
    if cfg.synthetic.layout != "apartment":
        raise SystemExit(f"{config}: synthetic.layout must be apartment (got {cfg.synthetic.layout})")
    cfg.synthetic.seed = seed
    root = out / f"seed_{seed}"
    scene = synthetic_scene(cfg, root / "scene")
    with mapping_session(cfg, root / "run", scene, command="benchmarks/rooms.py") as session:
        mapper = session.mapper
        summary = session.run()
    graph = mapper.graph
    if graph is None:
        raise RuntimeError(f"seed {seed}: the scene graph failed during mapping (see the log)")
    rooms_t = graph.timings.get("graph_rooms", {"seconds": 0.0, "count": 0})
    rec = {
        "seed": seed,
        "frames": int(mapper.frames_seen),
        "keyframes": max(int(mapper.keyframe_count), 1),
        "map_seconds": summary.seconds,
        "room_seconds": rooms_t["seconds"],
        "room_updates": rooms_t["count"],
    }
    return score(rec, root)


def score(rec: dict, root: Path) -> dict:
    """``rec`` with the evaluation of ``root``'s run against its scene (rooms, queries, notes)."""
    from ogscene3d.eval import evaluate_run

    t0 = time.perf_counter()
    report = evaluate_run(root / "run", root / "scene", plots=False, protocols=["hovsg"])
    return {
        **rec,
        "eval_seconds": time.perf_counter() - t0,
        "rooms": report.report["rooms"],
        "queries": report.report["queries"],
        "notes": report.report["notes"],
    }


HEADERS = ["seed", "rooms gt/pred", "P %", "R %", "matched P %", "matched R %", "types right",
           "settle (frames)", *(f"top-1 {k}" for k in KINDS), "room ms/kf", "keyframe ms",
           "room share %"]  # fmt: skip


def _row(rec: dict) -> dict:
    r, q = rec["rooms"] or {}, rec["queries"]["per_kind"]
    kf = rec["keyframes"]
    settle = [
        row["settle_frames"] for row in r.get("per_room", {}).values() if row["settle_frames"] is not None
    ]
    values = [
        rec["seed"],
        f"{r.get('num_gt_rooms', 0)}/{r.get('num_pred_rooms', 0)}",
        100 * r.get("precision", float("nan")),
        100 * r.get("recall", float("nan")),
        100 * r.get("matched_precision", float("nan")),
        100 * r.get("matched_recall", float("nan")),
        f"{r.get('types_correct', '-')}/{r.get('num_gt_rooms', 0)}",
        f"{min(settle)}..{max(settle)}" if settle else "-",
        *(f"{v['top1']}/{v['queries']}" for v in (q[k] for k in KINDS)),
        1000 * rec["room_seconds"] / kf,
        1000 * rec["map_seconds"] / kf,
        100 * rec["room_seconds"] / max(rec["map_seconds"], 1e-9),
    ]
    return dict(zip(HEADERS, values))


def pooled(records: list[dict]) -> dict:
    """Means over all rooms of all seeds, the lowest rooms, settle frames, query accuracy per kind, cost."""
    prec = [p for rec in records for p in (rec["rooms"] or {}).get("pred_precision", {}).values()]
    rows = [
        {"seed": rec["seed"], "gt_room": int(g), **row}
        for rec in records
        for g, row in (rec["rooms"] or {}).get("per_room", {}).items()
    ]
    recall = [row["best_recall"] for row in rows]
    settle = [row["settle_frames"] for row in rows if row["settle_frames"] is not None]
    kinds = {}
    for k in KINDS:
        n = sum(rec["queries"]["per_kind"][k]["queries"] for rec in records)
        ok = sum(rec["queries"]["per_kind"][k]["top1"] for rec in records)
        can = sum(rec["queries"]["per_kind"][k]["answerable"] or 0 for rec in records)
        kinds[k] = {"queries": n, "top1": ok, "top1_accuracy": ok / n if n else None, "answerable": can}
    room_s = sum(rec["room_seconds"] for rec in records)
    map_s = sum(rec["map_seconds"] for rec in records)
    kfs = sum(rec["keyframes"] for rec in records)
    worst = sorted(rows, key=lambda r: min(r["precision"], r["recall"]))[:5]
    return {
        "rooms_gt": len(rows),
        "rooms_pred": len(prec),
        "precision_mean": sum(prec) / len(prec) if prec else None,
        "recall_mean": sum(recall) / len(recall) if recall else None,
        "matched_precision_mean": sum(r["precision"] for r in rows) / len(rows) if rows else None,
        "matched_recall_mean": sum(r["recall"] for r in rows) / len(rows) if rows else None,
        "rooms_unmatched": sum(r["pred_room"] is None for r in rows),
        "types_correct": sum(
            r.get("gt_type") is not None and r.get("gt_type") == r.get("pred_type") for r in rows
        ),
        "settle_frames": {
            "mean": sum(settle) / len(settle) if settle else None,
            "median": sorted(settle)[len(settle) // 2] if settle else None,
            "max": max(settle) if settle else None,
            "rooms_never_seen": len(rows) - len(settle),
        },
        "worst_rooms": worst,
        "queries": kinds,
        "room_ms_per_keyframe": 1000 * room_s / max(kfs, 1),
        "map_ms_per_keyframe": 1000 * map_s / max(kfs, 1),
        "room_share": room_s / map_s if map_s else None,
    }


def main() -> int:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter
    )
    p.add_argument("--seeds", default="0-9", help="apartment seeds, e.g. 0-9 or 0,3,5 (default 0-9)")
    p.add_argument("--config", default="configs/apartment.yaml", help="an apartment config")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument(
        "--device", default="cpu", help="mapping device (default cpu: the room cost is a CPU figure)"
    )
    p.add_argument("--out", required=True, type=Path, help="folder for the scenes, runs and per-seed records")
    p.add_argument("--reuse", action="store_true", help="take a seed's record from OUT when it is there")
    p.add_argument(
        "--rescore",
        action="store_true",
        help="with --reuse: evaluate the runs in OUT again (after a change to the evaluation or the queries; "
        "the mapping figures stay the record's)",
    )
    p.add_argument("--json", type=Path, help="write the per-seed records and the pooled figures here")
    args = p.parse_args()
    records = []
    for seed in _seeds(args.seeds):
        path = args.out / f"seed_{seed}" / "rooms_seed.json"
        if args.reuse and path.is_file():
            rec = json.loads(path.read_text())
            if args.rescore:
                rec = score(rec, path.parent)
                path.write_text(json.dumps(json_safe(rec), indent=1))
        else:
            rec = map_and_score(seed, args.out, args.config, args.overrides, args.device)
            path.write_text(json.dumps(json_safe(rec), indent=1))
        records.append(rec)
        print(
            f"seed {seed}: {rec['frames']} frames, {rec['keyframes']} keyframes, {rec['map_seconds']:.0f} s",
            flush=True,
        )
    print_table([_row(r) for r in records], HEADERS)
    pool = pooled(records)
    pct = {k: 100 * (pool[k] or 0) for k in ("precision_mean", "recall_mean", "matched_precision_mean",
                                              "matched_recall_mean")}  # fmt: skip
    print(
        f"\npooled over {pool['rooms_gt']} GT rooms and {pool['rooms_pred']} predicted rooms: precision "
        f"{pct['precision_mean']:.1f} %, recall {pct['recall_mean']:.1f} % (HOV-SG); matched per room "
        f"{pct['matched_precision_mean']:.1f} / {pct['matched_recall_mean']:.1f} %, "
        f"{pool['rooms_unmatched']} GT rooms unmatched; room types right for {pool['types_correct']}"
    )
    s = pool["settle_frames"]
    print(
        f"rooms appear {s['median']} frames after they are entered (median; mean {s['mean']}, max "
        f"{s['max']}; {s['rooms_never_seen']} never)"
    )
    for k, v in pool["queries"].items():
        acc = "n/a" if v["top1_accuracy"] is None else f"{100 * v['top1_accuracy']:.1f} %"
        print(f"queries {k}: top-1 {acc} ({v['top1']}/{v['queries']}; {v['answerable']} answerable)")
    print(
        f"room update {pool['room_ms_per_keyframe']:.1f} ms per keyframe of "
        f"{pool['map_ms_per_keyframe']:.0f} ms: {100 * (pool['room_share'] or 0):.2f} % of the keyframe time"
    )
    for w in pool["worst_rooms"]:
        print(f"  lowest: seed {w['seed']} GT room {w['gt_room']}: precision {100 * w['precision']:.1f} %, "
              f"recall {100 * w['recall']:.1f} % (predicted room {w['pred_room']})")  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps(json_safe({"records": records, "pooled": pool}), indent=1))
    return 0


if __name__ == "__main__":
    run_main(main)
