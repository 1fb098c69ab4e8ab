"""Every figure of the studies and the demos, drawn with matplotlib and written as PNG.

* :func:`runs_figure` / :func:`plot_runs`: the paper's figures 3 and 4 for SMIB
  runs (``nni-simulate``, ``nni-demo``, ``nni-replay``);
* :func:`roa_figure`: the region of attraction of each b (``nni-simulate --roa``);
* :func:`plot_network`: angles, frequencies and battery powers of network runs
  (``nni-simulate --case``, ``nni-demo --case``);
* :func:`screen_heatmap`, :func:`screen_gain_chart`: a contingency screen's
  critical clearing times and their gain with batteries (``nni-simulate --case
  --screen``).

Each PNG carries its figure's title in its Title text chunk (:func:`save_png`).
matplotlib is imported by the function that draws, so that a command that
draws nothing does not load it. Pure python: no ROS import.
"""

from __future__ import annotations

import math

import numpy as np

from nni_battery_controller.network_common import limit_words
from nni_battery_controller.roa import RETURNS, STAYS, RoaGrid
from nni_battery_controller.verdicts import verdict_text
from nni_msgs_adapter.ros.cli_support import atomic_output
from nni_msgs_adapter.viewing.palette import colour_hex
from nni_plant_sim.model import SmibParams, critical_angles_rad, invariant_set_boundary


def scenario_title(scenario: dict) -> str:
    """The scenario and its values, for a figure title."""
    if scenario["name"] == "transfer_limit_fault":
        return (f"transfer-limit fault: P_max = {scenario['fault_p_max_pu']:g} pu, cleared at "
                f"{scenario['clearing_time_s']:g} s (shaded)")
    if scenario["name"] == "mechanical_step":
        if math.isinf(scenario["step_duration_s"]):
            return f"mechanical power step to {scenario['step_p_mech_pu']:g} pu for good (the equilibrium moves)"
        return f"mechanical power step to {scenario['step_p_mech_pu']:g} pu for {scenario['step_duration_s']:g} s (shaded)"
    return (f"initial angle: delta(0) = {scenario['delta0_rad']:g} rad, delta'(0) = {scenario['speed0_rad_s']:g} "
            f"rad/s (fault cleared before t = 0)")


def fault_interval(scenario: dict, end_s: float):
    """``(start, end)`` s of the scenario's disturbance on the run's time axis, or None (cleared before t = 0)."""
    if scenario["name"] == "transfer_limit_fault":
        return 0.0, min(scenario["clearing_time_s"], end_s)
    if scenario["name"] == "mechanical_step":
        return 0.0, min(scenario["step_duration_s"], end_s)
    return None


