"""``nni-simulate``: the paper's closed-loop study offline, as a table, JSON and figures.

By default runs the paper's case (H=4, D=0, P_M=0.8, P_max=1, f0=50 Hz,
delta(0)=0.2 rad; tau=0.1, K=1, L=1.1, alpha=1) for b in {0, 0.2, 0.3, inf}.
Defaults are the nodes' (the package config files). Each run gets two verdicts:
in synchronism (the rotor angle never passed +-180 degrees, a pole slip) and
settled (|delta - delta_bar| <= 0.02 rad for at least half a swing period at
the end); stable means both. A run out of reach (estimated from duration, rate and
the loop's fastest rate) is refused before any work.

The sampled-data runs take a communication link (--link-delay, --link-jitter,
--link-loss, --link-seed: what the plant nodes' link_* parameters model);
--delay-margin finds, per b, the largest fixed measurement-to-command delay
that keeps the run in synchronism.

A network of generators, with the same law at every generator, instead:
nni-simulate --case kundur_two_area|ieee39|kundur_ring_52|FILE.m ...; its
options: nni-simulate --case CASE --help.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

from nni_battery_controller.figures import plot_runs, roa_figure, save_png
from nni_battery_controller.law_comparison import (
    MWH_PER_PU_S_100MVA,
    basin_entries,
    compare,
    comparison_figure,
    format_rows,
)
from nni_battery_controller.law_tuning import BUDGET, format_results, tune
from nni_battery_controller.laws import LAW_NAMES
from nni_battery_controller.margins import (
    CCT_TOLERANCE_S,
    DELAY_MARGIN_TOLERANCE_S,
    DELAY_SCAN_STEP_S,
    critical_clearing_time,
    delay_margins,
    equal_area_clearing_time_s,
)
from nni_battery_controller.options import (
    PAPER_BATTERY_LIMITS,
    add_energy_option,
    add_link_options,
    add_model_options,
    given_link_options,
    link_of,
    resolve_model,
)
from nni_battery_controller.law_roa import COMPARISON_GRID, roa_description, sampled_basin
from nni_battery_controller.roa import RETURNS, STEP_S as ROA_STEP_S, RoaGrid, report, sweep
from nni_battery_controller.simulate import fastest_rate_per_s, simulate_continuous, simulate_sampled
from nni_battery_controller.study_common import (
    DEFAULT_DELAY_MAX_S,
    delay_margin_row,
    delay_search_lines,
    link_json,
    refuse_beside_delay_margin,
    resolve_delay_span,
)
from nni_battery_controller.verdicts import SETTLE_BAND_RAD, assess, number_or_dash, verdict_text
from nni_msgs_adapter.ros.cli_support import (
    CliError,
    OneLineParser,
    battery_limit,
    float_within,
    positive_float,
    run_cli,
    writable_output,
    write_json,
)
from nni_msgs_adapter.ros.defaults import plant_defaults
from nni_plant_sim.link import NO_LINK
from nni_plant_sim.model import SmibParams, restoring_power
from nni_plant_sim.scenarios import TransferLimitFault

#: Output step of the continuous runs, s (as simulate_continuous's default).
OUTPUT_STEP_S = 1e-3
#: Bounds on one command's work, checked before any: samples kept (memory, ~100 B each),
#: continuous work (duration x the loop's fastest rate, summed over the runs; 1e5 is
#: some 10 s of integration) and sampled RK4 steps (about 2 us each).
MAX_SAMPLES = 1_000_000
MAX_CONTINUOUS_WORK = 1e5
MAX_RK4_STEPS = 5_000_000
#: RK4 diverges on the swing beyond h * rate of about 2.8; refused beyond this.
RK4_STABLE_STEP_RATE = 2.5
#: Exit status after SIGPIPE (a closed pipe, e.g. ``| head``), as a shell reports a process it killed.
EXIT_BROKEN_PIPE = 141


_sampling_rate_hz = float_within(10.0, 10_000.0, "Hz or 'continuous'")
#: --controller-rate as given for the continuous law (None once the options are resolved; None on the parser: not given).
CONTINUOUS = "continuous"


def controller_rate(text: str):
    """argparse type: ``continuous`` or a sampling rate in Hz (10 to 10000)."""
    return CONTINUOUS if text == CONTINUOUS else _sampling_rate_hz(text)


#: Largest --roa grid per axis: 1000 x 1000 cells hold about 0.2 GB of state during the sweep.
ROA_GRID_MAX = 1000
#: Defaults of the options that only --roa takes (None on the parser, so that one given without --roa is refused).
ROA_DEFAULTS = {"roa_grid": 200, "roa_speed_max": 10.0}
DEFAULT_DURATION_S = 10.0


def roa_grid_size(text: str) -> int:
    """argparse type: cells per axis of the --roa grid, an integer 10 to ROA_GRID_MAX."""
    try:
        size = int(text)
    except ValueError:
        size = 0
    if not 10 <= size <= ROA_GRID_MAX:
        raise argparse.ArgumentTypeError(f"grid size must be an integer 10..{ROA_GRID_MAX}, got {text!r}")
    return size


def build_parser() -> OneLineParser:
    """The nni-simulate command line."""
    parser = OneLineParser(prog="nni-simulate", description=__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--b", type=battery_limit, nargs="+", default=list(PAPER_BATTERY_LIMITS),
                        metavar="B", help="battery power limits in pu (numbers >= 0 or 'inf'); default: 0 0.2 0.3 inf")
    parser.add_argument("--duration", type=positive_float, default=None,
                        help=f"simulated seconds (default: {DEFAULT_DURATION_S:g}); --roa has its own horizon")
    parser.add_argument("--controller-rate", type=controller_rate, default=None,
                        help="'continuous' (default) or the sampled-data controller rate in Hz")
    add_energy_option(parser, "sampled runs, --cct, --compare-laws")
    parser.add_argument("--json", type=writable_output, help="write the per-scenario summary as JSON here (default: none)")
    parser.add_argument("--plot", type=writable_output, help="write the paper's two figures as one PNG here (default: none)")
    parser.add_argument("--cct", action="store_true",
                        help="instead of one run per b: the critical clearing time of the transfer_limit_fault per b, "
                             "by bisection to 1 ms (in synchronism over --duration), printed and in --json as cct_s")
    parser.add_argument("--compare-laws", action="store_true",
                        help="every battery law (nni, nni-unsaturated, droop, vsm, pss) per b, sampled at the PMU "
                             "rate: verdict, settling, battery energy, time in saturation, the transfer-limit "
                             "fault's CCT and the region of attraction on a 41 x 41 grid; a table, --json, --plot "
                             "(CCT and ROA area against b per law); docs/laws.md (default: off)")
    parser.add_argument("--tune-laws", action="store_true",
                        help="the fair-tuning search behind the shipped gains: per law the same number of candidate "
                             "gains, each run and its transfer-limit fault's CCT found; the law's pick: the longest "
                             "CCT among the candidates whose run settles (ties: less battery energy); at one --b "
                             "(default 0.3); a table and --json; docs/laws.md (default: off)")
    parser.add_argument("--delay-margin", action="store_true",
                        help="instead of one run per b: the largest fixed measurement-to-command delay (the link's) "
                             "that keeps the sampled-data loop in synchronism over --duration, per b; a scan in "
                             "steps of --delay-step up to --delay-max, then bisection to "
                             f"{DELAY_MARGIN_TOLERANCE_S * 1e3:g} ms; printed and in --json (controller rate: "
                             "--controller-rate, default the plant node's pmu_rate_hz)")
    parser.add_argument("--delay-max", type=float_within(1e-3, 10.0, "s"), metavar="S",
                        help=f"--delay-margin: longest delay tried, s (default {DEFAULT_DELAY_MAX_S:g})")
    parser.add_argument("--delay-step", type=float_within(1e-3, 10.0, "s"), metavar="S",
                        help=f"--delay-margin: step of the scan before the bisection, s (default {DELAY_SCAN_STEP_S:g})")
    parser.add_argument("--roa", type=writable_output, metavar="PREFIX",
                        help="instead of the time-domain run: region of attraction of each b on a grid of initial "
                             "conditions, written to PREFIX.png (basins, Omega, EAC) and PREFIX.json (basin areas); "
                             "default: none")
    parser.add_argument("--roa-grid", type=roa_grid_size, default=None, metavar="N",
                        help=f"--roa: N x N initial conditions (10 to {ROA_GRID_MAX}, default: {ROA_DEFAULTS['roa_grid']})")
    parser.add_argument("--roa-speed-max", type=positive_float, default=None,
                        help=f"--roa: initial speed deviations within +-this, rad/s (default: "
                             f"{ROA_DEFAULTS['roa_speed_max']:g}); angles within +-pi")
    add_model_options(parser)
    add_link_options(parser)
    return parser


def controller_text(rate_hz) -> str:
    """``continuous`` or ``sampled at 50 Hz``: the controller a run used."""
    return "continuous" if rate_hz is None else f"sampled at {rate_hz:g} Hz"


def check_work(plant: SmibParams, ctrls, duration_s: float, rate_hz, runs_per_b: int = 1) -> None:
    """CliError, before any work, when the runs would be out of reach in time or memory.

    Estimated from the duration, the controller rate and the loop's fastest
    rate (:func:`fastest_rate_per_s`): samples kept, continuous integration
    work, sampled RK4 steps, and RK4's stability on the plant's swing.
    """
    samples = duration_s / (OUTPUT_STEP_S if rate_hz is None else 1.0 / rate_hz)
    if samples > MAX_SAMPLES:
        raise CliError(f"out of reach: --duration {duration_s:g} s keeps {samples:.3g} samples per run "
                       f"(limit {MAX_SAMPLES:g}); shorten --duration")
    if rate_hz is None:
        rates = [fastest_rate_per_s(plant, ctrl) for ctrl in ctrls]
        work = runs_per_b * duration_s * sum(rates)
        if work > MAX_CONTINUOUS_WORK:
            raise CliError(f"out of reach: the loop's fastest rate is {max(rates):.3g}/s (1/tau, alpha/K, "
                           f"sqrt((P_max + L)/M) or D/M), so {duration_s:g} s continuous needs about {work:.3g} "
                           f"integrator steps (limit {MAX_CONTINUOUS_WORK:g}); shorten --duration or use "
                           f"--controller-rate")
        return
    step = min(plant_step_s(), 1.0 / rate_hz)
    swing = math.sqrt((abs(plant.p_max_pu) + max(ctrl.gain_l for ctrl in ctrls)) / plant.inertia_m)
    if step * swing > RK4_STABLE_STEP_RATE:
        raise CliError(f"out of reach: the swing's rate {swing:.3g}/s is too fast for the plant's {step:g} s RK4 "
                       f"step (it would diverge); check --H, --P-max, --L")
    steps = runs_per_b * len(ctrls) * duration_s / step
    if steps > MAX_RK4_STEPS:
        raise CliError(f"out of reach: {steps:.3g} RK4 steps (limit {MAX_RK4_STEPS:g}); shorten --duration")


def plant_step_s() -> float:
    """Largest RK4 step of the sampled runs' plant, s: the plant node's (``integration_step_s`` of its YAML)."""
    return plant_defaults()["integration_step_s"]


def simulate(plant, law, scenario, duration_s, rate_hz, link=NO_LINK, energy_pu_s=math.inf):
    """One run of ``law`` (a :class:`.laws.Law`): the continuous nni law, or the sampled law at ``rate_hz`` (through
    ``link``, with a battery of ``energy_pu_s``)."""
    if rate_hz is None:
        return simulate_continuous(plant, law.ctrl, scenario, duration_s, OUTPUT_STEP_S)
    return simulate_sampled(plant, law.ctrl, scenario, duration_s, rate_hz, plant_step_s(), link, law, energy_pu_s)


def law_json(law) -> dict:
    """``{"law": name, "law_gains": {...}}``: what a JSON says ran."""
    return {"law": law.name, "law_gains": law.gain_values()}


def format_table(outcomes) -> str:
    """A fixed-width table of outcomes (``Outcome.to_json`` dicts), one row per battery limit."""

    header = (f"{'b (pu)':>7} {'in sync':>7} {'settled':>7} {'max|d| (rad)':>13} {'max|P_ST| (pu)':>15} "
              f"{'last sat (s)':>13} {'settle (s)':>10}  verdict")
    rows = [header, "-" * (len(header) + 40)]
    for o in outcomes:
        b = math.inf if o["b"] == "inf" else o["b"]
        settled = "-" if o["too_short_to_judge"] else ("yes" if o["settled"] else "NO")
        rows.append(
            f"{b:>7g} {('yes' if o['in_synchronism'] else 'NO'):>7} {settled:>7} "
            f"{o['max_abs_angle_dev_rad']:>13.4f} {o['max_abs_battery_power_pu']:>15.4f} "
            f"{number_or_dash(o['last_saturated_s']):>13} {number_or_dash(o['settling_time_s']):>10}  {verdict_text(o)}"
        )
    return "\n".join(rows)


def verdict_legend(outcomes) -> str:
    """The line under a table saying what its verdict words mean."""
    hold = outcomes[0]["settle_hold_s"] if outcomes else math.nan
    return (f"in sync: the rotor angle never passed +-180 degrees (a pole slip); settled: |d| <= "
            f"{SETTLE_BAND_RAD:g} rad for at least {hold:g} s (half a swing period) at the end; stable: both")


def run_roa(args, model, plant: SmibParams) -> int:
    """``--roa``: classify the grid for each b, print basin areas, write PREFIX.json and PREFIX.png."""
    if args.controller_rate is not None or model.scenario_name != "initial_angle":
        raise CliError("--roa sweeps initial conditions of the continuous law after the fault has cleared: "
                       "it takes neither --controller-rate nor --scenario")
    for flag in ("--plot", "--json"):
        if getattr(args, flag[2:]):
            raise CliError(f"--roa writes PREFIX.json and PREFIX.png: it takes no {flag}")
    grid = RoaGrid(-math.pi, math.pi, -args.roa_speed_max, args.roa_speed_max, args.roa_grid, args.roa_grid)
    ctrls = [model.controller_params(b) for b in args.b]
    fastest = max(fastest_rate_per_s(plant, ctrl) for ctrl in ctrls)
    if fastest * ROA_STEP_S > RK4_STABLE_STEP_RATE:
        raise CliError(f"out of reach: the loop's fastest rate {fastest:.3g}/s is too fast for the sweep's "
                       f"{ROA_STEP_S:g} s RK4 step (it would diverge)")

    def progress(index, total, basin):
        print(f"nni-simulate: region of attraction {index + 1}/{total} (b = {basin.b:g}): "
              f"{basin.count(RETURNS)} of {basin.outcome.size} initial conditions return, "
              f"{basin.elapsed_s:.1f} s", file=sys.stderr, flush=True)

    last_report = [time.monotonic()]

    def on_check(index, simulated_s, undecided):
        if time.monotonic() - last_report[0] >= 2.0:  # a line every 2 s of wall time on long sweeps
            last_report[0] = time.monotonic()
            print(f"nni-simulate: region of attraction {index + 1}/{len(ctrls)} "
                  f"(b = {ctrls[index].battery_limit_pu:g}): t = {simulated_s:.2f} s, "
                  f"{undecided} initial conditions undecided", file=sys.stderr, flush=True)

    basins = sweep(plant, ctrls, grid, progress=progress, on_check=on_check)
    summary = report(plant, ctrls, grid, basins)
    summary["plot_shows"] = ("filled: initial conditions that return to equilibrium; hatched: those that "
                             "stay in synchronism without returning (no battery, D = 0)")
    print(f"Region of attraction, {grid.n_angle} x {grid.n_speed} grid, x3(0) = 0 "
          f"(delta_bar = {plant.delta_bar_rad:.4f} rad, "
          f"Omega: {summary['invariant_set']['area_rad2_per_s']:.3f} rad^2/s); "
          f"a pole slip: the rotor angle passing +-180 degrees")
    print(f"{'b (pu)':>7} {'returns (rad^2/s)':>18} {'fraction':>9} {'in sync (rad^2/s)':>18} {'undecided':>10}")
    for basin, item in zip(basins, summary["basins"]):
        print(f"{basin.b:>7g} {item['returns_area_rad2_per_s']:>18.3f} {item['returns_fraction']:>9.4f} "
              f"{item['synchronism_area_rad2_per_s']:>18.3f} {item['cells']['undecided']:>10}")
    marked = (model.plant["delta0_rad"] - plant.delta_bar_rad, model.plant["speed0_rad_s"])
    fig = roa_figure(plant, grid, basins, marked, model.header())
    json_path, png_path = (args.roa.with_name(args.roa.name + suffix) for suffix in (".json", ".png"))
    write_json(json_path, summary)
    save_png(fig, png_path)
    print(f"wrote {json_path} and {png_path}")
    return 0


def run_cct(args, model, plant: SmibParams) -> int:
    """``--cct``: critical clearing time of the transfer-limit fault per b; table, and JSON with cct_s."""
    ctrls = [model.controller_params(b) for b in args.b]
    laws = [model.law(b) for b in args.b]
    runs = 2 * math.ceil(math.log2(args.duration / CCT_TOLERANCE_S)) + 2
    check_work(plant, ctrls, args.duration, args.controller_rate, runs_per_b=runs)
    fault_p_max = model.plant["fault_p_max_pu"]
    print(f"Critical clearing time, transfer_limit_fault with P_max = {fault_p_max:g} pu during the fault, "
          f"controller {controller_text(args.controller_rate)}, law {laws[0].describe()}: the longest clearing time "
          f"that keeps the rotor "
          f"angle within +-180 degrees over {args.duration:g} s")
    print(f"bisection to {CCT_TOLERANCE_S * 1e3:g} ms: bracket [0, {CCT_TOLERANCE_S:g}] s, upper end doubled until "
          f"a run slips (up to {args.duration:g} s), then halved")
    if link_of(args).active:
        print(link_of(args).describe())
    print(f"{'b (pu)':>7} {'CCT (s)':>9} {'slips at (s)':>13} {'runs':>5}")
    results = []
    for law in laws:
        result = smib_cct(plant, law, fault_p_max, args.duration, args.controller_rate, link_of(args), energy_of(args))
        results.append(result)
        slips = "-" if result.slips_s is None else f"{result.slips_s:.4f}"
        note = "" if result.slips_s is not None else f"  (no slip for any clearing time up to {args.duration:g} s)"
        print(f"{result.b:>7g} {result.cct_s:>9.4f} {slips:>13} {result.runs:>5}{note}", flush=True)
    closed_form = None
    if fault_p_max == 0.0 and plant.damping_pu == 0.0:
        closed_form = round(equal_area_clearing_time_s(plant), 6)
        print(f"equal-area closed form for b = 0 (bolted fault, D = 0): {closed_form:.4f} s")
    if args.json:
        write_json(args.json, {"cct": [r.to_json() for r in results], "tolerance_s": CCT_TOLERANCE_S,
                               **law_json(laws[0]),
                               "duration_s": args.duration, "controller": controller_text(args.controller_rate),
                               "scenario": {"name": "transfer_limit_fault", "fault_p_max_pu": fault_p_max},
                               "equal_area_cct_s": closed_form, **link_json(link_of(args))})
        print(f"wrote {args.json}")
    return 0


def smib_cct(plant, law, fault_p_max: float, duration_s: float, rate_hz, link=NO_LINK, energy_pu_s=math.inf):
    """The critical clearing time of the transfer-limit fault for ``law`` (:func:`.margins.critical_clearing_time`)."""
    def in_sync(clearing_s):
        scenario = TransferLimitFault(fault_p_max, clearing_s)
        return assess(simulate(plant, law, scenario, duration_s, rate_hz, link, energy_pu_s)).in_synchronism

    return critical_clearing_time(in_sync, law.limit_pu, duration_s)


def law_runners(args, model, plant: SmibParams):
    """``(simulate_run, cct_of)`` of the laws compared and tuned: ``simulate_run(law)`` the scenario's sampled run
    and the scenario, ``cct_of(law)`` its transfer-limit fault's CCT (:func:`smib_cct`), both at --duration and the
    controller rate."""
    scenario, fault_p_max, energy = model.scenario(), model.plant["fault_p_max_pu"], energy_of(args)
    return (lambda law: (simulate(plant, law, scenario, args.duration, args.controller_rate, NO_LINK, energy), scenario),
            lambda law: smib_cct(plant, law, fault_p_max, args.duration, args.controller_rate, NO_LINK, energy))


def energy_of(args) -> float:
    """The battery's energy, pu s (inf without --battery-energy-pu-s)."""
    return math.inf if args.battery_energy_pu_s is None else args.battery_energy_pu_s


