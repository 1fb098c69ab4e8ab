"""``nni-simulate``: the paper's closed-loop study offline, as a table, JSON and figures.

By default runs the paper's case (H=4, D=0, P_M=0.8, P_max=1, f0=50 Hz,
delta(0)=0.2 rad; tau=0.1, K=1, L=1.1, alpha=1) for b in {0, 0.2, 0.3, inf}.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

from nni_battery_controller.law import ControllerParams
from nni_battery_controller.roa import RETURNS, STAYS, RoaGrid, report, sweep
from nni_battery_controller.simulate import assess, simulate_continuous, simulate_sampled
from nni_msgs_adapter.cli_support import (
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
from nni_plant_sim.model import SmibParams, critical_angles_rad, invariant_set_boundary
from nni_plant_sim.scenarios import InitialAngle, MechanicalPowerStep, TransferLimitFault

PAPER_BATTERY_LIMITS = (0.0, 0.2, 0.3, math.inf)


_sampling_rate_hz = float_within(10.0, 10_000.0, "Hz or 'continuous'")


def controller_rate(text: str):
    """argparse type: ``continuous`` (None) or a sampling rate in Hz (10 to 10000)."""
    return None if text == "continuous" else _sampling_rate_hz(text)


#: Largest --roa grid per axis: 1000 x 1000 cells hold about 0.2 GB of state during the sweep.
ROA_GRID_MAX = 1000


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
    parser = OneLineParser(prog="nni-simulate", description=__doc__)
    parser.add_argument("--b", type=battery_limit, nargs="+", default=list(PAPER_BATTERY_LIMITS),
                        metavar="B", help="battery power limits in pu (numbers >= 0 or 'inf'); default: 0 0.2 0.3 inf")
    parser.add_argument("--duration", type=positive_float, default=10.0, help="simulated seconds (default 10)")
    parser.add_argument("--controller-rate", type=controller_rate, default=None,
                        help="'continuous' (default) or the sampled-data controller rate in Hz")
    parser.add_argument("--json", type=writable_output, help="write the per-scenario summary as JSON here")
    parser.add_argument("--plot", type=writable_output, help="write the paper's two figures as one PNG here")
    parser.add_argument("--roa", type=writable_output, metavar="PREFIX",
                        help="instead of the time-domain run: region of attraction of each b on a grid of initial "
                             "conditions, written to PREFIX.png (basins, Omega, EAC) and PREFIX.json (basin areas)")
    parser.add_argument("--roa-grid", type=roa_grid_size, default=200, metavar="N",
                        help=f"--roa: N x N initial conditions (10 to {ROA_GRID_MAX}, default 200)")
    parser.add_argument("--roa-speed-max", type=positive_float, default=10.0,
                        help="--roa: initial speed deviations within +-this, rad/s (default 10); angles within +-pi")
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


def run_roa(args, plant: SmibParams) -> int:
    """``--roa``: classify the grid for each b, print basin areas, write PREFIX.json and PREFIX.png."""
    if args.controller_rate is not None or args.scenario != "initial_angle":
        raise CliError("--roa sweeps initial conditions of the continuous law after the fault has cleared: "
                       "it takes neither --controller-rate nor --scenario")
    grid = RoaGrid(-math.pi, math.pi, -args.roa_speed_max, args.roa_speed_max, args.roa_grid, args.roa_grid)
    ctrls = [ControllerParams(args.tau_s, args.gain_k, args.gain_l, args.alpha, b) for b in args.b]

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
    summary["plot_shows"] = ("filled: initial conditions that return to equilibrium; dashed outline: those that "
                             "stay in synchronism without returning (no battery, D = 0)")
    print(f"Region of attraction, {grid.n_angle} x {grid.n_speed} grid, x3(0) = 0 "
          f"(delta_bar = {plant.delta_bar_rad:.4f} rad, "
          f"Omega: {summary['invariant_set']['area_rad2_per_s']:.3f} rad^2/s)")
    print(f"{'b (pu)':>7} {'returns (rad^2/s)':>18} {'fraction':>9} {'in sync (rad^2/s)':>18} {'undecided':>10}")
    for basin, item in zip(basins, summary["basins"]):
        print(f"{basin.b:>7g} {item['returns_area_rad2_per_s']:>18.3f} {item['returns_fraction']:>9.4f} "
              f"{item['synchronism_area_rad2_per_s']:>18.3f} {item['cells']['undecided']:>10}")
    png = plot_roa(plant, grid, basins, (args.delta0 - plant.delta_bar_rad, args.speed0))
    json_path, png_path = (args.roa.with_name(args.roa.name + suffix) for suffix in (".json", ".png"))
    with atomic_output(json_path) as handle:
        json.dump(summary, handle, indent=2)
        handle.write("\n")
    with atomic_output(png_path, "wb") as handle:
        handle.write(png)
    print(f"wrote {json_path} and {png_path}")
    return 0


def plot_roa(plant: SmibParams, grid: RoaGrid, basins, marked_state) -> bytes:
    """PNG of the basins of all b overlaid in the (d0, d0') plane, with Omega and the EAC's critical angles.

    ``marked_state`` (angle deviation rad, speed rad/s) is starred: the run's
    --delta0 / --speed0, by default the paper's case.
    """
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import to_rgb
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    # Cell centres, plus the grid's edges (with the edge cells' outcome) so that fills reach the axes.
    angles = np.concatenate(([grid.angle_min_rad], grid.angle_centres_rad, [grid.angle_max_rad]))
    speeds = np.concatenate(([grid.speed_min_rad_s], grid.speed_centres_rad_s, [grid.speed_max_rad_s]))
    fig, ax = plt.subplots(figsize=(9, 8.5), layout="constrained")
    handles = []
    # Largest basin first, opaque, so that each smaller one drawn over it shows as
    # its own band (the basins nest); each keeps its outline in the --plot colour.
    order = sorted(range(len(basins)), key=lambda i: -basins[i].count(RETURNS))
    for index in order:
        basin, color = basins[index], f"C{index}"
        fill = tuple(0.45 * c + 0.55 for c in to_rgb(color))  # the colour, lightened
        name = "no battery" if basin.b == 0 else ("unlimited" if math.isinf(basin.b) else "")
        label = f"b = {basin.b:g}" + (f" ({name})" if name else "")
        outcome = np.pad(basin.outcome, 1, mode="edge")
        returns = (outcome == RETURNS).astype(float)
        if returns.any():
            ax.contourf(angles, speeds, returns, levels=[0.5, 1.5], colors=[fill])
            ax.contour(angles, speeds, returns, levels=[0.5], colors=[color], linewidths=1.5)
            handles.append(Patch(facecolor=fill, edgecolor=color, label=f"{label}: returns to equilibrium"))
        stays = (outcome == STAYS).astype(float)
        if stays.any():
            ax.contour(angles, speeds, stays, levels=[0.5], colors=[color], linewidths=2.0, linestyles="--")
            handles.append(Line2D([], [], color=color, ls="--", lw=2.0,
                                  label=f"{label}: stays in synchronism, never returns (D = 0: oscillates)"))
    omega = invariant_set_boundary(plant)
    handles += ax.plot(omega[:, 0], omega[:, 1], color="black", lw=1.5,
                       label="invariant set Omega: W <= c, |d| <= pi - 2 delta_bar")
    low, high = (angle - plant.delta_bar_rad for angle in critical_angles_rad(plant))
    handles += ax.plot([low, high], [0.0, 0.0], color="black", lw=3.0, marker="|", markersize=14,
                       label=f"EAC (at rest, no battery): in synchronism for {low:.3f} < d0 < {high:.3f} rad")
    handles += ax.plot([marked_state[0]], [marked_state[1]], "k*", markersize=11,
                       label=f"delta(0) = {marked_state[0] + plant.delta_bar_rad:g} rad, "
                             f"d'(0) = {marked_state[1]:g} rad/s (--delta0, --speed0)")
    ax.set_xlim(grid.angle_min_rad, grid.angle_max_rad)
    ax.set_ylim(grid.speed_min_rad_s, grid.speed_max_rad_s)
    ax.set_xlabel("initial angle deviation d0 = delta(0) - delta_bar (rad)")
    ax.set_ylabel("initial speed deviation d0' = omega(0) - omega0 (rad/s)")
    ax.set_title("Region of attraction of the battery-controlled generator (x3(0) = 0)\n"
                 "outside a basin the angle deviation passes pi (a pole slip)")
    fig.legend(handles=handles, loc="outside lower center", ncol=2, fontsize=8)
    ax.grid(True, alpha=0.3)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=120)
    plt.close(fig)
    return buffer.getvalue()


def main(argv=None) -> int:
    """Entry point of ``nni-simulate`` (``--case``: the network study of :mod:`network_cli`)."""
    if any(arg == "--case" or arg.startswith("--case=") for arg in (sys.argv[1:] if argv is None else argv)):
        from nni_battery_controller import network_cli

        return network_cli.main(argv)
    parser = build_parser()

    def body():
        args = parser.parse_args(argv)
        plant = SmibParams(args.inertia_h_s, args.damping_pu, args.p_mech_pu, args.p_max_pu, args.f0_hz)
        if args.roa:
            return run_roa(args, plant)
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
