"""Section 1: closed-loop latency (realtime) beside a bare rclpy ping-pong, and 1b: the controller node's share of
it (the same timed ping answered by the bare echo and by the controller itself); each with its report section."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from bench.common import (
    LOOP_BATTERY_LIMIT_PU,
    closed_loop,
    fmt_rounds,
    median_latency_ms,
    percentiles_ms,
    pingpong,
    progress,
    row_at,
    verdict,
)

#: Issue 5's target at 100/s: the loop's p50 within this factor of the ping-pong's.
LATENCY_RATIO_TARGET = 1.3
#: The real controller node in the echo's place: it answers the ping (a PMU message) with a command
#: stamped like it, which the ping takes as its pong.
CONTROLLER_AS_PEER = [sys.executable, "-m", "nni_battery_controller.controller_node", "--ros-args",
                      "-r", "pmu:=bench/ping", "-r", "battery/command:=bench/pong",
                      "-p", f"battery_limit_pu:={LOOP_BATTERY_LIMIT_PU}"]


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
        progress(f"latency at {rate:g}/s, {rounds} x ({part_s:g} s ping-pong, {part_s:g} s closed loop)")
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
            "loop_ms": {**median_latency_ms(loops), "max": max(float(f["latency_max_ms"]) for f in loops)},
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
    progress(f"controller share at {rate_hz:g}/s, {rounds} x ({duration_s:g} s echo, {duration_s:g} s controller)")
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


def latency_section(latency: list[dict]) -> list[str]:
    """Section 1: the loop's latency beside the ping-pong's per rate, and issue 5's targets at 100/s."""
    lines = ["## 1. Closed-loop latency (realtime) beside a bare rclpy ping-pong", "",
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
        lines.append(f"| {row['rate_hz']:g} | {row['duration_s']:g} | {pp['p50']:.3f} / {pp['p99']:.3f} / "
                     f"{pp['max']:.2f} | {lp['p50']:.3f} / {lp['p99']:.3f} / {lp['max']:.2f} | "
                     f"**{row['p50_ratio']:.2f}** ({fmt_rounds(row['round_ratios'])}) | "
                     f"{row['loop_deadline_misses']} / {row['pingpong_deadline_misses']} | "
                     f"{row['loop_measurements']} | {row['loop_jitter_p99_ms']:.3f} |")
    row = row_at(latency, 100.0)
    if row:
        ratio = row["p50_ratio"]
        lines += ["", f"Targets at 100/s: p50 ratio {ratio:.2f} <= {LATENCY_RATIO_TARGET}: "
                      f"{verdict(ratio <= LATENCY_RATIO_TARGET)}; deadline misses "
                      f"{row['loop_deadline_misses']} over {row['duration_s']:g} s = 0: "
                      f"{verdict(row['loop_deadline_misses'] == 0)}."]
    return lines + [""]


def share_section(share: list[dict]) -> list[str]:
    """Section 1b: echo and controller round trips per round, and their mean difference."""
    echo_p50 = np.mean([row["echo"]["p50"] for row in share])
    ctrl_p50 = np.mean([row["controller"]["p50"] for row in share])
    lines = ["### 1b. The controller's share of the loop's latency", "",
             "The same timed ping at 100/s, answered in alternate rounds by the bare echo and by the "
             "controller node itself (topics remapped: `pmu:=bench/ping`, `battery/command:=bench/pong`): "
             "the difference is what the controller node (its callback, and its executor dispatching a node "
             "with timers and parameter services besides the subscription) adds; the rest of the loop's excess "
             "over the ping-pong is the plant's.", "",
             "| round | echo p50 / p99 (ms) | controller p50 / p99 (ms) | controller - echo, p50 (ms) |",
             "|---:|---|---|---:|"]
    for row in share:
        lines.append(f"| {row['round']} | {row['echo']['p50']:.3f} / {row['echo']['p99']:.3f} | "
                     f"{row['controller']['p50']:.3f} / {row['controller']['p99']:.3f} | "
                     f"{row['controller']['p50'] - row['echo']['p50']:+.3f} |")
    return lines + [f"| mean | {echo_p50:.3f} | {ctrl_p50:.3f} | {ctrl_p50 - echo_p50:+.3f} |", ""]