def energy_line(energy_pu_s: float, empties) -> str:
    """``battery of E pu s: b = 0.3 empty at 1.234 s, b = inf never empty``."""
    return f"battery of {energy_pu_s:g} pu s (from half charge): " + ", ".join(
        f"b = {b:g} " + ("never empty" if at is None else f"empty at {at:.3f} s") for b, at in empties)


def run_compare_laws(args, model, plant: SmibParams) -> int:
    """``--compare-laws``: every law per b on the same plant, limit and rate; table, --json, --plot."""
    rate = args.controller_rate
    laws_by_b = {b: [model.law(b, name) for name in LAW_NAMES] for b in args.b}
    # Bounded per law as --cct is (the comparison is five of those).
    check_work(plant, [model.controller_params(b) for b in args.b], args.duration, rate,
               runs_per_b=2 * math.ceil(math.log2(args.duration / CCT_TOLERANCE_S)) + 3)
    fault_p_max = model.plant["fault_p_max_pu"]
    print(f"Battery laws compared, SMIB, {model.header().split('; law ')[0]}")
    print(f"every law sampled at {rate:g} Hz, {args.duration:g} s; CCT: the transfer_limit_fault (P_max = "
          f"{fault_p_max:g} pu during it), bisection to {CCT_TOLERANCE_S * 1e3:g} ms; energy: integral of |P_ST| dt")
    for name in LAW_NAMES:
        print(f"  {laws_by_b[args.b[0]][LAW_NAMES.index(name)].describe()}")
    if args.battery_energy_pu_s is not None:
        print(f"every law with a battery of {args.battery_energy_pu_s:g} pu s to deliver and as much room to absorb, "
              "from half charge (empty at: when it first ran empty, '-' never)")
        print("ROA: not swept ('-'): the sweep models an unlimited battery")
        roa_of = None
    else:
        grid = COMPARISON_GRID
        print(f"ROA: region of attraction, {grid.n_angle} x {grid.n_speed} initial conditions after the fault has "
              f"cleared (angle within +-pi, speed within +-{grid.speed_max_rad_s:g} rad/s, the law's state at 0), "
              f"each law sampled at {rate:g} Hz for {args.duration:g} s: the area in rad x rad/s that stays in sync "
              "(sync) and that settles (back)")

        def roa_of(law):
            return basin_entries(sampled_basin(plant, law, grid, args.duration, rate))
    rows = compare(laws_by_b, *law_runners(args, model, plant), roa_of)
    print(format_rows(rows))
    print(f"energy in MWh: pu s x {MWH_PER_PU_S_100MVA:.5f} per 100 MVA of rating; saturated: the output at +-b")
    if args.json:
        write_json(args.json, {"scenario": model.scenario_values(), "controller": controller_text(rate),
                               "duration_s": args.duration, "cct_scenario": {"name": "transfer_limit_fault",
                                                                             "fault_p_max_pu": fault_p_max},
                               "tolerance_s": CCT_TOLERANCE_S, "battery_energy_pu_s": args.battery_energy_pu_s,
                               "roa": None if roa_of is None else roa_description(COMPARISON_GRID, args.duration),
                               "rows": rows})
        print(f"wrote {args.json}")
    if args.plot:
        what = "Critical clearing time" + ("" if roa_of is None else " and region of attraction")
        save_png(comparison_figure(rows, f"{what} per battery law, SMIB, sampled at {rate:g} Hz"), args.plot)
        print(f"wrote {args.plot}")
    return 0


