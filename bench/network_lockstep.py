"""Section 4 (issue 14): network lockstep throughput against N, a controller per generator deployed separate or
composed, beside a chained fan-out to N echoes deployed alike; the cost per added generator; its report section."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from bench.common import (
    NETWORK_BATTERY_LIMIT_PU,
    NETWORK_RATE_HZ,
    cycle_ms,
    network_loop,
    not_completed,
    pingpong,
    progress,
    verdict,
)
from bench.lockstep import generator_percentiles, lockstep_pair, lockstep_row, smib_pair, throughput_cells
from nni_msgs_adapter.ros.processes import ChildError

#: Issue 23: at N = 4 and 10, separate and composed, the median of the rounds within this factor of the fan-out
#: floor, and no round above the second.
NETWORK_FLOOR_RATIO_TARGET, NETWORK_FLOOR_ROUND_LIMIT = 1.5, 2.0
#: Issue 23: the 52-machine ring composed at least this fast (x real time), and the plant's turnaround at N = 10
#: at most this (p50, ms).
RING_THROUGHPUT_TARGET, TURNAROUND_TARGET_MS = 3.0, 0.5
#: Lockstep scaling, (case, alternating rounds, deployment): None is N = 1 (the SMIB plant node), then the
#: network cases by size, a controller process each, then composed in one process (network_deployment.DEPLOYMENTS).
#: No separate N = 52 row: 52 controller processes (and 52 echo processes for its floor) on 2 cores are the
#: machine's load, not the deployment's cost; at that size the controllers run composed.
NETWORK_LOCKSTEP_CASES = ((None, 3, "separate"), ("kundur_two_area", 3, "separate"), ("kundur_two_area", 3, "composed"),
                          ("ieee39", 3, "separate"), ("ieee39", 3, "composed"), ("kundur_ring_52", 3, "composed"))
NETWORK_LOCKSTEP_QUICK_CASES = ((None, 1, "separate"), ("kundur_two_area", 1, "separate"),
                                ("kundur_two_area", 1, "composed"), ("kundur_ring_52", 1, "composed"))
#: The separate rows also run the loop for this long with the plant on a core of its own (its threads on one core,
#: the controllers' on the others) for the plant's own turnaround: shared, its publish burst wakes N controller
#: processes that run on its core too. Not a deployment the demo makes; a measurement of where the turnaround goes.
PINNED_SIM_S = 10.0


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
        progress(f"network lockstep {label} ({deployment}) at {rate_hz:g}/s, {rounds} x (chained fan-out of "
                 f"{chained_samples // rounds}, {sim_duration_s / rounds:g} simulated s of the loop)")
        try:
            rows.append(network_lockstep_row(env, log_root, case, rounds, rate_hz, sim_duration_s, chained_samples,
                                             deployment))
        except (ChildError, RuntimeError) as error:
            rows.append({"case": label, "deployment": deployment,
                         **not_completed(f"network lockstep {label} ({deployment})", error)})
    return rows


def network_lockstep_row(env, log_root: Path, case, rounds: int, rate_hz: float, sim_duration_s: float,
                         chained_samples: int, deployment: str) -> dict:
    """One row of section 4: ``rounds`` alternating pairs of a lockstep run and a chained fan-out.

    ``deployment`` "composed": the controllers composed in one process, the fan-out's echoes too."""
    part_s, part_samples = sim_duration_s / rounds, chained_samples // rounds
    label = case or "smib"
    name = label if deployment == "separate" else f"{label}_{deployment}"
    pairs, partial, size = [], None, 1
    for index in range(1, rounds + 1):
        chained_dir, loop_dir = log_root / f"fanout_chained_{name}_{index}", log_root / f"net_lockstep_{name}_{index}"
        if case is None:
            pairs.append(smib_pair(env, chained_dir, loop_dir, rate_hz, part_s, part_samples, label))
        else:
            run = network_loop(env, loop_dir, case, "lockstep", rate_hz, part_s, deployment)
            size, partial = run["size"], run["partial"] or partial
            chained = pingpong(env, chained_dir, "chained", samples=part_samples, fanout=size,
                               composed=deployment == "composed")
            pairs.append(lockstep_pair(chained, run["summary"], rate_hz, label))
    row = {"case": label, "deployment": deployment, "generators": size, **lockstep_row(pairs, rate_hz),
           "partial": partial}
    if case is not None and deployment == "separate" and len(os.sched_getaffinity(0)) > 1:
        pinned = network_loop(env, log_root / f"net_lockstep_{name}_pinned", case, "lockstep", rate_hz,
                              min(PINNED_SIM_S, sim_duration_s), deployment, attach=plant_on_a_core_of_its_own)
        row["pinned"] = {"turnaround_ms": generator_percentiles(pinned["summary"], "turnaround")["p50"],
                         "cycle_ms": cycle_ms(pinned["summary"]), "plant_cpu": plant_cpu()}
    return row


