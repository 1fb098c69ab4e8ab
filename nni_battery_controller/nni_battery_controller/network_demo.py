"""``nni-demo --case CASE``: a network of generators over ROS 2, one battery controller per generator.

For each battery limit b it starts the MCAP logger, one controller node per
generator of the case (namespace ``/gen<i>``, g measured, b at every generator
unless ``--gen-b`` says otherwise; ``--deployment separate``, the default: a
process each; ``composed``: all in one process on one executor) and the
network plant node, with localhost-only discovery on one ROS domain; lets the plant run its disturbance
to the end, stops the others and reads the one recording (every namespace)
back. Each run is judged with the offline network study's assessment
(``network_sim.assess_network``) on the recorded trajectory and printed as
``nni-simulate --case`` prints it, with each generator's loop latency and
trust counters; ``OUT/summary.json`` holds it all per generator. A run in which
any generator's battery was commanded by anyone but its controller, or applied
more than its b, is reported as compromised (exit status 3). With
``--measurements c37118`` the controllers are fed through the plant's
C37.118.2 stream and the client node (:mod:`nni_battery_controller.demo_c37118`).
With ``--pmu-server`` the network plant also serves every generator's PMU as an
IEEE C37.118.2 stream, a station each (:mod:`nni_battery_controller.demo_pmu`).
Killed, it takes its processes with it.
"""

from __future__ import annotations

import json
import math
import signal
import sys
import textwrap
import time
from pathlib import Path

