"""Progress bars for long work that stay quiet when nobody is watching (stderr not a terminal)."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

Item = TypeVar("Item")


def progress(items: Iterable[Item], total: int | None = None, desc: str = "", enabled: bool | None = None) -> Iterator[Item]:
    """``items`` with a tqdm bar on stderr when it is a terminal (or when ``enabled`` says so)."""
    show = sys.stderr.isatty() if enabled is None else enabled
    if not show:
        yield from items
        return
    from tqdm import tqdm

    yield from tqdm(items, total=total, desc=desc, file=sys.stderr, leave=False, dynamic_ncols=True)
