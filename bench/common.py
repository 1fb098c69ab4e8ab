"""What the benchmarks share: the runs they are made of (a ping-pong, the SMIB loop, a network loop, each as child
processes started as ``nni-demo`` starts them), the processes' memory and CPU from /proc, and the report's formats.
"""

from __future__ import annotations

import json
import os
import resource
import signal
import sys
import time
from pathlib import Path

import numpy as np

from nni_msgs_adapter.ros.processes import ChildError, Supervisor, with_participants

ROOT = Path(__file__).resolve().parent.parent
#: The battery limit of the loop benchmarks (the controller's work does not depend on it).
LOOP_BATTERY_LIMIT_PU = 0.3
#: The network benchmarks' PMU rate (the network plant's default) and battery limit (the network tests').
NETWORK_RATE_HZ = 50.0
NETWORK_BATTERY_LIMIT_PU = 0.1


def progress(text: str) -> None:
    """One line of the run's progress on stderr (stdout gets the report)."""
    print(f"bench: {text}", file=sys.stderr, flush=True)


def not_completed(what: str, error: Exception) -> dict:
    """A run that could not complete, said on stderr; its result holds the error's first line for the report."""
    progress(f"{what}: not completed: {error}")
    return {"error": str(error).splitlines()[0][:300]}


# --- processes ----------------------------------------------------------------------------


def children(env: dict, log_dir: Path) -> Supervisor:
    """Child processes of one measurement (the project's supervisor); all stopped when the block ends."""
    return Supervisor(env, log_dir, cwd=ROOT)


def stop_together(procs: Supervisor) -> None:
    """SIGINT to every child at once, so that the supervisor's stops (one after another) find them finishing.

    With 50 and more children, stopping them one at a time took a second each.
    """
    for child in procs.children.values():
        if child.poll() is None:
            child.proc.send_signal(signal.SIGINT)


def printed_json(output: str, prefix: str) -> dict | None:
    """The JSON a child printed on its line starting with ``prefix`` (its result or summary); None without one."""
    for line in output.splitlines():
        if line.startswith(prefix):
            return json.loads(line[len(prefix):])
    return None


def cycle_ms(summary: dict) -> float:
    """Wall time per lockstep sample (ms) of a run, from the plant's final diagnostics (``{namespace: values}``:
    every generator has the run's wall time and samples)."""
    first = next(iter(summary.values()))
    return float(first["run_wall_s"]) * 1e3 / int(first["samples"])


