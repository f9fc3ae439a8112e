"""Workers for studies: a Dask client (a local cluster or an existing scheduler, with a clear error when none
answers) and the initializer that ties local pool workers to the study process."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from pathlib import Path
from typing import Any

#: How long to wait for an existing scheduler before giving up, seconds.
CONNECT_TIMEOUT_S = 10


@contextmanager
def dask_client(scheduler: str, workers: int) -> Iterator[Any]:
    """``scheduler == 'local'``: a LocalCluster of ``workers`` processes on this machine; else the address of a
    running scheduler (``tcp://host:port``). An unreachable address is a ValueError naming it, not a traceback."""
    from dask.distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=max(1, workers), threads_per_worker=1, processes=True, dashboard_address=None) if scheduler == "local" else None
    try:
        client = Client(cluster if cluster is not None else scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
    except (OSError, TimeoutError) as err:
        if cluster is not None:
            cluster.close()
        raise ValueError(f"--scheduler {scheduler}: no Dask scheduler answered within {CONNECT_TIMEOUT_S} s ({type(err).__name__}); "
                         "start one there (`dask scheduler`, then `dask worker ADDRESS`) or use --scheduler local") from None
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def die_with_parent() -> None:
    """Pool-worker initializer: on Linux, the worker is killed when the study process dies (even by kill -9),
    so no orphaned worker keeps running a study nobody reads."""
    import contextlib
    import ctypes
    import signal
    import sys

    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError):  # no libc by that name: the workers just are not tied
            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG = 1


def completed(fn: Callable[[Any], Any], items: Sequence[Any], workers: int, scheduler: str | None) -> Iterator[tuple[Any, Any]]:
    """``fn`` over ``items`` in this process (``workers <= 1``), a local process pool, or Dask (``scheduler``); yields
    ``(item, future)`` as each finishes, the future's ``result()`` giving ``fn(item)`` or raising what it raised."""
    if not items:
        return
    if scheduler is not None:
        from dask.distributed import as_completed as dask_completed

        with dask_client(scheduler, workers) as client:
            futures = {client.submit(fn, item, pure=False): item for item in items}
            for future in dask_completed(list(futures)):
                yield futures[future], future
        return
    if workers <= 1:
        for item in items:
            done: Future[Any] = Future()
            try:
                done.set_result(fn(item))
            except Exception as exc:  # noqa: BLE001 - handed to the caller through the future, as from a pool
                done.set_exception(exc)
            yield item, done
        return
    with ProcessPoolExecutor(max_workers=workers, initializer=die_with_parent) as pool:
        pending = {pool.submit(fn, item): item for item in items}
        for future in as_completed(pending):
            yield pending[future], future


def in_order(fn: Callable[[Any], Any], items: Sequence[Any], workers: int, scheduler: str | None = None,
             cost: Callable[[Any], float] | None = None, each: Callable[[Any, Any], None] | None = None) -> list[Any]:
    """``fn`` over ``items`` through ``completed`` (here, a local process pool, or Dask with ``scheduler``), the results in
    item order. ``cost``: how long an item takes, roughly; the costliest start first, so the workers finish together.
    ``each(item, result)``: called as each item finishes (to keep it before the others are done)."""
    position = {id(item): i for i, item in enumerate(items)}  # completed() hands back the very item objects
    results: list[Any] = [None] * len(items)
    for item, future in completed(fn, costliest_first(items, cost, workers, scheduler), workers, scheduler):
        results[position[id(item)]] = future.result()
        if each is not None:
            each(item, results[position[id(item)]])
    return results


def costliest_first(items: Sequence[Any], cost: Callable[[Any], float] | None, workers: int, scheduler: str | None) -> Sequence[Any]:
    """``items`` in the order to start them: the costliest first when they run in parallel (the last to start is a short
    one, so the workers finish together); as given otherwise or without a ``cost``."""
    if cost is None or (workers <= 1 and scheduler is None):
        return items
    return sorted(items, key=lambda item: -cost(item))


def path_bytes(where: str | Path) -> float:
    """A recording's cost for ``costliest_first``: the bytes of its file, or of the files of its folder."""
    path = Path(where)
    if path.is_dir():
        return float(sum(f.stat().st_size for f in path.iterdir() if f.is_file()))
    return float(path.stat().st_size) if path.is_file() else 0.0
