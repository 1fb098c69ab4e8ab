"""``nni-demo``: the distributed closed loop, one run per battery limit, recorded and summarised.

For each b it starts three processes (MCAP logger, controller, plant) on a ROS
domain of its own with localhost-only discovery, lets the plant run its
scenario to the end, stops the others with SIGINT (SIGKILL after a grace
period), and reads the recording back to write ``OUT/summary.json``: the keys of
``nni-simulate --json`` per run plus loop latency (p50, p99, max in ms, from
measurement to command arrival at the plant) and dropped / late sample counts
from the plant's final diagnostics. The orchestrator creates no ROS node of its own.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from nni_battery_controller.cli import PAPER_BATTERY_LIMITS, plot_runs
from nni_battery_controller.law import ControllerParams
from nni_battery_controller.options import add_model_options, resolve_model
from nni_battery_controller.simulate import Trajectory, assess, verdict_text
from nni_msgs_adapter.cli_support import (
    CliError,
    OneLineParser,
    atomic_output,
    battery_limit,
    float_within,
    positive_float,
    run_cli,
    writable_output,
)
from nni_msgs_adapter.mcap_logger import COUNTS_PREFIX
from nni_msgs_adapter.recording import read_generator_run
from nni_msgs_adapter.rerun_bridge import READY_TEXT
from nni_msgs_adapter.rerun_view import display_missing
from nni_plant_sim.model import SmibParams

#: Seconds the logger gets after the plant ends, for the last reliable messages to land.
DRAIN_S = 0.5
#: Seconds a process gets to exit after SIGINT before SIGKILL.
STOP_GRACE_S = 10.0


def build_parser() -> OneLineParser:
    """The nni-demo command line."""
    parser = OneLineParser(prog="nni-demo", description=__doc__)
    parser.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep",
                        help="lockstep: simulated /clock, deterministic, fast (default); realtime: wall clock")
    parser.add_argument("--b", type=battery_limit, nargs="+", default=list(PAPER_BATTERY_LIMITS), metavar="B",
                        help="battery limits in pu, one run each (default: 0 0.2 0.3 inf)")
    parser.add_argument("--duration", type=positive_float, default=10.0, help="simulated seconds per run (default: 10)")
    parser.add_argument("--rate", type=float_within(10.0, 1000.0, "frames/s"), default=50.0, help="PMU reporting rate, frames/s (default 50)")
    parser.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder, created (default: out/demo)")
    parser.add_argument("--rerun", nargs="+", metavar=("SINK", "PATH"), default=None,
                        help="stream the runs live to Rerun: 'save PATH' (.rrd), 'serve' (web viewer on this "
                             "machine, kept up until Ctrl-C) or 'spawn' (native viewer, needs a display); default: none")
    parser.add_argument("--domain-id", type=int, default=None,
                        help="ROS_DOMAIN_ID for the run (default: $ROS_DOMAIN_ID, else 42)")
    add_model_options(parser)
    return parser


def recording_name(b: float) -> str:
    """File name of one run's recording: paper_b0.3.mcap, paper_binf.mcap."""
    return f"paper_b{'inf' if math.isinf(b) else f'{b:g}'}.mcap"


def node_command(module: str, params: dict | None = None, ros_args: tuple = ()) -> list[str]:
    """``python -m module --ros-args [ros_args] -p k:=v ...``, values as ROS command-line YAML."""
    args = list(ros_args)
    for key, value in (params or {}).items():
        args += ["-p", f"{key}:={parameter_text(value)}"]
    return [sys.executable, "-m", module, *(["--ros-args", *args] if args else [])]


