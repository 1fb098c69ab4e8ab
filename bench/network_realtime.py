"""Sections 5 and 6 (issue 14): network realtime per generator, the controllers as separate processes and composed
in one, beside the timed fan-out to echoes deployed alike; and the memory and CPU per controller those runs show."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.common import median_latency_ms, network_loop, not_completed, percentiles_ms, pingpong, progress, verdict
from nni_msgs_adapter.ros.processes import ChildError


def bench_network_realtime(env, log_root: Path, case: str, rate_hz: float, round_s: float, rounds: int) -> dict:
    """``measure_network_realtime``, or the run that could not complete, reported as such."""
    try:
        return measure_network_realtime(env, log_root, case, rate_hz, round_s, rounds)
    except (ChildError, RuntimeError) as error:
        return not_completed("network realtime", error)


def measure_network_realtime(env, log_root: Path, case: str, rate_hz: float, round_s: float,
                             rounds: int) -> dict:
    """Realtime with N controller processes and with N composed in one, each beside its deployment's timed fan-out.

    In ``rounds`` alternating rounds of ``round_s`` each, per deployment: the loop, then the timed
    fan-out to N echoes deployed alike (N processes, or N nodes of one process) at the same rate. Per
    generator: the ping-pong's round trips pooled, the loop's median of the rounds' p50 and p99 (from the
    plant's diagnostics), misses summed; memory: the controllers' and echoes' resident sets at the end of
    each run.
    """
    kinds = ("separate", "composed")
    progress(f"network realtime {case} at {rate_hz:g}/s, {rounds} x ({round_s:g} s loop, then {round_s:g} s "
             f"fan-out ping-pong, with {' and '.join(kinds)} controllers and echoes)")
    pings, loops = {kind: [] for kind in kinds}, {kind: [] for kind in kinds}
    for index in range(1, rounds + 1):
        for kind in kinds:
            run = network_loop(env, log_root / f"net_realtime_{case}_{kind}_{index}", case, "realtime", rate_hz,
                               round_s, kind)
            loops[kind].append(run)
            pings[kind].append(pingpong(env, log_root / f"fanout_timed_{case}_{kind}_{index}", "timed",
                                        rate_hz=rate_hz, duration_s=round_s, fanout=run["size"],
                                        composed=kind == "composed"))
    namespaces = list(loops["separate"][0]["summary"])
    generators = []
    for i, ns in enumerate(namespaces):
        row = {"namespace": ns, "machine": loops["separate"][0]["summary"][ns]["machine"]}
        for kind in kinds:
            finals = [run["summary"][ns] for run in loops[kind]]
            row[kind] = {**median_latency_ms(finals),
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
            "round_s": round_s, "rounds": rounds, "kinds": kinds, "memory": memory}


def network_realtime_section(result: dict) -> list[str]:
    """Section 5: realtime per generator beside the timed fan-out, separate and composed; section 6: memory."""
    if "error" in result:
        return ["## 5. Network realtime (issue 14)", "", f"**Not completed**: {result['error']}", ""]
    kinds, gens = result["kinds"], result["generators"]
    lines = [f"## 5. Network realtime at {result['rate_hz']:g} frames/s, {result['size']} controllers (issue 14)", "",
             f"`{result['case']}` in realtime (the PMU grid on the wall clock), per deployment {result['rounds']} "
             f"alternating round(s) of {result['round_s']:g} s: the loop with separate controller "
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
    return lines + [""] + realtime_targets(result) + memory_section(result)


def realtime_targets(result: dict) -> list[str]:
    """Issue 23's realtime targets: composed, no deadline miss; separate, no more misses than its fan-out floor."""
    misses = {kind: sum(g[kind]["deadline_misses"] for g in result["generators"]) for kind in result["kinds"]}
    floor = {kind: sum(g[f"{kind}_floor"]["deadline_misses"] for g in result["generators"]) for kind in result["kinds"]}
    lines = []
    if "composed" in misses:
        lines.append(f"- composed: {misses['composed']} deadline misses = 0: {verdict(misses['composed'] == 0)}.")
    if "separate" in misses:
        lines.append(f"- separate: {misses['separate']} deadline misses <= its fan-out floor's {floor['separate']}: "
                     f"{verdict(misses['separate'] <= floor['separate'])}.")
    return ["Targets (issue 23, over the rounds together):", ""] + lines + [""]


def memory_section(result: dict) -> list[str]:
    """Section 6: the resident sets of section 5's controllers and echoes, per node and above a bare echo."""
    memory = result["memory"]
    mib = lambda kib: kib / 1024.0  # noqa: E731
    floor = np.median(memory["separate_echo_kib"])
    lines = ["## 6. Memory per controller (issue 14)", "",
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