def run_tune_laws(args, model, plant: SmibParams) -> int:
    """``--tune-laws``: the search of :mod:`.law_tuning` for every law at one b; table and --json."""
    rate, (b,) = args.controller_rate, args.b
    # Bounded per candidate as --cct is (the search is 5 x BUDGET of those, about 0.25 s each at the defaults).
    check_work(plant, [model.controller_params(b)], args.duration, rate,
               runs_per_b=2 * math.ceil(math.log2(args.duration / CCT_TOLERANCE_S)) + 4)
    fault_p_max = model.plant["fault_p_max_pu"]
    print(f"Fair tuning, SMIB, {model.header().split('; law ')[0]}, b = {b:g} pu")
    print(f"every law {BUDGET} candidates sampled at {rate:g} Hz, {args.duration:g} s; the pick: the longest CCT of the "
          f"transfer_limit_fault (P_max = {fault_p_max:g} pu during it, bisection to {CCT_TOLERANCE_S * 1e3:g} ms) "
          f"among the candidates whose run settles, ties to less battery energy")
    ctrl = model.controller_params(b)
    results, defaults = [], {}
    simulate_run, cct_of = law_runners(args, model, plant)
    for name in LAW_NAMES:
        results.append(tune(name, ctrl, simulate_run, cct_of, CCT_TOLERANCE_S))
        defaults[name] = cct_of(model.law(b, name)).cct_s
    print(format_results(results, defaults))
    print("default: the configured gains' CCT (shipped: config/controller.yaml; the NNI laws the paper's); "
          "worst nbr: the worst CCT one grid step from the pick; near: the share of the grid within 10 % of the "
          "pick's CCT; ok: candidates whose run settles")
    if args.json:
        write_json(args.json, {"scenario": model.scenario_values(), "controller": controller_text(rate), "b": b,
                               "duration_s": args.duration, "tolerance_s": CCT_TOLERANCE_S, "budget": BUDGET,
                               "default_cct_s": defaults, "laws": results})
        print(f"wrote {args.json}")
    return 0


