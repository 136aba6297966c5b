"""Progress bars that log lines do not tear: the one helper every run loop uses for its bar.

A tqdm bar redraws its line in place (``\\r``) and never ends it, so a warning logged while it runs lands on
the bar's line ("mapping:   0%| ... WARNING ... falling back to the classical segmenter"). While a bar from
:func:`progress` is open, the console handlers of the root logger write through ``tqdm.write`` instead
(tqdm's own ``logging_redirect_tqdm``): the bar is cleared, the line printed, the bar redrawn below it. A
program that set up no logging gets a temporary handler for warnings, as Python's last-resort handler
would have printed them.

    with progress(ds.frames(start), desc="mapping", total=len(ds) - start) as frames:
        for frame in frames:
            ...
            frames.set_postfix(gaussians=n)
"""

from __future__ import annotations

import contextlib
import logging
import sys
from collections.abc import Iterable, Iterator
from typing import Any


@contextlib.contextmanager
def progress(
    iterable: Iterable[Any],
    *,
    desc: str,
    total: int | None = None,
    unit: str = "frame",
    disable: bool = False,
) -> Iterator[Any]:
    """A tqdm bar over ``iterable`` (``disable``: none, the iterable's items as they are), with logging
    routed through the bar while it is open. Yields the bar (iterate it; ``set_postfix`` works on it)."""
    from tqdm import tqdm
    from tqdm.contrib.logging import logging_redirect_tqdm

    bar = tqdm(iterable, desc=desc, total=total, unit=unit, disable=disable, dynamic_ncols=True)
    try:
        if disable:
            yield bar
            return
        root = logging.getLogger()
        fallback = None
        if not root.handlers:
            # what logging's last-resort handler prints (warnings and worse, the bare message), but as a
            # handler that logging_redirect_tqdm can route through the bar
            fallback = logging.StreamHandler(sys.stderr)
            fallback.setLevel(logging.WARNING)
            root.addHandler(fallback)
        try:
            with logging_redirect_tqdm(loggers=[root], tqdm_class=tqdm):
                yield bar
        finally:
            if fallback is not None:
                root.removeHandler(fallback)
    finally:
        bar.close()