def runs_figure(trajectories, outcomes, scenario: dict, controller: str, mode: str):
    """The paper's figures 3 and 4 (angle deviation of every run, battery power for b > 0) as a Figure.

    The title names the scenario (the fault interval shaded), the controller
    (continuous or its rate) and the mode; each legend entry names b and the
    run's verdict. One colour per b (:func:`nni_msgs_adapter.palette.colour_hex`).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 7.5), layout="constrained")
    FigureCanvasAgg(fig)
    ax_angle, ax_power = fig.subplots(2, 1, sharex=True)
    fig.suptitle(f"SMIB with battery control: {scenario_title(scenario)}\n"
                 f"controller {controller}, {mode}", fontsize=10)
    for traj, outcome in zip(trajectories, outcomes):
        b = traj.ctrl.battery_limit_pu
        name = f"b = {b:g}" if b > 0 else "b = 0 (no battery)"
        label, color = f"{name}: {verdict_text(outcome)}", colour_hex(b)
        ax_angle.plot(traj.t_s, traj.angle_dev_rad, label=label, color=color)
        if b > 0:
            ax_power.plot(traj.t_s, traj.battery_power_pu, label=name, color=color, drawstyle=(
                "steps-post" if controller != "continuous" else "default"))
    end = max(float(traj.t_s[-1]) for traj in trajectories)
    interval = fault_interval(scenario, end)
    for ax in (ax_angle, ax_power):
        if interval is not None and interval[1] > interval[0]:
            ax.axvspan(*interval, color="red", alpha=0.12, lw=0, label="fault" if ax is ax_angle else None)
        ax.grid(True, alpha=0.3)
    ax_angle.set_ylim(-1.5, 3.5)
    ax_angle.axhline(math.pi - 2 * trajectories[0].plant.delta_bar_rad, color="grey", ls=":", lw=1,
                     label="unstable equilibrium pi - 2 delta_bar")
    ax_angle.set_ylabel("angle deviation delta - delta_bar (rad)")
    ax_angle.set_title("Angle deviation without (b = 0) and with battery control", fontsize=10)
    ax_angle.legend(loc="upper right", fontsize=8)
    ax_power.set_ylabel("battery power change P_ST (pu)")
    ax_power.set_xlabel("time after the fault (s)")
    ax_power.set_title("Battery power output change", fontsize=10)
    if any(traj.ctrl.battery_limit_pu > 0 for traj in trajectories):
        ax_power.legend(loc="upper right", fontsize=8)
    return fig


def plot_runs(trajectories, outcomes, path, scenario: dict, controller: str, mode: str) -> None:
    """:func:`runs_figure` written to ``path`` as PNG."""
    save_png(runs_figure(trajectories, outcomes, scenario, controller, mode), path)


def roa_figure(plant: SmibParams, grid: RoaGrid, basins, marked_state, model_text: str):
    """The basins of all b overlaid in the (d0, d0') plane, with Omega and the EAC's critical angles, as a Figure.

    Each basin is filled in its b's colour (the one every figure uses), the
    largest first so that each smaller one shows as its own band (the basins
    nest); where a basin only stays in synchronism (no battery, D = 0) it is
    hatched. Omega is a thin dotted outline drawn over them, so the b = 0
    basin, which Omega nearly equals, shows through. ``marked_state`` (angle
    deviation rad, speed rad/s) is starred: the run's --delta0 / --speed0.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import to_rgb
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    # Cell centres, plus the grid's edges (with the edge cells' outcome) so that fills reach the axes.
    angles = np.concatenate(([grid.angle_min_rad], grid.angle_centres_rad, [grid.angle_max_rad]))
    speeds = np.concatenate(([grid.speed_min_rad_s], grid.speed_centres_rad_s, [grid.speed_max_rad_s]))
    fig = Figure(figsize=(9, 8.5), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    handles = []
    order = sorted(range(len(basins)), key=lambda i: -(basins[i].count(RETURNS) + basins[i].count(STAYS)))
    for index in order:
        basin = basins[index]
        color = colour_hex(basin.b)
        fill = tuple(0.45 * c + 0.55 for c in to_rgb(color))  # the colour, lightened
        name = "no battery" if basin.b == 0 else ("unlimited" if math.isinf(basin.b) else "")
        label = f"b = {basin.b:g}" + (f" ({name})" if name else "")
        outcome = np.pad(basin.outcome, 1, mode="edge")
        for code, hatch, words in ((RETURNS, None, "returns to equilibrium"),
                                   (STAYS, "//", "stays in synchronism, never returns (D = 0: oscillates)")):
            region = (outcome == code).astype(float)
            if region.any():
                ax.contourf(angles, speeds, region, levels=[0.5, 1.5], colors=[fill],
                            hatches=[hatch])
                ax.contour(angles, speeds, region, levels=[0.5], colors=[color], linewidths=1.5)
                handles.append(Patch(facecolor=fill, edgecolor=color, hatch=hatch, label=f"{label}: {words}"))
    omega = invariant_set_boundary(plant)
    handles += ax.plot(omega[:, 0], omega[:, 1], color="black", lw=0.8, ls=":",
                       label="invariant set Omega: W <= c, |d| <= pi - 2 delta_bar")
    low, high = (angle - plant.delta_bar_rad for angle in critical_angles_rad(plant))
    handles += ax.plot([low, high], [0.0, 0.0], color="black", lw=3.0, marker="|", markersize=14,
                       label=f"EAC (at rest, no battery): in synchronism for {low:.3f} < d0 < {high:.3f} rad")
    handles += ax.plot([marked_state[0]], [marked_state[1]], "k*", markersize=11,
                       label=f"delta(0) = {marked_state[0] + plant.delta_bar_rad:g} rad, "
                             f"d'(0) = {marked_state[1]:g} rad/s (--delta0, --speed0)")
    handles.append(Line2D([], [], ls="none", label="outside every basin: a pole slip (rotor angle passes +-180 deg)"))
    ax.set_xlim(grid.angle_min_rad, grid.angle_max_rad)
    ax.set_ylim(grid.speed_min_rad_s, grid.speed_max_rad_s)
    ax.set_xlabel("initial angle deviation d0 = delta(0) - delta_bar (rad)")
    ax.set_ylabel("initial speed deviation d0' = omega(0) - omega0 (rad/s)")
    fig.suptitle("Region of attraction of the battery-controlled generator: controller continuous, offline, "
                 "x3(0) = 0,\npost-fault network (the fault has cleared at t = 0); "
                 + model_text.split("; ", 1)[1], fontsize=9)
    fig.legend(handles=handles, loc="outside lower center", ncol=2, fontsize=8)
    ax.grid(True, alpha=0.3)
    return fig


def save_png(fig, path) -> None:
    """Write ``fig`` as a PNG (atomically), its title also in the PNG's Title text chunk."""
    title = fig.get_suptitle()
    with atomic_output(path, "wb") as handle:
        fig.savefig(handle, format="png", dpi=120, metadata={"Title": title.replace("\n", "; ")})


def plot_network(runs, title: str, path) -> None:
    """Per run (column): COI-relative angles, frequency deviations and battery powers with their limits."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, len(runs), figsize=(4.2 * len(runs), 9), sharex=True, squeeze=False,
                             constrained_layout=True)
    for column, (label, traj, r) in enumerate(runs):
        net = traj.net
        scale = net.base_mva / net.mbase_mva
        angles, power = np.degrees(traj.coi_angles()[:, :, r]), traj.battery_power_pu[:, :, r] * scale
        for i, name in enumerate(net.names):
            color = f"C{i % 10}"
            axes[0, column].plot(traj.t_s, angles[:, i], color=color, label=name)
            axes[1, column].plot(traj.t_s, traj.speed_rad_s[:, i, r] / (2 * math.pi), color=color)
            axes[2, column].step(traj.t_s, power[:, i], where="post", color=color)
        limit = traj.limits_pu[:, r] * scale
        if np.all(np.isfinite(limit)) and np.ptp(limit) == 0:
            for sign in (1, -1):
                axes[2, column].axhline(sign * limit[0], color="grey", ls="--", lw=1)
        axes[0, column].set_title(label)
        axes[0, column].set_ylim(-200, 200)
        axes[2, column].set_xlabel("time after the disturbance (s)")
    axes[0, 0].set_ylabel("rotor angle - COI angle (deg)")
    axes[1, 0].set_ylabel("frequency deviation (Hz)")
    axes[2, 0].set_ylabel("battery P_ST (pu of rating; limits dashed)")
    axes[0, 0].legend(loc="upper right", fontsize="small", ncol=2)
    for ax in axes.flat:
        ax.grid(True, alpha=0.3)
    # Wrapped at the figure's edges when drawn: a one-run figure cut its title off at both.
    fig.suptitle(title, wrap=True)
    save_png(fig, path)
    plt.close(fig)


def _cct_grid(rows, contingencies, columns):
    """CCT (s) per contingency (rows) and (law, b) column; NaN where none is known, 0 where even 1 ms loses."""
    index = {(row["contingency"], row["law"], row["b"]): row for row in rows}
    grid = np.full((len(contingencies), len(columns)), np.nan)
    open_top = np.zeros(grid.shape, dtype=bool)
    for i, name in enumerate(contingencies):
        for j, (law, b) in enumerate(columns):
            row = index.get((name, law, b))
            if row is not None:
                grid[i, j] = 0.0 if row["cct_s"] is None else row["cct_s"]
                open_top[i, j] = row["at_search_limit"]
    return grid, open_top


def _screen_figure(count: int):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, max(4.0, min(0.16 * count + 2.0, 80.0))), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _label_contingencies(ax, names, order_text: str) -> None:
    ax.set_yticks(range(len(names)), names if len(names) <= 400 else [""] * len(names),
                  fontsize=7 if len(names) <= 60 else 5)
    ax.set_ylabel(f"contingency ({order_text} at the top)")


def screen_heatmap(rows, contingencies, columns, title: str, cct_max_s: float, path) -> None:
    """Contingency x (law, b): the critical clearing time in ms as colour, weakest contingency at the top.

    ``columns`` is a list of ``(law, b)``; contingencies are ordered by the
    first column's CCT (shortest first); a CCT at the search's upper end is
    marked ``>=``, one that loses synchronism even at 1 ms is 0.
    """
    grid, open_top = _cct_grid(rows, contingencies, columns)
    order = np.argsort(np.nan_to_num(grid[:, 0], nan=np.inf), kind="stable")
    fig = _screen_figure(len(contingencies))
    ax = fig.subplots()
    image = ax.imshow(grid[order] * 1e3, aspect="auto", cmap="viridis", vmin=0.0, vmax=cct_max_s * 1e3,
                      interpolation="nearest")
    for i, k in enumerate(order):
        for j in range(len(columns)):
            if open_top[k, j] and len(contingencies) <= 120:
                ax.text(j, i, ">=", ha="center", va="center", fontsize=5, color="black")
    ax.set_xticks(range(len(columns)), [f"{limit_words(b)}\n{law}" for law, b in columns], fontsize=8)
    _label_contingencies(ax, [contingencies[k] for k in order], "shortest CCT")
    fig.colorbar(image, ax=ax, label="critical clearing time (ms); >= : at the search's upper end")
    fig.suptitle(title, fontsize=10, wrap=True)
    save_png(fig, path)


def screen_gain_chart(rows, contingencies, columns, baseline, title: str, path) -> None:
    """Per contingency, the CCT gain (ms) of each battery limit over ``baseline`` (the same law without battery).

    ``columns``: the ``(law, b)`` with batteries; ``baseline[law]`` the
    ``(law, 0)`` column. A gain whose CCT is at the search's upper end is a
    lower bound (hatched). Contingencies ordered by the first column's gain.
    """
    grid, open_top = _cct_grid(rows, contingencies, columns)
    base, _ = _cct_grid(rows, contingencies, [baseline[law] for law, _ in columns])
    gain = (grid - base) * 1e3
    order = np.argsort(np.nan_to_num(gain[:, 0], nan=np.inf), kind="stable")
    fig = _screen_figure(len(contingencies))
    ax = fig.subplots()
    height = 0.8 / len(columns)
    for j, (law, b) in enumerate(columns):
        y = np.arange(len(contingencies)) + (j - (len(columns) - 1) / 2) * height
        bars = ax.barh(y, gain[order, j], height=height, color=colour_hex(b), label=f"{limit_words(b)}, {law}")
        for bar, lower_bound in zip(bars, open_top[order, j]):
            if lower_bound:
                bar.set_hatch("///")
    ax.axvline(0.0, color="black", lw=0.8)
    ax.invert_yaxis()
    _label_contingencies(ax, [contingencies[k] for k in order], "smallest gain")
    ax.set_xlabel("CCT gain over no battery (ms); hatched: at least this (the CCT reached the search's upper end)")
    ax.legend(loc="lower right", fontsize=8)
    ax.grid(True, axis="x", alpha=0.3)
    fig.suptitle(title, fontsize=10, wrap=True)
    save_png(fig, path)
