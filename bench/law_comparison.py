"""Section 13: ``nni-simulate --compare-laws`` (issue 32): the SMIB comparison beside a per-trajectory scipy loop,
and the network comparisons' wall time (Kundur, IEEE 39); with its report section.

The comparison's work is its trajectories: per law and b, the scenario's run and the CCT bisection's runs, each
one sampled-data trajectory of the plant's RK4 (``simulate_sampled``). The baseline integrates the same
trajectories as a user without that integrator would: the same sampled law, each held period integrated by
scipy's ``solve_ivp`` (RK45, rtol 1e-9, atol 1e-11, split at the fault's instants), one trajectory at a time. It
runs the bisections of a few laws at b = 0.3 in full (every CCT it finds must equal ours), and its time per
trajectory, times the comparison's trajectory count, is its extrapolated time for the whole comparison.
"""

from __future__ import annotations

import contextlib
import io
import math
import subprocess
import sys
import time

import numpy as np

from bench.common import ROOT, progress, verdict

#: Issue 32's targets: the SMIB comparison and IEEE 39's, wall time on the 2-core machine.
SMIB_SECONDS_TARGET = 60.0
IEEE39_SECONDS_TARGET = 300.0
#: What the SMIB comparison runs (docs/laws.md's table) and the laws whose bisections the baseline repeats.
SMIB_B = ("0", "0.2", "0.3", "inf")
BASELINE_LAWS = ("nni", "droop", "pss")
NETWORK_COMMANDS = {"kundur_two_area": ["--reference", "pmu", "coi"], "ieee39": ["--reference", "pmu", "coi"]}


def scipy_sampled(plant, law, scenario, duration_s: float, rate_hz: float):
    """The baseline trajectory: ``law`` sampled at ``rate_hz`` as ``simulate_sampled`` samples it, each held
    period integrated by ``solve_ivp``; a :class:`Trajectory` for the same verdicts."""
    from scipy.integrate import solve_ivp

    from nni_battery_controller.simulate import Trajectory
    from nni_plant_sim.model import held_acceleration

    period, n = 1.0 / rate_hz, int(round(duration_s * rate_hz))
    t = np.arange(n + 1) * period
    sampled = law.sampled(plant, period)
    x = np.asarray(scenario.initial_state(plant), dtype=float)
    rows = np.full((n + 1, 6), np.nan)
    for k in range(n + 1):
        if not np.all(np.isfinite(x)):
            break
        x3 = sampled.x3
        power, w, saturated = sampled.step(float(x[0]) - plant.delta_bar_rad, float(x[1]))
        rows[k] = (x[0], x[1], x3, power, w, saturated)
        if k == n:
            break
        cuts = [t[k], *(tb for tb in scenario.breakpoints() if t[k] < tb < t[k + 1]), t[k + 1]]
        for start, stop in zip(cuts[:-1], cuts[1:]):
            p_mech, network = scenario.network(start, plant)
            acceleration = held_acceleration(plant, p_mech, network, float(power), float(x[0]))
            x = solve_ivp(lambda _, y: (y[1], acceleration(y[0], y[1])), (start, stop), x, method="RK45",
                          rtol=1e-9, atol=1e-11).y[:, -1]
    return Trajectory(plant, law.ctrl, t, rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], rows[:, 4],
                      np.nan_to_num(rows[:, 5]).astype(bool), np.empty(0), law.name)


