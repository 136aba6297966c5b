"""The evaluation options, defined once: :class:`EvalOptions` is what :func:`~ogscene3d.eval.evaluate_run`
takes, and its fields' metadata (flag, help, choices, conversion) generate the command-line options of
``ogscene3d eval``, ``eval-batch`` and ``run-batch --eval`` (:func:`add_eval_arguments`,
:func:`eval_options_from_args`).

This module imports nothing heavy, so that ``ogscene3d --help`` stays fast.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import ConfigError

PROTOCOLS: tuple[str, ...] = ("hovsg", "conceptgraphs")
#: ConceptGraphs' ``downsample_voxel_size`` (metres): its object clouds are voxel-downsampled at this size.
CONCEPTGRAPHS_VOXEL_SIZE = 0.025


def _comma_list(text: str | None) -> tuple[str, ...] | None:
    return None if text is None else tuple(s.strip() for s in text.split(",") if s.strip())


def _int_list(text: str | None) -> list[int] | None:
    if text is None:
        return None
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"expected comma-separated integers, got {text!r}") from None


def option(
    default: Any,
    flag: str,
    help: str,  # noqa: A002 - argparse's word
    *,
    cli_default: Any = dataclasses.MISSING,
    from_arg: Callable[[Any], Any] | None = None,
    **argparse_kwargs: Any,
) -> Any:
    """An evaluation setting with its command-line option: ``flag``, ``help`` (``%(default)s`` is filled in),
    the argparse keywords (``type``, ``choices``, ``action``, ``metavar``), the option's own default when it
    differs in form from the field's (``cli_default``), and ``from_arg`` turning the parsed value into the
    field's (a ValueError it raises becomes a ConfigError naming ``flag``)."""
    metadata = {
        "flag": flag,
        "help": help,
        "cli_default": default if cli_default is dataclasses.MISSING else cli_default,
        "from_arg": from_arg,
        "argparse": argparse_kwargs,
    }
    return field(default=default, metadata=metadata)