def permanent_step_note(model, plant: SmibParams) -> str:
    """What a permanent mechanical power step does, with the new equilibrium angles in closed form."""
    step, c = model.plant["step_p_mech_pu"], model.controller
    # Unsaturated steady state: x3 = K d, P_ST = w = -(L - K) d - g(d); g(d) cancels the change of P_E,
    # so P_M,step - P_M = (L - K) d.
    with_battery = (step - plant.p_mech_pu) / (c["gain_l"] - c["gain_k"])
    battery = -(c["gain_l"] - c["gain_k"]) * with_battery - float(restoring_power(with_battery, plant))
    without = (math.asin(step / plant.p_max_pu) - plant.delta_bar_rad) if step < plant.p_max_pu else math.nan
    return (f"the mechanical power step is permanent: the equilibrium moves away from delta_bar, which the "
            f"controller's model keeps. With the battery unsaturated the rotor settles at d = (P_M,step - P_M)/(L - K)"
            f" = {with_battery:.3f} rad (the law's g(d) cancels the change of electrical power, only L - K holds the "
            f"rotor) with the battery at P_ST = {battery:+.3f} pu for as long as the step lasts (if b allows it, "
            f"else it saturates); without battery the "
            f"new equilibrium is d = asin(P_M,step/P_max) - delta_bar = {without:.3f} rad")


