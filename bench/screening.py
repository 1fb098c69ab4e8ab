"""Section 11: the contingency screen (``nni-simulate --case CASE --screen``, issue 33), each engine beside the
serial path in the same run, contingencies per second per case, the full IEEE 39 N-1 screen, and one IEEE 39
contingency's bisection beside ANDES' bisection of the same fault; with its report section.

Every screen runs as the command a user types (a child process, ``--json`` read back): the serial path
(``--workers 0``), then the LocalCluster of 2 single-threaded workers. The speed-up is the serial path's wall
time over the cluster's, both from the first task to the last result (the cluster's start-up, 2-4 s, is
reported apart); the task overhead share is what the workers spent outside the tasks' computing (scheduling,
transfers, the idle tail of the last tasks) of the cluster's worker time: 1 - sum(task compute) / (workers x
wall).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.common import ROOT, progress, verdict

SIMULATE = str(Path(sys.executable).with_name("nni-simulate"))
#: Issue 33's targets: the LocalCluster's speed-up on 2 cores, the task overhead share, the full N-1 screen's time.
SPEEDUP_TARGET = 1.8
OVERHEAD_TARGET = 0.05
N1_SECONDS_TARGET = 600.0
#: The screens' battery limits (pu of each rating): issue 33's 4 b, and the N-1 screen's 5.
LIMITS = ("0", "0.1", "0.3", "inf")
N1_LIMITS = ("0", "0.05", "0.1", "0.2", "inf")
#: ANDES in its own venv (tests/network_reference/make_andes_reference.py says how to make it).
ANDES_PYTHON = Path("/tmp/andes-venv/bin/python")
#: The fault compared with ANDES: IEEE 39 bus 16 through 1e-4 pu, no trip, 5 s after it, searched up to 0.6 s
#: (the reference script's first IEEE 39 fault).
ANDES_FAULT = {"bus": 16, "fault_x": 1e-4, "duration_s": 5.0, "cct_max_s": 0.6}


def screen(case: str, workers: int, limits, contingencies, extra=()) -> dict:
    """One screen as the user types it; its JSON (rows, engine) and the command's wall time."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "screen.json"
        started = time.monotonic()
        result = subprocess.run([SIMULATE, "--case", case, "--screen", "--workers", str(workers), "--b", *limits,
                                 "--contingencies", *contingencies, "--json", str(out), *extra],
                                capture_output=True, text=True, timeout=7200)
        command_s = time.monotonic() - started
        if result.returncode != 0:
            raise RuntimeError(f"the {case} screen exited with {result.returncode}: {result.stderr[-300:]}")
        data = json.loads(out.read_text())
    contingencies_done = len({row["contingency"] for row in data["rows"]})
    return {"engine": data["engine"], "command_s": command_s, "contingencies": contingencies_done,
            "skipped": len(data["skipped"]), "rows": data["rows"]}


def _bus_subset(case: str, count: int) -> list[str]:
    from nni_battery_controller.screening import CaseSpec, enumerate_contingencies, network_of

    buses = enumerate_contingencies(network_of(CaseSpec(case)), ("bus",))
    step = max(1, len(buses) // count)
    return [c.name for c in buses[::step][:count]]


def andes_bisection(python: Path) -> dict:
    """ANDES' plain bisection of :data:`ANDES_FAULT` (tests/network_reference's), timed in its own venv."""
    code = ("import json, time, andes, make_andes_reference as ref\n"
            "andes.config_logger(stream_level=40)\n"
            "ref.AFTER_FAULT_S = {duration}\n"
            "started = time.perf_counter()\n"
            "cct, visited = ref.critical_clearing_time('ieee39', {bus}, {fault_x}, None, {cct_max})\n"
            "print(json.dumps({{'cct_s': cct, 'runs': len(visited), 's': time.perf_counter() - started}}))\n"
            ).format(duration=ANDES_FAULT["duration_s"], bus=ANDES_FAULT["bus"], fault_x=ANDES_FAULT["fault_x"],
                     cct_max=ANDES_FAULT["cct_max_s"])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "nni_plant_sim"),
                                                       str(ROOT / "tests" / "network_reference")]))
    result = subprocess.run([str(python), "-c", code], capture_output=True, text=True, env=env, timeout=3600)
    if result.returncode != 0:
        # Its last line (the exception), not a traceback in BENCHMARKS.md.
        last = (result.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"ANDES' bisection in {python} exited with {result.returncode}: {last}")
    return json.loads(result.stdout.strip().splitlines()[-1])


