"""Section 7 (issue 23): where a network lockstep sample's CPU time goes, per part of the plant's step and of the
composed controllers' process, sampled with py-spy from outside (nothing in the nodes is instrumented), and how
much of it the transport alone costs: the same run without the sampler beside a chained fan-out to as many echoes
deployed alike, each process's CPU time (all threads) per sample.

py-spy samples the process's Python threads at a fixed rate, idle or not (a thread with no Python frame, one of
rclpy's or Fast DDS's own, is left out: the executor's is the one that runs the callbacks); a sample's part is the first rule of the
process's table that one of its frames matches, and a sample whose innermost Python frame is the spin loop itself
is the executor's: blocked waiting for work, or in its C++ dispatch (py-spy sees Python frames only). A part's wall
time per loop sample is its samples over the sampling rate and the loop's samples. The process's CPU time (user +
system, /proc) beside it also holds the threads py-spy does not see (Fast DDS's receive and event threads).
"""

from __future__ import annotations

import importlib.util
import signal
import subprocess
import sys
from collections import Counter
from functools import lru_cache
from pathlib import Path

from bench.common import NETWORK_RATE_HZ, cycle_ms, network_loop, not_completed, pingpong, progress
from bench.lockstep import generator_percentiles
from nni_msgs_adapter.ros.processes import ChildError

#: py-spy's sampling rate (samples/s per thread).
SAMPLING_HZ = 1000
#: (case, deployment, simulated s) profiled in a full run and in --quick.
PROFILE_RUN, PROFILE_QUICK_RUN = ("ieee39", "composed", 60.0), ("kundur_two_area", "composed", 4.0)


def _source_has(text: str):
    """A rule: a frame whose executing source line contains ``text``."""
    return lambda function, path, line: text in _source_line(path, line)


def _function(name: str, file_end: str = ""):
    """A rule: a frame of function or method ``name`` (in a file whose path ends with ``file_end``)."""
    return lambda function, path, line: (function == name or function.endswith("." + name)) and path.endswith(file_end)


def _any(*rules):
    """A rule: a frame that any of ``rules`` matches."""
    return lambda function, path, line: any(rule(function, path, line) for rule in rules)


def _file(file_end: str):
    """A rule: a frame in a file whose path ends with ``file_end``."""
    return lambda function, path, line: path.endswith(file_end)


#: Per process: (part, rule) in order; a sample goes to the first part one of its frames matches, else "other".
PLANT_PARTS = (
    ("RK4 over the machines and the network solve", _function("_integrate", "network_plant_node.py")),
    ("measurement frames (EMF, terminal V and I)", _function("_frames", "network_plant_node.py")),
    ("publish: /clock", _source_has("self._clock_pub.publish(")),  # before the measurements' rule, which it matches
    ("publish: N measurements", _source_has("pub.publish(sample.stamp_ns")),
    ("publish: N true states", _source_has("pub.publish(report.stamp_ns")),
    ("/diagnostics", _function("publish_diagnostics")),
    ("writer checks (graph queries)", _function("_check_writers", "plant_node_base.py")),
    ("command admission (parse, loop core)", _function("_on_command", "plant_node_base.py")),
    ("timer (the lockstep watchdog)", _function("_on_timer", "plant_node_base.py")),
)
CONTROLLER_PARTS = (
    ("/diagnostics and /clock readers", _any(_function("newest_clock_ns", "controller_node.py"),
                                             _function("_on_diagnostics", "controller_node.py"))),
    ("the law (ControllerCore)", _file("controller_core.py")),
    ("publish: commands and controller states", _function("publish", "loop_node.py")),
    ("measurement in (parse, gate)", _function("_on_pmu", "controller_node.py")),
)
#: The spin loop's own frames (:func:`nni_msgs_adapter.ros.node_main.run_node` and the future it spins on).
EXECUTOR = "executor (waiting, or its C++ dispatch)"
_SPIN_FILES = ("ros/node_main.py", "rclpy/task.py", "rclpy/executors.py")


@lru_cache(maxsize=None)
def _lines(path: str) -> tuple[str, ...]:
    """The source lines of a frame's file: py-spy names the project's files relative to their package's parent."""
    file = Path(path)
    if not file.is_absolute():
        try:
            spec = importlib.util.find_spec(file.parts[0]) if len(file.parts) > 1 else None
        except (ImportError, ValueError):
            spec = None
        if spec is None or not spec.submodule_search_locations:
            return ()
        file = Path(list(spec.submodule_search_locations)[0]).parent / file
    try:
        return tuple(file.read_text().splitlines())
    except OSError:
        return ()