def run_time_domain(args, model, plant: SmibParams) -> int:
    """One run per b: the table, --json and --plot."""
    scenario = model.scenario()
    ctrls = [model.controller_params(b) for b in args.b]
    check_work(plant, ctrls, args.duration, args.controller_rate)
    trajectories = [simulate(plant, model.law(b), scenario, args.duration, args.controller_rate, link_of(args),
                             energy_of(args)) for b in args.b]
    outcomes = [assess(traj, scenario=scenario).to_json() for traj in trajectories]
    if args.battery_energy_pu_s is not None:
        for outcome, traj in zip(outcomes, trajectories):
            outcome.update(battery_energy_pu_s=args.battery_energy_pu_s, battery_empty_at_s=traj.empty_at_s)
    print(f"SMIB, {model.header()}")
    print(f"controller {controller_text(args.controller_rate)}, {args.duration:g} s "
          f"(delta_bar = {plant.delta_bar_rad:.4f} rad)")
    if link_of(args).active:
        print(link_of(args).describe())
    print(format_table(outcomes))
    print(verdict_legend(outcomes))
    if args.battery_energy_pu_s is not None:
        print(energy_line(args.battery_energy_pu_s, [(b, traj.empty_at_s) for b, traj in zip(args.b, trajectories)]))
    if any(o["equilibrium_moved"] for o in outcomes):
        print(permanent_step_note(model, plant))
    if args.json:
        write_json(args.json, {"scenario": model.scenario_values(), "controller": controller_text(args.controller_rate),
                               **law_json(model.law(math.inf)), "scenarios": outcomes, **link_json(link_of(args))})
        print(f"wrote {args.json}")
    if args.plot:
        plot_runs(trajectories, outcomes, args.plot, model.scenario_values(),
                  controller_text(args.controller_rate), "offline")
        print(f"wrote {args.plot}")
    return 0