from nni_battery_controller import demo_c37118, demo_foxglove
from nni_battery_controller.demo_foxglove import add_foxglove_option
from nni_battery_controller.controller_config import parameters as controller_node_parameters
from nni_battery_controller.demo_common import (
    COMPROMISED_PREFIX,
    TRUST_COUNTERS,
    battery_block,
    battery_text,
    check_complete,
    compromised_reasons,
    compromised_words,
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
from nni_battery_controller.figures import plot_network
from nni_battery_controller.network_common import (
    DEFAULT_LIMITS,
    add_scenario_options,
    format_run,
    json_b,
    make_scenario,
    refuse_foreign_scenario_options,
)
from nni_battery_controller.network_deployment import (
    DEPLOYMENTS,
    battery_limits,
    controller_parameters,
    controller_readbacks,
    generator_limits,
    namespaces,
    participants,
    plant_parameters,
    pmu_readers,
    scenario_parameters,
    start_controllers,
)
from nni_battery_controller.network_sim import ANGLE_REFERENCES, assess_network, network_verdict
from nni_battery_controller.options import add_energy_option, add_network_law_options, network_laws_of
from nni_battery_controller.recorded_runs import network_trajectory
from nni_battery_controller.study_common import software_version
from nni_msgs_adapter.recording.runs import read_generator_runs
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
from nni_msgs_adapter.ros.defaults import controller_defaults
from nni_msgs_adapter.ros.processes import ChildError, Supervisor, with_participants
from nni_msgs_adapter.ros.readback import expected_parameters
from nni_msgs_adapter.viewing.bridge_protocol import PROGRESS_PREFIX
from nni_plant_sim.cases import CASES, load_network
from nni_plant_sim.network_plant_node import SUMMARY_PREFIX, parameters as plant_node_parameters

PROG = "nni-demo"
PLANT = "nni_plant_sim.network_plant_node"
#: The plant's counters shown per generator: the trust counters (any non-zero one compromises a run) and
#: those of commands dropped or clipped on the way to the battery.
SHOWN_COUNTERS = (*TRUST_COUNTERS, "expired_commands", "invalid_commands", "clipped_commands")

_SMIB_MODEL = "the machines, their data and their operating point come from the case"
#: Options of the SMIB demo (or of the offline network study) that a networked run cannot honour, and why.
REFUSED = {
    "--params-file": "its /**/plant and /**/controller sections describe one machine; give the gains with "
                     "--tau, --K, --L, --alpha (one value or one per generator)",
    **{flag: _SMIB_MODEL for flag in ("--H", "--D", "--P-M", "--P-max", "--f0")},
    **{flag: "it belongs to a scenario of the SMIB demo; a network runs --scenario bus_fault or line_trip"
       for flag in ("--delta0", "--speed0", "--fault-p-max")},
}


def build_parser() -> OneLineParser:
    """The ``nni-demo --case`` command line."""
    plant = {spec.name: spec.default for spec in plant_node_parameters()}
    parser = OneLineParser(prog=PROG, description=__doc__)
    parser.add_argument("--case", required=True, choices=tuple(CASES), help="the test system")
    parser.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep",
                        help="lockstep: simulated /clock, deterministic, fast (default); realtime: wall clock")
    parser.add_argument("--b", type=battery_limit, nargs="+", default=list(DEFAULT_LIMITS), metavar="B",
                        help="battery limits in pu of each machine's rating, one run each, the same at every "
                             "generator ('inf' allowed; default: 0 0.1 0.3 inf)")
    parser.add_argument("--gen-b", nargs="+", default=[], metavar="I=B",
                        help="generator I's battery limit in every run instead (I: 1.. as in /gen<I>, case order; "
                             "e.g. --gen-b 3=0.2 4=inf)")
    parser.add_argument("--duration", type=positive_float, default=10.0, help="simulated seconds per run (default: 10)")
    parser.add_argument("--rate", type=float_within(10.0, 1000.0, "frames/s"), default=plant["pmu_rate_hz"],
                        help=f"PMU reporting rate, frames/s (default: {plant['pmu_rate_hz']:g})")
    parser.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder, created (default: out/demo)")
    parser.add_argument("--domain-id", type=int, default=None,
                        help="ROS_DOMAIN_ID for the run (default: $ROS_DOMAIN_ID, else 42)")
    add_rerun_option(parser)
    add_foxglove_option(parser)
    demo_c37118.add_measurements_option(parser)
    add_pmu_options(parser)
    parser.add_argument("--deployment", choices=DEPLOYMENTS, default="separate",
                        help="separate: one controller process per generator (default); composed: all the case's "
                             "controllers as nodes of one composed_controllers process, on one executor")
    parser.add_argument("--reference", choices=ANGLE_REFERENCES, default="pmu",
                        help="the controllers' angle reference: pmu (own angle vs nominal frequency; default) or coi "
                             "(relative to the centre of inertia: each controller reads every generator's PMU)")
    add_scenario_options(parser.add_argument_group("disturbance at t = 0 (as nni-simulate --case)"))
    add_network_law_options(parser)
    add_energy_option(parser, "every generator's battery, in the network plant node")
    return parser


def refuse(words) -> None:
    """CliError naming the first option given that does not apply to a networked run."""
    for word in words:
        if word in REFUSED:
            raise CliError(f"{word} does not apply to --case: {REFUSED[word]}")


def parse_arguments(argv=None):
    """The command line, validated before anything starts: the case, its disturbance, gains and limits."""
    argv = sys.argv[1:] if argv is None else list(argv)
    refuse(given_options(argv))
    args = build_parser().parse_args(argv)
    refuse_foreign_scenario_options(args)
    args.net = net = load_network(args.case)
    args.scenario_object, args.description, _ = make_scenario(net, args)
    args.scenario_values = scenario_parameters(net, args.scenario_object, args.trip_line or ())
    name = args.law or controller_defaults()["law"]
    args.law = network_laws_of(args, net, args.reference, (name,))[name]
    args.gen_limits = generator_limits(args.gen_b, net.size)
    args.foxglove_address = demo_foxglove.foxglove_address(args)
    args.stream = stream_parameters(args, given_options(argv), float(net.f0_hz))
    for b in args.b:
        limits = battery_limits(net.size, b, args.gen_limits)
        check_ranges("network plant", plant_node_parameters(), network_plant_parameters(args, limits))
        for i in range(net.size):
            check_ranges("controller", controller_node_parameters(),
                         controller_parameters(net, i, limits[i], args.rate, args.law))
    return args


