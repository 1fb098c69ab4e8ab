"""``nni-simulate --case ...``: a battery law (the saturated NNI law by default) at every generator of a network, offline.

Runs one disturbance of a shipped test system (``kundur_two_area``, ``ieee39``)
or of a MATPOWER case file with its machine data, for each battery limit b
(pu of each machine's rating, the same at every generator) and each angle
reference, with the sampled-data H3-hat at every generator; prints one table
per run with per-generator verdicts, writes JSON and a figure; ``--cct`` finds
the critical clearing time of the bus fault per b instead, ``--delay-margin``
the largest fixed measurement-to-command delay that keeps the network in
synchronism, ``--compare-laws`` every battery law side by side (the run's verdict,
settling, battery energy and saturation, and the CCT, per b and reference:
:mod:`nni_battery_controller.law_comparison`). The runs take a communication link (``--link-*``, the same at
every generator, the draws its own per generator). ``--screen`` screens every
contingency of the case instead (:mod:`nni_battery_controller.screen_study`).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from nni_battery_controller import screen_study
from nni_battery_controller.figures import plot_network, save_png
from nni_battery_controller.law_comparison import comparison_figure, compare_network, format_network_rows
from nni_battery_controller.laws import LAW_NAMES
from nni_battery_controller.margins import DELAY_MARGIN_TOLERANCE_S, DELAY_SCAN_STEP_S, delay_margins
from nni_battery_controller.network_common import (
    DEFAULT_LIMITS,
    add_scenario_options,
    format_run,
    json_b,
    limit_words,
    make_scenario,
    refuse_foreign_scenario_options,
)
from nni_battery_controller.network_sim import (
    ANGLE_REFERENCES,
    assess_network,
    critical_clearing_times,
    simulate_network,
)
from nni_battery_controller.options import (
    add_link_options,
    add_network_law_options,
    given_link_options,
    link_of,
    network_laws_of,
)
from nni_battery_controller.study_common import (
    DEFAULT_DELAY_MAX_S,
    delay_margin_row,
    delay_search_lines,
    link_json,
    refuse_beside_delay_margin,
    resolve_delay_span,
)
from nni_msgs_adapter.ros.cli_support import (
    CliError,
    OneLineParser,
    battery_limit,
    float_within,
    positive_float,
    positive_int,
    run_cli,
    writable_output,
    write_json,
)
from nni_msgs_adapter.ros.defaults import controller_defaults
from nni_plant_sim.cases import CASES, load_network


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
    add_network_law_options(parser)
    parser.add_argument("--controller-rate", type=float_within(10.0, 1000.0, "Hz"), default=50.0,
                        help="PMU / controller rate, Hz (default 50)")
    parser.add_argument("--duration", type=positive_float, default=10.0, help="simulated seconds (default 10)")
    parser.add_argument("--cct", action="store_true",
                        help="critical clearing time of the bus fault per b (bisection to 1 ms), instead of runs")
    parser.add_argument("--cct-max", type=float_within(0.002, 5.0, "s"), default=1.0,
                        help="--cct: longest clearing time tried, s (default 1)")
    parser.add_argument("--compare-laws", action="store_true",
                        help=f"every battery law ({', '.join(LAW_NAMES)}) per b and reference, instead of runs: the "
                             "bus fault's verdict, settling time, battery energy (MWh), time saturated and CCT "
                             "(as --cct); a table, --json, --plot the CCT against b (default: off)")
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
    screen = parser.add_argument_group(
        "--screen: every contingency of the case, its critical clearing time per b and law (bisection as --cct; "
        "--clearing-time is then the clearing time of each row's verdict, default 0.1 s)")
    screen.add_argument("--screen", action="store_true",
                        help="screen the case's contingencies instead of runs (docs/screening.md)")
    screen.add_argument("--contingencies", nargs="+", metavar="WHAT",
                        help="bus, line (both, by default), and/or contingencies by name: bus:B, line:F-T[:C]@E "
                             "(E the faulted end; comma-separated or several words)")
    screen.add_argument("--contingency-file", type=Path, metavar="FILE",
                        help="contingencies to screen, one name a line as --contingencies takes them (# comments)")
    screen.add_argument("--laws", nargs="+", metavar="LAW", help="the battery laws screened (default: nni)")
    screen.add_argument("--workers", type=_workers, metavar="N",
                        help="worker processes of the LocalCluster started here (default: one per core); 0: no "
                             "cluster, every task in this process (the serial path)")
    screen.add_argument("--scheduler", metavar="ADDRESS",
                        help="run on the Dask cluster of this scheduler (tcp://HOST:8786) instead of a LocalCluster")
    screen.add_argument("--out", type=Path, metavar="DIR",
                        help="write each finished task's rows here as it ends (Parquet), the manifest, the heat "
                             "map and the gain chart; an empty or new folder")
    screen.add_argument("--resume", action="store_true",
                        help="continue the screen in --out: compute only the contingencies not written there")
    screen.add_argument("--weakest", type=positive_int, metavar="N",
                        help=f"rows per b and law in the table of weakest contingencies (default "
                             f"{screen_study.DEFAULT_WEAKEST})")
    screen.add_argument("--chunk", type=positive_int, metavar="N",
                        help="contingencies per task (default 1: each task is every b and law of one contingency)")
    return parser


def _workers(text: str) -> int:
    """argparse type: a worker count, 0 (the serial path) to 512."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 512:
        raise argparse.ArgumentTypeError(f"expected a worker count 0..512, got {text!r}")
    return value


