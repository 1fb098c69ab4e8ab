"""Where a screen's tasks run: in this process (``--workers 0``), on an embedded dask ``LocalCluster``, or on an
existing Dask cluster (``--scheduler tcp://HOST:8786``).

A task is :func:`nni_battery_controller.screening.screen_chunk` of a few
contingencies (every b and law of each: the b of one contingency share one
vectorised bisection). The cluster path submits every task at once and takes
the results as they complete; each finished task's rows go to the store
(:mod:`nni_battery_controller.screen_store`) before the next result is read,
so a screen stopped at any point keeps every row it had received. A worker
that dies loses only what it was computing: the scheduler gives its tasks to
the others (dask's ``allowed-failures``, 3 deaths per task by default), and a
LocalCluster's nanny starts a new worker. The compiled RK4 is loaded once per
worker when it joins (:class:`WarmRk4`, a worker plugin). Pure python (dask,
distributed, tqdm): no ROS import.
"""

from __future__ import annotations

import importlib.util
import logging
import os
import sys
import time

from distributed.diagnostics.plugin import WorkerPlugin

from nni_battery_controller import screening
from nni_msgs_adapter.ros.cli_support import CliError

#: How long a scheduler given with --scheduler may take to answer, and to have a worker, s.
CONNECT_TIMEOUT_S = 5.0
WORKERS_TIMEOUT_S = 30.0
#: A task whose function raised is tried this many more times (a worker's death is counted by dask apart).
RETRIES = 1


class WarmRk4(WorkerPlugin):
    """Loads the compiled RK4 (numba's cache) in each worker as it joins, so that no task pays for it."""

    name = "nni-warm-rk4"

    def setup(self, worker) -> None:
        screening.warm_up()


def default_workers() -> int:
    """One worker per core this process may use."""
    return len(os.sched_getaffinity(0))


def _bar(total: int, engine: str):
    from tqdm import tqdm

    return tqdm(total=total, unit="contingency", desc=f"screen ({engine})", file=sys.stderr, mininterval=1.0,
                smoothing=0.1)


def run_tasks(spec, settings, tasks, store, workers: int, scheduler: str | None) -> dict:
    """Run ``tasks`` (``(first contingency index, names)`` each) and add each one's rows to ``store`` as it ends.

    ``workers`` 0 runs them here, one after the other; otherwise on a
    LocalCluster of that many single-threaded worker processes, or, with
    ``scheduler``, on the cluster there. Returns what it measured: the engine,
    its workers, the tasks, the seconds the tasks spent computing (inside
    :func:`screen_chunk`) and the wall time from the first task submitted to
    the last result.
    """
    total = sum(len(names) for _, names in tasks)
    if workers == 0 and scheduler is None:
        screening.warm_up()
        started, compute_s = time.perf_counter(), 0.0
        with _bar(total, "serial") as bar:
            for index, names in tasks:
                result = _interruptible(screening.screen_chunk, spec, settings, names)
                store.add(index, result["rows"])
                compute_s += result["compute_s"]
                bar.update(len(names))
        return {"engine": "serial", "workers": 0, "tasks": len(tasks), "compute_s": compute_s,
                "wall_s": time.perf_counter() - started}
    return _run_on_dask(spec, settings, tasks, store, workers, scheduler, total)


def _interruptible(function, *args):
    """``function(*args)``, a Ctrl-C inside the compiled RK4 raised as the KeyboardInterrupt it is.

    numba's dispatcher turns an interrupt during a compiled call into a SystemError caused by the
    KeyboardInterrupt (sometimes through a second SystemError of its own).
    """
    try:
        return function(*args)
    except SystemError as error:
        cause = error
        while cause is not None and not isinstance(cause, KeyboardInterrupt):
            cause = cause.__cause__ or cause.__context__
        if cause is not None:
            raise KeyboardInterrupt from None
        raise


def _connect(workers: int, scheduler: str | None):
    """``(client, cluster or None)``: a client of the scheduler given, or of a LocalCluster started here."""
    from distributed import Client, LocalCluster

    logging.getLogger("distributed").setLevel(logging.CRITICAL)
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError, ValueError) as error:
            raise CliError(f"cannot reach the Dask scheduler at {scheduler} within {CONNECT_TIMEOUT_S:g} s "
                           f"({str(error).splitlines()[0]})") from None
        try:
            client.wait_for_workers(1, timeout=WORKERS_TIMEOUT_S)
        except (OSError, TimeoutError):
            client.close()
            raise CliError(f"the Dask scheduler at {scheduler} has no worker (waited {WORKERS_TIMEOUT_S:g} s)") \
                from None
        return client, None
    # A port of its own (two screens at once must not meet on dask's default 8787).
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address="127.0.0.1:0", silence_logs=logging.CRITICAL)
    return Client(cluster), cluster


def _dashboard(client, info, scheduler) -> str:
    """Where the dashboard is, when one is up: the scheduler's own, or the LocalCluster's (which needs bokeh)."""
    if "dashboard" not in info.get("services", {}):
        return "no dashboard"
    if scheduler is None and importlib.util.find_spec("bokeh") is None:
        return "no dashboard (its pages need bokeh, which is not installed)"
    return f"dashboard {client.dashboard_link}"


def _run_on_dask(spec, settings, tasks, store, workers, scheduler, total) -> dict:
    from distributed import as_completed

    client, cluster = _connect(workers, scheduler)
    try:
        client.register_plugin(WarmRk4())
        info = client.scheduler_info()
        count = len(info.get("workers", {}))
        where = f"the Dask scheduler at {scheduler}" if scheduler else "a LocalCluster started here"
        print(f"screen: {len(tasks)} tasks on {where}, {count} workers; {_dashboard(client, info, scheduler)}",
              file=sys.stderr, flush=True)
        started, compute_s = time.perf_counter(), 0.0
        futures = {client.submit(screening.screen_chunk, spec, settings, names, pure=False, retries=RETRIES,
                                 key=f"nni-screen-{index:05d}-{time.monotonic_ns()}"): (index, names)
                   for index, names in tasks}
        with _bar(total, "dask") as bar:
            for future in as_completed(futures):
                index, names = futures[future]
                try:
                    result = future.result()
                except Exception as error:  # a task that failed on every try: the screen cannot be whole
                    raise CliError(f"the task of {names[0]} failed: {type(error).__name__}: "
                                   f"{str(error).splitlines()[0] if str(error) else ''}") from None
                store.add(index, result["rows"])
                compute_s += result["compute_s"]
                bar.update(len(names))
        return {"engine": "scheduler" if scheduler else "LocalCluster", "workers": count, "tasks": len(tasks),
                "compute_s": compute_s, "wall_s": time.perf_counter() - started}
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