def bench_law_comparison(quick: bool) -> dict:
    """The SMIB comparison in this process (timed, trajectories counted), the baseline's bisections, and the
    network comparisons as a user types them (wall time of the command)."""
    from nni_battery_controller import smib_study
    from nni_battery_controller.margins import critical_clearing_time
    from nni_battery_controller.options import resolve_model
    from nni_battery_controller.verdicts import assess
    from nni_plant_sim.scenarios import TransferLimitFault

    duration_s = 4.0 if quick else 10.0
    argv = ["--compare-laws", "--b", *SMIB_B, "--duration", f"{duration_s:g}"]
    progress("law comparison: nni-simulate " + " ".join(argv))
    counted, simulate, basin, roa_s = [0], smib_study.simulate, smib_study.sampled_basin, [0.0]

    def counting(*args, **kwargs):
        counted[0] += 1
        return simulate(*args, **kwargs)

    def timed_basin(*args, **kwargs):
        started = time.perf_counter()
        try:
            return basin(*args, **kwargs)
        finally:
            roa_s[0] += time.perf_counter() - started

    smib_study.simulate, smib_study.sampled_basin = counting, timed_basin
    try:
        started = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()) as table:
            status = smib_study.main(argv)
        ours_s = time.perf_counter() - started
    finally:
        smib_study.simulate, smib_study.sampled_basin = simulate, basin
    if status != 0:
        raise RuntimeError(f"nni-simulate {' '.join(argv)} exited {status}")
    ours = {(line.split()[1], line.split()[0]): line.split()[2] for line in table.getvalue().splitlines()
            if line.split()[:1] and line.split()[0] in SMIB_B}
    parser = smib_study.build_parser()
    args = parser.parse_args(["--controller-rate", "50"])
    model = resolve_model(args, parser.prog)
    plant, rate = model.smib(), 50.0
    fault_p_max = model.plant["fault_p_max_pu"]
    checked, scipy_s, scipy_runs = [], 0.0, 0
    for name in BASELINE_LAWS[:1] if quick else BASELINE_LAWS:
        law = model.law(0.3, name)
        progress(f"  scipy per trajectory: {name} at b = 0.3, the CCT's bisection")
        runs = [0]

        def in_sync(clearing_s, law=law, runs=runs):
            runs[0] += 1
            return assess(scipy_sampled(plant, law, TransferLimitFault(fault_p_max, clearing_s), duration_s,
                                        rate)).in_synchronism

        started = time.perf_counter()
        cct = critical_clearing_time(in_sync, 0.3, duration_s)
        scipy_s += time.perf_counter() - started
        scipy_runs += runs[0]
        checked.append({"law": name, "scipy_cct_s": cct.cct_s, "ours": ours[(name, "0.3")], "runs": runs[0]})
    per_trajectory_s = scipy_s / scipy_runs
    networks = {}
    for case, extra in NETWORK_COMMANDS.items():
        command = [str(ROOT / ".venv" / "bin" / "nni-simulate"), "--case", case, "--compare-laws", *extra]
        if quick:
            command += ["--b", "0", "0.3", "--duration", "4"]
        progress("law comparison: " + " ".join(command[1:]))
        started = time.perf_counter()
        done = subprocess.run(command, capture_output=True, text=True, timeout=1800)
        networks[case] = {"wall_s": time.perf_counter() - started, "args": " ".join(command[1:]),
                          "error": None if done.returncode == 0 else done.stderr.strip()[:300]}
    # The region-of-attraction sweeps (one vectorised run of every grid cell per law and b) are timed apart: the
    # baseline's trajectories are the runs and bisections only.
    trajectories_s = ours_s - roa_s[0]
    return {"argv": " ".join(argv), "ours_s": ours_s, "roa_s": roa_s[0], "trajectories_s": trajectories_s,
            "trajectories": counted[0], "scipy_s": scipy_s,
            "scipy_runs": scipy_runs, "per_trajectory_ms": per_trajectory_s * 1e3,
            "ours_per_trajectory_ms": trajectories_s / counted[0] * 1e3,
            "scipy_extrapolated_s": per_trajectory_s * counted[0], "checked": checked, "networks": networks}


def law_comparison_section(r: dict) -> list[str]:
    """Section 13: the SMIB comparison beside the scipy loop, the checked CCTs, the networks' wall times."""
    speedup = r["scipy_extrapolated_s"] / r["trajectories_s"]
    lines = ["## 13. Law comparison beside a per-trajectory scipy loop (issue 32)", "",
             f"`nni-simulate {r['argv']}` in one process (5 laws x {len(SMIB_B)} b: each law's run and its "
             "CCT's bisection, every trajectory the plant's sampled RK4, its trajectories counted; and each law's "
             "region-of-attraction sweep, 41 x 41 initial conditions in one vectorised run, timed apart). Baseline: "
             "the same sampled laws with each held period integrated by scipy's `solve_ivp` (RK45, rtol 1e-9), "
             "one trajectory at a time, running the full CCT bisection of the laws below at b = 0.3; its time "
             "per trajectory times the comparison's trajectory count is its extrapolated time.", "",
             "| comparison (s) | of it ROA sweeps (s) | trajectories | ours per trajectory (ms) | scipy per "
             "trajectory (ms) | scipy extrapolated (s) | speed-up (trajectories) |",
             "|---:|---:|---:|---:|---:|---:|---:|",
             f"| {r['ours_s']:.2f} | {r['roa_s']:.2f} | {r['trajectories']} | {r['ours_per_trajectory_ms']:.1f} | "
             f"{r['per_trajectory_ms']:.1f} | {r['scipy_extrapolated_s']:.0f} | {speedup:.1f}x |", "",
             "| law at b = 0.3 | CCT ours (s) | CCT scipy (s) | scipy runs |", "|---|---:|---:|---:|"]
    for row in r["checked"]:
        lines.append(f"| {row['law']} | {row['ours']} | {row['scipy_cct_s']:.3f} | {row['runs']} |")
    lines += ["", "The networks, as a user types them (wall time of the command, every law at every generator, "
                  "the bus fault's run and CCT per b and reference):", "", "| command | wall (s) |", "|---|---:|"]
    for case, net in r["networks"].items():
        text = f"{net['wall_s']:.1f}" if net["error"] is None else f"failed: {net['error']}"
        lines.append(f"| `nni-simulate {net['args']}` | {text} |")
    smib_ok = r["ours_s"] < SMIB_SECONDS_TARGET
    ieee39 = r["networks"].get("ieee39", {})
    ieee39_ok = ieee39.get("error") is None and ieee39.get("wall_s", math.inf) < IEEE39_SECONDS_TARGET
    same = all(f"{row['scipy_cct_s']:.3f}" == row["ours"] for row in r["checked"])
    return lines + ["", f"Targets: the SMIB comparison {r['ours_s']:.1f} s < {SMIB_SECONDS_TARGET:g} s: "
                        f"{verdict(smib_ok)}; IEEE 39's {ieee39.get('wall_s', math.nan):.0f} s < "
                        f"{IEEE39_SECONDS_TARGET:g} s: {verdict(ieee39_ok)}; the baseline's CCTs equal ours: "
                        f"{verdict(same)}.", ""]


if __name__ == "__main__":  # python -m bench.law_comparison [--quick]: the section alone, on stdout
    print("\n".join(law_comparison_section(bench_law_comparison("--quick" in sys.argv))))
