"""Section 12: what the Foxglove bridge and a client that never reads cost the SMIB loop (issue 34); with its
report section.

Alternating rounds of the paper's case in lockstep, three runs each: the plant and its controller alone; the
same with the Foxglove bridge streaming the loop to a client that reads everything; and to a client
subscribed to every channel that never reads (:mod:`bench.stalled_client`). Lockstep is the measure most
sensitive to a slower bridge or writer: each sample waits for the previous command, so any time taken from
the loop shows in its throughput. The never-reading client's own cost is the third run against the second;
streaming's (the bridge's process beside the plant and the controller on a 2-core machine) the second
against the first.
"""

from __future__ import annotations

import socket

import numpy as np

from bench.common import closed_loop, fmt_rounds, progress

RATE_HZ = 100.0
#: The runs of a round: name -> the bridge's client (None: no bridge).
ARMS = {"alone": None, "reading": "reading", "stalled": "stalled"}


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def bench_foxglove(env, log_root, sim_s: float, rounds: int, realtime_s: float) -> dict:
    """``rounds`` alternating rounds of the three :data:`ARMS`; throughput and latency per run, ratios per round.
    Then as many rounds in realtime (``realtime_s`` each), where what counts is the loop's latency and its misses."""
    progress(f"foxglove: {rounds} x (lockstep alone, streamed to a reading client, to a never-reading client), "
             f"{sim_s:g} simulated s at {RATE_HZ:g}/s; then {rounds} x the same in realtime, {realtime_s:g} s each")
    runs = {arm: [] for arm in ARMS}
    realtime = {arm: [] for arm in ARMS}
    for index in range(1, rounds + 1):
        for arm, client in ARMS.items():
            summary = closed_loop(env, log_root / f"foxglove_{arm}_{index}", "lockstep", RATE_HZ, sim_s,
                                  foxglove_port=_free_port() if client else None, foxglove_client=client or "")
            runs[arm].append({"throughput": float(summary["sim_time_s"]) / float(summary["run_wall_s"]),
                              "latency_p50_ms": float(summary["latency_p50_ms"]),
                              "misses": int(summary["deadline_misses"])})
    for index in range(1, rounds + 1):
        for arm, client in ARMS.items():
            summary = closed_loop(env, log_root / f"foxglove_realtime_{arm}_{index}", "realtime", RATE_HZ,
                                  realtime_s, foxglove_port=_free_port() if client else None,
                                  foxglove_client=client or "")
            realtime[arm].append({key: float(summary[f"latency_{key}_ms"]) for key in ("p50", "p99", "max")}
                                 | {"misses": int(summary["deadline_misses"]), "late": int(summary.get("late", 0)),
                                    "skipped": int(summary.get("skipped_reports", 0)),
                                    "samples": int(summary["samples"])})
    throughput = {arm: [run["throughput"] for run in values] for arm, values in runs.items()}
    ratios = {"reading": [a / b for a, b in zip(throughput["alone"], throughput["reading"])],
              "stalled": [a / b for a, b in zip(throughput["reading"], throughput["stalled"])]}
    return {"rounds": rounds, "sim_s": sim_s, "rate_hz": RATE_HZ, "runs": runs, "ratios": ratios,
            "ratio": {key: float(np.median(values)) for key, values in ratios.items()},
            "spread": max(throughput["alone"]) / min(throughput["alone"]),
            "throughput": {arm: float(np.median(values)) for arm, values in throughput.items()},
            "latency_p50_ms": {arm: float(np.median([r["latency_p50_ms"] for r in values]))
                               for arm, values in runs.items()},
            "misses": sum(run["misses"] for values in runs.values() for run in values),
            "realtime_s": realtime_s,
            "realtime": {arm: {key: (float(np.median([r[key] for r in values])) if key in ("p50", "p99", "max")
                                     else sum(r[key] for r in values))
                               for key in ("p50", "p99", "max", "misses", "late", "skipped", "samples")}
                         for arm, values in realtime.items()},
            "realtime_runs": realtime}


