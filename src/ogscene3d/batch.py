"""Many scenes at once: the engine of ``ogscene3d run-batch SCENES_FILE --out OUT`` and ``eval-batch OUT``
(commands in :mod:`ogscene3d.commands.batch`).

A *scenes file* lists the sequences to map. Two forms:

* text (any suffix but .yaml/.yml/.json): one entry per line, ``#`` starts a comment. An entry is a
  dataset folder (Replica, ScanNet, TUM, 7-Scenes, synthetic; relative paths are relative to the
  scenes file) or ``synthetic:SEED``, a procedural room generated with the config's ``synthetic``
  section and that seed (into ``OUT/<name>/scene``, where ``ogscene3d eval`` finds its ground truth);
* YAML/JSON (.yaml/.yml/.json): a list, or ``{"scenes": [...]}``, of such strings or of mappings
  ``{path: DIR | synthetic: SEED, name: NAME, gt: GT, segments: DIR, set: [key=value, ...]}``
  (``gt`` is the ground truth for evaluation, ``set`` per-scene config overrides).

Every scene is mapped into ``OUT/<name>`` (a normal run directory). Executors:

* ``sequential`` (default): one scene after the other in this process;
* ``ray``: one Ray task per scene (``ray.init(address)``, or a local instance when no address and no
  ``RAY_ADDRESS``). A task asks for ``gpus_per_task`` GPUs when the cluster has GPUs (Ray then sets
  ``CUDA_VISIBLE_DEVICES`` and the task maps on ``cuda``), else it runs on the CPU. On a multi-node
  cluster ``OUT`` and the scene folders must be on a filesystem shared by all nodes, and ogscene3d
  must be installed on every node.

A scene that fails (bad data, out of memory, a crashed worker) is recorded with its error; the others
go on. The per-scene records, a text table and mean/std over the scenes that succeeded are printed
and written to ``OUT/run_batch.json`` / ``OUT/eval_batch.json``. ``std`` is the sample standard
deviation (ddof = 1; 0 for a single scene).
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import resource
import socket
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml

from .atomic import atomic_write_text
from .config import load_config
from .errors import ConfigError, DataError
from .eval.options import EvalOptions
from .runs import RunFolder, json_safe, write_metrics

log = logging.getLogger(__name__)

Executor = Literal["sequential", "ray"]
EXECUTORS = ("sequential", "ray")
RUN_SUMMARY = "run_batch.json"
EVAL_SUMMARY = "eval_batch.json"
_RAY_HINT = 'the ray executor needs Ray: pip install "ogscene3d[ray]"'
_PROTO_SHORT = {"hovsg": "HS", "conceptgraphs": "CG"}
_NAME_OK = re.compile(r"[^A-Za-z0-9._-]+")


# ---------------------------------------------------------------------------------------------- scenes
@dataclass(frozen=True)
class SceneSpec:
    """One entry of a scenes file. Exactly one of ``data`` / ``synthetic_seed`` is set; paths are absolute."""

    name: str
    data: str | None = None
    synthetic_seed: int | None = None
    gt: str | None = None
    segments: str | None = None
    overrides: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if (self.data is None) == (self.synthetic_seed is None):
            raise ConfigError(f"scene {self.name!r}: give exactly one of data and synthetic_seed")
        if not self.name or _NAME_OK.search(self.name) or self.name in (".", ".."):
            raise ConfigError(f"scene name {self.name!r} is not a plain folder name (letters, digits, . _ -)")

    def describe(self) -> str:
        return f"synthetic:{self.synthetic_seed}" if self.data is None else self.data


def _abs(path: Any, base: Path, what: str) -> str:
    if not isinstance(path, str) or not path.strip():
        raise ConfigError(f"{what}: expected a path string, got {path!r}")
    p = Path(path.strip()).expanduser()
    return str((p if p.is_absolute() else base / p).resolve())


def _parse_seed(text: Any, what: str) -> int:
    if isinstance(text, bool):
        raise ConfigError(f"{what}: synthetic seed must be an integer, got {text!r}")
    try:
        return int(str(text).strip())
    except ValueError:
        raise ConfigError(f"{what}: synthetic seed must be an integer, got {text!r}") from None


def _default_name(spec: dict[str, Any]) -> str:
    if spec.get("synthetic_seed") is not None:
        return f"synthetic_{spec['synthetic_seed']}"
    return Path(spec["data"]).name or "scene"


def parse_scene_entry(entry: Any, base: Path, where: str) -> dict[str, Any]:
    """One scenes-file entry (string or mapping) -> SceneSpec keyword arguments (name may be None)."""
    if isinstance(entry, str):
        text = entry.strip()
        if text.startswith("synthetic:"):
            return {"synthetic_seed": _parse_seed(text.split(":", 1)[1], where)}
        return {"data": _abs(text, base, where)}
    if not isinstance(entry, dict):
        raise ConfigError(f"{where}: expected a path, 'synthetic:SEED' or a mapping, got {entry!r}")
    known = {"path", "synthetic", "name", "gt", "segments", "set"}
    unknown = sorted(set(entry) - known)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; known: {sorted(known)}")
    if ("path" in entry) == ("synthetic" in entry):
        raise ConfigError(f"{where}: give exactly one of 'path' and 'synthetic'")
    out: dict[str, Any] = {}
    if "path" in entry:
        out["data"] = _abs(entry["path"], base, f"{where}.path")
    else:
        out["synthetic_seed"] = _parse_seed(entry["synthetic"], f"{where}.synthetic")
    if entry.get("name") is not None:
        name = str(entry["name"])
        if not name or _NAME_OK.search(name) or name in (".", ".."):
            raise ConfigError(f"{where}.name: {name!r} is not a plain folder name (letters, digits, . _ -)")
        out["name"] = name
    for key in ("gt", "segments"):
        if entry.get(key) is not None:
            out[key] = _abs(entry[key], base, f"{where}.{key}")
    sets = entry.get("set") or []
    if isinstance(sets, dict):
        # a nested mapping reads naturally in YAML: {mapping: {optimize: {iters: 2}}} ->
        # mapping.optimize.iters=2
        sets = [f"{k}={json.dumps(v)}" for k, v in _flatten(sets).items()]
    if not isinstance(sets, list) or not all(isinstance(s, str) and "=" in s for s in sets):
        raise ConfigError(f"{where}.set: expected a list of key=value strings or a mapping, got {sets!r}")
    out["overrides"] = tuple(sets)
    return out


def _flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


def read_scenes_file(path: str | Path) -> list[SceneSpec]:
    """Parse a scenes file (see the module docstring) into scenes with unique folder names.

    Default names are the dataset folder's name or ``synthetic_SEED``; repeated default names get
    ``_2``, ``_3``, ... A repeated explicit name is an error. Paths are made absolute relative to the
    scenes file; whether they exist is checked when the scene runs (on a cluster they may exist only
    on the workers), so a missing folder fails that scene alone.
    """
    p = Path(path)
    if not p.is_file():
        raise DataError(f"{p}: scenes file not found")
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise DataError(f"{p}: cannot read the scenes file ({e})") from None
    base = p.resolve().parent
    raw: list[tuple[Any, str]]
    if p.suffix.lower() in (".yaml", ".yml", ".json"):
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as e:
            raise DataError(f"{p}: invalid YAML ({e})") from None
        if isinstance(data, dict) and "scenes" in data:
            data = data["scenes"]
        if not isinstance(data, list):
            raise DataError(f"{p}: expected a list of scenes (or a mapping with a 'scenes' list)")
        raw = [(e, f"{p}: scene {i + 1}") for i, e in enumerate(data)]
    else:
        raw = []
        for i, line in enumerate(text.splitlines()):
            line = line.split("#", 1)[0].strip()
            if line:
                raw.append((line, f"{p}:{i + 1}"))
    if not raw:
        raise DataError(f"{p}: the scenes file lists no scene")
    parsed = [parse_scene_entry(e, base, where) for e, where in raw]
    explicit = [d["name"] for d in parsed if "name" in d]
    dup = sorted({n for n in explicit if explicit.count(n) > 1})
    if dup:
        raise ConfigError(f"{p}: scene name(s) {dup} are used more than once")
    taken = set(explicit)
    specs: list[SceneSpec] = []
    for d in parsed:
        if "name" not in d:
            stem = _NAME_OK.sub("_", _default_name(d)).strip("._") or "scene"
            name, k = stem, 2
            while name in taken:
                name, k = f"{stem}_{k}", k + 1
            d["name"] = name
        taken.add(d["name"])
        specs.append(SceneSpec(**d))
    return specs


# ------------------------------------------------------------------------------------------- one scene
def _peak_rss_mb() -> float:
    # ru_maxrss is KiB on Linux: the high-water mark of this whole process, i.e. per scene only when
    # each scene runs in its own process (Ray workers are reused, so it is an upper bound there).
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def map_scene(
    spec: SceneSpec,
    out_root: str | Path,
    config: str | Path | None = None,
    overrides: Sequence[str] = (),
    device: str | None = None,
    progress: bool = False,
) -> dict[str, Any]:
    """Map one scene into ``out_root/spec.name`` exactly as ``ogscene3d run`` does; return its record.

    ``overrides`` (then the scene's own, then ``device``) are applied to ``config``. A synthetic
    scene is generated (or reused) in ``out_root/name/scene`` from the config's ``synthetic``
    section with the scene's seed. Raises on failure (:func:`run_batch` turns that into a record).

    Returns a JSON-safe dict: name, status "ok", run_dir, data, device, host, frames, keyframes,
    gaussians, labels, map_seconds (processing + finalize), total_seconds (+ generation, I/O, save),
    fps (frames / map_seconds), peak_rss_mb, peak_cuda_mb (None on CPU).
    """
    # torch and the mapping inside: `ogscene3d --help` imports this module (run-batch's --executor choices)
    import torch

    from .mapping.session import mapping_session

    t_start = time.perf_counter()
    ov = [*overrides, *spec.overrides]
    if device is not None:
        ov.append(f"device={device}")
    cfg = load_config(config, ov)
    run_dir = Path(out_root) / spec.name
    data = None  # synthetic: the scene of the scene's seed, generated in RUN_DIR/scene
    if spec.synthetic_seed is not None:
        cfg.synthetic.seed = spec.synthetic_seed
    else:
        data = Path(str(spec.data))
    # recorded in config.yaml: where the frames came from (and where `eval` looks for ground truth); a scene
    # stopped by a bad frame resumes with `run --resume --out`
    with mapping_session(cfg, run_dir, data, command="run-batch", segments=spec.segments) as session:
        mapper = session.mapper
        dev = mapper.device
        if dev.type == "cuda":
            torch.cuda.reset_peak_memory_stats(dev)
        # bad frames raise, or are skipped with a warning (data.on_bad_frame)
        summary = session.run(progress=progress, desc=spec.name)
    if summary.status == "stopped":
        # Ctrl-C / SIGTERM: this scene's map so far is saved (`run --resume --out`); the batch stops
        raise KeyboardInterrupt(f"{run_dir}: stopped after {summary.read} frames")
    map_seconds = summary.seconds  # the frame loop and the final pass (synchronised by the timed sections)
    counts = mapper.timings.counts
    frames = int(mapper.frames_seen)
    return {
        "name": spec.name,
        "status": "ok",
        "run_dir": str(run_dir),
        "data": spec.describe(),
        "gt": spec.gt,
        "device": str(dev),
        "host": socket.gethostname(),
        "pid": os.getpid(),
        "frames": frames,
        "keyframes": int(mapper.keyframe_count),
        "gaussians": len(mapper.map),
        "labels": int(counts.get("labels", 0)),
        "map_seconds": map_seconds,
        "total_seconds": time.perf_counter() - t_start,
        "fps": frames / map_seconds if map_seconds > 0 else None,
        "peak_rss_mb": _peak_rss_mb(),
        "peak_cuda_mb": torch.cuda.max_memory_allocated(dev) / 2**20 if dev.type == "cuda" else None,
    }


def evaluate_scene(
    run_dir: str | Path,
    gt: str | Path | None = None,
    options: EvalOptions | None = None,
    device: str = "cpu",
    name: str | None = None,
) -> dict[str, Any]:
    """Evaluate one run directory like ``ogscene3d eval`` (writes ``RUN_DIR/metrics.json`` and, with
    ``options.plots``, per-protocol IoU bar charts); return a compact record.

    ``gt`` None: the ground truth of the scene the run was made from
    (:func:`ogscene3d.eval.find_ground_truth`).
    The record holds, per protocol, ``miou``/``fmiou``/``macc``/``oacc`` (fractions, None when not
    defined) and the protocol text, plus relation recall when the graph was scored.
    """
    from .eval import evaluate_run, find_ground_truth, write_iou_chart  # torch: as above

    opts = options or EvalOptions()
    run = Path(run_dir)
    if not RunFolder(run).gaussians.is_file():
        raise DataError(f"{run}: not a run directory (no gaussians.ply)")
    gt_path = Path(gt) if gt is not None else find_ground_truth(run)
    if gt_path is None:
        raise DataError(
            f"{run}: no ground truth given and none found for this run (a synthetic scene's gt/, ScanNet's "
            "*_vh_clean_2.labels.ply, or frames with class maps in its data.path)"
        )
    res = evaluate_run(run, gt_path, opts, out_dir=run if opts.plots else None, device=device)
    report = res.report
    if opts.plots:
        for proto, m in res.semantic.items():
            report["semantic_3d"][proto]["bar_chart"] = write_iou_chart(run, proto, m).name
    write_metrics(RunFolder(run).metrics, report)
    rec: dict[str, Any] = {
        "name": name or run.name,
        "status": "ok",
        "run_dir": str(run),
        "gt": str(gt_path),
        "label_mapping": report["label_mapping"]["method"],
        "semantic_3d": {
            p: {
                "protocol": m.protocol,
                "miou": m.miou,
                "fmiou": m.fmiou,
                "macc": m.macc,
                "oacc": m.overall_acc,
            }
            for p, m in res.semantic.items()
        },
    }
    if res.views is not None:
        rec["semantic_2d"] = {
            "protocol": res.views.protocol,
            "miou": res.views.miou,
            "macc": res.views.macc,
            "held_out": report["semantic_2d"]["held_out"],
        }
    if report.get("scene_graph"):
        rec["relation_recall"] = report["scene_graph"]["recall"]
    return json_safe(rec)


def map_and_evaluate(
    spec: SceneSpec,
    out_root: str | Path,
    config: str | Path | None,
    overrides: Sequence[str],
    evaluate: EvalOptions | None,
    device: str | None = None,
) -> dict[str, Any]:
    """:func:`map_scene`, then (when ``evaluate``) :func:`evaluate_scene` of its run, in one task.

    A failed evaluation keeps the mapping record (status "ok") and adds ``eval_error``.
    """
    rec = map_scene(spec, out_root, config, overrides, device)
    if evaluate is not None:
        try:
            ev = evaluate_scene(rec["run_dir"], spec.gt, evaluate, rec["device"], spec.name)
            rec["semantic_3d"] = ev["semantic_3d"]
            rec["gt"] = ev["gt"]
            for key in ("semantic_2d", "relation_recall"):
                if key in ev:
                    rec[key] = ev[key]
        except Exception as e:  # noqa: BLE001 - the map is done; report the evaluation problem next to it
            rec["eval_error"] = f"{type(e).__name__}: {e}"
    return json_safe(rec)


# ------------------------------------------------------------------------------------------- executors
@dataclass
class Task:
    """One unit of work: ``fn(*args, device=...)`` returning a record dict for scene ``name``."""

    name: str
    fn: Callable[..., dict[str, Any]]
    args: tuple[Any, ...]


def _guarded(fn: Callable[..., dict[str, Any]], name: str, args: tuple[Any, ...], device: str | None) -> dict:
    """Run a task and turn any exception into a 'failed' record (this runs inside Ray workers too)."""
    t0 = time.perf_counter()
    try:
        return fn(*args, device=device)
    except Exception as e:  # noqa: BLE001 - one scene's failure must not lose the others
        log.error("scene %s failed: %s: %s", name, type(e).__name__, e)
        return {
            "name": name,
            "status": "failed",
            "error": f"{type(e).__name__}: {e}",
            "traceback": traceback.format_exc(limit=8),
            "host": socket.gethostname(),
            "total_seconds": time.perf_counter() - t0,
        }


def _import_ray():
    try:
        import ray
    except ImportError as e:
        raise ConfigError(_RAY_HINT) from e
    return ray


def execute(
    tasks: Sequence[Task],
    executor: Executor = "sequential",
    ray_address: str | None = None,
    gpus_per_task: float = 1.0,
    cpus_per_task: float = 1.0,
    device: str | None = None,
) -> list[dict[str, Any]]:
    """Run ``tasks`` and return their records in the same order; failures become 'failed' records.

    ``sequential``: in this process on ``device`` (None: the config's, else CUDA if present).
    ``ray``: one Ray task each (``num_cpus=cpus_per_task``; ``num_gpus=gpus_per_task`` and device
    "cuda" when the cluster has GPUs and ``gpus_per_task > 0``, else device "cpu"). Uses the Ray
    connection of this process if there is one, else ``ray.init(address=ray_address)`` (a local
    instance when no address) which is shut down again at the end. A task whose worker dies is
    recorded as failed (it is retried once first, Ray's way for system failures).
    """
    if executor not in EXECUTORS:
        raise ConfigError(f"executor must be one of {EXECUTORS}, got {executor!r}")
    if executor == "sequential":
        out = []
        for i, t in enumerate(tasks):
            log.info("[%d/%d] %s", i + 1, len(tasks), t.name)
            out.append(_guarded(t.fn, t.name, t.args, device))
        return out
    if gpus_per_task < 0 or cpus_per_task < 0:
        raise ConfigError("--gpus-per-task and --cpus-per-task must be >= 0")
    ray = _import_ray()
    if device is not None:
        log.info("device=%s is not used by the ray executor: a task maps on cuda when it holds a GPU", device)
    started = False
    if not ray.is_initialized():
        ray.init(address=ray_address, include_dashboard=False, logging_level=logging.WARNING)
        started = True
    elif ray_address is not None:
        log.info("Ray is already initialised in this process: --ray-address %s is not used", ray_address)
    try:
        cluster_gpus = float(ray.cluster_resources().get("GPU", 0.0))
        use_gpu = cluster_gpus > 0 and gpus_per_task > 0
        task_device = "cuda" if use_gpu else "cpu"
        remote = ray.remote(_guarded).options(
            num_cpus=cpus_per_task, num_gpus=gpus_per_task if use_gpu else 0, max_retries=1
        )
        log.info(
            "Ray: %d task(s), %s per task (cluster: %g CPU, %g GPU)",
            len(tasks),
            f"{gpus_per_task:g} GPU" if use_gpu else f"{cpus_per_task:g} CPU, no GPU",
            ray.cluster_resources().get("CPU", 0.0),
            cluster_gpus,
        )
        refs = [remote.remote(t.fn, t.name, t.args, task_device) for t in tasks]
        index = {ref: i for i, ref in enumerate(refs)}
        results: list[dict[str, Any] | None] = [None] * len(tasks)
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            i = index[done[0]]
            try:
                results[i] = ray.get(done[0])
            except Exception as e:  # noqa: BLE001 - worker crash, OOM kill, node loss: record and go on
                results[i] = {"name": tasks[i].name, "status": "failed", "error": f"{type(e).__name__}: {e}"}
            r = results[i]
            log.info("[%d/%d] %s: %s", len(tasks) - len(pending), len(tasks), tasks[i].name, r["status"])
        return [r for r in results if r is not None]
    finally:
        if started:
            ray.shutdown()


# -------------------------------------------------------------------------------------------- summaries
RUN_COLUMNS: list[tuple[str, str, str]] = [
    # (record key, header, format)
    ("frames", "frames", "d"),
    ("keyframes", "kf", "d"),
    ("gaussians", "Gaussians", "d"),
    ("labels", "labels", "d"),
    ("map_seconds", "map s", ".1f"),
    ("fps", "fps", ".2f"),
    ("peak_rss_mb", "RSS MiB", ".0f"),
    ("peak_cuda_mb", "CUDA MiB", ".0f"),
]


def _metric_columns(records: Sequence[dict[str, Any]]) -> list[tuple[str, str, str]]:
    protos: list[str] = []
    for r in records:
        for p in r.get("semantic_3d") or {}:
            if p not in protos:
                protos.append(p)
    cols = []
    for p in protos:
        short = "" if len(protos) == 1 else f" {_PROTO_SHORT.get(p, p[:2])}"
        cols += [
            (f"semantic_3d.{p}.miou", f"mIoU{short}", "%"),
            (f"semantic_3d.{p}.fmiou", f"F-mIoU{short}", "%"),
            (f"semantic_3d.{p}.macc", f"mAcc{short}", "%"),
        ]
    if any(r.get("semantic_2d") for r in records):
        # held-out (novel-view) and mapped-frame 2D scores are not the same number: the header says which
        held = all((r.get("semantic_2d") or {}).get("held_out") for r in records if r.get("semantic_2d"))
        cols.append(("semantic_2d.miou", "2D mIoU held-out" if held else "2D mIoU", "%"))
    if any(r.get("relation_recall") is not None for r in records):
        cols.append(("relation_recall", "rel.rec", "%"))
    return cols


def _get(rec: dict[str, Any], key: str) -> Any:
    v: Any = rec
    for part in key.split("."):
        if not isinstance(v, dict):
            return None
        v = v.get(part)
    return v


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def aggregate(records: Sequence[dict[str, Any]], keys: Sequence[str]) -> dict[str, dict[str, Any]]:
    """Mean and sample std (ddof=1; 0 for one value) of each key over the records with status "ok"
    and a finite value; ``n`` is how many took part. Keys may be dotted paths into nested dicts."""
    out: dict[str, dict[str, Any]] = {}
    for key in keys:
        vals = [float(_get(r, key)) for r in records if r.get("status") == "ok" and _finite(_get(r, key))]
        if not vals:
            out[key] = {"mean": None, "std": None, "n": 0}
            continue
        mean = sum(vals) / len(vals)
        std = math.sqrt(sum((v - mean) ** 2 for v in vals) / (len(vals) - 1)) if len(vals) > 1 else 0.0
        out[key] = {"mean": mean, "std": std, "n": len(vals)}
    return out


def _fmt(v: Any, fmt: str) -> str:
    if not _finite(v):
        return "-"
    if fmt == "%":
        return f"{100 * v:.2f}"
    if fmt == "d":
        return f"{round(v):d}"
    return format(v, fmt)


def format_table(
    records: Sequence[dict[str, Any]], columns: Sequence[tuple[str, str, str]], agg: dict[str, dict[str, Any]]
) -> str:
    """Per-scene rows, then mean and std rows (percentages for metric columns), then the errors."""
    header = ["scene", "status", *(h for _, h, _ in columns)]
    rows = [
        [r.get("name", "?"), r.get("status", "?"), *(_fmt(_get(r, k), f) for k, _, f in columns)]
        for r in records
    ]
    n_ok = sum(1 for r in records if r.get("status") == "ok")
    stat_fmt = lambda f: ".2f" if f == "d" else f  # noqa: E731 - the mean of counts is fractional
    rows.append(
        ["mean", f"{n_ok}/{len(records)} ok", *(_fmt(agg[k]["mean"], stat_fmt(f)) for k, _, f in columns)]
    )
    rows.append(["std", "", *(_fmt(agg[k]["std"], stat_fmt(f)) for k, _, f in columns)])
    widths = [max(len(str(row[i])) for row in [header, *rows]) for i in range(len(header))]
    line = lambda row: "  ".join(  # noqa: E731
        str(c).ljust(w) if i < 2 else str(c).rjust(w) for i, (c, w) in enumerate(zip(row, widths))
    )
    sep = "-" * (sum(widths) + 2 * (len(widths) - 1))
    out = [line(header), sep, *(line(r) for r in rows[:-2]), sep, line(rows[-2]), line(rows[-1])]
    for r in records:
        if r.get("status") != "ok":
            out.append(f"{r.get('status')}: {r.get('name')}: {r.get('error')}")
        elif r.get("eval_error"):
            out.append(f"not evaluated: {r.get('name')}: {r['eval_error']}")
    return "\n".join(out)


@dataclass
class BatchResult:
    """Records (one per scene, input order), aggregates, the text table and the JSON summary path."""

    records: list[dict[str, Any]]
    aggregate: dict[str, dict[str, Any]]
    table: str
    summary_path: Path
    protocols: dict[str, str] = field(default_factory=dict)

    @property
    def num_failed(self) -> int:
        return sum(1 for r in self.records if r.get("status") != "ok")


def _protocol_texts(records: Sequence[dict[str, Any]]) -> dict[str, str]:
    out: dict[str, str] = {}
    for r in records:
        for p, m in (r.get("semantic_3d") or {}).items():
            out.setdefault(p, m.get("protocol", p))
    return out


def _finish(
    records: list[dict[str, Any]], columns: list[tuple[str, str, str]], path: Path, meta: dict[str, Any]
) -> BatchResult:
    agg = aggregate(records, [k for k, _, _ in columns])
    table = format_table(records, columns, agg)
    protocols = _protocol_texts(records)
    summary = {
        "version": 1,
        **meta,
        "protocols": protocols,
        "statistics": "mean and sample standard deviation (ddof=1) over the scenes with status ok",
        "scenes": records,
        "aggregate": agg,
    }
    atomic_write_text(path, json.dumps(json_safe(summary), indent=2, allow_nan=False) + "\n")
    return BatchResult(records, agg, table, path, protocols)


# ---------------------------------------------------------------------------------------------- batches
def run_batch(
    scenes: Sequence[SceneSpec] | str | Path,
    out: str | Path,
    config: str | Path | None = None,
    overrides: Sequence[str] = (),
    executor: Executor = "sequential",
    ray_address: str | None = None,
    gpus_per_task: float = 1.0,
    cpus_per_task: float = 1.0,
    device: str | None = None,
    evaluate: EvalOptions | None = None,
) -> BatchResult:
    """Map every scene (a list or a scenes file) into ``out/<name>``; optionally evaluate each run in
    the same task; write ``out/run_batch.json``. See :func:`execute` for the executors."""
    specs = read_scenes_file(scenes) if isinstance(scenes, (str, Path)) else list(scenes)
    if not specs:
        raise ConfigError("no scenes to run")
    names = [s.name for s in specs]
    if len(set(names)) != len(names):
        raise ConfigError(f"scene names must be unique, got {names}")
    # Fail fast on a bad config or override, before any scene starts (per-scene ones fail per scene).
    load_config(config, list(overrides))
    out_root = Path(out).resolve()
    out_root.mkdir(parents=True, exist_ok=True)
    cfg_arg = None if config is None else str(Path(config).resolve())
    tasks = [
        Task(s.name, map_and_evaluate, (s, str(out_root), cfg_arg, tuple(overrides), evaluate)) for s in specs
    ]
    records = execute(tasks, executor, ray_address, gpus_per_task, cpus_per_task, device)
    for s, r in zip(specs, records):
        r.setdefault("data", s.describe())
    cols = [*RUN_COLUMNS, *_metric_columns(records)]
    meta = {
        "command": "run-batch",
        "executor": executor,
        "config": cfg_arg,
        "overrides": list(overrides),
        "evaluation": None if evaluate is None else asdict(evaluate),
    }
    return _finish(records, cols, out_root / RUN_SUMMARY, meta)


def find_runs(out: str | Path) -> tuple[list[tuple[str, Path, str | None]], list[dict[str, Any]]]:
    """The runs under ``out`` and the scenes that were never mapped.

    Runs: (name, run_dir, gt or None) for the scenes of ``out/run_batch.json`` in its order (with
    their explicit ``gt``), then any other sub-folder; a run is a folder holding ``gaussians.ply``.
    Unmapped: a "not mapped" record for each scene of ``run_batch.json`` without ``gaussians.ply``
    (its mapping failed), so that the evaluation summary still lists it.
    """
    root = Path(out)
    if not root.is_dir():
        raise DataError(f"{root}: batch output folder not found")
    runs: list[tuple[str, Path, str | None]] = []
    unmapped: list[dict[str, Any]] = []
    seen: set[str] = set()
    summary = root / RUN_SUMMARY
    if summary.is_file():
        try:
            scenes = json.loads(summary.read_text())["scenes"]
            listed = [(s["name"], s) for s in scenes if isinstance(s["name"], str)]
        except (json.JSONDecodeError, KeyError, TypeError) as e:
            raise DataError(f"{summary}: not a run-batch summary ({e})") from None
        for name, s in listed:
            if name in seen or _NAME_OK.search(name):
                continue
            seen.add(name)
            # run directories are found relative to OUT, so a moved batch folder still works
            if RunFolder(root / name).gaussians.is_file():
                runs.append((name, root / name, s.get("gt")))
            else:
                why = s.get("error") or "no gaussians.ply in its run directory"
                unmapped.append({"name": name, "status": "not mapped", "error": f"run-batch: {why}"})
    for d in sorted(p for p in root.iterdir() if p.is_dir() and p.name not in seen):
        if RunFolder(d).gaussians.is_file():
            runs.append((d.name, d, None))
    if not runs and not unmapped:
        raise DataError(f"{root}: no run directories (sub-folders with gaussians.ply) found")
    return runs, unmapped


def _eval_task(run_dir: str, gt: str | None, options: EvalOptions, name: str, device: str | None) -> dict:
    return evaluate_scene(run_dir, gt, options, device or "cpu", name)


def eval_batch(
    out: str | Path,
    options: EvalOptions | None = None,
    executor: Executor = "sequential",
    ray_address: str | None = None,
    gpus_per_task: float = 1.0,
    cpus_per_task: float = 1.0,
    device: str | None = None,
) -> BatchResult:
    """Evaluate every run under ``out`` (see :func:`find_runs`), writing each run's ``metrics.json``
    and ``out/eval_batch.json``. Runs without a ground truth fail alone."""
    opts = options or EvalOptions()
    root = Path(out).resolve()
    runs, unmapped = find_runs(root)
    tasks = [Task(n, _eval_task, (str(d), gt, opts, n)) for n, d, gt in runs]
    records = execute(tasks, executor, ray_address, gpus_per_task, cpus_per_task, device) if tasks else []
    records += unmapped
    meta = {"command": "eval-batch", "executor": executor, "evaluation": asdict(opts)}
    return _finish(records, _metric_columns(records), root / EVAL_SUMMARY, meta)