def network_plant_parameters(args, limits) -> dict:
    """The network plant's parameters for one run of battery limits ``limits``: the case, its disturbance, the
    run, its stream; it waits for each pmu's readers (the Rerun and Foxglove bridges among them)."""
    viewers = (args.rerun is not None) + (getattr(args, "foxglove_address", None) is not None)
    readers = demo_c37118.plant_readers(args.measurements, pmu_readers(args.net, args.reference), viewers)
    energy = {} if args.battery_energy_pu_s is None else {"battery_energy_pu_s": args.battery_energy_pu_s}
    return {**plant_parameters(args.case, args.scenario_values, args.mode, args.rate, args.duration, limits,
                               readers), "wait_for_recorders": 1 + viewers, **args.stream, **energy}


def controllers_parameters(args, limits) -> dict:
    """``{absolute namespace: controller parameters}`` of a run whose battery limits are ``limits``."""
    return {f"/{ns}": {**controller_parameters(args.net, i, limits[i], args.rate, args.law),
                       **demo_c37118.controller_parameters(args.measurements)} for i, ns in enumerate(namespaces(args.net))}


def check_ranges(node: str, specs, values: dict) -> None:
    """CliError for a value outside its node parameter's declared range (the node would refuse to start)."""
    for spec in specs:
        value = values.get(spec.name)
        if spec.low is None or isinstance(value, (bool, str)) or value is None:
            continue
        if not spec.low <= value <= spec.high:
            raise CliError(f"{node} parameter {spec.name} = {value:g} is outside {spec.low:g}..{spec.high:g}")


def b_text(b: float) -> str:
    return "inf" if math.isinf(b) else f"{b:g}"


def run_label(args, b: float) -> str:
    """``b = 0.1`` and, with --gen-b, the generators that differ: ``b = 0.1 (gen3 0.2)``."""
    others = ", ".join(f"gen{i + 1} {b_text(v)}" for i, v in sorted(args.gen_limits.items()))
    return f"b = {b_text(b)}" + (f" ({others})" if others else "")


def recording_name(args, b: float) -> str:
    """``<case>_<scenario>_b<b>[_gen<i>-<b_i>...].mcap``."""
    others = "".join(f"_gen{i + 1}-{b_text(v)}" for i, v in sorted(args.gen_limits.items()))
    return f"{args.case}_{args.scenario}_b{b_text(b)}{others}.mcap"


def run_metadata(args, plant: dict, controllers: dict) -> dict:
    """The recording's ``nni_run`` record: the case, the scenario, every node's parameters, mode, rate, version."""
    values = {key: value for key, value in args.scenario_values.items() if key != "scenario"}
    return {"case": args.case, "scenario": {"name": args.scenario, **values}, "network_plant": plant,
            "controllers": controllers, "deployment": args.deployment, "mode": args.mode, "rate_hz": args.rate,
            "measurements": args.measurements, "software_version": software_version()}


def generator_result(outcome_json: dict, loop: dict, counts: dict, namespace: str) -> dict:
    """One generator's entry in summary.json: its offline-style outcome, loop timing, counters, recorded counts."""
    return {**outcome_json, "samples": int(loop["samples"]),
            "latency_ms": {q: round(float(loop[f"latency_{q}_ms"]), 6) for q in ("p50", "p99", "max")
                           if f"latency_{q}_ms" in loop},
            "dropped_samples": int(loop["deadline_misses"]), "late_samples": int(loop["late"]),
            "trust": {key: int(loop[key]) for key in SHOWN_COUNTERS if key in loop},
            "max_abs_applied_power_pu": float(loop["max_abs_applied_power_pu"]),
            "paired_controller": loop["paired_controller"],
            "logger_counts": {topic: n for topic, n in counts.items() if topic.startswith(f"/{namespace}/")}}