def foxglove_section(result: dict) -> list[str]:
    ratio, spread = result["ratio"], result["spread"]
    rows = [("streaming to a client that reads, beside the loop alone", "reading", "alone", "reading"),
            ("a client that never reads, beside one that reads", "stalled", "reading", "stalled")]
    lines = ["## 12. The Foxglove bridge and a client that never reads, beside the loop alone (issue 34)", "",
             f"The paper's case (b = 0.3) in lockstep at {result['rate_hz']:g}/s, {result['sim_s']:g} simulated s per "
             f"run, {result['rounds']} alternating rounds of three runs: the plant and its controller alone; with "
             "the Foxglove bridge (`foxglove_bridge`: KEEP_LAST subscriptions, every seal checked, nice 10, the "
             "server's backlog 1024 messages per client) streaming to a client that reads everything; to a "
             "client subscribed to every channel that never reads (`bench/stalled_client.py`: its receive queue holds one frame, "
             "so its socket fills). Ratios are throughput before / after, per round, their median in bold; the "
             "alone runs' own spread (fastest / slowest) is the noise they are read against.", "",
             "| what is added | throughput before / after (x real time) | ratio, median (rounds) | loop latency "
             "p50 before / after (ms) |", "|---|---|---|---|"]
    for text, key, before, after in rows:
        lines.append(f"| {text} | {result['throughput'][before]:.1f} / {result['throughput'][after]:.1f} | "
                     f"**{ratio[key]:.2f}** ({fmt_rounds(result['ratios'][key])}) | "
                     f"{result['latency_p50_ms'][before]:.3f} / {result['latency_p50_ms'][after]:.3f} |")
    lines += ["", f"The alone runs' spread: {spread:.2f}; deadline misses in all runs: {result['misses']}. "
              f"The never-reading client: {ratio['stalled']:.2f} "
              + ("(within the noise: it costs the loop nothing measurable)." if ratio["stalled"] <= spread else
                 "(**beyond the noise**)."),
              f"Streaming itself: {ratio['reading']:.2f} "
              + ("(within the noise)." if ratio["reading"] <= spread else
                 "(**beyond the noise**: a third busy process on two cores, checking every seal and forwarding "
                 "every message, takes CPU from the lockstep loop; in realtime the loop waits for the clock)."), ""]
    if "realtime" in result:
        lines += realtime_lines(result)
    return lines


def realtime_lines(result: dict) -> list[str]:
    """The realtime rounds: each arm's measurement -> command latency (median over the rounds of each run's
    quantile) and the samples it missed, late or skipped (summed over the rounds)."""
    rows = [("the loop alone", "alone"), ("streaming to a client that reads", "reading"),
            ("streaming, beside a client that never reads", "stalled")]
    lines = [f"The same three in realtime ({result['rounds']} alternating rounds of {result['realtime_s']:g} s at "
             f"{result['rate_hz']:g}/s), where the loop waits for the clock and what streaming could cost is "
             "latency and missed samples:", "",
             "| run | latency p50 / p99 / max (ms, median of the rounds) | samples | deadline misses | late | "
             "skipped reports |", "|---|---|---:|---:|---:|---:|"]
    for text, arm in rows:
        r = result["realtime"][arm]
        lines.append(f"| {text} | {r['p50']:.3f} / {r['p99']:.3f} / {r['max']:.3f} | {r['samples']} | "
                     f"{r['misses']} | {r['late']} | {r['skipped']} |")
    alone, reading = result["realtime"]["alone"], result["realtime"]["reading"]
    lines += ["", f"Streaming adds {reading['p50'] - alone['p50']:+.3f} ms to the median latency and "
              f"{reading['p99'] - alone['p99']:+.3f} ms to its 99th percentile, against a {1e3 / result['rate_hz']:g} ms "
              "period.", ""]
    return lines
