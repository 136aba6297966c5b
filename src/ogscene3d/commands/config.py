"""``ogscene3d config``: list every config setting: default, allowed values, doc.

Print every setting of the run configuration with its default, its allowed values (choices or range) and what
it does. --format yaml (default) prints a commented YAML file that load_config reads back (a starting point
for your own config); --format table one line per key. With --config / --set the values shown are those of
that configuration instead of the defaults.

The settings are read from the fields of :class:`ogscene3d.config.Config`.
"""

from __future__ import annotations

import argparse
import textwrap
from typing import Any

import yaml

from ..config import Setting, load_config, sections, settings
from ..errors import ConfigError
from .options import add_command, add_override_argument, add_shared_arguments


def add_parser(subparsers: Any) -> None:
    p = add_command(subparsers, __doc__, run)
    p.add_argument(
        "prefix", nargs="?", default="", help="show only the keys that start with this (e.g. mapping.tau)"
    )
    p.add_argument("--format", choices=["yaml", "table"], default="yaml", help="output form (default yaml)")
    add_shared_arguments(p, "--config", config="YAML config whose values to show instead of the defaults")
    add_override_argument(p, "mapping.association.tau_p=0.2")


def allowed_text(s: Setting) -> str:
    """What ``s`` accepts, in words: its choices, its range, or its type."""
    if s.choices is not None:
        return "one of " + ", ".join(str(c) for c in s.choices)
    if s.range is not None:
        return s.range.describe()
    return s.describe_type()


def _value(value: Any) -> str:
    """``value`` as YAML in one line (lists in flow style)."""
    return yaml.safe_dump([value], default_flow_style=True, width=10_000).strip()[1:-1]


def _selected(prefix: str, values: Any) -> list[tuple[Setting, Any]]:
    out = []
    for s in settings():
        if not s.key.startswith(prefix):
            continue
        value = values
        for part in s.key.split("."):
            value = getattr(value, part)
        out.append((s, value))
    return out


def format_yaml(items: list[tuple[Setting, Any]], width: int = 100) -> str:
    """A commented YAML document of ``items``: each setting preceded by its doc and allowed values."""
    section_docs = {key: doc for key, _, doc in sections()}
    lines: list[str] = []
    open_path: list[str] = []
    for s, value in items:
        *path, name = s.key.split(".")
        common = 0
        while common < min(len(path), len(open_path)) and path[common] == open_path[common]:
            common += 1
        for depth in range(common, len(path)):
            indent = "  " * depth
            if lines and depth == 0:
                lines.append("")
            doc = section_docs.get(".".join(path[: depth + 1]), "")
            if doc:
                lines.append(f"{indent}# {doc}")
            lines.append(f"{indent}{path[depth]}:")
        open_path = path
        indent = "  " * len(path)
        text = f"{s.doc} [{allowed_text(s)}]"
        lines += [f"{indent}# {t}" for t in textwrap.wrap(text, width - len(indent) - 2)]
        lines.append(f"{indent}{name}: {_value(value)}")
    return "\n".join(lines) + "\n"


def format_table(items: list[tuple[Setting, Any]], width: int = 110) -> str:
    """One line per setting: key, value, allowed values, doc (wrapped under the doc column)."""
    rows = [(s.key, _value(value), allowed_text(s), s.doc) for s, value in items]
    heads = ("key", "value", "allowed", "doc")
    w = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(heads[:2])]
    w.append(min(40, max(len(heads[2]), *(len(r[2]) for r in rows))))
    doc_col = sum(w) + 3 * 2
    doc_width = max(30, width - doc_col)
    out = ["  ".join(h.ljust(n) for h, n in zip(heads, [*w, 0])).rstrip()]
    for key, value, allowed, doc in rows:
        first = f"{key.ljust(w[0])}  {value.ljust(w[1])}  "
        allowed_lines = textwrap.wrap(allowed, w[2]) or [""]
        doc_lines = textwrap.wrap(doc, doc_width) or [""]
        for i in range(max(len(allowed_lines), len(doc_lines))):
            left = first if i == 0 else " " * len(first)
            a = allowed_lines[i] if i < len(allowed_lines) else ""
            d = doc_lines[i] if i < len(doc_lines) else ""
            out.append(f"{left}{a.ljust(w[2])}  {d}".rstrip())
    return "\n".join(out) + "\n"


def run(args: argparse.Namespace) -> int:
    values = load_config(args.config, args.overrides)
    items = _selected(args.prefix, values)
    if not items:
        raise ConfigError(f"no config key starts with {args.prefix!r} (`ogscene3d config` lists them all)")
    print(format_yaml(items) if args.format == "yaml" else format_table(items), end="")
    return 0
