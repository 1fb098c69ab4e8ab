"""``nni-simulate --case ...``: the saturated NNI law at every generator of a network, offline.

Runs one disturbance of a shipped test system (``kundur_two_area``, ``ieee39``)
or of a MATPOWER case file with its machine data, for each battery limit b
(pu of each machine's rating, the same at every generator) and each angle
reference, with the sampled-data H3-hat at every generator; prints one table
per run with per-generator verdicts, writes JSON and a figure; ``--cct`` finds
the critical clearing time of the bus fault per b instead, ``--delay-margin``
the largest fixed measurement-to-command delay that keeps the network in
synchronism. The runs take a communication link (``--link-*``, the same at
every generator, the draws its own per generator).
"""

from __future__ import annotations

import json
import math
import time

import numpy as np

from nni_battery_controller.cli import DEFAULT_DELAY_MAX_S, delay_margin_row, delay_search_text
from nni_battery_controller.figures import plot_network
from nni_battery_controller.network_sim import (
    ANGLE_REFERENCES,
    NetworkLaw,
    assess_network,
    critical_clearing_times,
    simulate_network,
)
from nni_battery_controller.options import add_link_options, link_of
from nni_battery_controller.margins import DELAY_MARGIN_TOLERANCE_S, DELAY_SCAN_STEP_S, delay_margins
from nni_msgs_adapter.ros.cli_support import (
    CliError,
    OneLineParser,
    atomic_output,
    battery_limit,
    finite_float,
    float_within,
    positive_float,
    run_cli,
    writable_output,
)
from nni_plant_sim.cases import CASES, DEFAULT_FAULT_BUS, load_network
from nni_plant_sim.network_scenarios import (
    NETWORK_SCENARIOS,
    SCENARIO_PARAMETERS as SCENARIO_OPTIONS,
    AngleDisplacement,
    BusFault,
    LineTrip,
    MechanicalStep,
)

DEFAULT_LIMITS = (0.0, 0.1, 0.3, math.inf)


def add_scenario_options(group) -> None:
    """The disturbance options of a network (``nni-simulate --case`` and ``nni-demo --case``)."""
    group.add_argument("--scenario", choices=NETWORK_SCENARIOS, default="bus_fault")
    group.add_argument("--fault-bus", type=int,
                       help="bus of the three-phase fault (default: 7 Kundur and kundur_ring_52, 16 IEEE 39)")
    group.add_argument("--fault-r", type=float_within(0.0, 1e6, "pu"), help="fault resistance, pu system base (0)")
    group.add_argument("--fault-x", type=finite_float, help="fault reactance, pu system base (0: bolted)")
    group.add_argument("--clearing-time", type=positive_float, help="fault duration, s (default 0.1)")
    group.add_argument("--trip-line", type=int, nargs="+", metavar="BUS",
                       help="FROM TO [CIRCUIT]: the branch that opens (at clearing, or at t = 0 for line_trip)")
    group.add_argument("--step-p-mech", type=float_within(0.0, 100.0, "pu"),
                       help="mechanical_step: the machine's P_m during the step, pu of its rating")
    group.add_argument("--step-duration", type=positive_float, help="mechanical_step: s (default: for good)")
    group.add_argument("--displace", type=finite_float, help="angle_displacement: rad added to --machine angles")
    group.add_argument("--machine", type=int, nargs="+", metavar="BUS",
                       help="generator bus(es) of mechanical_step (one) or angle_displacement")