def wait_for_bridge(bridge, index: int, runs: dict, logs: Path) -> None:
    """Wait until the Rerun bridge reports run ``index`` with every generator's answered samples of the recording."""
    expected = {ns: int(run.answered.sum()) for ns, run in runs.items()}

    def logged(line: str) -> tuple[int, dict]:
        report = json.loads(line[line.find(PROGRESS_PREFIX) + len(PROGRESS_PREFIX):])
        return report["run"], report.get("generators", {})

    def complete(line: str) -> bool:
        run, got = logged(line)
        return run == index and all(got.get(ns, 0) >= n for ns, n in expected.items())

    try:
        bridge.wait_for_line(PROGRESS_PREFIX, BRIDGE_WAIT_S, complete)
    except ChildError:
        got = {}
        for line in bridge.output().splitlines():
            if PROGRESS_PREFIX in line and logged(line)[0] == index:
                got = logged(line)[1]
        short = ", ".join(f"{ns} {got.get(ns, 0)} of {n}" for ns, n in expected.items() if got.get(ns, 0) < n)
        raise CliError(f"the Rerun stream is partial: the bridge logged {short} samples of run {index} within "
                       f"{BRIDGE_WAIT_S:g} s (logs in {logs})") from None


def run_one(args, b: float, env: dict, bridge=None, index: int = 1):
    """One run: logger, a controller per generator, the network plant; returns (summary entry, trajectory).

    With a Rerun ``bridge`` (run ``index`` of its stream) the plant waits for it too, and the run ends
    only when the bridge has logged every generator's recorded samples."""
    net, spaces = args.net, namespaces(args.net)
    limits = battery_limits(net.size, b, args.gen_limits)
    plant_params = network_plant_parameters(args, limits)
    controllers = controllers_parameters(args, limits)
    recording = args.out / recording_name(args, b)
    logs = args.out / "logs" / recording.stem
    started = time.monotonic()
    with run_key() as key, Supervisor(env, logs) as procs:
        foxglove = demo_foxglove.start_bridge(procs, args.foxglove_address, key_environment(key), {
            "run": index, "b": b, "gen_b": {f"gen{i + 1}": v for i, v in sorted(args.gen_limits.items())},
            "law": args.law.name, "case": args.case, "scenario": args.scenario, "deployment": args.deployment,
            "mode": args.mode}, logs)
        logger = procs.start_node("mcap_logger", "nni_msgs_adapter.recording.mcap_logger", {
            "output_path": str(recording), "discovery_period_s": 0.1,
            "run_metadata": json.dumps(run_metadata(args, plant_params, controllers))}, env=key_environment(key))
        started_controllers = start_controllers(procs, controllers, args.deployment, key_environment(key))
        # The plant holds its run until released: it starts beside the others, its release waits for the logger.
        plant = procs.start_node("network_plant", PLANT, plant_params, env=key_environment(key))
        writers = loop_writers(spaces, lambda ns: f"/{ns}/controller", "/network_plant")
        wait_for_recorder(logger, writers, logs)
        demo_foxglove.wait_streaming(foxglove, writers, logs, index, args.foxglove_wait)
        watch = StreamWatch(plant) if args.stream else None
        where = watch.listening() if watch is not None else None
        client = demo_c37118.start_client(procs, where, args.measurements, args.mode,
                                          pmu_readers(net, args.reference), [f"/{ns}" for ns in spaces],
                                          args.pmu_idcode, env=key_environment(key))
        start_when_read_back([*controller_readbacks(started_controllers, controllers, args.deployment),
                              (plant, {"/network_plant": expected_parameters(plant_node_parameters(), plant_params)}),
                              *stated_only(logger, client), *demo_foxglove.stated(foxglove)],
                             plant, logs, key)
        demo_c37118.wait_connected(client, run_label(args, b))
        finish_plant(procs, plant, args, run_label(args, b), SUMMARY_PREFIX, watch)
        for controller in started_controllers:
            controller.stop()
        if logger.stop() != 0:
            raise CliError(f"the logger {logger.how_it_ended()}: {logger.tail()}")
        wall_s = time.monotonic() - started
        counts = logger_counts(logger.output())
        loops = plant_summary(plant.output(), SUMMARY_PREFIX)
        for ns in spaces:
            check_complete(recording, counts.get(f"/{ns}/{contract.TOPIC_PMU}", 0), int(loops[ns]["measurements"]),
                           logs, f" to /{ns}")
            check_complete(recording, counts.get(f"/{ns}/{contract.TOPIC_BATTERY_COMMAND}", 0),
                           int(loops[ns]["commands"]), logs, f" from /{ns}'s controller",
                           "battery commands the plant received")
        runs = read_generator_runs(recording)
        if bridge is not None:
            wait_for_bridge(bridge, index, runs, logs)
        traj = network_trajectory(runs, net, [f"/{ns}" for ns in spaces], limits)
        outcome = assess_network(traj)[0]
        outcome_json = outcome.to_json()
        result = {"b": json_b(b), "gen_b": {f"gen{i + 1}": json_b(v) for i, v in sorted(args.gen_limits.items())},
                  "reference": args.reference, **{k: v for k, v in outcome_json.items() if k != "generators"},
                  "deployment": args.deployment, "mode": args.mode, "rate_hz": args.rate,
                  "measurements": args.measurements, "recording": str(recording),
                  "wall_time_s": round(wall_s, 3),
                  "generators": {ns: generator_result(g, loops[ns], counts, ns)
                                 for ns, g in zip(spaces, outcome_json["generators"])}}
        if args.battery_energy_pu_s is not None:  # the plant's own account of each battery
            for ns in spaces:
                result["generators"][ns]["battery"] = battery_block(args.battery_energy_pu_s, loops[ns])
        if watch is not None:
            result["c37118"] = watch.summary()
        compromised = {ns: reasons for i, ns in enumerate(spaces)
                       if (reasons := compromised_reasons(loops[ns], runs[f"/{ns}"], float(limits[i])))}
        if compromised:
            result["compromised"] = compromised
        # Judged with the bridge still up: the Foxglove stream ends with the verdict the demo prints.
        demo_foxglove.stream_verdict(foxglove, logs, {
            "run": index, "b": b, "case": args.case, "in_synchronism": bool(outcome.in_synchronism),
            "compromised": bool(compromised),
            "verdict": compromised_line(result, limits, spaces) if compromised else network_verdict(outcome)})
    return result, outcome, traj, limits


