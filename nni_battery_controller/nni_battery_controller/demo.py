"""``nni-demo``: the distributed closed loop, one run per battery limit, recorded and summarised.

For each b it starts three processes (MCAP logger, controller, plant) with
localhost-only discovery on one ROS domain (``--domain-id``, else
$ROS_DOMAIN_ID, else 42; the runs follow one another on it), lets the plant run
its scenario to the end, stops the others with SIGINT (SIGKILL after a grace
period), and reads the recording back to write ``OUT/summary.json``: the keys of
``nni-simulate --json`` per run plus loop latency (p50, p99, max in ms, from
measurement to command arrival at the plant) and dropped / late sample counts
from the plant's final diagnostics. A run in which the battery was commanded by
anyone but its controller, or applied more than b, is reported as compromised
(exit status 3). With ``--rerun`` a Rerun bridge is part of every run: the
plant starts only once the bridge hears it, and a run ends only when the
bridge has logged every sample the recording holds. The orchestrator creates
no ROS node of its own; killed (SIGINT, SIGTERM, SIGKILL), it takes its
processes with it.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import socket
import sys
import time
import urllib.parse
from importlib import metadata
from pathlib import Path

import numpy as np

from nni_battery_controller.cli import PAPER_BATTERY_LIMITS, plot_runs
from nni_battery_controller.options import add_model_options, resolve_model
from nni_battery_controller.simulate import Trajectory, assess, verdict_text
from nni_msgs_adapter.ros.cli_support import (
    CliError,
    OneLineParser,
    atomic_output,
    battery_limit,
    float_within,
    positive_float,
    run_cli,
    writable_output,
)
from nni_msgs_adapter.recording.mcap_logger import COUNTS_PREFIX
from nni_msgs_adapter.ros.processes import ChildError, Supervisor
from nni_msgs_adapter.recording.runs import GeneratorRun, read_generator_run, sampled_trajectory
from nni_msgs_adapter.viewing.rerun_bridge import PROGRESS_PREFIX, READY_TEXT
from nni_msgs_adapter.viewing.rerun_stream import display_missing
from nni_msgs_adapter.ros.defaults import controller_defaults, plant_defaults
from nni_plant_sim.cases import CASES
from nni_plant_sim.plant_node import SUMMARY_PREFIX
from nni_plant_sim.scenarios import SCENARIO_FIELDS

#: Seconds the logger gets after the plant ends, for the last reliable messages to land.
DRAIN_S = 0.5
#: Seconds the Rerun bridge gets, once the run's recording is read, to report every one of its samples.
BRIDGE_WAIT_S = 30.0
#: Exit status of a call with a compromised run (the battery commanded by a stranger, or beyond b).
EXIT_COMPROMISED = 3
#: The plant's trust counters (INTERFACES.md item 1) of which any non-zero one compromises a run.
TRUST_COUNTERS = ("foreign_commands", "unsolicited_commands", "writer_alarms")
#: Plant parameters that set up a run without changing its case (the recording name ignores them).
RUN_CONTROL = frozenset({"mode", "duration_s", "pmu_rate_hz", "wait_for_subscribers"})
#: Where the Rerun web viewer of ``--rerun serve`` listens (gRPC proxy, web page).
SERVE_GRPC_PORT, SERVE_WEB_PORT = 9876, 9090


def build_parser() -> OneLineParser:
    """The nni-demo command line."""
    parser = OneLineParser(prog="nni-demo", description=__doc__)
    parser.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep",
                        help="lockstep: simulated /clock, deterministic, fast (default); realtime: wall clock")
    parser.add_argument("--b", type=battery_limit, nargs="+", default=list(PAPER_BATTERY_LIMITS), metavar="B",
                        help="battery limits in pu, one run each (default: 0 0.2 0.3 inf)")
    parser.add_argument("--duration", type=positive_float, default=10.0, help="simulated seconds per run (default: 10)")
    rate = plant_defaults()["pmu_rate_hz"]
    parser.add_argument("--rate", type=float_within(10.0, 1000.0, "frames/s"), default=rate,
                        help=f"PMU reporting rate, frames/s (default: {rate:g})")
    parser.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder, created (default: out/demo)")
    add_rerun_option(parser)
    parser.add_argument("--domain-id", type=int, default=None,
                        help="ROS_DOMAIN_ID for the run (default: $ROS_DOMAIN_ID, else 42)")
    parser.add_argument("--case", metavar="CASE",
                        help=f"run a network of generators instead, one controller per generator ({', '.join(CASES)}; "
                             "its options: nni-demo --case CASE --help; default: none, the paper's SMIB)")
    add_model_options(parser)
    return parser


#: Options of ``nni-demo --case`` only: given to the SMIB demo, they are refused.
NETWORK_ONLY_OPTIONS = ("--gen-b", "--fault-bus", "--fault-r", "--fault-x", "--trip-line", "--deployment")


def given_options(argv) -> list[str]:
    """The ``--option`` words of a command line (``--name=value`` as ``--name``)."""
    return [word.split("=", 1)[0] for word in argv if word.startswith("--")]


def recording_name(b: float, plant: dict | None = None) -> str:
    """File name of one run's recording: paper_b0.3.mcap for the paper's case, <scenario>_b0.3.mcap otherwise.

    ``plant`` holds the plant parameters the demo sets (None: the paper's case);
    the paper's case is the package defaults for everything but the run's set-up
    (mode, duration, rate, subscribers to wait for).
    """
    defaults = plant_defaults()
    case = {key: value for key, value in (plant or {}).items() if key not in RUN_CONTROL}
    paper = all(defaults.get(key) == value for key, value in case.items())
    scenario = case.get("scenario", defaults["scenario"])
    return f"{'paper' if paper else scenario}_b{'inf' if math.isinf(b) else f'{b:g}'}.mcap"


def plant_parameters(args, with_bridge: bool) -> dict:
    """The plant parameters of one run that differ from the package defaults (or set up the run)."""
    # It waits for the controller and the logger, and for the Rerun bridge when there is one.
    return {**args.model.plant_node_parameters(), "mode": args.mode, "duration_s": args.duration,
            "pmu_rate_hz": args.rate, "wait_for_subscribers": 3 if with_bridge else 2}


def controller_parameters(args, b: float) -> dict:
    """The controller parameters of one run that differ from the package defaults."""
    return {**args.model.controller_node_parameters(), "battery_limit_pu": b, "sample_rate_hz": args.rate}


def software_version() -> str:
    """Version of the installed nni_battery_controller package."""
    try:
        return metadata.version("nni_battery_controller")
    except metadata.PackageNotFoundError:
        return "unknown"


def run_metadata(args, plant: dict, controller: dict) -> dict:
    """What the logger stores as the recording's ``nni_run`` metadata (INTERFACES.md item 2)."""
    plant_values = {**plant_defaults(), **plant}
    scenario = plant_values["scenario"]
    options = {key: value for key, value in plant_values.items() if key in SCENARIO_FIELDS.get(scenario, ())}
    return {"scenario": {"name": scenario, **options}, "plant": plant_values,
            "controller": {**controller_defaults(), **controller}, "mode": args.mode, "rate_hz": args.rate,
            "software_version": software_version()}



def add_rerun_option(parser) -> None:
    """``--rerun`` of the SMIB and the network demo."""
    parser.add_argument("--rerun", nargs="+", metavar=("SINK", "PATH"), default=None,
                        help="stream the runs live to Rerun: 'save PATH' (.rrd), 'serve' (web viewer on this "
                             "machine, kept up until Ctrl-C) or 'spawn' (native viewer, needs a display); default: none")


def rerun_sink(words) -> dict:
    """What ``--rerun`` asks for: save PATH | serve [ADDRESS] | spawn (ADDRESS: where the viewer listens)."""
    sink, rest = words[0], words[1:]
    if sink not in ("save", "serve", "spawn") or len(rest) != {"save": 1, "serve": len(rest[:1]), "spawn": 0}[sink]:
        raise CliError("--rerun takes 'save PATH', 'serve [ADDRESS]' (default 127.0.0.1) or 'spawn'")
    if sink == "save":
        try:
            path = writable_output(rest[0])
        except argparse.ArgumentTypeError as exc:
            raise CliError(f"--rerun save: {exc}") from None
        return {"sink": "save", "path": str(path)}
    if sink == "spawn" and display_missing():
        raise CliError("--rerun spawn needs a display (DISPLAY and WAYLAND_DISPLAY are unset): "
                       "use --rerun save PATH or --rerun serve")
    if sink == "serve":
        return {"sink": "serve", "address": rest[0] if rest else "127.0.0.1"}
    return {"sink": sink}


def start_viewer(viewer: Supervisor, sink: dict, f0_hz: float, **network):
    """Start the Rerun bridge (and for ``serve`` the web viewer it streams to); return the bridge.

    ``network``: the bridge's ``namespaces`` and ``case`` for a network's generators.
    """
    params = {**sink, "f0_hz": f0_hz, **network}
    if sink["sink"] == "serve":
        # The SDK's own server listens on every interface; the rerun CLI's binds where it is told.
        host = sink["address"]
        viewer.start("rerun_viewer", [str(Path(sys.executable).parent / "rerun"), "--serve-web", "--bind", host,
                                      "--port", str(SERVE_GRPC_PORT), "--web-viewer-port", str(SERVE_WEB_PORT)])
        proxy = f"rerun+http://{host}:{SERVE_GRPC_PORT}/proxy"
        params = {"sink": "connect", "url": proxy, "f0_hz": f0_hz, **network}
        wait_for_port(viewer["rerun_viewer"], host, SERVE_GRPC_PORT)
        print(f"Rerun web viewer: http://{host}:{SERVE_WEB_PORT}/?url={urllib.parse.quote(proxy, safe='')}",
              flush=True)
    bridge = viewer.start_node("rerun_bridge", "nni_msgs_adapter.viewing.rerun_bridge", params)
    try:
        bridge.wait_for_line(READY_TEXT, timeout_s=30.0)
    except ChildError as error:
        raise CliError(f"the Rerun bridge did not start: {error}") from None
    return bridge


def wait_for_port(child, host: str, port: int, timeout_s: float = 30.0) -> None:
    """Wait until ``child`` accepts TCP connections on host:port; CliError if it exits or times out."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            socket.create_connection((host, port), timeout=0.5).close()
            return
        except OSError:
            if child.poll() is not None or time.monotonic() > deadline:
                raise CliError(f"the Rerun web viewer did not listen on {host}:{port}: {child.tail()}") from None
            time.sleep(0.1)


def compromised_reasons(plant_summary: dict, run: GeneratorRun, b: float) -> dict:
    """Why a run cannot be trusted (empty if it can): non-zero trust counters, or |P_ST| applied above b.

    The largest power applied is the plant's own count where it reports one, and
    in any case the largest ``plant/state`` battery power in the recording.
    """
    missing = [key for key in (*TRUST_COUNTERS, "max_abs_applied_power_pu") if key not in plant_summary]
    if missing:
        raise CliError(f"the plant's final diagnostics lack {', '.join(missing)}: the run cannot be judged")
    reasons = {key: int(plant_summary[key]) for key in TRUST_COUNTERS if int(plant_summary[key])}
    recorded = float(np.max(np.abs(run.battery_power_pu))) if run.battery_power_pu.size else 0.0
    applied = max(recorded, float(plant_summary["max_abs_applied_power_pu"]))
    if applied > b + 1e-12:
        reasons["max_abs_applied_power_pu"] = applied
    return reasons


#: How a compromised run is printed instead of its verdict.
COMPROMISED_PREFIX = "COMPROMISED (not a valid result): "


def compromised_words(b: float, reasons: dict) -> list[str]:
    """Why a run is compromised, one phrase per reason."""
    words = []
    if "max_abs_applied_power_pu" in reasons:
        words.append(f"|P_ST| {reasons['max_abs_applied_power_pu']:.4f} pu applied, above b = {b:g} pu")
    return words + [f"{reasons[key]} {key.replace('_', ' ')}" for key in TRUST_COUNTERS if key in reasons]


def compromised_text(b: float, reasons: dict) -> str:
    """One line saying why a run is compromised."""
    return COMPROMISED_PREFIX + "; ".join(compromised_words(b, reasons))


def plant_summary(output: str, prefix: str = SUMMARY_PREFIX) -> dict:
    """The final diagnostics values the plant printed at exit (the line starting with ``prefix``)."""
    for line in output.splitlines():
        if line.startswith(prefix):
            return json.loads(line[len(prefix):])
    raise CliError("the plant did not report its final diagnostics")


def wait_for_plant(plant, args, label: str, limit_s: float, prefix: str = SUMMARY_PREFIX) -> None:
    """Wait for the plant's final summary line (``prefix``); on a terminal, show a realtime run's progress."""
    show = args.mode == "realtime" and sys.stderr.isatty()
    deadline, started, shown = time.monotonic() + limit_s, None, ""
    while prefix not in plant.output():
        if plant.poll() is not None:
            return
        if time.monotonic() > deadline:
            raise CliError(f"the plant did not finish within {limit_s:.0f} s (logs in {plant.log_path.parent})")
        if show:
            if started is None and "started in" in plant.output():
                started = time.monotonic()
            if started is not None:
                # Realtime: simulated time runs with the wall clock from the plant's start.
                elapsed_s = min(time.monotonic() - started, args.duration)
                text = f"\r  {label} t = {elapsed_s:5.1f} of {args.duration:g} s"
                if text != shown:
                    print(text, end="", file=sys.stderr, flush=True)
                    shown = text
        time.sleep(0.05)
    if show:
        print("\r\033[K", end="", file=sys.stderr, flush=True)


def finish_plant(procs, plant, args, label: str, prefix: str = SUMMARY_PREFIX) -> None:
    """The plant's run to its end (bounded wait), its clean exit, then the drain for the recorders; else CliError."""
    wait_for_plant(plant, args, label, run_time_limit_s(args), prefix)
    try:
        status = plant.wait_exit(procs.grace_s)
    except ChildError as error:
        raise CliError(str(error)) from None
    if status != 0:
        raise CliError(f"the {plant.name} exited with status {status}: {plant.tail()}")
    time.sleep(DRAIN_S)


def check_complete(recording: Path, recorded: int, sent: int, logs: Path, where: str = "",
                   what: str = "measurements the plant sent") -> None:
    """CliError unless the logger recorded every one of ``what`` (``where``: to or from which namespace)."""
    if recorded < sent:
        raise CliError(f"the recording {recording} is partial: the logger recorded {recorded} of the {sent} "
                       f"{what}{where} (logs in {logs})")


def run_time_limit_s(args) -> float:
    """Longest wall time a plant may take for one run (start-up and discovery included)."""
    return 60.0 + (args.duration if args.mode == "realtime" else args.duration * 2)


def wait_for_bridge(bridge, index: int, run: GeneratorRun, logs: Path) -> None:
    """Wait until the Rerun bridge reports run ``index`` with every answered sample of the recording."""
    answered = run.answered
    expected, last_t_s = int(answered.sum()), float(run.t_s[answered][-1]) if answered.any() else math.nan

    def progress(line: str) -> dict:
        return json.loads(line[len(PROGRESS_PREFIX):])

    try:
        line = bridge.wait_for_line(PROGRESS_PREFIX, BRIDGE_WAIT_S,
                                    lambda line: progress(line)["run"] == index
                                    and progress(line)["samples"] >= expected)
    except ChildError:
        reports = [progress(line[line.find(PROGRESS_PREFIX):]) for line in bridge.output().splitlines()
                   if PROGRESS_PREFIX in line]
        got = max((r["samples"] for r in reports if r["run"] == index), default=0)
        raise CliError(f"the Rerun stream is partial: the bridge logged {got} of the {expected} samples of run "
                       f"{index} within {BRIDGE_WAIT_S:g} s (logs in {logs})") from None
    report = progress(line)
    if report["samples"] != expected or not math.isclose(report["last_t_s"], last_t_s, abs_tol=1e-6):
        raise CliError(f"the Rerun stream does not match the recording for run {index}: {report['samples']} "
                       f"samples up to t = {report['last_t_s']:.3f} s, recorded {expected} up to {last_t_s:.3f} s")


def run_one(args, b: float, env: dict, out: Path, bridge=None, index: int = 0) -> tuple[dict, Trajectory]:
    """One run: start logger, controller, plant; wait for the plant; summarise its recording.

    With a Rerun ``bridge`` (run ``index`` of its stream), the plant waits for it
    too, and the run ends only when the bridge has logged every recorded sample.
    """
    plant_params = plant_parameters(args, with_bridge=bridge is not None)
    controller_params = controller_parameters(args, b)
    recording = out / recording_name(b, plant_params)
    logs = out / "logs" / recording.stem
    started = time.monotonic()
    with Supervisor(env, logs) as procs:
        logger = procs.start_node("mcap_logger", "nni_msgs_adapter.recording.mcap_logger", {
            "output_path": str(recording), "discovery_period_s": 0.1,
            "run_metadata": json.dumps(run_metadata(args, plant_params, controller_params))})
        controller = procs.start_node("controller", "nni_battery_controller.controller_node", controller_params)
        plant = procs.start_node("plant", "nni_plant_sim.plant_node", plant_params)
        finish_plant(procs, plant, args, f"b = {b:<5g}")
        controller.stop()
        if logger.stop() != 0:
            raise CliError(f"the logger failed: {logger.tail()}")
    wall_s = time.monotonic() - started
    counts = logger_counts(logger.output())
    summary = plant_summary(plant.output())
    check_complete(recording, sum(n for topic, n in counts.items() if topic.endswith("/pmu")),
                   int(summary["measurements"]), logs)
    run = read_generator_run(recording)
    if bridge is not None:
        wait_for_bridge(bridge, index, run, logs)
    # Assessed with the very model and scenario the nodes ran with.
    traj = sampled_trajectory(run, args.model.smib(), args.model.controller_params(b))
    outcome = assess(traj, scenario=args.model.scenario()).to_json()
    diag = run.diagnostics
    outcome.update({
        "mode": args.mode, "rate_hz": args.rate, "recording": str(recording),
        "wall_time_s": round(wall_s, 3),
        "samples": int(diag.get("samples", 0)),
        # The plant measures latency to the nanosecond: more digits are float noise (0.33549999999999996).
        "latency_ms": {q: round(float(diag[f"latency_{q}_ms"]), 6) for q in ("p50", "p99", "max")
                       if f"latency_{q}_ms" in diag},
        "dropped_samples": int(diag.get("deadline_misses", 0)),
        "late_samples": int(diag.get("late", 0)),
        "logger_counts": counts,
    })
    reasons = compromised_reasons(summary, run, b)
    if reasons:
        outcome["compromised"] = reasons
    return outcome, traj


def run_all(args, env: dict, bridge=None) -> tuple[list[dict], list[Trajectory]]:
    """One run per battery limit, each reported on one line as it finishes."""
    runs, trajectories = [], []
    for index, b in enumerate(args.b, start=1):
        run, traj = run_one(args, b, env, args.out, bridge, index)
        runs.append(run)
        trajectories.append(traj)
        if "compromised" in run:
            print(f"  b = {b:<5g} {compromised_text(b, run['compromised'])}")
            continue
        lat = run["latency_ms"]
        print(f"  b = {b:<5g} {verdict_text(run):<34} "
              f"max|d| {run['max_abs_angle_dev_rad']:8.4f} rad  max|P_ST| {run['max_abs_battery_power_pu']:.4f} pu"
              f"  latency p50/p99/max {lat.get('p50', math.nan):.2f}/{lat.get('p99', math.nan):.2f}/"
              f"{lat.get('max', math.nan):.2f} ms  dropped {run['dropped_samples']}  late {run['late_samples']}"
              f"  wall {run['wall_time_s']:.1f} s")
    return runs, trajectories


def wait_for_interrupt(message: str) -> None:
    """Print ``message``, then block until Ctrl-C (SIGINT) or SIGTERM (a signal right after the message is caught too)."""
    try:
        print(message, flush=True)
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


def parse_arguments(parser: OneLineParser, argv=None) -> argparse.Namespace:
    """The command line, with the model, scenario and gains resolved (``args.model``) and validated."""
    args = parser.parse_args(argv)
    args.model = resolve_model(args, parser.prog)
    args.model.validate()
    return args


def run_environment(args) -> tuple[dict, int]:
    """The children's environment and ROS domain (``--domain-id``, else $ROS_DOMAIN_ID, else 42); ``--out`` made.

    CliError for a domain outside 0..232 or an output folder that cannot be written.
    """
    domain = args.domain_id if args.domain_id is not None else int(os.environ.get("ROS_DOMAIN_ID", "42"))
    if not 0 <= domain <= 232:
        raise CliError(f"ROS domain id must be within 0..232, got {domain}")
    args.out.mkdir(parents=True, exist_ok=True)
    if not os.access(args.out, os.W_OK):
        raise CliError(f"output folder {args.out} is not writable")
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED="1")
    return env, domain