def build_parser() -> OneLineParser:
    """The network part of the nni-simulate command line."""
    parser = OneLineParser(prog="nni-simulate", description=__doc__)
    parser.add_argument("--case", required=True,
                        help=f"a shipped case ({', '.join(CASES)}) or a MATPOWER .m file (with --machines, --f0)")
    parser.add_argument("--machines", help="machine data CSV for a MATPOWER case file (see nni_plant_sim/cases)")
    parser.add_argument("--f0", type=positive_float, help="nominal frequency, Hz (shipped cases: 60)")
    add_scenario_options(parser)
    parser.add_argument("--b", type=battery_limit, nargs="+", default=list(DEFAULT_LIMITS), metavar="B",
                        help="battery limits, pu of each machine's rating ('inf' allowed); default 0 0.1 0.3 inf")
    parser.add_argument("--reference", choices=ANGLE_REFERENCES, nargs="+", default=["pmu"],
                        help="controllers' angle reference: pmu (own angle vs nominal frequency) and/or coi")
    parser.add_argument("--tau", type=positive_float, nargs="+", default=[0.1], help="tau, s: one or per generator")
    parser.add_argument("--K", dest="gain_k", type=positive_float, nargs="+", default=[1.0],
                        help="K, pu of the rating per rad: one or per generator")
    parser.add_argument("--L", dest="gain_l", type=positive_float, nargs="+", default=[1.1],
                        help="L, pu of the rating per rad: one or per generator (K < L each)")
    parser.add_argument("--alpha", type=positive_float, nargs="+", default=[1.0], help="alpha: one or per generator")
    parser.add_argument("--controller-rate", type=float_within(10.0, 1000.0, "Hz"), default=50.0,
                        help="PMU / controller rate, Hz (default 50)")
    parser.add_argument("--duration", type=positive_float, default=10.0, help="simulated seconds (default 10)")
    parser.add_argument("--cct", action="store_true",
                        help="critical clearing time of the bus fault per b (bisection to 1 ms), instead of runs")
    parser.add_argument("--cct-max", type=float_within(0.002, 5.0, "s"), default=1.0,
                        help="--cct: longest clearing time tried, s (default 1)")
    parser.add_argument("--delay-margin", action="store_true",
                        help="the largest fixed measurement-to-command delay (the link's) that keeps the network in "
                             "synchronism per b and reference, instead of runs: scan by --delay-step up to "
                             f"--delay-max, then bisection to {DELAY_MARGIN_TOLERANCE_S * 1e3:g} ms")
    parser.add_argument("--delay-max", type=float_within(1e-3, 10.0, "s"), metavar="S",
                        help=f"--delay-margin: longest delay tried, s (default {DEFAULT_DELAY_MAX_S:g})")
    parser.add_argument("--delay-step", type=float_within(1e-3, 10.0, "s"), metavar="S",
                        help=f"--delay-margin: step of the scan, s (default {DELAY_SCAN_STEP_S:g})")
    parser.add_argument("--json", type=writable_output, help="write the results as JSON here")
    parser.add_argument("--plot", type=writable_output, help="write angles, frequencies, battery powers as PNG")
    add_link_options(parser)
    return parser


def _refuse_foreign_options(args) -> None:
    for option, scenarios in SCENARIO_OPTIONS.items():
        if getattr(args, option) is not None and args.scenario not in scenarios:
            raise CliError(f"--{option.replace('_', '-')} does not apply to --scenario {args.scenario}")
    if args.cct and args.scenario != "bus_fault":
        raise CliError("--cct applies to --scenario bus_fault only")
    if args.cct and args.plot:
        raise CliError("--plot does not apply to --cct (it draws time series of runs)")
    if args.cct and args.clearing_time is not None:
        raise CliError("--clearing-time does not apply to --cct (it searches the clearing time)")
    if args.delay_margin:
        for flag in ("cct", "plot", "link_delay"):
            if getattr(args, flag):
                raise CliError(f"--delay-margin searches the link's fixed delay and prints a table (and --json): "
                               f"it takes no --{flag.replace('_', '-')}")
        args.delay_max = DEFAULT_DELAY_MAX_S if args.delay_max is None else args.delay_max
        args.delay_step = DELAY_SCAN_STEP_S if args.delay_step is None else args.delay_step
        if args.delay_step > args.delay_max:
            raise CliError(f"--delay-step {args.delay_step:g} s is longer than --delay-max {args.delay_max:g} s")
    for flag in ("delay_max", "delay_step"):
        if getattr(args, flag) is not None and not args.delay_margin:
            raise CliError(f"--{flag.replace('_', '-')} applies to --delay-margin only")


def _machine_index(net, bus: int) -> int:
    where = np.flatnonzero(net.gen_bus == bus)
    if where.size != 1:
        raise CliError(f"--machine {bus}: no generator at that bus (generators at {', '.join(map(str, net.gen_bus))})")
    return int(where[0])


def _trip(net, values):
    if values is None:
        return ()
    if len(values) not in (2, 3):
        raise CliError("--trip-line takes FROM TO [CIRCUIT]")
    return (net.bus_model.branch_index(*values),)


