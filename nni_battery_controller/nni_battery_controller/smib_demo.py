"""``nni-demo``: the distributed closed loop, one run per battery limit, recorded and summarised.

For each b it starts three processes (MCAP logger, controller, plant) with
localhost-only discovery on one ROS domain (``--domain-id``, else
$ROS_DOMAIN_ID, else 42; the runs follow one another on it), the plant's
battery rated b and the controller sealing its commands with a fresh key of
the run (removed after it); compares the parameters the controller and the
plant state at start with what it gave them (one line and exit 2 if they
differ: the plant holds its run until then), lets the plant run its scenario to the end, stops the others with SIGINT (SIGKILL after a grace
period), and reads the recording back to write ``OUT/summary.json``: the keys of
``nni-simulate --json`` per run plus loop latency (p50, p99, max in ms, from
measurement to command arrival at the plant) and dropped / late sample counts
from the plant's final diagnostics. A run in which the battery was commanded by
anyone but its controller, or applied more than b, is reported as compromised
(exit status 3). With ``--pmu-server`` each run's plant also serves its PMU
as an IEEE C37.118.2 stream (:mod:`nni_battery_controller.demo_pmu`): where
it listens, each PDC's arrival and departure, and its counters are printed,
the counters also in the summary (``c37118``). With ``--rerun`` a Rerun bridge is part of every run: the
plant starts only once the bridge hears it, and a run ends only when the
bridge has logged every sample the recording holds. With ``--measurements
c37118`` the controller is fed through the plant's C37.118.2 stream and the
client node (:mod:`nni_battery_controller.demo_c37118`). The orchestrator creates
no ROS node of its own; killed (SIGINT, SIGTERM, SIGKILL), it takes its
processes with it.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import time
from pathlib import Path

from nni_battery_controller import demo_c37118, demo_foxglove
from nni_battery_controller.demo_foxglove import add_foxglove_option
from nni_battery_controller.controller_config import parameters as controller_node_parameters
from nni_battery_controller.demo_common import (
    battery_block,
    battery_text,
    check_complete,
    compromised_reasons,
    compromised_text,
    exit_status,
    finish_plant,
    key_environment,
    logger_counts,
    loop_writers,
    plant_summary,
    run_environment,
    start_when_read_back,
    stated_only,
    wait_for_recorder,
    write_summary,
)
from nni_battery_controller.demo_pmu import StreamWatch, add_pmu_options, stream_parameters, wait_text
from nni_battery_controller.demo_viewer import (
    BRIDGE_WAIT_S,
    add_rerun_option,
    rerun_sink,
    start_viewer,
    wait_for_interrupt,
)
from nni_battery_controller.figures import plot_runs
from nni_battery_controller.options import PAPER_BATTERY_LIMITS, add_energy_option, add_model_options, resolve_model
from nni_battery_controller.recorded_runs import sampled_trajectory
from nni_battery_controller.simulate import Trajectory
from nni_battery_controller.verdicts import assess, verdict_text
from nni_battery_controller.study_common import software_version
from nni_msgs_adapter.c37118.cli import summary_line
from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.cli_support import (
    CliError,
    OneLineParser,
    battery_limit,
    float_within,
    given_options,
    positive_float,
    run_cli,
)
from nni_msgs_adapter.ros.command_auth import run_key
from nni_msgs_adapter.ros.processes import ChildError, Supervisor
from nni_msgs_adapter.ros.readback import expected_parameters
from nni_msgs_adapter.recording.runs import GeneratorRun, read_generator_run
from nni_msgs_adapter.viewing.bridge_protocol import PROGRESS_PREFIX
from nni_msgs_adapter.ros.defaults import controller_defaults, plant_defaults
from nni_plant_sim.cases import CASES
from nni_plant_sim.plant_config import parameters as plant_node_parameters
from nni_plant_sim.scenarios import SCENARIO_FIELDS

#: Plant parameters that set up a run without changing its case (the recording name ignores them; the rating is b).
RUN_CONTROL = frozenset({"mode", "duration_s", "pmu_rate_hz", "wait_for_subscribers", "wait_for_recorders",
                         "battery_rating_pu", "hold_until_released", "pmu_host", "pmu_port", "pmu_idcode", "pmu_freq_format",
                         "pmu_wait_for_pdcs"})


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
    add_foxglove_option(parser)
    demo_c37118.add_measurements_option(parser)
    add_pmu_options(parser)
    parser.add_argument("--domain-id", type=int, default=None,
                        help="ROS_DOMAIN_ID for the run (default: $ROS_DOMAIN_ID, else 42)")
    parser.add_argument("--case", metavar="CASE",
                        help=f"run a network of generators instead, one controller per generator ({', '.join(CASES)}; "
                             "its options: nni-demo --case CASE --help; default: none, the paper's SMIB)")
    add_model_options(parser)
    add_energy_option(parser, "the plant's battery, in the plant node")
    return parser


#: Options of ``nni-demo --case`` only: given to the SMIB demo, they are refused.
NETWORK_ONLY_OPTIONS = ("--gen-b", "--fault-bus", "--fault-r", "--fault-x", "--trip-line", "--deployment")


def recording_name(b: float, plant: dict | None = None) -> str:
    """File name of one run's recording: paper_b0.3.mcap for the paper's case, <scenario>_b0.3.mcap otherwise.

    ``plant`` holds the plant parameters the demo sets (None: the paper's case);
    the paper's case is the package defaults for everything but the run's set-up
    (mode, duration, rate, subscribers to wait for, the C37.118 stream).
    """
    defaults = plant_defaults()
    case = {key: value for key, value in (plant or {}).items() if key not in RUN_CONTROL}
    paper = all(defaults.get(key) == value for key, value in case.items())
    scenario = case.get("scenario", defaults["scenario"])
    return f"{'paper' if paper else scenario}_b{'inf' if math.isinf(b) else f'{b:g}'}.mcap"


def plant_parameters(args, b: float, with_bridge: bool) -> dict:
    """The plant parameters of one run that differ from the package defaults (or set up the run): its battery
    rated b, its run held until the read-back."""
    # It waits for the controller and the logger, and for the Rerun and Foxglove bridges when there are; on
    # plant/state for the recorders among them (the logger and the bridges), as its writer sees them.
    viewers = with_bridge + (getattr(args, "foxglove_address", None) is not None)
    return {**args.model.plant_node_parameters(), "mode": args.mode, "duration_s": args.duration,
            "pmu_rate_hz": args.rate,
            "wait_for_subscribers": demo_c37118.plant_readers(args.measurements, 2, viewers),
            "wait_for_recorders": 1 + viewers,
            "battery_rating_pu": b, "hold_until_released": True, **args.stream,
            **({} if args.battery_energy_pu_s is None else {"battery_energy_pu_s": args.battery_energy_pu_s})}


def controller_parameters(args, b: float) -> dict:
    """The controller parameters of one run that differ from the package defaults."""
    return {**args.model.controller_node_parameters(), "battery_limit_pu": b, "sample_rate_hz": args.rate,
            **demo_c37118.controller_parameters(args.measurements)}


def run_metadata(args, plant: dict, controller: dict) -> dict:
    """What the logger stores as the recording's ``nni_run`` metadata (INTERFACES.md item 2)."""
    plant_values = {**plant_defaults(), **plant}
    scenario = plant_values["scenario"]
    options = {key: value for key, value in plant_values.items() if key in SCENARIO_FIELDS.get(scenario, ())}
    return {"scenario": {"name": scenario, **options}, "plant": plant_values,
            "controller": {**controller_defaults(), **controller}, "mode": args.mode, "rate_hz": args.rate,
            "measurements": args.measurements, "software_version": software_version()}


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
    plant_params = plant_parameters(args, b, with_bridge=bridge is not None)
    controller_params = controller_parameters(args, b)
    recording = out / recording_name(b, plant_params)
    logs = out / "logs" / recording.stem
    started = time.monotonic()
    meta = run_metadata(args, plant_params, controller_params)
    with run_key() as key, Supervisor(env, logs) as procs:
        foxglove = demo_foxglove.start_bridge(procs, args.foxglove_address, key_environment(key), {
            "run": index, "b": b, "law": meta["controller"]["law"], "scenario": meta["scenario"]["name"],
            "mode": args.mode}, logs)
        logger = procs.start_node("mcap_logger", "nni_msgs_adapter.recording.mcap_logger", {
            "output_path": str(recording), "discovery_period_s": 0.1, "run_metadata": json.dumps(meta)},
            env=key_environment(key))
        controller = procs.start_node("controller", "nni_battery_controller.controller_node", controller_params,
                                      env=key_environment(key))
        # The plant holds its run until released: it starts beside the others, its release waits for the logger.
        plant = procs.start_node("plant", "nni_plant_sim.plant_node", plant_params, env=key_environment(key))
        writers = loop_writers([""], lambda _: "/controller", "/plant")
        wait_for_recorder(logger, writers, logs)
        demo_foxglove.wait_streaming(foxglove, writers, logs, index, args.foxglove_wait)
        watch = StreamWatch(plant) if args.stream else None
        where = watch.listening() if watch is not None else None
        client = demo_c37118.start_client(procs, where, args.measurements, args.mode, 2, idcode=args.pmu_idcode,
                                          env=key_environment(key))
        start_when_read_back(
            [(controller, {"/controller": expected_parameters(controller_node_parameters(), controller_params)}),
             (plant, {"/plant": expected_parameters(plant_node_parameters(), plant_params)}),
             *stated_only(logger, client), *demo_foxglove.stated(foxglove)], plant, logs, key)
        demo_c37118.wait_connected(client, f"b = {b:<5g}")
        finish_plant(procs, plant, args, f"b = {b:<5g}", watch=watch)
        controller.stop()
        if logger.stop() != 0:
            raise CliError(f"the logger {logger.how_it_ended()}: {logger.tail()}")
        wall_s = time.monotonic() - started
        counts = logger_counts(logger.output())
        summary = plant_summary(plant.output())
        check_complete(recording, counts.get("/pmu", 0), int(summary["measurements"]), logs)
        check_complete(recording, counts.get(f"/{contract.TOPIC_BATTERY_COMMAND}", 0), int(summary["commands"]), logs,
                       " from the controller", "battery commands the plant received")
        run = read_generator_run(recording)
        if bridge is not None:
            wait_for_bridge(bridge, index, run, logs)
        # Assessed with the very model and scenario the nodes ran with.
        traj = sampled_trajectory(run, args.model.smib(), args.model.controller_params(b))
        outcome = assess(traj, scenario=args.model.scenario()).to_json()
        diag = run.diagnostics
        outcome.update({
            "mode": args.mode, "rate_hz": args.rate, "measurements": args.measurements, "recording": str(recording),
            "wall_time_s": round(wall_s, 3),
            "samples": int(diag.get("samples", 0)),
            # The plant measures latency to the nanosecond: more digits are float noise (0.33549999999999996).
            "latency_ms": {q: round(float(diag[f"latency_{q}_ms"]), 6) for q in ("p50", "p99", "max")
                           if f"latency_{q}_ms" in diag},
            "dropped_samples": int(diag.get("deadline_misses", 0)),
            "late_samples": int(diag.get("late", 0)),
            # Reporting instants a stalled realtime plant skipped (an overloaded core): measurements never sent.
            "skipped_reports": int(summary.get("skipped_reports", 0)),
            "logger_counts": counts,
        })
        if args.battery_energy_pu_s is not None:  # the plant's own account of its battery
            outcome["battery"] = battery_block(args.battery_energy_pu_s, summary)
        if watch is not None:
            outcome["c37118"] = watch.summary()
        reasons = compromised_reasons(summary, run, b)
        if reasons:
            outcome["compromised"] = reasons
        # Judged with the bridge still up: the Foxglove stream ends with the verdict the demo prints.
        demo_foxglove.stream_verdict(foxglove, logs, {
            "run": index, "b": b, "in_synchronism": outcome["in_synchronism"], "compromised": bool(reasons),
            "verdict": compromised_text(b, reasons) if reasons else verdict_text(outcome)})
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
        else:
            lat = run["latency_ms"]
            print(f"  b = {b:<5g} {verdict_text(run):<34} "
                  f"max|d| {run['max_abs_angle_dev_rad']:8.4f} rad  max|P_ST| {run['max_abs_battery_power_pu']:.4f} pu"
                  f"  latency p50/p99/max {lat.get('p50', math.nan):.2f}/{lat.get('p99', math.nan):.2f}/"
                  f"{lat.get('max', math.nan):.2f} ms  dropped {run['dropped_samples']}  late {run['late_samples']}"
                  f"  wall {run['wall_time_s']:.1f} s" + battery_text(run.get("battery")))
        if "c37118" in run:
            print(summary_line(run["c37118"]))
    return runs, trajectories


def parse_arguments(parser: OneLineParser, argv=None) -> argparse.Namespace:
    """The command line, with the model, scenario and gains resolved (``args.model``) and validated."""
    args = parser.parse_args(argv)
    args.model = resolve_model(args, parser.prog)
    args.model.validate()
    args.foxglove_address = demo_foxglove.foxglove_address(args)
    args.stream = stream_parameters(args, given_options(sys.argv[1:] if argv is None else argv),
                                    args.model.plant["f0_hz"])
    return args


def main(argv=None) -> int:
    """``nni-demo`` without ``--case`` (called by :func:`nni_battery_controller.demo_command.main`)."""
    words = given_options(sys.argv[1:] if argv is None else argv)
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
        print(f"nni-demo: {args.mode}, {args.rate:g} frames/s, {args.duration:g} s per run, domain {domain}"
              + (", measurements through C37.118" if args.measurements == "c37118" else ""))
        print(f"  {args.model.header()}")
        if wait_text(args):
            print(f"  {wait_text(args)}")
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