def write_summary(out: Path, content: dict) -> Path:
    """``OUT/summary.json`` (written whole or not at all); its path."""
    summary = out / "summary.json"
    with atomic_output(summary) as handle:
        json.dump(content, handle, indent=2)
        handle.write("\n")
    return summary


def exit_status(prog: str, runs: list[dict], what: str) -> int:
    """0, or EXIT_COMPROMISED with one line on stderr naming the b of the compromised runs (``what`` was not ...)."""
    compromised = [run for run in runs if "compromised" in run]
    if not compromised:
        return 0
    limits = ", ".join(str(run["b"]) for run in compromised)
    print(f"{prog}: error: {len(compromised)} of {len(runs)} run(s) compromised (b = {limits}): {what} not under "
          "its controller's command alone; see summary.json", file=sys.stderr)
    return EXIT_COMPROMISED


def main(argv=None) -> int:
    """Entry point of ``nni-demo`` (``--case``: the network demo of :mod:`network_demo`)."""
    words = given_options(sys.argv[1:] if argv is None else argv)
    if "--case" in words:
        from nni_battery_controller import network_demo

        return network_demo.main(argv)
    parser = build_parser()

    def body():
        # SIGTERM stops the demo as Ctrl-C does: every child is stopped on the way out.
        signal.signal(signal.SIGTERM, signal.default_int_handler)
        network_only = [word for word in words if word in NETWORK_ONLY_OPTIONS]
        if network_only:
            raise CliError(f"{network_only[0]} applies to a network of generators only (nni-demo --case CASE ...)")
        args = parse_arguments(parser, argv)
        sink = rerun_sink(args.rerun) if args.rerun else None
        env, domain = run_environment(args)
        print(f"nni-demo: {args.mode}, {args.rate:g} frames/s, {args.duration:g} s per run, domain {domain}")
        print(f"  {args.model.header()}")
        with Supervisor(env, args.out) as viewer:
            bridge = start_viewer(viewer, sink, args.model.plant["f0_hz"]) if sink else None
            runs, trajectories = run_all(args, env, bridge)
            if sink and sink["sink"] == "serve":
                wait_for_interrupt("serving the Rerun stream; Ctrl-C to stop")
        summary = write_summary(args.out, {"scenarios": runs})
        figure = args.out / "figures.png"
        plot_runs(trajectories, runs, figure, args.model.scenario_values(), f"sampled at {args.rate:g} Hz",
                  args.mode)
        written = [str(summary), str(figure)] + ([sink["path"]] if sink and sink["sink"] == "save" else [])
        print(f"wrote {', '.join(written)} and {len(runs)} recording(s) in {args.out}")
        return exit_status(parser.prog, runs, "the battery was")

    return run_cli(body, parser.prog)


if __name__ == "__main__":
    sys.exit(main())
