"""A solver's run with Python's cyclic garbage collector paused (``collector_paused``)."""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Iterator


@contextlib.contextmanager
def collector_paused() -> Iterator[None]:
    """Python's cyclic garbage collector off while a solver runs (reference counting still frees everything a solver
    drops: its factors, values and samples hold no cycles). The builders make many small objects, and each automatic
    collection of the oldest generation walks every object the process holds: after a report's earlier sessions, the
    head batch on BROAD's motion ran at 171x real time inside ``bench speed`` against 193x alone, 201x with the collector
    paused."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()
