"""``python -m bench`` (or ``bench/run_all``): run every benchmark and write BENCHMARKS.md.

Each table sets a measurement beside a baseline taken in the same run:

1. closed-loop latency (plant -> controller -> plant, realtime mode) at 50, 100,
   500 and 1000 measurements/s beside a bare rclpy ping-pong of the same message
   type and QoS in two processes, in alternating rounds;
   1b. the controller's share of it: the same timed ping answered in
   alternate rounds by the bare echo and by the controller node itself;
2. lockstep throughput (simulated s per wall s) of the paper's case at 50 and
   100 samples/s beside its floor, the samples times a chained ping-pong's
   round trip, in alternating rounds;
3. the region-of-attraction sweep, 200 x 200 x 4, vectorised, beside the
   per-trajectory scipy solve_ivp loop (``simulate_continuous``) on a subsample,
   extrapolated, with the fraction of cells where the two disagree;
4. network lockstep throughput (issue 14) of the network plant node with one
   controller process per generator for N = 1 (the SMIB plant node), 4
   (kundur_two_area) and 10 (ieee39) beside a chained fan-out ping-pong to N
   echo processes, and with the controllers composed in one process for N =
   10 and 52 (kundur_ring_52) beside a chained fan-out to N echo nodes
   composed in one process, in alternating rounds, and the cost per added
   generator of each deployment;
5. network realtime at 50 frames/s, ieee39's 10 controllers as separate
   processes and composed in one, per generator beside the timed fan-out to
   echoes deployed alike;
6. memory (and CPU) per controller process and per composed controller.

Node processes are started exactly as ``nni-demo`` starts them; discovery stays
on localhost (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) in a ROS domain of the
benchmark's own (``--domain-id``, default 87). ``--quick`` shortens everything
for development; its numbers are not the ones to publish.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import signal
import sys
import time
from importlib import metadata
from pathlib import Path

import numpy as np

from nni_msgs_adapter.ros.processes import ChildError, Supervisor, with_participants

ROOT = Path(__file__).resolve().parent.parent
#: Targets of issue 5 (ratios are measured in the same run).
LATENCY_RATIO_TARGET = 1.3
LOCKSTEP_REALTIME_TARGET = 10.0
LOCKSTEP_FLOOR_RATIO_TARGET = 1.5
ROA_SECONDS_TARGET = 10.0
ROA_SPEEDUP_TARGET = 100.0
ROA_DISAGREEMENT_TARGET = 0.005
#: Alternating (ping-pong, loop) pairs per rate, latency and lockstep; the duration is split among them.
LATENCY_ROUNDS = 3
#: The battery limit of the loop benchmarks (the controller's work does not depend on it).
LOOP_BATTERY_LIMIT_PU = 0.3
#: Issue 14: network lockstep within this factor of its fan-out floor at N = 10.
NETWORK_FLOOR_RATIO_TARGET = 2.0
#: The network benchmarks' PMU rate (the network plant's default) and battery limit (the network tests').
NETWORK_RATE_HZ = 50.0
NETWORK_BATTERY_LIMIT_PU = 0.1
#: Lockstep scaling, (case, alternating rounds, deployment): None is N = 1 (the SMIB plant node), then the
#: network cases by size, a controller process each, then composed in one process (network_deployment.DEPLOYMENTS).
#: No separate N = 52 row: 52 controller processes (and 52 echo processes for its floor) on 2 cores are the
#: machine's load, not the deployment's cost; at that size the controllers run composed.
NETWORK_LOCKSTEP_CASES = ((None, 3, "separate"), ("kundur_two_area", 3, "separate"), ("ieee39", 3, "separate"),
                          ("ieee39", 3, "composed"), ("kundur_ring_52", 3, "composed"))
NETWORK_LOCKSTEP_QUICK_CASES = ((None, 1, "separate"), ("kundur_two_area", 1, "separate"),
                                ("kundur_two_area", 1, "composed"), ("kundur_ring_52", 1, "composed"))
#: What --only selects (all by default).
BENCHMARKS = ("latency", "lockstep", "roa", "network-lockstep", "network-realtime")


def parse_args(argv=None):
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="short runs (development; not for publishing)")
    parser.add_argument("--only", nargs="+", choices=BENCHMARKS, default=list(BENCHMARKS),
                        help="run only these benchmarks")
    parser.add_argument("--out", type=Path, default=ROOT / "BENCHMARKS.md", help="report path (default BENCHMARKS.md)")
    parser.add_argument("--domain-id", type=int, default=87, help="ROS_DOMAIN_ID of the benchmark (default 87)")
    parser.add_argument("--rates", type=float, nargs="+", default=[50.0, 100.0, 500.0, 1000.0],
                        help="latency benchmark rates, measurements/s")
    args = parser.parse_args(argv)
    if not 0 <= args.domain_id <= 232:
        parser.error(f"ROS domain id must be within 0..232, got {args.domain_id}")
    return args


# --- machine ------------------------------------------------------------------------------


def machine_description() -> dict:
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    packages = {}
    for name in ("ros-jazzy-rclpy", "ros-rmw-fastrtps-cpp", "ros-fastrtps", "numpy", "scipy", "matplotlib"):
        try:
            packages[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            pass
    return {
        "cpu": cpu, "cores": os.cpu_count(), "kernel": platform.release(),
        "python": platform.python_version(), "packages": packages,
        "rmw": os.environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp (default)"),
        "load_average_at_start": os.getloadavg(),
    }


# --- processes ----------------------------------------------------------------------------


def children(env: dict, log_dir: Path) -> Supervisor:
    """Child processes of one measurement (the project's supervisor); all stopped when the block ends."""
    return Supervisor(env, log_dir, cwd=ROOT)


#: The real controller node in the echo's place: it answers the ping (a PMU message) with a command
#: stamped like it, which the ping takes as its pong.
CONTROLLER_AS_PEER = [sys.executable, "-m", "nni_battery_controller.controller_node", "--ros-args",
                      "-r", "pmu:=bench/ping", "-r", "battery/command:=bench/pong",
                      "-p", f"battery_limit_pu:={LOOP_BATTERY_LIMIT_PU}"]


def pingpong(env: dict, log_dir: Path, mode: str, rate_hz: float = 100.0, duration_s: float = 0.0,
             samples: int = 0, peer: list[str] | None = None, fanout: int = 0, composed: bool = False) -> dict:
    """One ping-pong run: the ping and the bare echo (or ``peer``), or ``fanout`` echoes in /gen1.. /genN
    (``composed``: as nodes of one echo process, on one executor).

    Returns the ping's JSON result.
    """
    from bench.pingpong import RESULT_PREFIX, fanout_namespaces

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
        try:
            status = procs["ping"].wait_exit(60.0 + 3.0 * fanout + duration_s + samples * 0.05)
            if status != 0:
                raise RuntimeError(f"ping-pong ping exited with {status}: {procs['ping'].tail(400)}")
            echo_rss = [rss_kib(child.pid) for name, child in procs.children.items() if name != "ping"]
        finally:
            stop_together(procs)
        for line in procs["ping"].output().splitlines():
            if line.startswith(RESULT_PREFIX):
                return {**json.loads(line[len(RESULT_PREFIX):]), "echo_rss_kib": echo_rss}
    raise RuntimeError("ping-pong printed no result")


def stop_together(procs: Supervisor) -> None:
    """SIGINT to every child at once, so that the supervisor's stops (one after another) find them finishing.

    With 50 and more children, stopping them one at a time took a second each.
    """
    for child in procs.children.values():
        if child.poll() is None:
            child.proc.send_signal(signal.SIGINT)


def closed_loop(env: dict, log_dir: Path, mode: str, rate_hz: float, duration_s: float) -> dict:
    """Plant and controller nodes as ``nni-demo`` starts them; the plant's final diagnostics values.

    Read from the JSON line the plant prints at exit, not over DDS: a listener in
    this process had to discover every new plant before its run ended, and
    after a short lockstep run (0.2 s) it sometimes had not (measured).
    """
    from nni_plant_sim.plant_node import SUMMARY_PREFIX

    with children(env, log_dir) as procs:
        procs.start_node("controller", "nni_battery_controller.controller_node",
                         {"battery_limit_pu": LOOP_BATTERY_LIMIT_PU, "sample_rate_hz": rate_hz})
        procs.start_node("plant", "nni_plant_sim.plant_node",
                         {"mode": mode, "duration_s": duration_s, "pmu_rate_hz": rate_hz,
                          "wait_for_subscribers": 1})
        limit = 60.0 + duration_s * (1.0 if mode == "realtime" else 2.0)
        status = procs["plant"].wait_exit(limit)
        if status != 0:
            raise RuntimeError(f"plant exited with {status}: {procs['plant'].tail(400)}")
        for line in procs["plant"].output().splitlines():
            if line.startswith(SUMMARY_PREFIX):
                return json.loads(line[len(SUMMARY_PREFIX):])
    raise RuntimeError("the plant printed no summary")


def percentiles_ms(values_ns) -> dict:
    ms = np.asarray(values_ns, dtype=float) * 1e-6
    return {"p50": float(np.percentile(ms, 50)), "p99": float(np.percentile(ms, 99)), "max": float(ms.max()),
            "mean": float(ms.mean())}


def bench_latency(env, log_root: Path, rates, duration_s: float, rounds: int) -> list[dict]:
    """Loop and ping-pong at each rate, in ``rounds`` alternating pairs of ``duration_s / rounds`` each.

    The machine drifts between runs by more than the effect measured (the
    ping-pong p50 alone moved by 30 % between runs a minute apart), so each
    round's ratio compares back-to-back runs, and the reported ratio is their
    median. Ping-pong percentiles pool every round trip; the loop's come from
    the plant's diagnostics per round (median of the rounds' p50 and p99, the
    largest max); misses and samples are summed over all rounds.
    """
    rows = []
    part_s = duration_s / rounds
    for rate in rates:
        print(f"bench: latency at {rate:g}/s, {rounds} x ({part_s:g} s ping-pong, {part_s:g} s closed loop)",
              file=sys.stderr, flush=True)
        trips, pings, loops, ratios = [], [], [], []
        for index in range(1, rounds + 1):
            ping = pingpong(env, log_root / f"pingpong_{rate:g}_{index}", "timed", rate_hz=rate, duration_s=part_s)
            final = closed_loop(env, log_root / f"realtime_{rate:g}_{index}", "realtime", rate, part_s)
            trips += ping["round_trips_ns"]
            pings.append(ping)
            loops.append(final)
            ratios.append(float(final["latency_p50_ms"]) / percentiles_ms(ping["round_trips_ns"])["p50"])
        rows.append({
            "rate_hz": rate, "duration_s": duration_s, "rounds": rounds,
            "pingpong_ms": percentiles_ms(trips), "pingpong_samples": sum(p["sent"] for p in pings),
            "pingpong_deadline_misses": sum(p["deadline_misses"] for p in pings),
            "pingpong_unanswered": sum(p["lost_or_unanswered"] for p in pings),
            "loop_ms": {"p50": float(np.median([float(f["latency_p50_ms"]) for f in loops])),
                        "p99": float(np.median([float(f["latency_p99_ms"]) for f in loops])),
                        "max": max(float(f["latency_max_ms"]) for f in loops)},
            "p50_ratio": float(np.median(ratios)), "round_ratios": ratios,
            "loop_measurements": sum(int(f["measurements"]) for f in loops),
            "loop_commands": sum(int(f["commands"]) for f in loops),
            "loop_deadline_misses": sum(int(f["deadline_misses"]) for f in loops),
            "loop_late": sum(int(f["late"]) for f in loops),
            "loop_jitter_p99_ms": max(float(f["jitter_p99_ms"]) for f in loops),
        })
    return rows


def bench_controller_share(env, log_root: Path, rate_hz: float, rounds: int, duration_s: float) -> list[dict]:
    """Timed ping against the bare echo and against the controller node, alternating round by round.

    Both see the same ping, timer and transport, so the difference of their
    round trips is what the controller node (its callback and its larger
    executor) adds to the loop; alternating spreads the machine's drift over both.
    """
    print(f"bench: controller share at {rate_hz:g}/s, {rounds} x ({duration_s:g} s echo, {duration_s:g} s "
          "controller)", file=sys.stderr, flush=True)
    rows = []
    peer_cmd = CONTROLLER_AS_PEER + ["-p", f"sample_rate_hz:={rate_hz}"]
    for index in range(rounds):
        row = {"round": index + 1}
        for name, peer in (("echo", None), ("controller", peer_cmd)):
            result = pingpong(env, log_root / f"share_{name}_{index + 1}", "timed", rate_hz=rate_hz,
                              duration_s=duration_s, peer=peer)
            row[name] = percentiles_ms(result["round_trips_ns"])
        rows.append(row)
    return rows


def bench_lockstep(env, log_root: Path, rates, sim_duration_s: float, chained_samples: int,
                   rounds: int) -> list[dict]:
    """Lockstep runs beside chained ping-pongs, in ``rounds`` alternating pairs per rate (as the latency bench)."""
    rows = []
    for rate in rates:
        part_s, part_samples = sim_duration_s / rounds, chained_samples // rounds
        print(f"bench: lockstep at {rate:g}/s, {rounds} x (chained ping-pong of {part_samples} round trips, "
              f"{part_s:g} simulated s of the loop)", file=sys.stderr, flush=True)
        pairs = []
        for index in range(1, rounds + 1):
            chained = pingpong(env, log_root / f"pingpong_chained_{rate:g}_{index}", "chained", samples=part_samples)
            round_trip_s = float(np.mean(chained["round_trips_ns"])) * 1e-9
            final = closed_loop(env, log_root / f"lockstep_{rate:g}_{index}", "lockstep", rate, part_s)
            # The whole run, from the plant's final status: simulated time over the wall time since its start.
            sim_s, wall_s = float(final["sim_time_s"]), float(final["run_wall_s"])
            if not (sim_s > 0 and wall_s > 0):
                raise RuntimeError(f"lockstep at {rate:g}/s: the plant's final status shows no run ({final})")
            pairs.append({"round_trip_s": round_trip_s, "sim_s": sim_s, "wall_s": wall_s, "final": final,
                          "floor_ratio": ((1.0 / rate) / round_trip_s) / (sim_s / wall_s)})
        sim_s, wall_s = sum(p["sim_s"] for p in pairs), sum(p["wall_s"] for p in pairs)
        round_trip_s = float(np.median([p["round_trip_s"] for p in pairs]))
        finals = [p["final"] for p in pairs]
        rows.append({
            "rate_hz": rate, "sim_duration_s": sim_s, "run_wall_s": wall_s, "rounds": rounds,
            "throughput": sim_s / wall_s, "floor_throughput": (1.0 / rate) / round_trip_s,
            "floor_ratio": float(np.median([p["floor_ratio"] for p in pairs])),
            "round_ratios": [p["floor_ratio"] for p in pairs],
            "round_trip_mean_ms": round_trip_s * 1e3, "cycle_ms": wall_s / (sim_s * rate) * 1e3,
            **{f"{name}_ms": {q: float(np.median([float(f[f"{name}_{q}_ms"]) for f in finals])) for q in ("p50", "p99")}
               for name in ("latency", "turnaround")},
            "deadline_misses": sum(int(f["deadline_misses"]) for f in finals),
        })
    return rows


# --- networks (issue 14) --------------------------------------------------------------------


def rss_kib(pid: int) -> int:
    """Resident set size of a running process, KiB (``VmRSS`` of /proc/<pid>/status)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError(f"process {pid} shows no VmRSS")


def network_loop(env: dict, log_dir: Path, case: str, mode: str, rate_hz: float, duration_s: float,
                 deployment: str = "separate") -> dict:
    """The network plant node and one controller per generator, deployed as ``nni-demo --case --deployment``
    deploys them (N processes, or N nodes composed in one: ``network_deployment.start_controllers``), each with
    the parameters ``nni-demo`` gives it (g measured, the controller's default gains).

    Returns the plant's summary (``{namespace: values}``) and the controllers'
    resident set sizes, read at the end of the run while they are still up.
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
            return run_network_plant(plant, controllers, case, mode, net.size, duration_s)
        finally:
            stop_together(procs)


def run_network_plant(plant, controllers, case: str, mode: str, size: int, duration_s: float) -> dict:
    """Wait for the plant's run (stopped as partial past its limit); its summary, the controllers' RSS and CPU."""
    from nni_plant_sim.network_plant_node import SUMMARY_PREFIX

    limit_s = 120.0 + 5.0 * size + duration_s * (1.0 if mode == "realtime" else 4.0)
    started = time.monotonic()
    plant.wait_for_line("started in", limit_s)
    run_started, cpu_started = time.monotonic(), [cpu_seconds(child.pid) for child in controllers]
    partial = None
    try:
        status = plant.wait_exit(max(1.0, limit_s - (run_started - started)))
    except ChildError:
        partial, status = f"stopped after {limit_s:.0f} s of wall time", None
    run_s = time.monotonic() - run_started
    rss = [rss_kib(child.pid) for child in controllers]
    cpu = [(cpu_seconds(child.pid) - before) / run_s for child, before in zip(controllers, cpu_started)]
    if partial:
        status = plant.stop()  # SIGINT: the plant prints its summary of the run so far
    if status != 0:
        raise RuntimeError(f"network plant ({case}) exited with {status}: {plant.tail(400)}")
    for line in plant.output().splitlines():
        if line.startswith(SUMMARY_PREFIX):
            return {"summary": json.loads(line[len(SUMMARY_PREFIX):]), "rss_kib": rss, "cpu_share": cpu,
                    "size": size, "partial": partial}
    raise RuntimeError(f"the network plant ({case}) printed no summary")


def cpu_seconds(pid: int) -> float:
    """User and system CPU time of a running process so far, s (/proc/<pid>/stat)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def generator_percentiles(summary: dict, name: str) -> dict:
    """Across generators: the median of their ``name`` p50 and p99, and the largest p99 (ms)."""
    p50 = [float(values[f"{name}_p50_ms"]) for values in summary.values()]
    p99 = [float(values[f"{name}_p99_ms"]) for values in summary.values()]
    return {"p50": float(np.median(p50)), "p99": float(np.median(p99)), "p99_max": max(p99)}


def bench_network_lockstep(env, log_root: Path, cases, rate_hz: float, sim_duration_s: float,
                           chained_samples: int) -> list[dict]:
    """Lockstep of each case and deployment beside a chained fan-out to N echoes deployed alike, alternating.

    ``cases`` holds (case, rounds, deployment); the simulated time and the round
    trips are split among the rounds. Case ``None`` is N = 1: the SMIB plant node
    with its controller beside the one-echo chained ping-pong (section 2's pair).
    """
    rows = []
    for case, rounds, deployment in cases:
        label = case or "smib"
        print(f"bench: network lockstep {label} ({deployment}) at {rate_hz:g}/s, {rounds} x (chained fan-out of "
              f"{chained_samples // rounds}, {sim_duration_s / rounds:g} simulated s of the loop)",
              file=sys.stderr, flush=True)
        try:
            rows.append(network_lockstep_row(env, log_root, case, rounds, rate_hz, sim_duration_s, chained_samples,
                                             deployment))
        except (ChildError, RuntimeError) as error:
            print(f"bench: network lockstep {label} ({deployment}): not completed: {error}", file=sys.stderr,
                  flush=True)
            rows.append({"case": label, "deployment": deployment, "error": str(error).splitlines()[0][:300]})
    return rows


def network_lockstep_row(env, log_root: Path, case, rounds: int, rate_hz: float, sim_duration_s: float,
                         chained_samples: int, deployment: str = "separate") -> dict:
    """One row of section 4: ``rounds`` alternating pairs of a lockstep run and a chained fan-out.

    ``composed``: the controllers composed in one process, the fan-out's echoes too."""
    part_s, part_samples = sim_duration_s / rounds, chained_samples // rounds
    label = case or "smib"
    name = label if deployment == "separate" else f"{label}_{deployment}"
    pairs, partial = [], None
    for index in range(1, rounds + 1):
        if case is None:
            chained = pingpong(env, log_root / f"fanout_chained_{name}_{index}", "chained", samples=part_samples)
            final = closed_loop(env, log_root / f"net_lockstep_{name}_{index}", "lockstep", rate_hz, part_s)
            summary, size = {"gen1": final}, 1
        else:
            run = network_loop(env, log_root / f"net_lockstep_{name}_{index}", case, "lockstep", rate_hz, part_s,
                               deployment)
            summary, size, partial = run["summary"], run["size"], run["partial"] or partial
            chained = pingpong(env, log_root / f"fanout_chained_{name}_{index}", "chained",
                               samples=part_samples, fanout=size, composed=deployment == "composed")
        first = next(iter(summary.values()))
        sim_s, wall_s = float(first["sim_time_s"]), float(first["run_wall_s"])
        if not (sim_s > 0 and wall_s > 0):
            raise RuntimeError(f"lockstep {label}: the plant's final status shows no run ({first})")
        round_trip_s = float(np.mean(chained["round_trips_ns"])) * 1e-9
        pairs.append({"round_trip_s": round_trip_s, "sim_s": sim_s, "wall_s": wall_s, "summary": summary,
                      "floor_ratio": ((1.0 / rate_hz) / round_trip_s) / (sim_s / wall_s)})
    sim_s, wall_s = sum(p["sim_s"] for p in pairs), sum(p["wall_s"] for p in pairs)
    round_trip_s = float(np.median([p["round_trip_s"] for p in pairs]))
    return {
        "case": label, "deployment": deployment, "generators": size, "rate_hz": rate_hz, "rounds": rounds,
        "sim_duration_s": sim_s,
        "run_wall_s": wall_s, "throughput": sim_s / wall_s, "floor_throughput": (1.0 / rate_hz) / round_trip_s,
        "floor_ratio": float(np.median([p["floor_ratio"] for p in pairs])),
        "round_ratios": [p["floor_ratio"] for p in pairs], "round_trip_mean_ms": round_trip_s * 1e3,
        "cycle_ms": wall_s / (sim_s * rate_hz) * 1e3,
        **{f"{name}_ms": {q: float(np.median([generator_percentiles(p["summary"], name)[q] for p in pairs]))
                          for q in ("p50", "p99")} for name in ("latency", "turnaround")},
        "deadline_misses": sum(int(v["deadline_misses"]) for p in pairs for v in p["summary"].values()),
        "partial": partial,
    }


def per_generator_cost(rows: list[dict]) -> dict:
    """Least-squares slopes of the cycle and of the floor's round trip against N (ms per added generator).

    Over the network plant's rows (of one deployment) when there are two or more, else over every row.
    """
    network = [row for row in rows if row["case"] != "smib"]
    fit = network if len(network) >= 2 else rows
    sizes = np.array([row["generators"] for row in fit], dtype=float)
    if len(fit) < 2 or np.ptp(sizes) == 0:
        return {}
    cycle = np.polyfit(sizes, [row["cycle_ms"] for row in fit], 1)[0]
    floor = np.polyfit(sizes, [row["round_trip_mean_ms"] for row in fit], 1)[0]
    return {"sizes": [int(n) for n in sizes], "cycle_ms": float(cycle), "floor_ms": float(floor)}


def bench_network_realtime(env, log_root: Path, case: str, rate_hz: float, duration_s: float, rounds: int) -> dict:
    """Realtime with N controller processes and with N composed in one, each beside its deployment's timed fan-out.

    In ``rounds`` alternating rounds of ``duration_s / rounds``, per deployment: the loop, then the timed
    fan-out to N echoes deployed alike (N processes, or N nodes of one process) at the same rate. Per
    generator: the ping-pong's round trips pooled, the loop's median of the rounds' p50 and p99 (from the
    plant's diagnostics), misses summed; memory: the controllers' and echoes' resident sets at the end of
    each run.
    """
    part_s = duration_s / rounds
    kinds = ("separate", "composed")
    print(f"bench: network realtime {case} at {rate_hz:g}/s, {rounds} x ({part_s:g} s loop, then {part_s:g} s "
          f"fan-out ping-pong, with {' and '.join(kinds)} controllers and echoes)", file=sys.stderr, flush=True)
    pings, loops = {kind: [] for kind in kinds}, {kind: [] for kind in kinds}
    for index in range(1, rounds + 1):
        for kind in kinds:
            run = network_loop(env, log_root / f"net_realtime_{case}_{kind}_{index}", case, "realtime", rate_hz,
                               part_s, kind)
            loops[kind].append(run)
            pings[kind].append(pingpong(env, log_root / f"fanout_timed_{case}_{kind}_{index}", "timed",
                                        rate_hz=rate_hz, duration_s=part_s, fanout=run["size"],
                                        composed=kind == "composed"))
    namespaces = list(loops["separate"][0]["summary"])
    generators = []
    for i, ns in enumerate(namespaces):
        row = {"namespace": ns, "machine": loops["separate"][0]["summary"][ns]["machine"]}
        for kind in kinds:
            finals = [run["summary"][ns] for run in loops[kind]]
            row[kind] = {"p50": float(np.median([float(f["latency_p50_ms"]) for f in finals])),
                         "p99": float(np.median([float(f["latency_p99_ms"]) for f in finals])),
                         "deadline_misses": sum(int(f["deadline_misses"]) for f in finals),
                         "measurements": sum(int(f["measurements"]) for f in finals)}
            row[f"{kind}_floor"] = {
                **percentiles_ms([t for ping in pings[kind] for t in ping["echo_round_trips_ns"][i]]),
                "deadline_misses": sum(ping["echo_deadline_misses"][i] for ping in pings[kind])}
        generators.append(row)
    memory = {f"{kind}_kib": [kib for run in loops[kind] for kib in run["rss_kib"]] for kind in kinds}
    memory.update({f"{kind}_cpu": [share for run in loops[kind] for share in run["cpu_share"]] for kind in kinds})
    memory.update({f"{kind}_echo_kib": [kib for ping in pings[kind] for kib in ping["echo_rss_kib"]] for kind in kinds})
    return {"case": case, "generators": generators, "size": len(namespaces), "rate_hz": rate_hz,
            "duration_s": duration_s, "rounds": rounds, "kinds": kinds, "memory": memory}


def bench_roa(per_b_subsample: int) -> dict:
    """Vectorised sweep of 200 x 200 x 4 beside simulate_continuous on a stratified subsample."""
    from nni_battery_controller import roa
    from nni_battery_controller.law import ControllerParams
    from nni_plant_sim.model import SmibParams

    print("bench: region of attraction 200 x 200 x 4", file=sys.stderr, flush=True)
    plant = SmibParams()
    ctrls = [ControllerParams(battery_limit_pu=b) for b in (0.0, 0.2, 0.3, math.inf)]
    grid = roa.RoaGrid(n_angle=200, n_speed=200)
    started = time.perf_counter()
    basins = roa.sweep(plant, ctrls, grid)
    vectorised_s = time.perf_counter() - started
    angle_dev0, speed0 = grid.initial_conditions()
    rng = np.random.default_rng(2024)
    per_b, loop_s, loop_runs, disagreement_cells, loop_extrapolated_s = [], 0.0, 0, 0.0, 0.0
    for ctrl, basin in zip(ctrls, basins):
        edge = roa.boundary_cells(basin.outcome).ravel()
        strata = {"boundary": np.flatnonzero(edge), "interior": np.flatnonzero(~edge)}
        row = {"b": basin.b, "vectorised_s": basin.elapsed_s, "cells": basin.outcome.size}
        for name, cells in strata.items():
            pick = rng.choice(cells, min(per_b_subsample // 2, cells.size), replace=False)
            print(f"bench:   b = {basin.b:g}: {pick.size} {name} cells with simulate_continuous",
                  file=sys.stderr, flush=True)
            started = time.perf_counter()
            reference, _ = roa.classify_continuous(plant, ctrl, angle_dev0[pick], speed0[pick])
            elapsed = time.perf_counter() - started
            loop_s += elapsed
            loop_extrapolated_s += cells.size * elapsed / pick.size  # boundary runs last longer: weigh by stratum
            loop_runs += pick.size
            differ = int(np.count_nonzero(reference != basin.outcome.ravel()[pick]))
            row[name] = {"cells": int(cells.size), "checked": int(pick.size), "disagree": differ}
            disagreement_cells += cells.size * differ / pick.size  # stratified estimate
        per_b.append(row)
    per_trajectory_s = loop_extrapolated_s / (angle_dev0.size * len(ctrls))
    return {
        "grid": f"{grid.n_angle} x {grid.n_speed} x {len(ctrls)}", "vectorised_s": vectorised_s,
        "loop_runs": loop_runs, "loop_s": loop_s, "per_trajectory_ms": per_trajectory_s * 1e3,
        "loop_extrapolated_s": loop_extrapolated_s, "speedup": loop_extrapolated_s / vectorised_s,
        "disagreement_fraction": disagreement_cells / (angle_dev0.size * len(ctrls)), "per_b": per_b,
        "step_s": roa.STEP_S,
    }


# --- report -------------------------------------------------------------------------------


def verdict(ok: bool) -> str:
    return "met" if ok else "**not met**"


def report(command: str, machine: dict, quick: bool, latency, share, lockstep, roa_result, started: str,
           wall_s: float, network_lockstep=None, network_realtime=None) -> str:
    lines = ["# Benchmarks", "",
             f"Written by `{command}` on {started} (whole run {wall_s:.0f} s of wall time). "
             "Every table sets a measurement beside a baseline taken in the same run; the targets are issue 5's "
             "(sections 1-3) and issue 14's (sections 4-6).", ""]
    if quick:
        lines += ["> **`--quick` run**: shortened durations for development, not the numbers to publish.", ""]
    packages = ", ".join(f"{name} {version}" for name, version in machine["packages"].items())
    lines += ["## Machine", "",
              f"- CPU: {machine['cpu']}, {machine['cores']} cores; Linux {machine['kernel']}",
              f"- Python {machine['python']}; {packages}",
              f"- RMW: {machine['rmw']}; executor {machine['executor']}; localhost discovery, ROS domain "
              f"{machine['domain_id']}",
              f"- load average (1, 5, 15 min) at start {fmt_load(machine['load_average_at_start'])}, "
              f"at end {fmt_load(machine['load_average_at_end'])} (other work on the machine shows at the start; "
              "at the end, the last section's own processes too)", ""]
    # The start only: the network sections run 10 to 20 processes of their own, which the end's load average holds.
    if machine["load_average_at_start"][0] > 0.5 * machine["cores"]:
        lines += [f"> **Measured on a loaded machine**: a 1-minute load average above half the {machine['cores']} "
                  "cores at the start of the run (other work ran before or beside the benchmarks); the numbers are "
                  "noisy, the ratios (each against a baseline measured back to back) less so.", ""]
    if latency:
        lines += ["## 1. Closed-loop latency (realtime) beside a bare rclpy ping-pong", "",
                  "Loop: the plant and controller nodes as `nni-demo` starts them (no logger), realtime mode, "
                  f"b = {LOOP_BATTERY_LIMIT_PU}; latency per sample, measured at the plant, from the measurement's "
                  "instant (its stamp) to the arrival of the command that answers it. Ping-pong: two processes, "
                  "sensor_msgs/JointState with `contract.SAMPLE_QOS`, the same executor loop, a timer at the same "
                  "rate, no work between receive and send (`bench/pingpong.py`). Both time a sample from its "
                  "ideal instant (the plant measures and stamps at its reporting instants t0 + k T; the ping "
                  "stamps each ping with its tick's instant), so the timer's lateness counts in both. "
                  "A deadline miss: a reporting "
                  "instant that finds the previous sample unanswered. Each rate runs as "
                  f"{latency[0]['rounds']} alternating pairs (ping-pong, then loop) of "
                  f"{latency[0]['duration_s'] / latency[0]['rounds']:g} s each; the p50 ratio is the median of "
                  "the pairs' ratios (each pair back to back, so that the machine's drift between runs, larger "
                  "than the effect measured, cancels), the rounds' ratios in brackets. Ping-pong percentiles "
                  "pool all round trips; the loop's are the median of the rounds' p50 and p99 (from the plant's "
                  "diagnostics) and the largest max.", "",
                  "| rate (/s) | s | ping-pong p50 / p99 / max (ms) | loop p50 / p99 / max (ms) | p50 ratio "
                  "(rounds) | misses loop / ping-pong | measurements | timer jitter p99 (ms) |",
                  "|---:|---:|---|---|---|---|---:|---:|"]
        for row in latency:
            pp, lp = row["pingpong_ms"], row["loop_ms"]
            rounds = ", ".join(f"{ratio:.2f}" for ratio in row["round_ratios"])
            lines.append(f"| {row['rate_hz']:g} | {row['duration_s']:g} | {pp['p50']:.3f} / {pp['p99']:.3f} / "
                         f"{pp['max']:.2f} | {lp['p50']:.3f} / {lp['p99']:.3f} / {lp['max']:.2f} | "
                         f"**{row['p50_ratio']:.2f}** ({rounds}) | {row['loop_deadline_misses']} / "
                         f"{row['pingpong_deadline_misses']} | {row['loop_measurements']} | "
                         f"{row['loop_jitter_p99_ms']:.3f} |")
        at100 = [row for row in latency if row["rate_hz"] == 100.0]
        if at100:
            row = at100[0]
            ratio = row["p50_ratio"]
            lines += ["", f"Targets at 100/s: p50 ratio {ratio:.2f} <= {LATENCY_RATIO_TARGET}: "
                          f"{verdict(ratio <= LATENCY_RATIO_TARGET)}; deadline misses "
                          f"{row['loop_deadline_misses']} over {row['duration_s']:g} s = 0: "
                          f"{verdict(row['loop_deadline_misses'] == 0)}."]
        lines.append("")
    if share:
        echo_p50 = np.mean([row["echo"]["p50"] for row in share])
        ctrl_p50 = np.mean([row["controller"]["p50"] for row in share])
        lines += ["### 1b. The controller's share of the loop's latency", "",
                  "The same timed ping at 100/s, answered in alternate rounds by the bare echo and by the "
                  "controller node itself (topics remapped: `pmu:=bench/ping`, `battery/command:=bench/pong`): "
                  "the difference is what the controller node (its callback, and its executor dispatching a node "
                  "with timers and parameter services besides the subscription) adds; the rest of the loop's excess over the ping-pong is the plant's.", "",
                  "| round | echo p50 / p99 (ms) | controller p50 / p99 (ms) | controller - echo, p50 (ms) |",
                  "|---:|---|---|---:|"]
        for row in share:
            lines.append(f"| {row['round']} | {row['echo']['p50']:.3f} / {row['echo']['p99']:.3f} | "
                         f"{row['controller']['p50']:.3f} / {row['controller']['p99']:.3f} | "
                         f"{row['controller']['p50'] - row['echo']['p50']:+.3f} |")
        lines += [f"| mean | {echo_p50:.3f} | {ctrl_p50:.3f} | {ctrl_p50 - echo_p50:+.3f} |", ""]
    if lockstep:
        lines += ["## 2. Lockstep throughput beside its floor", "",
                  "The paper's case (delta(0) = 0.2 rad, b = 0.3) in lockstep mode: the plant publishes /clock and "
                  "sample k and advances only when the command for k has arrived. Throughput = simulated s per "
                  "wall s, from the plants' final diagnostics (`sim_time_s` / `run_wall_s`, wall time since each "
                  "start), over all rounds. Floor = what the transport alone allows: period / mean round trip of "
                  "a chained ping-pong (each pong sends the next ping at once). Each rate runs as "
                  f"{lockstep[0]['rounds']} alternating pairs (chained ping-pong, then a lockstep run); the "
                  "floor / throughput ratio is the median of the pairs' ratios, the rounds' in brackets. A cycle "
                  "(wall time per sample) is the loop latency (measurement out to command in, the controller's "
                  "work included) plus the plant's turnaround (command in to the next measurement out: RK4 over "
                  "the period, /clock, the measurement); the floor's cycle is one bare round trip.", "",
                  "| rate (/s) | simulated s / wall s | throughput (x real time) | floor (x real time) "
                  "| floor / throughput (rounds) | cycle (ms) | ping-pong round trip (ms) | loop latency p50 / p99 "
                  "(ms) | plant turnaround p50 / p99 (ms) | misses |",
                  "|---:|---:|---:|---:|---|---:|---:|---|---|---:|"]
        for row in lockstep:
            rounds = ", ".join(f"{ratio:.2f}" for ratio in row["round_ratios"])
            lines.append(f"| {row['rate_hz']:g} | {row['sim_duration_s']:g} / {row['run_wall_s']:.2f} | "
                         f"{row['throughput']:.1f} | {row['floor_throughput']:.1f} | **{row['floor_ratio']:.2f}** "
                         f"({rounds}) | {row['cycle_ms']:.3f} | {row['round_trip_mean_ms']:.3f} | "
                         f"{row['latency_ms']['p50']:.3f} / {row['latency_ms']['p99']:.3f} | "
                         f"{row['turnaround_ms']['p50']:.3f} / {row['turnaround_ms']['p99']:.3f} | "
                         f"{row['deadline_misses']} |")
        at100 = [row for row in lockstep if row["rate_hz"] == 100.0]
        if at100:
            row = at100[0]
            lines += ["", f"Targets at 100/s: throughput {row['throughput']:.1f} >= {LOCKSTEP_REALTIME_TARGET:g}x "
                          f"real time: {verdict(row['throughput'] >= LOCKSTEP_REALTIME_TARGET)}; within "
                          f"{LOCKSTEP_FLOOR_RATIO_TARGET}x of the floor ({row['floor_ratio']:.2f}): "
                          f"{verdict(row['floor_ratio'] <= LOCKSTEP_FLOOR_RATIO_TARGET)}."]
        lines.append("")
    if roa_result:
        r = roa_result
        lines += ["## 3. Region-of-attraction sweep beside a per-trajectory scipy loop", "",
                  f"The paper's plant and gains, b in {{0, 0.2, 0.3, inf}}, a {r['grid']} grid of initial "
                  "conditions (angle deviation within +-pi rad, speed deviation within +-10 rad/s, x3(0) = 0), "
                  f"classified vectorised (`roa.sweep`: RK4 at {r['step_s'] * 1e3:g} ms across all cells at once, "
                  "early exits). Baseline: `simulate_continuous` (scipy solve_ivp, DOP853, located switching "
                  "events, Filippov sliding) one trajectory at a time on a subsample, half on basin-boundary "
                  "cells and half inside, extrapolated to the whole grid (each stratum's time per trajectory "
                  "times its cell count; the time per trajectory is that total over all cells). Disagreement: "
                  "a stratified estimate over the grid (boundary and interior disagreement rates weighted by "
                  "their cell counts).", "",
                  "| vectorised, whole grid (s) | scipy loop per trajectory (ms) | scipy loop extrapolated (s) "
                  "| speed-up | cells checked | disagreement (of all cells) |",
                  "|---:|---:|---:|---:|---:|---:|",
                  f"| {r['vectorised_s']:.2f} | {r['per_trajectory_ms']:.1f} | {r['loop_extrapolated_s']:.0f} | "
                  f"{r['speedup']:.0f}x | {r['loop_runs']} | {100 * r['disagreement_fraction']:.3f} % |", "",
                  "| b (pu) | vectorised (s) | boundary cells: checked / disagree | interior cells: checked / "
                  "disagree |", "|---:|---:|---|---|"]
        for row in r["per_b"]:
            lines.append(f"| {row['b']:g} | {row['vectorised_s']:.2f} | {row['boundary']['checked']} of "
                         f"{row['boundary']['cells']} / {row['boundary']['disagree']} | "
                         f"{row['interior']['checked']} of {row['interior']['cells']} / "
                         f"{row['interior']['disagree']} |")
        lines += ["", f"Targets: {r['vectorised_s']:.2f} s < {ROA_SECONDS_TARGET:g} s: "
                      f"{verdict(r['vectorised_s'] < ROA_SECONDS_TARGET)}; {r['speedup']:.0f}x >= "
                      f"{ROA_SPEEDUP_TARGET:g}x: {verdict(r['speedup'] >= ROA_SPEEDUP_TARGET)}; "
                      f"{100 * r['disagreement_fraction']:.3f} % < {100 * ROA_DISAGREEMENT_TARGET:g} %: "
                      f"{verdict(r['disagreement_fraction'] < ROA_DISAGREEMENT_TARGET)}.", ""]
    if network_lockstep:
        lines += network_lockstep_section(network_lockstep)
    if network_realtime:
        lines += network_realtime_section(network_realtime)
    return "\n".join(lines)


def network_lockstep_section(rows: list[dict]) -> list[str]:
    """Section 4: lockstep throughput against N beside the chained fan-out, per deployment, and the cost per added
    generator of each deployment."""
    lines = ["## 4. Network lockstep throughput beside its fan-out floor (issue 14)", "",
             "The network plant node (`nni_plant_sim.network_plant_node`, its default disturbance: a bolted fault "
             f"at bus 7 cleared after 0.1 s) in lockstep at {rows[0].get('rate_hz', NETWORK_RATE_HZ):g} frames/s "
             "with one controller per generator (`controller_node` in `/gen<i>`, g measured, "
             f"b = {NETWORK_BATTERY_LIMIT_PU} pu, the parameters `nni-demo --case` gives); a sample advances when "
             "every generator's command has arrived. Two deployments, as `nni-demo --case --deployment` starts "
             "them: **separate**, a controller process per generator, and **composed**, all the case's "
             "controllers as nodes of one `composed_controllers` process on one executor. N = 1 is the SMIB "
             "plant node (`plant_node`, the paper's case) with its controller. Cases: `kundur_two_area` (N = 4), "
             "`ieee39` (N = 10), `kundur_ring_52` (N = 52: 13 copies of the two-area system tied in a ring, "
             "`nni_plant_sim/cases/replicated.py`). Floor: the same deployment's transport, a chained fan-out "
             "ping-pong to N echoes (`bench/pingpong.py --fanout N`: one ping to every echo, the next when all N "
             "pongs are in; N = 1: one echo), the echoes N processes (separate) or N nodes of one process on one "
             "executor (composed, `pingpong echo --composed N`); period / mean round trip. Each row runs as "
             "alternating pairs (lockstep run, then fan-out), the simulated time and round trips split among "
             "them; floor / throughput is the median of the pairs' ratios (each pair's in brackets). Cycle = wall "
             "time per sample; latency and turnaround: the median over generators of each generator's p50 and "
             "p99 (plant diagnostics). No separate N = 52 row: 52 controller processes beside 52 echo processes "
             "on this 2-core machine measure the machine's overload, not the deployment; at that size the "
             "controllers run composed, as one substation computer would run them.", "",
             "| N | case | deployment | simulated s / wall s | throughput (x real time) | floor (x real time) "
             "| floor / throughput (rounds) | cycle (ms) | fan-out round trip (ms) | latency p50 / p99 (ms) "
             "| turnaround p50 / p99 (ms) | misses |", "|---:|---|---|---:|---:|---:|---|---:|---:|---|---|---:|"]
    failed = [row for row in rows if "error" in row]
    rows = [row for row in rows if "error" not in row]
    for row in rows:
        rounds = ", ".join(f"{ratio:.2f}" for ratio in row["round_ratios"])
        case = f"{row['case']} (**partial**: {row['partial']})" if row["partial"] else row["case"]
        lines.append(f"| {row['generators']} | {case} | {row['deployment']} | "
                     f"{row['sim_duration_s']:g} / {row['run_wall_s']:.2f} | "
                     f"{row['throughput']:.1f} | {row['floor_throughput']:.1f} | **{row['floor_ratio']:.2f}** "
                     f"({rounds}) | {row['cycle_ms']:.3f} | {row['round_trip_mean_ms']:.3f} | "
                     f"{row['latency_ms']['p50']:.3f} / {row['latency_ms']['p99']:.3f} | "
                     f"{row['turnaround_ms']['p50']:.3f} / {row['turnaround_ms']['p99']:.3f} | "
                     f"{row['deadline_misses']} |")
    for row in failed:
        lines.append(f"| - | {row['case']}: **not completed**: {row['error']} | {row['deployment']} |" + " |" * 9)
    for deployment in ("separate", "composed"):
        cost = per_generator_cost([row for row in rows if row["deployment"] == deployment])
        if cost:
            lines += ["", f"Cost per added generator, {deployment} (least-squares slope over N = "
                          f"{', '.join(map(str, cost['sizes']))}): the cycle grows by **{cost['cycle_ms']:.3f} ms** "
                          f"per generator, the floor's round trip by {cost['floor_ms']:.3f} ms."]
    for row in rows:
        if row["generators"] == 10:
            met = verdict(row["floor_ratio"] <= NETWORK_FLOOR_RATIO_TARGET)
            lines += ["", f"Target at N = 10 ({row['deployment']}): within {NETWORK_FLOOR_RATIO_TARGET:g}x of the "
                          f"floor ({row['floor_ratio']:.2f}): {met}."]
    return lines + [""]


def network_realtime_section(result: dict) -> list[str]:
    """Section 5: realtime per generator beside the timed fan-out, separate and composed; section 6: memory."""
    if "error" in result:
        return ["## 5. Network realtime (issue 14)", "", f"**Not completed**: {result['error']}", ""]
    kinds, gens = result["kinds"], result["generators"]
    lines = [f"## 5. Network realtime at {result['rate_hz']:g} frames/s, {result['size']} controllers (issue 14)", "",
             f"`{result['case']}` in realtime (the PMU grid on the wall clock) for {result['duration_s']:g} s per "
             f"deployment, as {result['rounds']} alternating round(s): the loop with separate controller "
             "processes, then the timed fan-out ping-pong to "
             f"{result['size']} echo processes at the same rate; the loop with the controllers composed in one "
             "process (`composed_controllers`), then the fan-out to as many echo nodes composed in one process "
             "(`pingpong echo --composed N`). Latency per generator, measured at the plant from the measurement's "
             "instant to its command's arrival: the median of the rounds' p50 and p99; the ping-pong's per echo, "
             "from the tick's instant, pooled. A miss: an instant that finds the previous sample unanswered, "
             "summed over the rounds.", ""]
    header, rule = "| generator |", "|---|"
    for kind in kinds:
        header += f" {kind} fan-out p50 / p99 (ms) | misses | {kind} loop p50 / p99 (ms) | misses |"
        rule += "---|---:|---|---:|"
    lines += [header, rule]

    def cells(values: list[dict]) -> str:
        return (f" {np.median([v['p50'] for v in values]):.3f} / {np.median([v['p99'] for v in values]):.3f} | "
                f"{sum(v['deadline_misses'] for v in values)} |")

    for row in gens:
        lines.append(f"| {row['namespace']} ({row['machine']}) |"
                     + "".join(cells([row[f"{kind}_floor"]]) + cells([row[kind]]) for kind in kinds))
    lines += ["| median / total |" + "".join(cells([g[f"{kind}_floor"] for g in gens]) + cells([g[kind] for g in gens])
                                             for kind in kinds), ""]
    for kind in kinds:
        ratio = np.median([g[kind]["p50"] for g in gens]) / np.median([g[f"{kind}_floor"]["p50"] for g in gens])
        measurements = sum(g[kind]["measurements"] for g in gens)
        lines.append(f"- {kind}: median p50 {ratio:.2f}x its fan-out's; {measurements} measurements in all, "
                     f"{sum(g[kind]['deadline_misses'] for g in gens)} deadline misses.")
    memory = result["memory"]
    mib = lambda kib: kib / 1024.0  # noqa: E731
    floor = np.median(memory["separate_echo_kib"])
    lines += ["", "## 6. Memory per controller (issue 14)", "",
              "Resident set size (`VmRSS`) at the end of each realtime run of section 5, while the processes are "
              "up; beside it the fan-outs' echoes: a bare echo process (rclpy, one node, one subscription and one "
              "publisher), the floor of any ROS 2 Python process here, and N echo nodes composed in one process. "
              "CPU: each controller process's user + system time from the plant's start of the run to its end, "
              "over that wall time (% of one core). Above the echo: the median RSS less the bare echo process's "
              "median, per controller or echo node (what one more costs beyond the Python and rclpy floor every "
              "process pays once).", "",
              "| process | runs x processes | RSS median (MiB) | min .. max (MiB) | RSS per node (MiB) "
              "| above the echo, per node (MiB) | CPU per controller, median (% of a core) |",
              "|---|---:|---:|---|---:|---:|---:|"]
    for name, kib, cpu, per in (
            ("bare echo (fan-out), one process per echo", memory["separate_echo_kib"], None, 1),
            ("echo nodes (fan-out), all in one process", memory["composed_echo_kib"], None, result["size"]),
            ("controller_node, one process per generator", memory["separate_kib"], memory["separate_cpu"], 1),
            ("composed_controllers, all in one process", memory["composed_kib"], memory["composed_cpu"],
             result["size"])):
        share = "-" if cpu is None else f"{100 * np.median(cpu) / per:.1f}"
        above = mib(np.median(kib) - floor) / per
        lines.append(f"| {name} | {len(kib)} | {mib(np.median(kib)):.1f} | {mib(min(kib)):.1f} .. "
                     f"{mib(max(kib)):.1f} | {mib(np.median(kib)) / per:.1f} | {above:+.1f} | {share} |")
    return lines + [""]


def executor_name() -> str:
    """The executor class the nodes (and the ping-pong) spin, from ``node_main.make_executor``."""
    import rclpy

    from nni_msgs_adapter.ros.node_main import make_executor

    rclpy.init()
    try:
        return type(make_executor()).__name__
    finally:
        rclpy.shutdown()


def fmt_load(load) -> str:
    return ", ".join(f"{value:.2f}" for value in load)


def main(argv=None) -> int:
    args = parse_args(argv)
    command = "bench/run_all" + (" " + " ".join(sys.argv[1:] if argv is None else argv)).rstrip()
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(args.domain_id),
                      PYTHONUNBUFFERED="1")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    log_root = ROOT / "out" / "bench"
    started_text, started = time.strftime("%Y-%m-%d %H:%M %Z"), time.monotonic()
    machine = machine_description()
    machine["domain_id"] = args.domain_id
    machine["executor"] = executor_name()
    duration_s = 6.0 if args.quick else 30.0
    latency = share = lockstep = roa_result = None
    if "latency" in args.only:
        latency = bench_latency(env, log_root, args.rates, duration_s, LATENCY_ROUNDS)
        share = bench_controller_share(env, log_root, 100.0, 4, 3.0 if args.quick else 15.0)
    if "lockstep" in args.only:
        lockstep = bench_lockstep(env, log_root, [50.0, 100.0], 30.0 if args.quick else 60.0,
                                  600 if args.quick else 6000, LATENCY_ROUNDS)
    if "roa" in args.only:
        roa_result = bench_roa(40 if args.quick else 200)
    network_lockstep = network_realtime = None
    if "network-lockstep" in args.only:
        network_lockstep = bench_network_lockstep(
            env, log_root, NETWORK_LOCKSTEP_QUICK_CASES if args.quick else NETWORK_LOCKSTEP_CASES, NETWORK_RATE_HZ,
            4.0 if args.quick else 30.0, 200 if args.quick else 1500)
    if "network-realtime" in args.only:
        try:
            network_realtime = bench_network_realtime(
                env, log_root, "kundur_two_area" if args.quick else "ieee39", NETWORK_RATE_HZ,
                5.0 if args.quick else 30.0, 1 if args.quick else LATENCY_ROUNDS)
        except (ChildError, RuntimeError) as error:
            print(f"bench: network realtime: not completed: {error}", file=sys.stderr, flush=True)
            network_realtime = {"error": str(error).splitlines()[0][:300]}
    machine["load_average_at_end"] = os.getloadavg()
    text = report(command, machine, args.quick, latency, share, lockstep, roa_result, started_text,
                  time.monotonic() - started, network_lockstep, network_realtime)
    tmp = args.out.with_name(args.out.name + ".part")
    tmp.write_text(text)
    tmp.replace(args.out)
    print(text)
    print(f"wrote {args.out} (logs in {log_root})", file=sys.stderr)
    return 0


def run(argv=None) -> int:
    """``main``, with a benchmark that cannot run (a child that failed or stayed silent) as one line and exit 1."""
    try:
        return main(argv)
    except (ChildError, RuntimeError) as error:
        print(f"bench: error: {error}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(run())
