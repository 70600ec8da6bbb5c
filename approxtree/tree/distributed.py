"""Block tasks on dask.distributed: a LocalCluster of N processes, or an existing scheduler.

``dask_runner`` returns the ``run`` callable of ``tree.blocks.build_blocked``: it submits one
task per block, reports blocks done (as they complete) to a progress callback, optionally
records a dask performance report (an HTML file with the task stream: where the time goes),
and turns a failed task or a lost worker into an ApproxTreeError naming the block.
"""

from __future__ import annotations

import contextlib
import logging
import os
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from approxtree.errors import ApproxTreeError, InvalidParameterError
from approxtree.progress import ProgressCallback, as_callback
from approxtree.tree.blocks import BlockResult, BlockTask, run_block

if TYPE_CHECKING:
    # Types only: distributed is imported when a cluster is used (it is slow to import).
    from distributed import Client

#: Memory of one idle local worker with approxtree imported, its nanny included (measured
#: 145 MB a worker on Linux, Python 3.11).
WORKER_BYTES = 150 * 2**20


def check_cluster_options(workers: int | None, scheduler: str | None) -> None:
    """InvalidParameterError for a bad worker count, a local cluster larger than this machine
    (more than ``io._common.most_workers``, or more worker processes than the available
    memory holds) or both options at once."""
    if workers is not None and scheduler is not None:
        raise InvalidParameterError(
            "Give either workers (a local cluster) or scheduler (an existing one), not both."
        )
    if workers is not None and (not isinstance(workers, int) or workers < 1):
        raise InvalidParameterError(f"workers must be an integer >= 1, got {workers!r}.")
    if workers is not None:
        from approxtree.io._common import available_memory, most_workers

        cores = os.cpu_count() or 1
        most = most_workers()
        memory = available_memory()
        if workers > most or workers * WORKER_BYTES > memory:
            fits = max(1, min(most, memory // WORKER_BYTES))
            raise InvalidParameterError(
                f"workers={workers} asks for {workers} worker processes of about "
                f"{WORKER_BYTES >> 20} MB each on a machine with {cores} cores and "
                f"{memory / 2**30:.1f} GiB of memory available: use at most {fits} (the core "
                f"count, {cores}, is the usual choice), or a dask cluster (scheduler) for more."
            )
    if scheduler is not None and not str(scheduler).strip():
        raise InvalidParameterError("scheduler must be an address such as tcp://host:8786.")


@contextlib.contextmanager
def dask_client(
    workers: int | None, scheduler: str | None, processes: bool = True
) -> Iterator[Client]:
    """A distributed Client: of ``scheduler``, or of a LocalCluster of ``workers`` processes
    (one thread each; ``processes=False``: worker threads in this process), closed on exit."""
    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise ApproxTreeError(
                f"Cannot reach the dask scheduler at {scheduler!r} ({exc}); check the address "
                "(e.g. tcp://host:8786) and that the scheduler runs."
            ) from None
        try:
            yield client
        finally:
            client.close()
        return
    cluster = LocalCluster(
        n_workers=workers or os.cpu_count() or 1,
        threads_per_worker=1,
        processes=processes,
        dashboard_address=":0",
        # A failed task comes back through its future as one error; the workers' own log
        # of it ("Compute Failed" and its traceback, per task) would bury that line.
        silence_logs=logging.CRITICAL,
    )
    client = Client(cluster)
    try:
        yield client
    finally:
        client.close()
        cluster.close()


def _report_context(client: Client, report: str | os.PathLike | None):
    """distributed.performance_report writing ``report`` (needs bokeh), or a null context."""
    if report is None:
        return contextlib.nullcontext()
    try:
        import bokeh  # noqa: F401
    except ImportError:
        raise InvalidParameterError(
            "A dask performance report needs bokeh: pip install 'approxtree[bench]' (or bokeh)."
        ) from None
    from distributed import performance_report

    return performance_report(filename=str(Path(report)))


def dask_runner(
    workers: int | None = None,
    scheduler: str | None = None,
    report: str | os.PathLike | None = None,
    progress: ProgressCallback | bool | None = None,
    client: Client | None = None,
) -> Callable[[list[BlockTask]], list[BlockResult]]:
    """The ``run`` of ``build_blocked`` on dask (an existing ``client``, else one made from
    ``workers`` / ``scheduler`` for the duration of the build)."""
    check_cluster_options(workers, scheduler)

    def run(tasks: list[BlockTask]) -> list[BlockResult]:
        from distributed import as_completed

        own = contextlib.nullcontext(client) if client is not None else None
        # No more local workers than blocks: the others would start only to wait.
        local = None if workers is None else max(1, min(workers, len(tasks)))
        with own or dask_client(local, scheduler) as cl, _report_context(cl, report):
            # One thread per task: the cluster's processes are the parallelism.
            for t in tasks:
                t.threads = 1
            # Keys unique to this build: a key reused on a shared cluster could return the
            # result of another build's task still held there.
            build_id = uuid.uuid4().hex[:12]
            futures = [
                cl.submit(run_block, t, key=f"approxtree-{build_id}-block-{t.block}") for t in tasks
            ]
            block_of = {f.key: t.block for f, t in zip(futures, tasks, strict=True)}
            results: list[BlockResult] = []
            on_progress, close = as_callback(progress, "blocks", "block")
            on_progress(0, len(futures))
            try:
                for fut in as_completed(futures):
                    try:
                        results.append(fut.result())
                        # The worker may forget the task and its result now.
                        fut.release()
                    except ApproxTreeError:
                        raise
                    except Exception as exc:
                        block = block_of[fut.key]
                        raise ApproxTreeError(
                            f"Block {block} of the build failed on a dask worker: "
                            f"{type(exc).__name__}: {exc}. Check the workers' memory and logs "
                            "(a smaller --block-size needs less memory per task)."
                        ) from exc
                    on_progress(len(results), len(futures))
            finally:
                close()
                for fut in futures:
                    fut.release()
            return results

    return run


#: The least --block-size: every block is a task with its own window read and subtree, and
#: smaller blocks cost more to schedule than they build (the 500 × 450 NC DEM: 1.6 s at 64,
#: 5 s at 8 in this process and 49 s on 2 dask workers, 295 s at 1).
MIN_BLOCK_SIZE = 64


def check_block_size(block_size: int | None) -> None:
    """InvalidParameterError for a block size below MIN_BLOCK_SIZE, saying why."""
    if block_size is not None and block_size < MIN_BLOCK_SIZE:
        raise InvalidParameterError(
            f"--block-size {block_size} is below the least block of {MIN_BLOCK_SIZE} cells a "
            "side: each block is a task with its own window and subtree, and smaller blocks "
            f"take longer to schedule than to build (minutes for a 500 × 450 DEM at 1). Use "
            f"--block-size {MIN_BLOCK_SIZE} or more (default 2048)."
        )