@dataclass(frozen=True)
class EvalOptions:
    """How a run is scored: the protocols, the label naming, and what is rendered. The same fields are
    keyword arguments of :func:`~ogscene3d.eval.evaluate_run` and options of the evaluation commands."""

    protocols: Sequence[str] = option(
        ("hovsg",),
        "--protocol",
        "hovsg: k-NN vote onto GT points, counted on GT points; conceptgraphs: nearest GT label per "
        "predicted point, counted on predicted points; both (default: %(default)s)",
        cli_default="hovsg",
        choices=[*PROTOCOLS, "both"],
        from_arg=lambda v: PROTOCOLS if v == "both" else (v,),
    )
    ignore: Sequence[str] | None = option(
        None,
        "--ignore",
        "comma-separated class names left out of the means (default: wall,floor,ceiling for hovsg, 'other' "
        "for conceptgraphs; '' = none); names matching no class are warned about. preset:hovsg-replica / "
        "preset:hovsg-scannet: the lists HOV-SG's own evaluation ignores, to compare with its tables",
        from_arg=_comma_list,
    )
    mapping: str = option(
        "auto",
        "--mapping",
        "naming of scene labels: text (graph node tags vs class names), overlap (majority overlap with GT "
        "instances: oracle), auto (text when tags match, else overlap; default)",
        choices=["auto", "text", "overlap"],
    )
    classes: str | Path | None = option(
        None,
        "--classes",
        "class-name JSON (list or {id: name}) for a bare labelled PLY or a sequence's per-frame class ids "
        "(label-fusion; default classes.json beside them; ScanNet's NYU40 names are built in); 'scannet20': "
        "ScanNet's 20 benchmark classes (the other NYU40 ids void), as HOV-SG scores ScanNet; 'nyu40': "
        "all 40",
    )
    k: int = option(5, "--k", "neighbours of the HOV-SG majority vote (default %(default)s)", type=int)
    cg_voxel_size: float = option(
        CONCEPTGRAPHS_VOXEL_SIZE,
        "--cg-voxel-size",
        "metres; conceptgraphs resamples the Gaussians to one point per scene label and voxel, like "
        "ConceptGraphs' voxel-downsampled object clouds (default %(default)s, its downsample_voxel_size; "
        "0 = every Gaussian counts)",
        type=float,
    )
    min_opacity: float = option(
        0.0, "--min-opacity", "drop Gaussians below this opacity (default %(default)s: keep all)", type=float
    )
    assoc_radius: float | None = option(
        0.1,
        "--assoc-radius",
        "metres; Gaussians farther from the GT take no part in overlap mapping and node matching "
        "(default %(default)s; 0 = no limit)",
        type=float,
        from_arg=lambda v: v if v > 0 else None,
    )
    gt_points: str = option(
        "observed",
        "--gt-points",
        "score only GT points some frame saw, where the GT says so (synthetic scenes; default), or all of "
        "them",
        choices=["observed", "all"],
    )
    min_node_iou: float = option(
        0.1, "--min-node-iou", "IoU for a node to match a GT instance (default %(default)s)", type=float
    )
    num_views: int = option(
        0,
        "--views",
        "render the map at this many evenly spread frames of a GT sequence whose frames carry class maps "
        "(synthetic, label-fusion, ScanNet label-filt/): 2D metrics and RGB | labels | GT | confidence PNGs "
        "(default %(default)s; 0 = none; --no-plots keeps the metrics only). The frames are spread over the "
        "whole sequence, mostly frames the run mapped; --held-out picks frames it did not map",
        type=int,
    )
    view_frames: Sequence[int] | None = option(
        None,
        "--view-frames",
        "comma-separated frame indices to render instead (positions in the whole sequence: the run's "
        "data.start/stride/max_frames do not apply)",
        from_arg=_int_list,
    )
    held_out: bool = option(
        False,
        "--held-out",
        "score held-out novel views: the --views frames are spread over the frames the run did NOT map (its "
        "config.yaml's data.start/stride/max_frames, and how far map.npz says it got), those between its "
        "first and last mapped frames first (e.g. every odd frame of a run at --set data.stride=2); frames "
        "outside that range only when no other is left (extrapolation, noted). --view-frames that the run "
        "mapped are refused. A run that mapped every frame has none (map at --set data.stride=2)",
        action="store_true",
    )
    mapping_frames: Sequence[int] | None = option(
        None,
        "--mapping-frames",
        "without 3D GT: comma-separated frame indices whose renders the overlap mapping reads (default: the "
        "scored frames; with --held-out as many evenly spread frames the run mapped)",
        from_arg=_int_list,
    )
    plots: bool = option(
        True,
        "--no-plots",
        "write no PNG (bar chart, views)",
        cli_default=False,
        action="store_true",
        from_arg=lambda v: not v,
    )

    def replace(self, **changes: Any) -> EvalOptions:
        """A copy with ``changes`` (field names; an unknown one is a TypeError naming it)."""
        return dataclasses.replace(self, **changes)

    def check(self, cli: bool = False) -> None:
        """Raise :class:`ConfigError` for the first value out of its range, naming the option (``cli``: its
        command-line flag, else the field)."""

        def name(f: str) -> str:
            return _FLAGS[f] if cli else f

        for p in self.protocols:
            if p not in PROTOCOLS:
                raise ConfigError(f"unknown protocol {p!r}; expected one of {PROTOCOLS}")
        if self.gt_points not in ("observed", "all"):
            raise ConfigError(f"{name('gt_points')} must be 'observed' or 'all', got {self.gt_points!r}")
        if self.mapping not in ("auto", "text", "overlap"):
            raise ConfigError(f"{name('mapping')} must be 'auto', 'text' or 'overlap', got {self.mapping!r}")
        if self.k < 1:
            raise ConfigError(f"{name('k')} must be >= 1, got {self.k}")
        if self.num_views < 0:
            raise ConfigError(f"{name('num_views')} must be >= 0, got {self.num_views}")
        if not (math.isfinite(self.cg_voxel_size) and self.cg_voxel_size >= 0):
            raise ConfigError(
                f"{name('cg_voxel_size')} must be >= 0 metres (0 = none), got {self.cg_voxel_size}"
            )
        if self.held_out and self.num_views <= 0 and not self.view_frames:
            raise ConfigError(
                f"{name('held_out')} needs views to score: {name('num_views')} N (N > 0) or "
                f"{name('view_frames')}"
            )


_FLAGS = {f.name: f.metadata["flag"] for f in dataclasses.fields(EvalOptions)}


def add_eval_arguments(parser: Any, defaults: dict[str, Any] | None = None) -> None:
    """Add every :class:`EvalOptions` field's option to ``parser`` (a parser or an argument group).
    ``defaults``: a command's own defaults, by field name, in the option's form (``{"num_views": 3}``)."""
    defaults = defaults or {}
    for f in dataclasses.fields(EvalOptions):
        md = f.metadata
        default = defaults.get(f.name, md["cli_default"])
        kwargs = dict(md["argparse"])
        if "action" not in kwargs and "choices" not in kwargs:
            kwargs.setdefault("metavar", md["flag"].lstrip("-").upper().replace("-", "_"))
        parser.add_argument(md["flag"], dest=f"eval_{f.name}", default=default, help=md["help"], **kwargs)


def eval_options_from_args(args: argparse.Namespace) -> EvalOptions:
    """The :class:`EvalOptions` of parsed options (:func:`add_eval_arguments`), checked."""
    values = {}
    for f in dataclasses.fields(EvalOptions):
        value = getattr(args, f"eval_{f.name}")
        convert = f.metadata["from_arg"]
        try:
            values[f.name] = convert(value) if convert is not None else value
        except ValueError as e:  # a from_arg's message, named by the option
            raise ConfigError(f"{f.metadata['flag']}: {e}") from None
    opts = EvalOptions(**values)
    opts.check(cli=True)
    return opts