def make_scenario(net, args):
    """The scenario object and a one-line description of it; a factory of bus faults for --cct."""
    if args.scenario in ("bus_fault", "line_trip"):
        trip = _trip(net, args.trip_line)
        trip_text = f", trip {'-'.join(map(str, args.trip_line))}" if trip else ""
    if args.scenario == "bus_fault":
        bus = args.fault_bus if args.fault_bus is not None else DEFAULT_FAULT_BUS.get(args.case)
        if bus is None:
            raise CliError("--fault-bus is needed for a case file")
        net.bus_model.bus_index(bus)
        impedance = complex(args.fault_r or 0.0, args.fault_x or 0.0)
        clearing = 0.1 if args.clearing_time is None else args.clearing_time

        def factory(clearing_s):
            return BusFault(net, bus, clearing_s, impedance, trip)

        return factory(clearing), f"bus fault at bus {bus} (Z = {impedance:g} pu), cleared at {clearing:g} s" \
                                  f"{trip_text}", factory
    if args.scenario == "line_trip":
        if not trip:
            raise CliError("--scenario line_trip needs --trip-line FROM TO [CIRCUIT]")
        return LineTrip(net, trip), f"line trip{trip_text}", None
    if args.machine is None:
        raise CliError(f"--scenario {args.scenario} needs --machine BUS")
    machines = [_machine_index(net, bus) for bus in args.machine]
    if args.scenario == "mechanical_step":
        if len(machines) != 1 or args.step_p_mech is None:
            raise CliError("--scenario mechanical_step needs one --machine BUS and --step-p-mech PU")
        duration = math.inf if args.step_duration is None else args.step_duration
        p_mech = float(net.pu_of_machine(np.full(net.size, args.step_p_mech))[machines[0]])
        return MechanicalStep(machines[0], p_mech, duration), \
            f"P_m of {net.names[machines[0]]} to {args.step_p_mech:g} pu for {duration:g} s", None
    if args.displace is None:
        raise CliError("--scenario angle_displacement needs --displace RAD")
    displacement = np.zeros(net.size)
    displacement[machines] = args.displace
    return AngleDisplacement(displacement), \
        f"angles of {', '.join(net.names[i] for i in machines)} displaced by {args.displace:g} rad", None


def _num(value, fmt="{:.3f}"):
    return "-" if value is None else fmt.format(value)


def _b_text(b, net) -> str:
    return "b = inf (unsaturated)" if math.isinf(b) else ("b = 0 (no battery)" if b == 0 else f"b = {b:g} pu")


def format_run(outcome, b, reference, net) -> str:
    """One run's table: the system verdict line, then one row per generator."""
    verdict = ("in synchronism" if outcome.in_synchronism else f"LOST SYNCHRONISM at {outcome.pole_slip_s:.2f} s") \
        + (", settled" if outcome.settled else ", not settled")
    head = f"{_b_text(b, net)}, reference {reference}: {verdict} (max angle spread " \
           f"{math.degrees(outcome.max_angle_spread_rad):.1f} deg, final COI frequency deviation " \
           f"{outcome.final_coi_frequency_hz:+.3f} Hz)"
    header = f"  {'generator':<9} {'in sync':>7} {'settled':>7} {'settle (s)':>10} {'max|P_ST| (pu)':>14} " \
             f"{'max|P_ST| (MW)':>14} {'last sat (s)':>12}"
    rows = [head, header, "  " + "-" * (len(header) - 2)]
    for g in outcome.generators:
        rows.append(f"  {g.name:<9} {('yes' if g.in_synchronism else 'NO'):>7} {('yes' if g.settled else 'no'):>7} "
                    f"{_num(g.settling_time_s):>10} {g.max_abs_battery_power_pu:>14.4f} "
                    f"{g.max_abs_battery_power_mw:>14.1f} {_num(g.last_saturated_s):>12}")
    return "\n".join(rows)


def _json_b(b):
    return "inf" if math.isinf(b) else b