def _refuse_foreign_options(args) -> None:
    screen_study.refuse_screen_options(args)
    refuse_foreign_scenario_options(args)
    if args.cct and args.scenario != "bus_fault":
        raise CliError("--cct applies to --scenario bus_fault only")
    if args.cct and args.plot:
        raise CliError("--plot does not apply to --cct (it draws time series of runs)")
    if args.cct and args.clearing_time is not None:
        raise CliError("--clearing-time does not apply to --cct (it searches the clearing time)")
    if args.compare_laws:
        for flag in ("cct", "delay_margin", "law"):
            if getattr(args, flag):
                raise CliError(f"--compare-laws runs every law: it takes no --{flag.replace('_', '-')}")
        if args.scenario != "bus_fault":
            raise CliError("--compare-laws applies to --scenario bus_fault only (its CCT is the bus fault's)")
        if given_link_options(args):
            raise CliError("--compare-laws runs every law without a link: it takes no --link-* option")
    if args.delay_margin:
        refuse_beside_delay_margin(args, ("cct", "plot", "link_delay"))
    resolve_delay_span(args)


def run_compare_laws(args, net, scenario, description, factory, started: float) -> int:
    """``--case CASE --compare-laws``: every law per reference and b, the bus fault's run and its CCT."""
    laws = {ref: list(network_laws_of(args, net, ref, LAW_NAMES).values()) for ref in args.reference}
    print(f"Battery laws compared, {args.case}: {description}; every law sampled at {args.controller_rate:g} Hz at "
          f"every generator (b the same at each), {args.duration:g} s; CCT: the bus fault's (as --cct, up to "
          f"{args.cct_max:g} s, 1 ms); energy: integral of |P_ST| dt over every battery")
    for law in laws[args.reference[0]]:
        print(f"  {law.describe()}")

    def simulate_runs(law):
        traj = simulate_network(net, law, scenario, args.b, args.duration, args.controller_rate)
        return traj, assess_network(traj)

    def ccts_of(law):
        return critical_clearing_times(net, law, factory, args.b, args.duration, args.controller_rate,
                                       high_s=args.cct_max)

    rows = compare_network(args.b, laws, simulate_runs, ccts_of)
    print(format_network_rows(rows))
    print("settle: the last generator to settle; saturated: the longest any battery was at +-b; a run that lost "
          "synchronism: energy and saturation up to its pole slip; CCT none: even the shortest clearing time loses "
          "synchronism")
    print(f"({time.perf_counter() - started:.1f} s)")
    if args.json:
        write_json(args.json, {"case": args.case, "generators": list(net.names), "mbase_mva": net.mbase_mva.tolist(),
                               "scenario": args.scenario, "description": description,
                               "rate_hz": args.controller_rate, "duration_s": args.duration,
                               "cct_max_s": args.cct_max, "tolerance_s": 1e-3, "rows": rows})
        print(f"wrote {args.json}")
    if args.plot:
        save_png(comparison_figure(rows, f"{args.case}: critical clearing time per battery law, sampled at "
                                         f"{args.controller_rate:g} Hz"), args.plot)
        print(f"wrote {args.plot}")
    return 0


