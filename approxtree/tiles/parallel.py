"""Tile batches as dask.distributed tasks (or in this process for one worker).

Web tiles are independent: a writer splits them into batches and ``run_batches`` calls
``fn(job, batch)`` for each. With ``workers == 1`` and no scheduler that happens here, in
order. Otherwise the batches are tasks on a dask cluster — a LocalCluster of ``workers``
processes (or threads, for work that releases the GIL) or the cluster at ``scheduler`` —
made with the build's helpers (tree/distributed.py); the job (terrain, tree, output
folder...) is scattered to every worker once, and the results come back in batch order, so
the output does not depend on where a tile was made. Workers write their tiles into the
job's folder themselves: a remote cluster must see that folder (a shared file system).
"""

from __future__ import annotations

import uuid
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from approxtree.errors import ApproxTreeError, InvalidParameterError
from approxtree.tree.distributed import check_cluster_options, dask_client

T = TypeVar("T")
R = TypeVar("R")


def check_workers(workers: int, scheduler: str | None) -> None:
    """InvalidParameterError for a worker count below 1 (or not an int), a local cluster
    larger than the machine (``check_cluster_options``) or a blank address."""
    if not (isinstance(workers, int) and not isinstance(workers, bool) and workers >= 1):
        raise InvalidParameterError(f"workers must be an integer >= 1, got {workers!r}.")
    # Both only when workers is left at 1: a scheduler's cluster has its own workers.
    check_cluster_options(workers if workers != 1 else None, scheduler)


def batches_of(items: Sequence[T], workers: int) -> list[Sequence[T]]:
    """``items`` cut into batches of at most 32, about 8 per worker, so that the workers stay
    busy to the end while each task carries enough tiles to pay for its scheduling."""
    size = max(1, min(32, len(items) // (8 * max(workers, 1))))
    return [items[i : i + size] for i in range(0, len(items), size)]


def run_batches(
    fn: Callable[[Any, Sequence[T]], list[R]],
    job: Any,
    items: Sequence[T],
    workers: int = 1,
    scheduler: str | None = None,
    what: str = "tiles",
    processes: bool = True,
) -> list[R]:
    """``fn(job, batch)`` over ``items`` cut into batches, concatenated in item order.

    workers == 1 and no scheduler: in this process. Else dask tasks on a LocalCluster of
    ``workers`` processes (one thread each; ``processes=False``: worker threads in this
    process, for work that releases the GIL) or on the cluster at ``scheduler``. A task that
    fails on a worker becomes an ApproxTreeError naming its first item.
    """
    check_workers(workers, scheduler)
    if workers == 1 and scheduler is None:
        return fn(job, items) if items else []
    # A cluster with N workers: batches sized for them (or for 8 per default on a scheduler).
    batches = batches_of(items, workers if scheduler is None else 8)
    out: list[R] = []
    # No more local workers than batches: the others would start only to wait.
    local = None if scheduler else max(1, min(workers, len(batches)))
    with dask_client(local, scheduler, processes) as client:
        # The job goes to every worker once (it holds the terrain), not with each task.
        [shared] = client.scatter([job], broadcast=True, hash=False)
        # Keys unique to this run: a key reused on a shared cluster could return another
        # run's result still held there.
        run_id = uuid.uuid4().hex[:12]
        futures = [
            client.submit(fn, shared, b, key=f"approxtree-{what}-{run_id}-{i}", pure=False)
            for i, b in enumerate(batches)
        ]
        try:
            for fut, batch in zip(futures, batches, strict=True):
                try:
                    out.extend(fut.result())
                except ApproxTreeError:
                    raise
                except Exception as exc:
                    raise ApproxTreeError(
                        f"Writing the {what} from {batch[0]!r} failed on a dask worker: "
                        f"{type(exc).__name__}: {exc}. Check the workers' memory and logs, and "
                        "that they can write the output folder."
                    ) from exc
                fut.release()
        finally:
            for fut in futures:
                fut.release()
    return out