def main(argv=None) -> int:
    """Entry point of ``nni-simulate --case ...``."""
    parser = build_parser()

    def body():
        args = parser.parse_args(argv)
        _refuse_foreign_options(args)
        started = time.perf_counter()
        net = load_network(args.case, args.machines, args.f0)
        scenario, description, factory = make_scenario(net, args)
        laws = {ref: NetworkLaw.uniform(net, args.tau, args.gain_k, args.gain_l, args.alpha, ref)
                for ref in args.reference}
        link = link_of(args)
        title = f"{args.case}: {description}; controller {args.controller_rate:g} Hz"
        result = {"case": args.case, "generators": list(net.names), "mbase_mva": net.mbase_mva.tolist(),
                  "scenario": args.scenario, "description": description, "rate_hz": args.controller_rate}
        if link.active or args.delay_margin:
            result["link"] = link.to_json() | ({"delay_s": "searched"} if args.delay_margin else {})
        if args.delay_margin:
            print(f"{args.case}: delay margin, {description}; controller {args.controller_rate:g} Hz; the longest "
                  f"fixed delay from a measurement to its command taking effect (every generator) that keeps every "
                  f"pair of generators within 180 degrees (in synchronism) over {args.duration:g} s")
            print(delay_search_text(args.delay_step, args.delay_max))
            if link.active:
                print(f"on top of the delay: {link.describe()}")
            print(f"  {'reference':>9} {'b (pu)':>7} {'margin (ms)':>12} {'slips at (ms)':>14} {'runs':>5}  result")
            result.update(delay_margin=[], tolerance_s=DELAY_MARGIN_TOLERANCE_S, scan_step_s=args.delay_step,
                          searched_up_to_s=args.delay_max, duration_s=args.duration,
                          criterion="in synchronism: no pair of generators ever more than 180 degrees apart")
            for ref, law in laws.items():
                def in_sync(delay_s, indices, law=law):
                    traj = simulate_network(net, law, scenario, [args.b[i] for i in indices], args.duration,
                                            args.controller_rate, drop_lost_runs=True,
                                            link=link.with_delay(delay_s))
                    return [outcome.in_synchronism for outcome in assess_network(traj)]

                for margin in delay_margins(in_sync, args.b, args.delay_step, args.delay_max):
                    print(delay_margin_row(margin, f"  {ref:>9} "), flush=True)
                    result["delay_margin"].append({"reference": ref, **margin.to_json()})
        elif args.cct:
            print(f"{args.case}: critical clearing time of the {description.split(', cleared')[0]}"
                  f"{', with the trip' if args.trip_line else ''}; {args.duration:g} s runs, controller "
                  f"{args.controller_rate:g} Hz")
            print(f"  {'b (pu)':>7} {'reference':>9} {'CCT (s)':>9}")
            result["cct"] = []
            for ref, law in laws.items():
                found = critical_clearing_times(net, law, factory, args.b, args.duration, args.controller_rate,
                                                high_s=args.cct_max, link=link)
                for b, (cct, bracket, open_top) in zip(args.b, found):
                    text = "none" if cct is None else (f">= {cct:.3f}" if open_top else f"{cct:.3f}")
                    print(f"  {b:>7g} {ref:>9} {text:>9}")
                    result["cct"].append({"b": _json_b(b), "reference": ref, "cct_s": cct,
                                          "bracket_s": list(bracket), "at_search_limit": bool(open_top)})
        else:
            print(f"{title}, {args.duration:g} s" + (f"; {link.describe()}" if link.active else ""))
            result["runs"] = []
            plotted = []
            for ref, law in laws.items():
                traj = simulate_network(net, law, scenario, args.b, args.duration, args.controller_rate, link=link)
                for r, (b, outcome) in enumerate(zip(args.b, assess_network(traj))):
                    print(format_run(outcome, b, ref, net))
                    result["runs"].append({"b": _json_b(b), "reference": ref, **outcome.to_json()})
                    plotted.append((f"{_b_text(b, net)}, {ref}", traj, r))
        elapsed = time.perf_counter() - started
        print(f"({elapsed:.1f} s)")
        if args.json:
            with atomic_output(args.json) as handle:
                json.dump(result, handle, indent=2)
                handle.write("\n")
            print(f"wrote {args.json}")
        if args.plot:
            plot_network(plotted, title, args.plot)
            print(f"wrote {args.plot}")
        return 0

    return run_cli(body, parser.prog)