def run_delay_margin(args, model, plant: SmibParams) -> int:
    """``--delay-margin``: per b, the largest fixed link delay in synchronism; table, and JSON with delay_margin_s."""
    scenario, rate, link = model.scenario(), args.controller_rate, link_of(args)
    ctrls = [model.controller_params(b) for b in args.b]
    scan_s = args.delay_step
    runs = math.ceil(args.delay_max / scan_s) + math.ceil(math.log2(max(scan_s / DELAY_MARGIN_TOLERANCE_S, 1))) + 1
    check_work(plant, ctrls, args.duration, rate, runs_per_b=runs)
    print(f"Delay margin, SMIB, {model.header()}")
    print(f"controller sampled at {rate:g} Hz: the longest fixed delay from a measurement to its command taking "
          f"effect that keeps the rotor angle within +-180 degrees (in synchronism) over {args.duration:g} s")
    print("\n".join(delay_search_lines(scan_s, args.delay_max, link)))

    laws = [model.law(b) for b in args.b]

    def in_sync(delay_s, indices):
        return [assess(simulate(plant, laws[i], scenario, args.duration, rate, link.with_delay(delay_s)))
                .in_synchronism for i in indices]

    results = delay_margins(in_sync, [ctrl.battery_limit_pu for ctrl in ctrls], scan_s, args.delay_max)
    for result in results:
        print(delay_margin_row(result))
    if args.json:
        write_json(args.json, {"delay_margin": [r.to_json() for r in results], "tolerance_s": DELAY_MARGIN_TOLERANCE_S,
                               "scan_step_s": scan_s, "searched_up_to_s": args.delay_max, "duration_s": args.duration,
                               "controller": controller_text(rate), "scenario": model.scenario_values(),
                               **law_json(laws[0]),
                               "criterion": "in synchronism: the rotor angle never passed +-180 degrees",
                               **link_json(link, delay_searched=True)})
        print(f"wrote {args.json}")
    return 0