def rss_kib(pid: int) -> int:
    """Resident set size of a running process, KiB (``VmRSS`` of /proc/<pid>/status)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError(f"process {pid} shows no VmRSS")


def _children_cpu_s() -> float:
    """User and system CPU time of this process's reaped children so far, s."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def cpu_seconds(pid: int) -> float:
    """User and system CPU time of a running process so far, s (/proc/<pid>/stat)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


# --- runs ---------------------------------------------------------------------------------


def pingpong(env: dict, log_dir: Path, mode: str, rate_hz: float = 100.0, duration_s: float = 0.0,
             samples: int = 0, peer: list[str] | None = None, fanout: int = 0, composed: bool = False) -> dict:
    """One ping-pong run: the ping and the bare echo (or ``peer``), or ``fanout`` echoes in /gen1.. /genN
    (``composed``: as nodes of one echo process, on one executor).

    Returns the ping's JSON result, with ``echo_cpu_s``: the echo processes' CPU time over the pinging.
    """
    from bench.pingpong import RESULT_PREFIX, STARTED_LINE, fanout_namespaces

    echo = [sys.executable, "-m", "bench.pingpong", "echo"]
    env = with_participants(env, 2 if composed else max(fanout, 1) + 1)
    with children(env, log_dir) as procs:
        if composed:
            procs.start("echoes", echo + ["--composed", str(fanout)])
        elif fanout:
            for ns in fanout_namespaces(fanout):
                procs.start(f"echo{ns.replace('/', '_')}", echo + ["--ros-args", "-r", f"__ns:={ns}"])
        else:
            procs.start("echo", peer or echo)
        procs.start("ping", [sys.executable, "-m", "bench.pingpong", "ping", "--mode", mode, "--rate", str(rate_hz),
                             "--duration", str(duration_s), "--samples", str(samples), "--fanout", str(fanout)])
        limit_s = 60.0 + 3.0 * fanout + duration_s + samples * 0.05
        try:
            echoes = [child for name, child in procs.children.items() if name != "ping"]
            procs["ping"].wait_for_line(STARTED_LINE, limit_s)
            echo_cpu_started_s = sum(cpu_seconds(child.pid) for child in echoes)
            status = procs["ping"].wait_exit(limit_s)
            if status != 0:
                raise RuntimeError(f"ping-pong ping exited with {status}: {procs['ping'].tail(400)}")
            echo_rss = [rss_kib(child.pid) for child in echoes]
            echo_cpu_s = sum(cpu_seconds(child.pid) for child in echoes) - echo_cpu_started_s
        finally:
            stop_together(procs)
        result = printed_json(procs["ping"].output(), RESULT_PREFIX)
    if result is None:
        raise RuntimeError("ping-pong printed no result")
    return {**result, "echo_rss_kib": echo_rss, "echo_cpu_s": echo_cpu_s}


def closed_loop(env: dict, log_dir: Path, mode: str, rate_hz: float, duration_s: float,
                measurements: str = "ros", foxglove_port: int | None = None, foxglove_client: str = "stalled") -> dict:
    """Plant and controller nodes as ``nni-demo`` starts them; the plant's final diagnostics values.

    ``measurements`` c37118: the controller fed through the plant's C37.118 stream and the client node, as
    ``nni-demo --measurements c37118`` feeds it (the plant waits for the client, not for a pmu reader).
    ``foxglove_port``: a Foxglove bridge serves the loop there (the plant waits for it as a reader) to a client
    subscribed to every channel (:mod:`bench.stalled_client`) that never reads (``foxglove_client`` stalled)
    or reads everything (``reading``).
    Read from the JSON line the plant prints at exit, not over DDS: a listener in
    this process had to discover every new plant before its run ended, and
    after a short lockstep run (0.2 s) it sometimes had not (measured).
    """
    from nni_battery_controller import demo_c37118
    from nni_battery_controller.demo_pmu import StreamWatch
    from nni_plant_sim.plant_node import SUMMARY_PREFIX

    with children(env, log_dir) as procs:
        if foxglove_port is not None:
            bridge = procs.start_node("foxglove_bridge", "nni_msgs_adapter.viewing.foxglove_bridge",
                                      {"address": f"127.0.0.1:{foxglove_port}", "discovery_period_s": 0.1})
            bridge.wait_for_line("foxglove bridge serving on", 60.0)
            procs.start("foxglove_client", [sys.executable, "-m", "bench.stalled_client",
                                            f"ws://127.0.0.1:{foxglove_port}", str(120.0 + 2 * duration_s),
                                            *(["--read"] if foxglove_client == "reading" else [])])
        procs.start_node("controller", "nni_battery_controller.controller_node",
                         {"battery_limit_pu": LOOP_BATTERY_LIMIT_PU, "sample_rate_hz": rate_hz,
                          **demo_c37118.controller_parameters(measurements)})
        procs.start_node("plant", "nni_plant_sim.plant_node",
                         {"mode": mode, "duration_s": duration_s, "pmu_rate_hz": rate_hz,
                          # the controller on pmu (and the Foxglove bridge); through the stream nobody reads pmu:
                          # the plant waits for the client
                          "wait_for_subscribers": 0 if measurements == "c37118" else 1 + (foxglove_port is not None),
                          **demo_c37118.plant_parameters(measurements)})
        if measurements == "c37118":
            demo_c37118.start_client(procs, StreamWatch(procs["plant"]).listening(announce=False), measurements,
                                     mode, 1)
        limit = 60.0 + duration_s * (1.0 if mode == "realtime" else 2.0)
        status = procs["plant"].wait_exit(limit)
        if status != 0:
            raise RuntimeError(f"plant exited with {status}: {procs['plant'].tail(400)}")
        summary = printed_json(procs["plant"].output(), SUMMARY_PREFIX)
    if summary is None:
        raise RuntimeError("the plant printed no summary")
    return summary


def network_loop(env: dict, log_dir: Path, case: str, mode: str, rate_hz: float, duration_s: float,
                 deployment: str, attach=None, detach=None) -> dict:
    """The network plant node and one controller per generator, deployed as ``nni-demo --case --deployment``
    deploys them (N processes, or N nodes composed in one: ``network_deployment.start_controllers``), each with
    the parameters ``nni-demo`` gives it (g measured, the controller's default gains).

    Returns the plant's summary (``{namespace: values}``) and the controllers'
    resident set sizes, read at the end of the run while they are still up.
    ``attach(plant_pid, controller_pids)`` is called when the run starts,
    ``detach()`` when the plant has ended it (a profiler's hooks).
    """
    from nni_battery_controller.network_deployment import (
        controller_parameters,
        default_law,
        namespaces,
        participants,
        start_controllers,
    )
    from nni_plant_sim.cases import load_network

    net = load_network(case)
    law = default_law(net)
    parameters = {f"/{ns}": controller_parameters(net, i, NETWORK_BATTERY_LIMIT_PU, rate_hz, law)
                  for i, ns in enumerate(namespaces(net))}
    env = with_participants(env, participants(net, deployment, 1))  # the controllers and the plant
    with children(env, log_dir) as procs:
        controllers = start_controllers(procs, parameters, deployment)
        plant = procs.start_node("plant", "nni_plant_sim.network_plant_node",
                                 {"case": case, "mode": mode, "duration_s": duration_s, "pmu_rate_hz": rate_hz,
                                  "wait_for_subscribers": 1, "wait_timeout_s": 600.0})
        try:
            return run_network_plant(plant, controllers, case, mode, net.size, duration_s, attach, detach)
        finally:
            stop_together(procs)


def run_network_plant(plant, controllers, case: str, mode: str, size: int, duration_s: float, attach=None,
                      detach=None) -> dict:
    """Wait for the plant's run (stopped as partial past its limit); its summary, the controllers' RSS and CPU,
    the plant's CPU and the run's wall time (``attach``/``detach``: :func:`network_loop`'s)."""
    from nni_plant_sim.network_plant_node import SUMMARY_PREFIX

    limit_s = 120.0 + 5.0 * size + duration_s * (1.0 if mode == "realtime" else 4.0)
    started = time.monotonic()
    plant.wait_for_line("started in", limit_s)
    run_started, cpu_started = time.monotonic(), [cpu_seconds(child.pid) for child in controllers]
    plant_cpu_started, children_cpu_started = cpu_seconds(plant.pid), _children_cpu_s()
    if attach:
        attach(plant.pid, [child.pid for child in controllers])
    partial, plant_cpu_s = None, None
    try:
        # The plant's CPU over its run: read when it prints its summary (its run is over), before its exit's
        # teardown (0.1-0.3 s of CPU, a large share of a short run's).
        plant.wait_for_line(SUMMARY_PREFIX, max(1.0, limit_s - (run_started - started)))
        plant_cpu_s = cpu_seconds(plant.pid) - plant_cpu_started
    except (OSError, ChildError):
        pass  # gone already (its CPU through its rusage below), or no summary within the limit (said below)
    try:
        status = plant.wait_exit(max(1.0, limit_s - (time.monotonic() - started)))
    except ChildError:
        partial, status = f"stopped after {limit_s:.0f} s of wall time", None
    run_s = time.monotonic() - run_started
    rss = [rss_kib(child.pid) for child in controllers]
    cpu_s = [cpu_seconds(child.pid) - before for child, before in zip(controllers, cpu_started)]
    if partial:
        status = plant.stop()  # SIGINT: the plant prints its summary of the run so far
    if plant_cpu_s is None:  # reaped: what the children's rusage gained meanwhile, less what it had spent before
        plant_cpu_s = _children_cpu_s() - children_cpu_started - plant_cpu_started
    if detach:
        detach()
    if status != 0:
        raise RuntimeError(f"network plant ({case}) exited with {status}: {plant.tail(400)}")
    summary = printed_json(plant.output(), SUMMARY_PREFIX)
    if summary is None:
        raise RuntimeError(f"the network plant ({case}) printed no summary")
    return {"summary": summary, "rss_kib": rss, "cpu_share": [seconds / run_s for seconds in cpu_s],
            "controller_cpu_s": cpu_s, "plant_cpu_s": plant_cpu_s, "wall_s": run_s, "size": size,
            "partial": partial}


# --- results ------------------------------------------------------------------------------


def percentiles_ms(values_ns) -> dict:
    ms = np.asarray(values_ns, dtype=float) * 1e-6
    return {"p50": float(np.percentile(ms, 50)), "p99": float(np.percentile(ms, 99)), "max": float(ms.max()),
            "mean": float(ms.mean())}


def median_latency_ms(finals: list[dict]) -> dict:
    """The median over runs of the plant's latency p50 and p99 (ms), from each run's final diagnostics."""
    return {q: float(np.median([float(final[f"latency_{q}_ms"]) for final in finals])) for q in ("p50", "p99")}


def row_at(rows: list[dict], rate_hz: float) -> dict | None:
    """The row measured at ``rate_hz`` (the rate a target is set at), None when the run left it out."""
    return next((row for row in rows if row["rate_hz"] == rate_hz), None)


# --- report -------------------------------------------------------------------------------


def verdict(ok: bool) -> str:
    return "met" if ok else "**not met**"


def fmt_rounds(ratios: list[float]) -> str:
    """Each alternating round's ratio, for the brackets beside their median."""
    return ", ".join(f"{ratio:.2f}" for ratio in ratios)
