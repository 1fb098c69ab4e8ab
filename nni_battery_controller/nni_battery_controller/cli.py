"""``nni-simulate``: the paper's closed-loop study offline, as a table, JSON and figures.

By default runs the paper's case (H=4, D=0, P_M=0.8, P_max=1, f0=50 Hz,
delta(0)=0.2 rad; tau=0.1, K=1, L=1.1, alpha=1) for b in {0, 0.2, 0.3, inf}.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

from nni_battery_controller.law import ControllerParams
from nni_battery_controller.simulate import assess, simulate_continuous, simulate_sampled
from nni_msgs_adapter.cli_support import (
    OneLineParser,
    atomic_output,
    battery_limit,
    finite_float,
    positive_float,
    run_cli,
    writable_output,
)
from nni_plant_sim.model import SmibParams
from nni_plant_sim.scenarios import InitialAngle, MechanicalPowerStep, TransferLimitFault

PAPER_BATTERY_LIMITS = (0.0, 0.2, 0.3, math.inf)


def controller_rate(text: str):
    """argparse type: ``continuous`` or a sampling rate in Hz (10 to 10000)."""
    if text == "continuous":
        return None
    rate = positive_float(text)
    if not 10.0 <= rate <= 10_000.0:
        raise argparse.ArgumentTypeError(f"controller rate must be 'continuous' or 10..10000 Hz, got {text}")
    return rate


def build_parser() -> OneLineParser:
    """The nni-simulate command line."""
    parser = OneLineParser(prog="nni-simulate", description=__doc__)
    parser.add_argument("--b", type=battery_limit, nargs="+", default=list(PAPER_BATTERY_LIMITS),
                        metavar="B", help="battery power limits in pu (numbers >= 0 or 'inf'); default: 0 0.2 0.3 inf")
    parser.add_argument("--duration", type=positive_float, default=10.0, help="simulated seconds (default 10)")
    parser.add_argument("--controller-rate", type=controller_rate, default=None,
                        help="'continuous' (default) or the sampled-data controller rate in Hz")
    parser.add_argument("--json", type=writable_output, help="write the per-scenario summary as JSON here")
    parser.add_argument("--plot", type=writable_output, help="write the paper's two figures as one PNG here")
    plant = parser.add_argument_group("plant (per unit)")
    plant.add_argument("--H", dest="inertia_h_s", type=finite_float, default=4.0, help="inertia constant H, s")
    plant.add_argument("--D", dest="damping_pu", type=finite_float, default=0.0, help="damping D, pu/(rad/s)")
    plant.add_argument("--P-M", dest="p_mech_pu", type=finite_float, default=0.8, help="mechanical power P_M, pu")
    plant.add_argument("--P-max", dest="p_max_pu", type=finite_float, default=1.0, help="max transfer P_max, pu")
    plant.add_argument("--f0", dest="f0_hz", type=finite_float, default=50.0, help="nominal frequency, Hz")
    ctrl = parser.add_argument_group("controller")
    ctrl.add_argument("--tau", dest="tau_s", type=finite_float, default=0.1, help="time constant tau, s")
    ctrl.add_argument("--K", dest="gain_k", type=finite_float, default=1.0, help="gain K, pu/rad")
    ctrl.add_argument("--L", dest="gain_l", type=finite_float, default=1.1, help="gain L, pu/rad (K < L)")
    ctrl.add_argument("--alpha", type=finite_float, default=1.0, help="saturated decay factor alpha")
    fault = parser.add_argument_group("fault scenario")
    fault.add_argument("--scenario", choices=("initial_angle", "mechanical_step", "transfer_limit_fault"),
                       default="initial_angle", help="default: the paper's initial angle jump")
    fault.add_argument("--delta0", type=finite_float, default=0.2, help="initial_angle: delta(0), rad")
    fault.add_argument("--speed0", type=finite_float, default=0.0, help="initial_angle: delta'(0), rad/s")
    fault.add_argument("--step-p-mech", type=finite_float, default=0.95, help="mechanical_step: P_M during step, pu")
    fault.add_argument("--step-duration", type=positive_float, default=math.inf,
                       help="mechanical_step: step length, s (default: for good)")
    fault.add_argument("--fault-p-max", type=finite_float, default=0.0, help="transfer_limit_fault: P_max in fault, pu")
    fault.add_argument("--clearing-time", type=positive_float, default=0.1,
                       help="transfer_limit_fault: clearing time, s")
    return parser


def scenario_from_args(args):
    """The fault scenario the options describe."""
    if args.scenario == "mechanical_step":
        return MechanicalPowerStep(args.step_p_mech, args.step_duration)
    if args.scenario == "transfer_limit_fault":
        return TransferLimitFault(args.fault_p_max, args.clearing_time)
    return InitialAngle(args.delta0, args.speed0)


def format_table(outcomes) -> str:
    """A fixed-width table of outcomes, one row per battery limit."""

    def num(value, fmt="{:.4f}"):
        return "-" if value is None else fmt.format(value)

    header = f"{'b (pu)':>7} {'stable':>7} {'final d (rad)':>14} {'max|d| (rad)':>13} " \
             f"{'max|P_ST| (pu)':>15} {'last sat (s)':>13} {'settle (s)':>11}"
    rows = [header, "-" * len(header)]
    for o in outcomes:
        rows.append(
            f"{o.b:>7g} {('yes' if o.stable else 'NO'):>7} {o.final_angle_dev_rad:>14.4g} "
            f"{o.max_abs_angle_dev_rad:>13.4f} {o.max_abs_battery_power_pu:>15.4f} "
            f"{num(o.last_saturated_s, '{:.3f}'):>13} {num(o.settling_time_s, '{:.3f}'):>11}"
        )
    return "\n".join(rows)


def plot_runs(trajectories, path) -> None:
    """The paper's figures 3 and 4: angle deviation (all runs) and battery power (b > 0)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_angle, ax_power) = plt.subplots(2, 1, figsize=(8, 7), sharex=True, constrained_layout=True)
    for index, traj in enumerate(trajectories):
        b = traj.ctrl.battery_limit_pu
        label = f"b = {b:g}" if b > 0 else "b = 0 (no battery)"
        color = f"C{index}"  # one colour per run in both panels
        ax_angle.plot(traj.t_s, traj.angle_dev_rad, label=label, color=color)
        if b > 0:
            ax_power.plot(traj.t_s, traj.battery_power_pu, label=label, color=color)
    ax_angle.set_ylim(-1.5, 3.5)
    ax_angle.axhline(math.pi - 2 * trajectories[0].plant.delta_bar_rad, color="grey", ls=":", lw=1,
                     label="unstable equilibrium pi - 2 delta_bar")
    ax_angle.set_ylabel("angle deviation delta - delta_bar (rad)")
    ax_angle.set_title("Angle deviation without (b = 0) and with battery control")
    ax_angle.legend(loc="upper right")
    ax_power.set_ylabel("battery power change P_ST (pu)")
    ax_power.set_xlabel("time after the fault (s)")
    ax_power.set_title("Battery power output change")
    ax_power.legend(loc="upper right")
    for ax in (ax_angle, ax_power):
        ax.grid(True, alpha=0.3)
    with atomic_output(path, "wb") as handle:
        fig.savefig(handle, format="png", dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    """Entry point of ``nni-simulate``."""
    parser = build_parser()

    def body():
        args = parser.parse_args(argv)
        plant = SmibParams(args.inertia_h_s, args.damping_pu, args.p_mech_pu, args.p_max_pu, args.f0_hz)
        scenario = scenario_from_args(args)
        trajectories = []
        for b in args.b:
            ctrl = ControllerParams(args.tau_s, args.gain_k, args.gain_l, args.alpha, b)
            if args.controller_rate is None:
                trajectories.append(simulate_continuous(plant, ctrl, scenario, args.duration))
            else:
                trajectories.append(simulate_sampled(plant, ctrl, scenario, args.duration, args.controller_rate))
        outcomes = [assess(traj) for traj in trajectories]
        rate = "continuous" if args.controller_rate is None else f"{args.controller_rate:g} Hz"
        print(f"SMIB, {args.scenario}, controller {rate}, {args.duration:g} s "
              f"(delta_bar = {plant.delta_bar_rad:.4f} rad)")
        print(format_table(outcomes))
        if args.json:
            with atomic_output(args.json) as handle:
                json.dump({"scenarios": [o.to_json() for o in outcomes]}, handle, indent=2)
                handle.write("\n")
            print(f"wrote {args.json}")
        if args.plot:
            plot_runs(trajectories, args.plot)
            print(f"wrote {args.plot}")
        return 0

    return run_cli(body, parser.prog)


if __name__ == "__main__":
    sys.exit(main())