def resolve_link_options(args) -> None:
    """The controller rate (--delay-margin: the plant node's by default) and the link options where they apply."""
    continuous_given = args.continuous_given = args.controller_rate == CONTINUOUS
    if args.delay_margin:
        refuse_beside_delay_margin(args, ("roa", "cct", "plot", "link_delay"))
        if continuous_given:
            raise CliError("--delay-margin delays the commands of the sampled-data loop: it takes no "
                           "--controller-rate continuous")
        if args.controller_rate is None:
            args.controller_rate = plant_defaults()["pmu_rate_hz"]
    resolve_delay_span(args)
    if args.delay_margin:
        return
    if continuous_given:
        args.controller_rate = None
    given = given_link_options(args)
    if given and args.controller_rate is None:
        raise CliError(f"{given[0]} applies to the sampled-data loop (its commands go over the link): give "
                       f"--controller-rate HZ")


def apply_mode_defaults(args) -> None:
    """Fill the defaults of --duration and the --roa options; CliError for one given where it does not apply."""
    resolve_link_options(args)
    if args.roa:
        if args.duration is not None:
            raise CliError("--roa integrates each initial condition until decided (up to its own horizon): "
                           "it takes no --duration")
        for name, value in ROA_DEFAULTS.items():
            setattr(args, name, value if getattr(args, name) is None else getattr(args, name))
        return
    for name in ROA_DEFAULTS:
        if getattr(args, name) is not None:
            raise CliError(f"--{name.replace('_', '-')} applies to --roa only")
    args.duration = DEFAULT_DURATION_S if args.duration is None else args.duration