def loop_table(result: dict, net, limits) -> list[str]:
    """Per generator: its b, loop latency, dropped and late samples, and the plant's counters."""
    header = (f"  {'namespace':<9} {'generator':<9} {'b (pu)':>6}  {'latency p50/p99/max (ms)':>24} {'dropped':>7} "
              f"{'late':>4}  " + " ".join(key.replace("_commands", "").replace("_", " ") for key in SHOWN_COUNTERS))
    rows = [header]
    for i, (ns, g) in enumerate(result["generators"].items()):
        lat = g["latency_ms"]
        latency = "/".join(f"{lat.get(q, math.nan):.2f}" for q in ("p50", "p99", "max"))
        counters = " ".join(f"{g['trust'].get(key, 0):>{len(key.replace('_commands', '').replace('_', ' '))}}"
                            for key in SHOWN_COUNTERS)
        rows.append(f"  {'/' + ns:<9} {net.names[i]:<9} {b_text(float(limits[i])):>6}  {latency:>24} "
                    f"{g['dropped_samples']:>7} {g['late_samples']:>4}  {counters}")
    return rows


def clipped_lines(result: dict, limits) -> list[str]:
    """One line per generator whose commands the plant clipped to its battery's rating, b there."""
    return [f"  /{ns}: {g['trust']['clipped_commands']} command(s) beyond the battery's rating "
            f"(b = {b_text(float(limits[i]))} pu) were clipped to it"
            for i, (ns, g) in enumerate(result["generators"].items()) if g["trust"].get("clipped_commands", 0)]