def parameter_text(value) -> str:
    """A parameter value as ROS command-line YAML (.inf for inf, true/false for bools)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and math.isinf(value):
        return ".inf" if value > 0 else "-.inf"
    return str(value)


class Processes:
    """The run's child processes; all stopped (SIGINT, then SIGKILL) when the block ends."""

    def __init__(self, env: dict, log_dir: Path):
        self.env, self.log_dir, self.children = env, log_dir, {}

    def start(self, name: str, module: str, params: dict) -> subprocess.Popen:
        log = open(self.log_dir / f"{name}.log", "wb")
        proc = subprocess.Popen(node_command(module, params), env=self.env, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)
        self.children[name] = (proc, log)
        return proc

    def stop(self, name: str) -> int:
        proc, log = self.children[name]
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=STOP_GRACE_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        log.close()
        return proc.returncode

    def wait_for_output(self, name: str, text: str, timeout_s: float) -> None:
        """Wait until process ``name`` printed ``text``; CliError if it exits or times out first."""
        deadline = time.monotonic() + timeout_s
        while text not in self.output(name):
            proc = self.children[name][0]
            if proc.poll() is not None or time.monotonic() > deadline:
                raise CliError(f"{name} did not start: {self.output(name).strip()[-300:]}")
            time.sleep(0.05)

    def output(self, name: str) -> str:
        return (self.log_dir / f"{name}.log").read_text(errors="replace")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        for name in list(self.children):
            self.stop(name)


def trajectory_from_recording(path: Path, plant: SmibParams, ctrl: ControllerParams) -> tuple[Trajectory, dict]:
    """The sampled trajectory and the plant's last diagnostics from a run's MCAP (read as replay reads it)."""
    run = read_generator_run(path)
    traj = Trajectory(plant, ctrl, run.t_s, run.delta_rad, run.speed_rad_s, run.signals["x3"], run.battery_power_pu,
                      run.signals["w"], run.saturated, np.empty(0))
    return traj, run.diagnostics


def rerun_sink(words) -> dict:
    """Bridge parameters for ``--rerun`` words: save PATH | serve | spawn."""
    sink = words[0]
    if sink not in ("save", "serve", "spawn") or (sink == "save") != (len(words) == 2) or len(words) > 2:
        raise CliError("--rerun takes 'save PATH', 'serve' or 'spawn'")
    if sink == "save":
        try:
            path = writable_output(words[1])
        except argparse.ArgumentTypeError as exc:
            raise CliError(f"--rerun save: {exc}") from None
        return {"sink": "save", "path": str(path)}
    if sink == "spawn" and display_missing():
        raise CliError("--rerun spawn needs a display (DISPLAY and WAYLAND_DISPLAY are unset): "
                       "use --rerun save PATH or --rerun serve")
    return {"sink": sink}


def run_one(args, b: float, env: dict, out: Path) -> tuple[dict, Trajectory]:
    """One run: start logger, controller, plant; wait for the plant; summarise its recording."""
    recording = out / recording_name(b)
    logs = out / "logs" / recording.stem
    logs.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    with Processes(env, logs) as procs:
        procs.start("mcap_logger", "nni_msgs_adapter.mcap_logger",
                    {"output_path": str(recording), "discovery_period_s": 0.1})
        procs.start("controller", "nni_battery_controller.controller_node",
                    {**args.model.controller_node_parameters(), "battery_limit_pu": b, "sample_rate_hz": args.rate})
        plant = procs.start("plant", "nni_plant_sim.plant_node",
                            {**args.model.plant_node_parameters(), "mode": args.mode, "duration_s": args.duration,
                             "pmu_rate_hz": args.rate, "wait_for_subscribers": 2})
        limit = 60.0 + (args.duration if args.mode == "realtime" else args.duration * 2)
        try:
            status = plant.wait(timeout=limit)
        except subprocess.TimeoutExpired:
            raise CliError(f"the plant did not finish within {limit:.0f} s (logs in {logs})") from None
        if status != 0:
            raise CliError(f"the plant exited with status {status}: {procs.output('plant').strip()[-300:]}")
        time.sleep(DRAIN_S)
        procs.stop("controller")
        if procs.stop("mcap_logger") != 0:
            raise CliError(f"the logger failed: {procs.output('mcap_logger').strip()[-300:]}")
    wall_s = time.monotonic() - started
    counts = logger_counts(procs.output("mcap_logger"))
    # Assessed with the very model and scenario the nodes ran with.
    traj, diag = trajectory_from_recording(recording, args.model.smib(), args.model.controller_params(b))
    outcome = assess(traj, scenario=args.model.scenario()).to_json()
    outcome.update({
        "mode": args.mode, "rate_hz": args.rate, "recording": str(recording), "wall_time_s": wall_s,
        "samples": int(diag.get("samples", 0)),
        "latency_ms": {q: float(diag[f"latency_{q}_ms"]) for q in ("p50", "p99", "max") if f"latency_{q}_ms" in diag},
        "dropped_samples": int(diag.get("deadline_misses", 0)),
        "late_samples": int(diag.get("late", 0)),
        "logger_counts": counts,
    })
    return outcome, traj