def bench_screening(quick: bool, andes_python: Path = ANDES_PYTHON) -> dict:
    """The screens of section 11 (``quick``: fewer contingencies, no N-1 screen, no ANDES run)."""
    ieee39 = ["bus"] if not quick else _bus_subset("ieee39", 10)
    progress(f"screen: ieee39 bus faults ({len(ieee39) if quick else 39} contingencies x {len(LIMITS)} b), serial")
    serial = screen("ieee39", 0, LIMITS, ieee39)
    progress("screen: the same on a 2-worker LocalCluster")
    cluster = screen("ieee39", 2, LIMITS, ieee39)
    out = {"quick": quick, "limits": LIMITS, "serial": serial, "cluster": cluster,
           "same_rows": serial["rows"] == cluster["rows"], "rates": []}
    for case in ("ieee118", "ieee300"):
        names = _bus_subset(case, 2 if quick else 8)
        progress(f"screen: {case}, {len(names)} bus faults x {len(LIMITS)} b on a 2-worker LocalCluster")
        out["rates"].append({"case": case, **screen(case, 2, LIMITS, names)})
    if not quick:
        progress(f"screen: ieee39 N-1 (bus and line-end faults x {len(N1_LIMITS)} b) on a 2-worker LocalCluster")
        out["n1"] = screen("ieee39", 2, N1_LIMITS, ["bus", "line"])
    extra = ["--fault-x", str(ANDES_FAULT["fault_x"]), "--duration", str(ANDES_FAULT["duration_s"]), "--cct-max",
             str(ANDES_FAULT["cct_max_s"])]
    progress(f"screen: ieee39 bus {ANDES_FAULT['bus']} alone (b = 0), serial, beside ANDES")
    mine = screen("ieee39", 0, ("0",), [f"bus:{ANDES_FAULT['bus']}"], extra)
    out["andes_fault"] = {**ANDES_FAULT, "ours_s": mine["engine"]["compute_s"], "ours_cct_s": mine["rows"][0]["cct_s"]}
    if quick or not andes_python.is_file():
        out["andes_fault"]["andes"] = None if quick else f"no ANDES at {andes_python}"
    else:
        progress("screen: ANDES' bisection of the same fault (its own venv)")
        try:
            out["andes_fault"]["andes"] = andes_bisection(andes_python)
        except (RuntimeError, subprocess.TimeoutExpired) as error:
            out["andes_fault"]["andes"] = f"ANDES did not complete: {error}"
    for run in (serial, cluster, *out["rates"], *([out["n1"]] if "n1" in out else []), mine):
        run.pop("rows")
    return out


def _per_s(run) -> float:
    return run["contingencies"] / run["engine"]["wall_s"]


def _overhead(run) -> float:
    engine = run["engine"]
    return max(0.0, 1.0 - engine["compute_s"] / (engine["workers"] * engine["wall_s"]))


def screening_section(r: dict) -> list[str]:
    """Section 11: serial beside the LocalCluster, contingencies per second, the N-1 screen, ANDES."""
    serial, cluster = r["serial"], r["cluster"]
    speedup = serial["engine"]["wall_s"] / cluster["engine"]["wall_s"]
    overhead = _overhead(cluster)
    b_text = " ".join(r["limits"])
    lines = ["## 11. Contingency screen: serial beside a 2-worker LocalCluster (issue 33)", "",
             "`nni-simulate --case CASE --screen --contingencies ... --b " + b_text + "` (law nni, reference pmu, "
             "10 s runs, controller 50 Hz, CCT by bisection to 1 ms up to 1 s), run as the user types it, first "
             "with `--workers 0` (every task in the command's process), then on a LocalCluster of 2 "
             "single-threaded workers. A task is one contingency with all its b in one vectorised bisection. "
             "Wall time from the first task to the last result; the cluster's start-up apart (command minus that). "
             "Task overhead: 1 - (seconds the tasks computed) / (workers x wall): scheduling, transfers and the "
             "idle tail of the last tasks.", "",
             "| screen | engine | contingencies | wall (s) | command (s) | contingencies / s | tasks' compute (s) | "
             "task overhead |", "|---|---|---:|---:|---:|---:|---:|---:|"]
    for name, run in (("ieee39 bus faults", serial), ("ieee39 bus faults", cluster),
                      *((f"{rate['case']} bus faults (a subset)", rate) for rate in r["rates"]),
                      *((("ieee39 N-1 (bus + line-end), b 0 0.05 0.1 0.2 inf", r["n1"]),) if "n1" in r else ())):
        engine = run["engine"]
        share = "-" if not engine["workers"] else f"{100 * _overhead(run):.1f} %"
        lines.append(f"| {name} | {engine['engine']}{'' if not engine['workers'] else ', ' + str(engine['workers'])} "
                     f"| {run['contingencies']} | {engine['wall_s']:.1f} | {run['command_s']:.1f} | "
                     f"{_per_s(run):.3f} | {engine['compute_s']:.1f} | {share} |")
    lines += ["", f"Same rows (every CCT, verdict and weakest generator) serial and on the cluster: "
                  f"{'yes' if r['same_rows'] else '**no**'}.", ""]
    andes = r["andes_fault"]
    fault = f"IEEE 39, bus {andes['bus']} through x = {andes['fault_x']:g} pu, no trip, {andes['duration_s']:g} s " \
            f"runs, searched up to {andes['cct_max_s']:g} s, b = 0"
    if isinstance(andes["andes"], dict):
        theirs = andes["andes"]
        lines += [f"One contingency's bisection beside ANDES ({fault}): ours {andes['ours_s']:.2f} s (CCT "
                  f"{andes['ours_cct_s']}; 31 candidates a round, every round one vectorised run), ANDES 2.0 "
                  f"{theirs['s']:.1f} s ({theirs['runs']} runs of a plain bisection, trapezoid at 1 ms, "
                  f"tests/network_reference's script; CCT {theirs['cct_s']}): ANDES / ours = "
                  f"**{theirs['s'] / andes['ours_s']:.0f}x**.", ""]
    else:
        lines += [f"One contingency's bisection ({fault}): ours {andes['ours_s']:.2f} s; ANDES not run "
                  f"({andes['andes'] or 'a --quick run'}).", ""]
    lines += [f"Targets (issue 33): the LocalCluster {speedup:.2f}x the serial path >= {SPEEDUP_TARGET:g}x: "
              f"{verdict(speedup >= SPEEDUP_TARGET)}; task overhead {100 * overhead:.1f} % < "
              f"{100 * OVERHEAD_TARGET:g} %: {verdict(overhead < OVERHEAD_TARGET)}"]
    if "n1" in r:
        n1 = r["n1"]["command_s"]
        lines[-1] += f"; the IEEE 39 N-1 screen in {n1:.0f} s < {N1_SECONDS_TARGET:g} s: " \
                     f"{verdict(n1 < N1_SECONDS_TARGET)}"
    lines[-1] += "."
    return lines + [""]