def main(argv=None) -> int:
    """``nni-simulate --case ...`` (called by :func:`nni_battery_controller.simulate_command.main`)."""
    parser = build_parser()

    def body():
        args = parser.parse_args(argv)
        _refuse_foreign_options(args)
        if args.screen:
            return screen_study.run_screen(args)
        started = time.perf_counter()
        net = load_network(args.case, args.machines, args.f0)
        scenario, description, factory = make_scenario(net, args)
        if args.compare_laws:
            return run_compare_laws(args, net, scenario, description, factory, started)
        name = args.law or controller_defaults()["law"]
        laws = {ref: network_laws_of(args, net, ref, (name,))[name] for ref in args.reference}
        link = link_of(args)
        law_text = laws[args.reference[0]].describe()
        title = f"{args.case}: {description}; controller {args.controller_rate:g} Hz, law {law_text}"
        result = {"case": args.case, "generators": list(net.names), "mbase_mva": net.mbase_mva.tolist(),
                  "scenario": args.scenario, "description": description, "rate_hz": args.controller_rate,
                  "law": name, "law_gains": laws[args.reference[0]].laws()[0].gain_values()}
        result.update(link_json(link, delay_searched=args.delay_margin))
        if args.delay_margin:
            print(f"{args.case}: delay margin, {description}; controller {args.controller_rate:g} Hz, law {law_text}; the longest "
                  f"fixed delay from a measurement to its command taking effect (every generator) that keeps every "
                  f"pair of generators within 180 degrees (in synchronism) over {args.duration:g} s")
            print("\n".join(delay_search_lines(args.delay_step, args.delay_max, link, f"  {'reference':>9} ")))
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
                  f"{args.controller_rate:g} Hz, law {law_text}")
            print(f"  {'b (pu)':>7} {'reference':>9} {'CCT (s)':>9}")
            result["cct"] = []
            for ref, law in laws.items():
                found = critical_clearing_times(net, law, factory, args.b, args.duration, args.controller_rate,
                                                high_s=args.cct_max, link=link)
                for b, (cct, bracket, open_top) in zip(args.b, found):
                    text = "none" if cct is None else (f">= {cct:.3f}" if open_top else f"{cct:.3f}")
                    print(f"  {b:>7g} {ref:>9} {text:>9}")
                    result["cct"].append({"b": json_b(b), "reference": ref, "cct_s": cct,
                                          "bracket_s": list(bracket), "at_search_limit": bool(open_top)})
        else:
            print(f"{title}, {args.duration:g} s" + (f"; {link.describe()}" if link.active else ""))
            result["runs"] = []
            plotted = []
            for ref, law in laws.items():
                traj = simulate_network(net, law, scenario, args.b, args.duration, args.controller_rate, link=link)
                for r, (b, outcome) in enumerate(zip(args.b, assess_network(traj))):
                    print(format_run(outcome, b, ref, net))
                    result["runs"].append({"b": json_b(b), "reference": ref, **outcome.to_json()})
                    plotted.append((f"{limit_words(b)}, {ref}", traj, r))
        elapsed = time.perf_counter() - started
        print(f"({elapsed:.1f} s)")
        if args.json:
            write_json(args.json, result)
            print(f"wrote {args.json}")
        if args.plot:
            plot_network(plotted, title, args.plot)
            print(f"wrote {args.plot}")
        return 0

    return run_cli(body, parser.prog)