def run_all(args, env: dict) -> tuple[list[dict], list[Trajectory]]:
    """One run per battery limit, each reported on one line as it finishes."""
    runs, trajectories = [], []
    for b in args.b:
        run, traj = run_one(args, b, env, args.out)
        runs.append(run)
        trajectories.append(traj)
        lat = run["latency_ms"]
        print(f"  b = {b:<5g} {verdict_text(run):<34} "
              f"max|d| {run['max_abs_angle_dev_rad']:8.4f} rad  max|P_ST| {run['max_abs_battery_power_pu']:.4f} pu"
              f"  latency p50/p99/max {lat.get('p50', math.nan):.2f}/{lat.get('p99', math.nan):.2f}/"
              f"{lat.get('max', math.nan):.2f} ms  dropped {run['dropped_samples']}  late {run['late_samples']}"
              f"  wall {run['wall_time_s']:.1f} s")
    return runs, trajectories


def wait_for_interrupt() -> None:
    """Block until Ctrl-C (SIGINT) or SIGTERM."""
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass


def logger_counts(output: str) -> dict:
    """The per-topic counts the logger printed at exit."""
    for line in output.splitlines():
        if line.startswith(COUNTS_PREFIX):
            return json.loads(line[len(COUNTS_PREFIX):])["counts"]
    raise CliError("the logger did not report its message counts")


def main(argv=None) -> int:
    """Entry point of ``nni-demo``."""
    parser = build_parser()

    def body():
        args = parser.parse_args(argv)
        args.model = resolve_model(args, parser.prog)
        args.model.validate()
        sink = rerun_sink(args.rerun) if args.rerun else None
        domain = args.domain_id if args.domain_id is not None else int(os.environ.get("ROS_DOMAIN_ID", "42"))
        if not 0 <= domain <= 232:
            raise CliError(f"ROS domain id must be within 0..232, got {domain}")
        args.out.mkdir(parents=True, exist_ok=True)
        if not os.access(args.out, os.W_OK):
            raise CliError(f"output folder {args.out} is not writable")
        env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain),
                   PYTHONUNBUFFERED="1")
        print(f"nni-demo: {args.mode}, {args.rate:g} frames/s, {args.duration:g} s per run, domain {domain}")
        print(f"  {args.model.header()}")
        with Processes(env, args.out) as viewer:
            if sink:
                viewer.start("rerun_bridge", "nni_msgs_adapter.rerun_bridge", sink)
                viewer.wait_for_output("rerun_bridge", READY_TEXT, timeout_s=30.0)
            runs, trajectories = run_all(args, env)
            if args.rerun and args.rerun[0] == "serve":
                print("serving the Rerun stream (URL in rerun_bridge.log); Ctrl-C to stop")
                wait_for_interrupt()
        summary = args.out / "summary.json"
        with atomic_output(summary) as handle:
            json.dump({"scenarios": runs}, handle, indent=2)
            handle.write("\n")
        figure = args.out / "figures.png"
        plot_runs(trajectories, runs, figure, args.model.scenario_values(), f"sampled at {args.rate:g} Hz",
                  args.mode)
        print(f"wrote {summary}, {figure} and {len(runs)} recording(s) in {args.out}")
        return 0

    return run_cli(body, parser.prog)


if __name__ == "__main__":
    sys.exit(main())