def compromised_line(result: dict, limits, spaces) -> str:
    """``COMPROMISED (not a valid result): gen3: 2 foreign commands; ...``."""
    where = [f"/{ns}: {', '.join(compromised_words(float(limits[spaces.index(ns)]), reasons))}"
             for ns, reasons in result["compromised"].items()]
    return COMPROMISED_PREFIX + "; ".join(where)


def show_run(args, b: float, env: dict, bridge, index: int, plotted: list) -> dict:
    """Run b (stream run ``index`` to ``bridge`` if any), print its table and loops; its summary entry."""
    net, spaces = args.net, namespaces(args.net)
    result, outcome, traj, limits = run_one(args, b, env, bridge, index)
    plotted.append((f"{run_label(args, b)}, {args.mode}", traj, 0))
    if "compromised" in result:
        print(f"  {run_label(args, b)}: {compromised_line(result, limits, spaces)}")
    else:
        print(textwrap.indent(format_run(outcome, b, args.reference, net), "  "))
    print("\n".join(loop_table(result, net, limits) + clipped_lines(result, limits)))
    for ns, generator in result["generators"].items():
        if "battery" in generator:
            print(f"  /{ns}{battery_text(generator['battery'])}")
    print(f"  wall {result['wall_time_s']:.1f} s, recording {result['recording']}")
    if "c37118" in result:
        print(summary_line(result["c37118"]))
    return result


def main(argv=None) -> int:
    """``nni-demo --case ...`` (called by :func:`nni_battery_controller.demo_command.main`)."""

    def body():
        signal.signal(signal.SIGTERM, signal.default_int_handler)
        args = parse_arguments(argv)
        env, domain = run_environment(args)
        net, spaces = args.net, namespaces(args.net)
        # The logger and the plant, a Rerun bridge, the controllers: beyond 32, discovery is widened to cover them.
        env = with_participants(env, participants(net, args.deployment, 2 + (args.rerun is not None)
                                                  + (args.foxglove is not None)
                                                  + (args.measurements == "c37118")))
        deployment = ("a controller process each" if args.deployment == "separate"
                      else "their controllers composed in one process")
        print(f"{PROG}: {args.case}, {net.size} generators ({deployment}, /{spaces[0]} .. /{spaces[-1]}), {args.mode},"
              f" {args.rate:g} frames/s, {args.duration:g} s per run, domain {domain}"
              + (", measurements through C37.118" if args.measurements == "c37118" else ""))
        print(f"  {args.description}; g measured, angle reference {args.reference}; law {args.law.describe()}")
        if wait_text(args):
            print(f"  {wait_text(args)}")
        results, plotted = [], []
        sink = rerun_sink(args.rerun) if args.rerun else None
        with Supervisor(env, args.out) as viewer:
            bridge = start_viewer(viewer, sink, float(net.f0_hz), namespaces=[f"/{ns}" for ns in spaces],
                                  case=args.case, coi_weights=[float(m) for m in net.inertia_m]) if sink else None
            for index, b in enumerate(args.b, start=1):  # the bridge counts its runs from 1
                results.append(show_run(args, b, env, bridge, index, plotted))
            if sink and sink["sink"] == "serve":
                wait_for_interrupt("serving the Rerun stream; Ctrl-C to stop")
        summary = write_summary(args.out, {
            "case": args.case, "generators": list(net.names), "namespaces": list(spaces),
            "mbase_mva": net.mbase_mva.tolist(), "scenario": args.scenario_values, "description": args.description,
            "deployment": args.deployment, "mode": args.mode, "rate_hz": args.rate, "measurements": args.measurements,
            "runs": results})
        figure = args.out / "figures.png"
        plot_network(plotted, f"{args.case}: {args.description}; controllers {args.rate:g} Hz over ROS 2", figure)
        written = [str(summary), str(figure)] + ([sink["path"]] if sink and sink["sink"] == "save" else [])
        print(f"wrote {', '.join(written)} and {len(results)} recording(s) in {args.out}")
        return exit_status(PROG, results, "a battery was")

    return run_cli(body, PROG)
