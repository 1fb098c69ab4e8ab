"""Section 2: lockstep throughput of the paper's case beside its floor, a chained ping-pong's round trip; with its
report section, and the lockstep pairs, rows and table cells the network lockstep (section 4) is made of too."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.common import closed_loop, fmt_rounds, pingpong, progress, row_at, verdict

#: Issue 5's targets at 100/s: throughput (simulated s per wall s) and the floor / throughput ratio.
LOCKSTEP_REALTIME_TARGET = 10.0
LOCKSTEP_FLOOR_RATIO_TARGET = 1.5


def bench_lockstep(env, log_root: Path, rates, sim_duration_s: float, chained_samples: int,
                   rounds: int) -> list[dict]:
    """Lockstep runs beside chained ping-pongs, in ``rounds`` alternating pairs per rate (as the latency bench)."""
    rows = []
    for rate in rates:
        part_s, part_samples = sim_duration_s / rounds, chained_samples // rounds
        progress(f"lockstep at {rate:g}/s, {rounds} x (chained ping-pong of {part_samples} round trips, "
                 f"{part_s:g} simulated s of the loop)")
        rows.append(lockstep_row([smib_pair(env, log_root / f"pingpong_chained_{rate:g}_{index}",
                                            log_root / f"lockstep_{rate:g}_{index}", rate, part_s, part_samples,
                                            f"at {rate:g}/s")
                                  for index in range(1, rounds + 1)], rate))
    return rows


def smib_pair(env, chained_dir: Path, loop_dir: Path, rate_hz: float, sim_s: float, samples: int,
              label: str) -> dict:
    """One alternating pair of the SMIB loop: a chained ping-pong of ``samples``, then the plant node and its
    controller in lockstep for ``sim_s`` simulated s."""
    chained = pingpong(env, chained_dir, "chained", samples=samples)
    final = closed_loop(env, loop_dir, "lockstep", rate_hz, sim_s)
    return lockstep_pair(chained, {"gen1": final}, rate_hz, label)


def lockstep_pair(chained: dict, summary: dict, rate_hz: float, label: str) -> dict:
    """A pair's floor (the chained ping-pong's mean round trip) and run (``summary``: ``{namespace: the plant's
    final diagnostics}``), and its floor / throughput ratio."""
    # The whole run, from the plant's final status: simulated time over the wall time since its start.
    first = next(iter(summary.values()))
    sim_s, wall_s = float(first["sim_time_s"]), float(first["run_wall_s"])
    if not (sim_s > 0 and wall_s > 0):
        raise RuntimeError(f"lockstep {label}: the plant's final status shows no run ({first})")
    round_trip_s = float(np.mean(chained["round_trips_ns"])) * 1e-9
    return {"round_trip_s": round_trip_s, "sim_s": sim_s, "wall_s": wall_s, "summary": summary,
            "floor_ratio": ((1.0 / rate_hz) / round_trip_s) / (sim_s / wall_s)}


def lockstep_row(pairs: list[dict], rate_hz: float) -> dict:
    """A row from its alternating pairs: times summed over them, the floor's round trip and the floor / throughput
    ratio their median, latency and turnaround the median over pairs of each pair's median over generators."""
    sim_s, wall_s = sum(p["sim_s"] for p in pairs), sum(p["wall_s"] for p in pairs)
    round_trip_s = float(np.median([p["round_trip_s"] for p in pairs]))
    return {
        "rate_hz": rate_hz, "rounds": len(pairs), "sim_duration_s": sim_s, "run_wall_s": wall_s,
        "throughput": sim_s / wall_s, "floor_throughput": (1.0 / rate_hz) / round_trip_s,
        "floor_ratio": float(np.median([p["floor_ratio"] for p in pairs])),
        "round_ratios": [p["floor_ratio"] for p in pairs],
        "round_trip_mean_ms": round_trip_s * 1e3, "cycle_ms": wall_s / (sim_s * rate_hz) * 1e3,
        **{f"{name}_ms": {q: float(np.median([generator_percentiles(p["summary"], name)[q] for p in pairs]))
                          for q in ("p50", "p99")} for name in ("latency", "turnaround")},
        "deadline_misses": sum(int(v["deadline_misses"]) for p in pairs for v in p["summary"].values()),
    }


def generator_percentiles(summary: dict, name: str) -> dict:
    """Across generators: the median of their ``name`` p50 and p99, and the largest p99 (ms)."""
    p50 = [float(values[f"{name}_p50_ms"]) for values in summary.values()]
    p99 = [float(values[f"{name}_p99_ms"]) for values in summary.values()]
    return {"p50": float(np.median(p50)), "p99": float(np.median(p99)), "p99_max": max(p99)}


def throughput_cells(row: dict) -> str:
    """A lockstep row's table cells from its simulated and wall time to its misses (sections 2 and 4)."""
    return (f"{row['sim_duration_s']:g} / {row['run_wall_s']:.2f} | "
            f"{row['throughput']:.1f} | {row['floor_throughput']:.1f} | **{row['floor_ratio']:.2f}** "
            f"({fmt_rounds(row['round_ratios'])}) | {row['cycle_ms']:.3f} | {row['round_trip_mean_ms']:.3f} | "
            f"{row['latency_ms']['p50']:.3f} / {row['latency_ms']['p99']:.3f} | "
            f"{row['turnaround_ms']['p50']:.3f} / {row['turnaround_ms']['p99']:.3f} | "
            f"{row['deadline_misses']} |")


def lockstep_section(lockstep: list[dict]) -> list[str]:
    """Section 2: throughput beside the floor per rate, and issue 5's targets at 100/s."""
    lines = ["## 2. Lockstep throughput beside its floor", "",
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
        lines.append(f"| {row['rate_hz']:g} | {throughput_cells(row)}")
    row = row_at(lockstep, 100.0)
    if row:
        lines += ["", f"Targets at 100/s: throughput {row['throughput']:.1f} >= {LOCKSTEP_REALTIME_TARGET:g}x "
                      f"real time: {verdict(row['throughput'] >= LOCKSTEP_REALTIME_TARGET)}; within "
                      f"{LOCKSTEP_FLOOR_RATIO_TARGET}x of the floor ({row['floor_ratio']:.2f}): "
                      f"{verdict(row['floor_ratio'] <= LOCKSTEP_FLOOR_RATIO_TARGET)}."]
    return lines + [""]