def refuse_beside_every_law(args, option: str, what: str, flags) -> None:
    """CliError when ``option``, a mode that runs every law (``what`` it does), is given one of ``flags``,
    continuous time or a link; else every law's gain options apply (``args.laws_compared``)."""
    for flag in flags:
        if getattr(args, flag):
            raise CliError(f"{option} {what}: it takes no --{flag.replace('_', '-')}")
    if args.continuous_given or given_link_options(args):
        raise CliError(f"{option} runs every law sampled at the PMU rate without a link: it takes "
                       "no --controller-rate continuous and no --link-* option")
    args.laws_compared = LAW_NAMES


def main(argv=None) -> int:
    """``nni-simulate`` without ``--case`` (called by :func:`nni_battery_controller.simulate_command.main`)."""
    parser = build_parser()

    def body():
        try:
            args = parser.parse_args(argv)
            apply_mode_defaults(args)
            if args.compare_laws:
                refuse_beside_every_law(args, "--compare-laws", "runs every law", ("cct", "roa", "delay_margin", "law"))
            if args.tune_laws:
                refuse_beside_every_law(args, "--tune-laws", "searches every law's gains",
                                        ("compare_laws", "cct", "roa", "delay_margin", "law", "plot"))
                if args.b is parser.get_default("b"):
                    args.b = [0.3]
                if len(args.b) != 1 or not 0 < args.b[0] < math.inf:
                    raise CliError("--tune-laws searches at one finite battery limit: --b takes one number > 0")
            if args.battery_energy_pu_s is not None:
                for flag, option, why in (("roa", "--roa", "sweeps the continuous nni law"),
                                          ("delay_margin", "--delay-margin", "does not model it yet"),
                                          ("tune_laws", "--tune-laws", "tunes with an unlimited battery"),
                                          ("continuous_given", "--controller-rate continuous", "is the paper's "
                                           "continuous law, without one")):
                    if getattr(args, flag):
                        raise CliError(f"--battery-energy-pu-s is a sampled run's battery: {option} {why}")
                if args.controller_rate is None:
                    args.controller_rate = plant_defaults()["pmu_rate_hz"]
            if args.cct:
                if args.roa or args.plot:
                    raise CliError("--cct prints and writes --json only: it takes neither --roa nor --plot")
                if args.scenario not in (None, "transfer_limit_fault") or args.clearing_time_s is not None:
                    raise CliError("--cct searches the clearing time of the transfer_limit_fault: it takes no "
                                   "--scenario or --clearing-time")
                args.scenario = "transfer_limit_fault"
            model = resolve_model(args, parser.prog)
            plant = model.smib()
            model.validate()
            if model.law_name != "nni" or args.compare_laws or args.tune_laws:
                if args.roa or args.continuous_given:
                    raise CliError(f"--law {model.law_name} runs sampled at the PMU rate: "
                                   + ("--roa sweeps the continuous nni law only" if args.roa else "it takes no --controller-rate "
                                                                               "continuous"))
                if args.controller_rate is None:  # the sampled law at the plant node's PMU rate
                    args.controller_rate = plant_defaults()["pmu_rate_hz"]
            if args.roa:
                status = run_roa(args, model, plant)
            elif args.delay_margin:
                status = run_delay_margin(args, model, plant)
            elif args.compare_laws:
                status = run_compare_laws(args, model, plant)
            elif args.tune_laws:
                status = run_tune_laws(args, model, plant)
            elif args.cct:
                status = run_cct(args, model, plant)
            else:
                status = run_time_domain(args, model, plant)
            sys.stdout.flush()  # here, so that a closed pipe is met inside, not at exit
            return status
        except BrokenPipeError:
            # The reader went away (``| head``): nothing more to say, and nothing at exit either.
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return EXIT_BROKEN_PIPE
        except RuntimeError as exc:  # the integration gave up (too stiff, or chattering at |w| = b)
            raise CliError(str(exc)) from None
        except KeyboardInterrupt:
            print(f"{parser.prog}: interrupted", file=sys.stderr)
            return 130

    return run_cli(body, parser.prog)
