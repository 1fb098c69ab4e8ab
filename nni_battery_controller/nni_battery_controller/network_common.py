"""What the network study (``nni-simulate --case``) and the network demo (``nni-demo --case``) share.

The disturbance options of a network (:func:`add_scenario_options`), the
scenario they make of a case (:func:`make_scenario`), the default battery
limits, and the table both print for one run's verdicts (:func:`format_run`).
Pure python: no ROS import.
"""

from __future__ import annotations

import math

import numpy as np

from nni_msgs_adapter.ros.cli_support import CliError, finite_float, float_within, positive_float
from nni_battery_controller.network_sim import network_verdict
from nni_battery_controller.verdicts import number_or_dash
from nni_plant_sim.cases import DEFAULT_FAULT_BUS
from nni_plant_sim.network_scenarios import (
    NETWORK_SCENARIOS,
    SCENARIO_PARAMETERS,
    AngleDisplacement,
    BusFault,
    LineTrip,
    MechanicalStep,
)

#: The default --b of a network, pu of each machine's rating.
DEFAULT_LIMITS = (0.0, 0.1, 0.3, math.inf)


def refuse_foreign_scenario_options(args) -> None:
    """CliError for a disturbance option given that does not belong to ``--scenario``."""
    for option, scenarios in SCENARIO_PARAMETERS.items():
        if getattr(args, option, None) is not None and args.scenario not in scenarios:
            raise CliError(f"--{option.replace('_', '-')} does not apply to --scenario {args.scenario}")


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


def json_b(b):
    """A battery limit as JSON writes it: ``"inf"`` for the unlimited battery."""
    return "inf" if math.isinf(b) else b


def limit_words(b) -> str:
    """A run's battery limit in words: ``b = 0.1 pu``, ``b = 0 (no battery)``, ``b = inf (unsaturated)``."""
    return "b = inf (unsaturated)" if math.isinf(b) else ("b = 0 (no battery)" if b == 0 else f"b = {b:g} pu")


#: An angle spread beyond this (degrees) is no machine's: a lost run's integration ran away after the pole slip.
DIVERGED_SPREAD_DEG = 1e6


def format_run(outcome, b, reference, net) -> str:
    """One run's table: the system verdict line, then one row per generator."""
    spread_deg = math.degrees(outcome.max_angle_spread_rad)
    if math.isfinite(spread_deg) and spread_deg < DIVERGED_SPREAD_DEG:
        numbers = f"max angle spread {spread_deg:.1f} deg, final COI frequency deviation " \
                  f"{outcome.final_coi_frequency_hz:+.3f} Hz"
    else:
        numbers = f"the angles diverged after the loss: spread beyond {DIVERGED_SPREAD_DEG:g} deg"
    head = f"{limit_words(b)}, reference {reference}: {network_verdict(outcome)} ({numbers})"
    header = f"  {'generator':<9} {'in sync':>7} {'settled':>7} {'settle (s)':>10} {'max|P_ST| (pu)':>14} " \
             f"{'max|P_ST| (MW)':>14} {'last sat (s)':>12}"
    rows = [head, header, "  " + "-" * (len(header) - 2)]
    for g in outcome.generators:
        rows.append(f"  {g.name:<9} {('yes' if g.in_synchronism else 'NO'):>7} {('yes' if g.settled else 'no'):>7} "
                    f"{number_or_dash(g.settling_time_s):>10} {g.max_abs_battery_power_pu:>14.4f} "
                    f"{g.max_abs_battery_power_mw:>14.1f} {number_or_dash(g.last_saturated_s):>12}")
    return "\n".join(rows)