def _source_line(path: str, line: int) -> str:
    lines = _lines(path)
    return lines[line - 1] if 0 < line <= len(lines) else ""


def parse_frame(frame: str) -> tuple[str, str, int]:
    """``function (path:line)`` of py-spy's raw output -> (function, path, line); line 0 where there is none."""
    function, _, where = frame.partition(" (")
    path, _, line = where.rstrip(")").rpartition(":")
    return function, path, int(line) if line.isdigit() else 0


def classify(collapsed: str, parts) -> Counter:
    """Samples per part of py-spy's collapsed stacks (``frame;frame;... count`` lines); unmatched: "other"."""
    counts = Counter()
    for entry in collapsed.splitlines():
        stack, _, count = entry.rpartition(" ")
        if not stack.strip() or not count.isdigit():
            continue  # a thread with no Python frame: rclpy's and Fast DDS's own, idle here
        frames = [parse_frame(frame) for frame in stack.split(";")]
        part = next((name for name, rule in parts if any(rule(*frame) for frame in frames)), None)
        if part is None:
            part = EXECUTOR if frames[-1][1].endswith(_SPIN_FILES) else "other"
        counts[part] += int(count)
    return counts


def _py_spy(pid: int, out: Path) -> subprocess.Popen:
    return subprocess.Popen([str(Path(sys.executable).with_name("py-spy")), "record", "--pid", str(pid),
                             "--rate", str(SAMPLING_HZ), "--format", "raw", "--idle", "--nonblocking", "--output", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def bench_network_profile(env, log_root: Path, run=PROFILE_RUN, rate_hz: float = NETWORK_RATE_HZ) -> dict:
    """One lockstep run of ``run`` = (case, deployment, simulated s), its plant and controller processes sampled."""
    case, deployment, sim_s = run
    progress(f"network profile: {case} ({deployment}) lockstep, {sim_s:g} simulated s, py-spy at {SAMPLING_HZ}/s")
    log_dir = log_root / f"profile_{case}_{deployment}"
    log_dir.mkdir(parents=True, exist_ok=True)
    samplers = {}

    def attach(plant_pid: int, controller_pids: list[int]) -> None:
        samplers["plant"] = _py_spy(plant_pid, log_dir / "plant.txt")
        samplers["controllers"] = _py_spy(controller_pids[0], log_dir / "controllers.txt")

    def detach() -> None:
        for sampler in samplers.values():
            sampler.send_signal(signal.SIGINT)
            sampler.wait(timeout=60)

    samples = round(sim_s * rate_hz)
    try:
        plain = network_loop(env, log_dir / "plain", case, "lockstep", rate_hz, sim_s, deployment)
        fanout = pingpong(env, log_dir / "fanout", "chained", samples=samples, fanout=plain["size"],
                          composed=deployment == "composed")
        loop = network_loop(env, log_dir, case, "lockstep", rate_hz, sim_s, deployment, attach=attach, detach=detach)
    except (ChildError, RuntimeError, subprocess.TimeoutExpired) as error:
        return not_completed(f"network profile {case} ({deployment})", error)
    finally:
        for sampler in samplers.values():
            if sampler.poll() is None:
                sampler.kill()
    processes = []
    for name, parts, cpu_s in (("plant", PLANT_PARTS, loop["plant_cpu_s"]),
                               ("controllers", CONTROLLER_PARTS, loop["controller_cpu_s"][0])):
        out = log_dir / f"{name}.txt"
        if not out.exists():
            error = samplers[name].stderr.read().decode(errors="replace").strip()
            return {"error": f"py-spy wrote no profile of the {name} process: {error[-300:]}"}
        counts = classify(out.read_text(), parts)
        processes.append({"process": name, "cpu_s": cpu_s, "samples_seen": sum(counts.values()),
                          "parts": [(part, counts.get(part, 0)) for part in (*(name for name, _ in parts), EXECUTOR, "other")]})
    round_trips = len(fanout["round_trips_ns"])
    transport = {"plant_us": plain["plant_cpu_s"] * 1e6 / samples, "ping_us": fanout["cpu_s"] * 1e6 / round_trips,
                 "controllers_us": sum(plain["controller_cpu_s"]) * 1e6 / samples,
                 "echoes_us": fanout["echo_cpu_s"] * 1e6 / round_trips,
                 "cycle_ms": cycle_ms(plain["summary"]),
                 "round_trip_ms": fanout["wall_s"] * 1e3 / round_trips}
    return {"case": case, "deployment": deployment, "sim_s": sim_s, "rate_hz": rate_hz, "loop_samples": samples,
            "wall_s": loop["wall_s"], "size": loop["size"], "processes": processes, "transport": transport,
            "turnaround_ms": generator_percentiles(loop["summary"], "turnaround")["p50"]}


def network_profile_section(result: dict) -> list[str]:
    """Section 7: per process, each part's share of the sampled CPU and its CPU per loop sample."""
    title = "## 7. Where a network lockstep sample's time goes (issue 23)"
    if "error" in result:
        return [title, "", f"**Not completed**: {result['error']}", ""]
    lines = [title, "", f"`{result['case']}` (N = {result['size']}) in lockstep at {result['rate_hz']:g} frames/s, "
             f"the controllers {result['deployment']}, {result['sim_s']:g} simulated s ({result['loop_samples']} "
             f"samples) in {result['wall_s']:.2f} s of wall time; the plant's turnaround p50 "
             f"{result['turnaround_ms']:.3f} ms. " + " ".join(__doc__.split("\n\n")[1].split()), ""]
    for process in result["processes"]:
        seen_s = process["samples_seen"] / SAMPLING_HZ
        lines += [f"**{process['process']}** (sampled {seen_s:.2f} s of its executor thread): "
                  f"{process['cpu_s']:.2f} s of CPU in all threads, "
                  f"{process['cpu_s'] * 1e6 / result['loop_samples']:.0f} us per loop sample.", "",
                  "| part | share of the thread's wall time | wall time per loop sample (us) |", "|---|---:|---:|"]
        for part, count in process["parts"]:
            share = count / process["samples_seen"] if process["samples_seen"] else 0.0
            lines.append(f"| {part} | {100 * share:.1f} % | {count / SAMPLING_HZ * 1e6 / result['loop_samples']:.1f} |")
        lines.append("")
    measurements = dict(result["processes"][0]["parts"]).get("publish: N measurements", 0)
    per_message_us = measurements / SAMPLING_HZ * 1e6 / result["loop_samples"] / result["size"]
    lines += [f"The plant's measurement publishes: {per_message_us:.1f} us per message (rclpy's publish of "
              "the message's exact bytes, through rcl and Fast DDS to its one subscriber), paid N times a "
              "sample on the plant's one executor thread.", ""]
    return lines + transport_lines(result) if "transport" in result else lines


def transport_lines(result: dict) -> list[str]:
    """What the transport alone costs each side per sample (the fan-out's ping and echoes), beside the loop."""
    cost, n = result["transport"], result["size"]
    rows = (("plant", "ping", cost["plant_us"], cost["ping_us"]),
            (f"controllers ({result['deployment']})", "echoes", cost["controllers_us"], cost["echoes_us"]))
    lines = ["CPU time per sample, all threads (/proc), of the same loop run without the sampler "
             f"(cycle {cost['cycle_ms']:.3f} ms) and of a chained fan-out to {n} echoes deployed alike, run after it "
             f"(round trip {cost['round_trip_ms']:.3f} ms): the fan-out's processes publish and take the same number "
             "of messages a sample and do nothing else, so their CPU is rclpy's and Fast DDS's per-message cost; "
             "the difference is the loop's own work.", "",
             "| loop process | its CPU per sample (us) | fan-out process | its CPU per round trip (us) "
             "| the loop's own work (us) | per generator (us) |", "|---|---:|---|---:|---:|---:|"]
    for loop_name, floor_name, loop_us, floor_us in rows:
        lines.append(f"| {loop_name} | {loop_us:.0f} | {floor_name} | {floor_us:.0f} | {loop_us - floor_us:.0f} "
                     f"| {(loop_us - floor_us) / n:.1f} |")
    per_message = (cost["ping_us"] + cost["echoes_us"]) / (2 * n)
    return lines + ["", f"The transport's cost per message and side (a publish at one end, a take and its "
                        f"callback at the other): {per_message:.1f} us of CPU, 2N messages a sample.", ""]
