"""Section 8: the latency the C37.118 path adds to the loop (plant -> its stream -> c37118_client -> controller)
against the ROS-fed loop, realtime, alternating rounds; with its report section."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.common import LOOP_BATTERY_LIMIT_PU, closed_loop, fmt_rounds, median_latency_ms, progress, verdict

#: Issue 22's target: the C37.118 path adds at most this to the loop's p50 latency at 50 frames/s, ms.
ADDED_P50_TARGET_MS = 1.0


def bench_c37118_loop(env, log_root: Path, rate_hz: float, duration_s: float, rounds: int) -> dict:
    """ROS-fed and C37.118-fed loops in ``rounds`` alternating pairs of ``duration_s / rounds`` each; the p50
    added is the median of the pairs' differences (back to back: the machine's drift cancels)."""
    part_s = duration_s / rounds
    progress(f"C37.118 loop at {rate_hz:g}/s, {rounds} x ({part_s:g} s ROS-fed, {part_s:g} s through C37.118)")
    loops = {"ros": [], "c37118": []}
    for index in range(1, rounds + 1):
        for kind, finals in loops.items():
            finals.append(closed_loop(env, log_root / f"c37118_loop_{kind}_{index}", "realtime", rate_hz, part_s,
                                      kind))
    added = [float(c37["latency_p50_ms"]) - float(ros["latency_p50_ms"])
             for ros, c37 in zip(loops["ros"], loops["c37118"])]
    return {"rate_hz": rate_hz, "duration_s": duration_s, "rounds": rounds,
            **{kind: {**median_latency_ms(finals), "max": max(float(f["latency_max_ms"]) for f in finals),
                      "deadline_misses": sum(int(f["deadline_misses"]) for f in finals),
                      "measurements": sum(int(f["measurements"]) for f in finals)}
               for kind, finals in loops.items()},
            "added_p50_ms": float(np.median(added)), "round_added_ms": added}


def c37118_loop_section(result: dict) -> list[str]:
    """Section 8: both loops' latency and what C37.118 adds, against the 1 ms target."""
    added = result["added_p50_ms"]
    lines = ["## 8. Latency the C37.118 path adds to the loop", "",
             f"The SMIB loop of section 1 (realtime, b = {LOOP_BATTERY_LIMIT_PU}, no logger) at "
             f"{result['rate_hz']:g} frames/s, fed by ROS (`pmu`) and, in alternate runs, through C37.118 as "
             "`nni-demo --measurements c37118` feeds it: the plant's IEEE C37.118.2 stream on a loopback port, "
             "the `c37118_client` node publishing `c37118/pmu`, the controller reading it. Latency per sample at "
             "the plant, from the measurement's instant to the command's arrival. "
             f"{result['rounds']} alternating pairs of {result['duration_s'] / result['rounds']:g} s; the p50 "
             "added is the median of the pairs' differences, the rounds' in brackets.", "",
             "| fed by | p50 / p99 / max (ms) | deadline misses | measurements |", "|---|---|---:|---:|"]
    for kind, label in (("ros", "ROS (`pmu`)"), ("c37118", "C37.118 (`c37118/pmu`)")):
        row = result[kind]
        lines.append(f"| {label} | {row['p50']:.3f} / {row['p99']:.3f} / {row['max']:.2f} | "
                     f"{row['deadline_misses']} | {row['measurements']} |")
    return lines + ["", f"Added p50: **{added:.3f} ms** ({fmt_rounds(result['round_added_ms'])}) <= "
                        f"{ADDED_P50_TARGET_MS:g} ms: {verdict(added <= ADDED_P50_TARGET_MS)}.", ""]