def plant_cpu() -> int:
    """The core the plant gets of its own: the first this process may use."""
    return min(os.sched_getaffinity(0))


def plant_on_a_core_of_its_own(plant_pid: int, controller_pids: list[int]) -> None:
    """Every thread of the plant on :func:`plant_cpu`, every thread of the controllers on the other cores."""
    own = plant_cpu()
    others = os.sched_getaffinity(0) - {own}
    for pid, where in [(plant_pid, {own})] + [(pid, others) for pid in controller_pids]:
        for thread in os.listdir(f"/proc/{pid}/task"):
            os.sched_setaffinity(int(thread), where)


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
        case = f"{row['case']} (**partial**: {row['partial']})" if row["partial"] else row["case"]
        lines.append(f"| {row['generators']} | {case} | {row['deployment']} | {throughput_cells(row)}")
    for row in failed:
        lines.append(f"| - | {row['case']}: **not completed**: {row['error']} | {row['deployment']} |" + " |" * 9)
    for deployment in ("separate", "composed"):
        cost = per_generator_cost([row for row in rows if row["deployment"] == deployment])
        if cost:
            lines += ["", f"Cost per added generator, {deployment} (least-squares slope over N = "
                          f"{', '.join(map(str, cost['sizes']))}): the cycle grows by **{cost['cycle_ms']:.3f} ms** "
                          f"per generator, the floor's round trip by {cost['floor_ms']:.3f} ms."]
    lines += [""] + network_lockstep_targets(rows)
    return lines + [""]


def network_lockstep_targets(rows: list[dict]) -> list[str]:
    """Issue 23's targets, one line each, for the rows measured (a target whose row is missing says so)."""
    lines = []
    for size in (4, 10):
        for deployment in ("separate", "composed"):
            row = next((r for r in rows if r["generators"] == size and r["deployment"] == deployment), None)
            if row is None:
                lines.append(f"- N = {size} ({deployment}): not measured in this run.")
                continue
            worst = max(row["round_ratios"])
            met = verdict(row["floor_ratio"] <= NETWORK_FLOOR_RATIO_TARGET and worst <= NETWORK_FLOOR_ROUND_LIMIT)
            lines.append(f"- N = {size} ({deployment}): floor / throughput {row['floor_ratio']:.2f} (median) <= "
                         f"{NETWORK_FLOOR_RATIO_TARGET:g}, its worst round {worst:.2f} <= "
                         f"{NETWORK_FLOOR_ROUND_LIMIT:g}: {met}.")
    ring = next((r for r in rows if r["generators"] == 52 and r["deployment"] == "composed"), None)
    lines.append("- N = 52 (composed): not measured in this run." if ring is None else
                 f"- N = 52 (composed): {ring['throughput']:.1f}x real time >= {RING_THROUGHPUT_TARGET:g}: "
                 f"{verdict(ring['throughput'] >= RING_THROUGHPUT_TARGET)}.")
    for row in (r for r in rows if r["generators"] == 10):
        turnaround = row["turnaround_ms"]["p50"]
        lines.append(f"- N = 10 ({row['deployment']}): the plant's turnaround p50 {turnaround:.3f} ms <= "
                     f"{TURNAROUND_TARGET_MS:g} ms: {verdict(turnaround <= TURNAROUND_TARGET_MS)}.")
    pinned = [row for row in rows if "pinned" in row]
    return ["Targets (issue 23):", ""] + lines + ([
        "", "The plant on a core of its own (a run of each separate row with the plant's threads on CPU "
        f"{pinned[0]['pinned']['plant_cpu']} and the controllers' on the others, `sched_setaffinity` when the run "
        "starts; no target, "
        "a measurement of where the turnaround goes: sharing the cores, the plant's burst of N measurements wakes "
        "N controller processes that run on its core too):", ""] + [
        f"- N = {row['generators']} (separate): turnaround p50 {row['pinned']['turnaround_ms']:.3f} ms (shared: "
        f"{row['turnaround_ms']['p50']:.3f} ms), cycle {row['pinned']['cycle_ms']:.3f} ms (shared: "
        f"{row['cycle_ms']:.3f} ms)." for row in pinned] if pinned else [])
