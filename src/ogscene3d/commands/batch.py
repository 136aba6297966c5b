"""``ogscene3d run-batch``: map many scenes (sequentially or on a Ray cluster) and summarise them.

Map every scene of SCENES_FILE into OUT/<name> (like `ogscene3d run`), one scene per task; print a per-scene
table with mean/std and write OUT/run_batch.json. SCENES_FILE: a text file (one dataset folder or
synthetic:SEED per line) or a YAML list (strings or {path|synthetic, name, gt, segments, set}).

``ogscene3d eval-batch OUT`` (:data:`EVAL_BATCH_DOC`) evaluates such a folder. The engine, scenes files and
executors: :mod:`ogscene3d.batch`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ..batch import EXECUTORS, eval_batch, run_batch
from ..errors import OGSceneError
from ..eval.options import add_eval_arguments, eval_options_from_args
from .options import add_command, add_override_argument, add_shared_arguments

#: ``ogscene3d eval-batch``'s text (the module's docstring is run-batch's)
EVAL_BATCH_DOC = """``ogscene3d eval-batch``: evaluate every run of a batch folder and summarise (mean/std).

Evaluate every run directory under OUT (the scenes of OUT/run_batch.json, else every sub-folder with
gaussians.ply) like `ogscene3d eval`: writes each run's metrics.json, prints a per-scene table with mean/std
and writes OUT/eval_batch.json. Ground truth: the scene's `gt` from the scenes file, else the synthetic scene
the run was made from.
"""


def _add_executor_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--executor",
        default="sequential",
        choices=EXECUTORS,
        help="sequential (default): one scene after the other here; ray: one Ray task per scene",
    )
    p.add_argument(
        "--ray-address",
        default=None,
        help="Ray cluster to join (e.g. ray://head:10001 or auto); default: RAY_ADDRESS, else a local one",
    )
    p.add_argument(
        "--gpus-per-task",
        type=float,
        default=1.0,
        help="GPUs per Ray task when the cluster has GPUs (default 1)",
    )
    p.add_argument("--cpus-per-task", type=float, default=1.0, help="CPUs per Ray task (default 1)")
    add_shared_arguments(
        p, "--device", device="sequential executor: cpu, cuda or cuda:N (default: config, else CUDA)"
    )


def _executor_options(args: argparse.Namespace) -> dict[str, Any]:
    """The options of :func:`_add_executor_args`, as ``run_batch`` and ``eval_batch`` take them."""
    return {
        "executor": args.executor,
        "ray_address": args.ray_address,
        "gpus_per_task": args.gpus_per_task,
        "cpus_per_task": args.cpus_per_task,
        "device": args.device,
    }


def add_parser(subparsers: Any) -> None:
    p = add_command(subparsers, __doc__, _run_batch_cli)
    p.add_argument("scenes_file", metavar="SCENES_FILE", type=Path, help="text or YAML list of scenes")
    add_shared_arguments(
        p,
        "--out",
        "--config",
        out={"type": Path, "help": "batch output folder (one run directory per scene)"},
        config="YAML config for every scene (e.g. configs/replica.yaml)",
    )
    add_override_argument(p, "mapping.optimize.iters=5")
    _add_executor_args(p)
    g = p.add_argument_group("evaluation (with --eval)")
    g.add_argument("--eval", action="store_true", help="evaluate each run right after mapping (same task)")
    add_eval_arguments(g)

    q = add_command(subparsers, EVAL_BATCH_DOC, _eval_batch_cli)
    q.add_argument("out", metavar="OUT", type=Path, help="batch output folder of run-batch")
    _add_executor_args(q)
    add_eval_arguments(q)


def protocol_line(name: str, text: str) -> str:
    """The footer line of one protocol. Its text usually starts with the name ("hovsg (k=5 ...)"): say it
    once ("protocol hovsg (k=5 ...)"), not "protocol hovsg: hovsg (...)"."""
    if text == name or text.startswith((f"{name} ", f"{name}:")):
        return f"protocol {text}"
    return f"protocol {name}: {text}"


def _report(res: Any) -> int:
    print(res.table)
    for p, text in res.protocols.items():
        print(protocol_line(p, text))
    print(f"wrote {res.summary_path}")
    if res.num_failed == len(res.records):
        raise OGSceneError(f"all {len(res.records)} scene(s) failed")
    if res.num_failed:
        print(f"{res.num_failed} of {len(res.records)} scene(s) failed", file=sys.stderr)
        return 1
    return 0


def _run_batch_cli(args: argparse.Namespace) -> int:
    res = run_batch(
        args.scenes_file,
        args.out,
        config=args.config,
        overrides=args.overrides,
        evaluate=eval_options_from_args(args) if args.eval else None,
        **_executor_options(args),
    )
    return _report(res)


def _eval_batch_cli(args: argparse.Namespace) -> int:
    res = eval_batch(args.out, eval_options_from_args(args), **_executor_options(args))
    return _report(res)
