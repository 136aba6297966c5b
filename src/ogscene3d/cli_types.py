"""argparse types shared by the commands (and the benchmarks): the CLI names the option in its message,
where a value would otherwise fail deep inside (a zero grid, stride, size or iteration count)."""

from __future__ import annotations

import argparse
from collections.abc import Callable


def positive_int(text: str) -> int:
    """An integer >= 1."""
    try:
        value = int(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from e
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    return value


def image_size(minimum: int = 1, example: str = "160x120") -> Callable[[str], tuple[int, int]]:
    """A ``WxH`` type with both sides >= ``minimum`` -> (width, height)."""

    def parse(text: str) -> tuple[int, int]:
        try:
            w, h = (int(v) for v in text.lower().split("x"))
        except ValueError as e:
            raise argparse.ArgumentTypeError(f"expected WxH such as {example}, got {text!r}") from e
        if w < minimum or h < minimum:
            raise argparse.ArgumentTypeError(f"width and height must be >= {minimum}, got {text!r}")
        return w, h

    return parse