#: Issue 33's full screens of the large cases: every bus fault at b = 0 and one b.
LARGE_CASES = ("ieee118", "ieee300")
LARGE_LIMITS = ("0", "0.3")
#: The weakest contingencies per b that section 14 lists.
LARGE_WEAKEST = 3


def bench_large_screens(quick: bool) -> dict:
    """Section 14: every bus fault of IEEE 118 and 300 at :data:`LARGE_LIMITS` on a 2-worker LocalCluster
    (``quick``: 4 of each case's buses)."""
    out = {"quick": quick, "limits": LARGE_LIMITS, "screens": []}
    for case in LARGE_CASES:
        names = _bus_subset(case, 4) if quick else ["bus"]
        progress(f"screen: {case}, {'4' if quick else 'every'} bus fault x {len(LARGE_LIMITS)} b on a 2-worker "
                 "LocalCluster")
        run = screen(case, 2, LARGE_LIMITS, names)
        weakest = {}
        for b in LARGE_LIMITS:
            rows = sorted((row for row in run["rows"] if row["b"] == float(b) and row["cct_s"] is not None),
                          key=lambda row: row["cct_s"])
            weakest[b] = [(row["contingency"], row["cct_s"], bool(row["at_search_limit"]), row["weakest_generator"])
                          for row in rows[:LARGE_WEAKEST]]
        run["weakest"] = weakest
        run["rows"] = len(run["rows"])
        out["screens"].append({"case": case, **run})
    return out


def large_screens_section(r: dict) -> list[str]:
    """Section 14: the large cases' full bus-fault screens, their time and their weakest contingencies."""
    b_text = " ".join(r["limits"])
    lines = ["## 14. Every bus fault of IEEE 118 and 300, b " + b_text + ", on a 2-worker LocalCluster (issue 33)", "",
             f"`nni-simulate --case CASE --screen --contingencies bus --b {b_text} --workers 2 --json ...` as the "
             "user types it (law nni, reference pmu, 10 s runs, controller 50 Hz, CCT by bisection to 1 ms up to "
             "1 s). The cases' dynamic data are typical, not the utility's (docs/screening.md says the rule). "
             "Wall time from the first task to the last result; command: the whole command, the cluster's "
             "start-up included.", "",
             "| case | contingencies | skipped | rows | wall (s) | command (s) | contingencies / s | task overhead |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for run in r["screens"]:
        engine = run["engine"]
        lines.append(f"| {run['case']} | {run['contingencies']} | {run['skipped']} | {run['rows']} | "
                     f"{engine['wall_s']:.0f} | {run['command_s']:.0f} | {_per_s(run):.3f} | "
                     f"{100 * _overhead(run):.1f} % |")
    lines += ["", f"The {LARGE_WEAKEST} weakest bus faults per b (CCT in s, `>=` where the search limit held; the "
                  "generator that swings furthest):", "",
              "| case | b | weakest |", "|---|---:|---|"]
    for run in r["screens"]:
        for b, rows in run["weakest"].items():
            cells = "; ".join(f"{name} {'>= ' if limit else ''}{cct:.3f} ({generator})"
                              for name, cct, limit, generator in rows) or "none found"
            lines.append(f"| {run['case']} | {b} | {cells} |")
    return lines + [""]
