"""Section 3: the region-of-attraction sweep, 200 x 200 x 4, vectorised, beside the per-trajectory scipy loop
(``simulate_continuous``) on a stratified subsample, extrapolated; with its report section."""

from __future__ import annotations

import math
import time

import numpy as np

from bench.common import progress, verdict

#: Issue 5's targets: the whole grid's time, the speed-up over the scipy loop, the cells where the two disagree.
ROA_SECONDS_TARGET = 10.0
ROA_SPEEDUP_TARGET = 100.0
ROA_DISAGREEMENT_TARGET = 0.005


def bench_roa(per_b_subsample: int) -> dict:
    """Vectorised sweep of 200 x 200 x 4 beside simulate_continuous on a stratified subsample."""
    from nni_battery_controller import roa
    from nni_battery_controller.law import ControllerParams
    from nni_plant_sim.model import SmibParams

    progress("region of attraction 200 x 200 x 4")
    plant = SmibParams()
    ctrls = [ControllerParams(battery_limit_pu=b) for b in (0.0, 0.2, 0.3, math.inf)]
    grid = roa.RoaGrid(n_angle=200, n_speed=200)
    started = time.perf_counter()
    basins = roa.sweep(plant, ctrls, grid)
    vectorised_s = time.perf_counter() - started
    angle_dev0, speed0 = grid.initial_conditions()
    rng = np.random.default_rng(2024)
    per_b, loop_s, loop_runs, disagreement_cells, loop_extrapolated_s = [], 0.0, 0, 0.0, 0.0
    for ctrl, basin in zip(ctrls, basins):
        edge = roa.boundary_cells(basin.outcome).ravel()
        strata = {"boundary": np.flatnonzero(edge), "interior": np.flatnonzero(~edge)}
        row = {"b": basin.b, "vectorised_s": basin.elapsed_s, "cells": basin.outcome.size}
        for name, cells in strata.items():
            pick = rng.choice(cells, min(per_b_subsample // 2, cells.size), replace=False)
            progress(f"  b = {basin.b:g}: {pick.size} {name} cells with simulate_continuous")
            started = time.perf_counter()
            reference, _ = roa.classify_continuous(plant, ctrl, angle_dev0[pick], speed0[pick])
            elapsed = time.perf_counter() - started
            loop_s += elapsed
            loop_extrapolated_s += cells.size * elapsed / pick.size  # boundary runs last longer: weigh by stratum
            loop_runs += pick.size
            differ = int(np.count_nonzero(reference != basin.outcome.ravel()[pick]))
            row[name] = {"cells": int(cells.size), "checked": int(pick.size), "disagree": differ}
            disagreement_cells += cells.size * differ / pick.size  # stratified estimate
        per_b.append(row)
    per_trajectory_s = loop_extrapolated_s / (angle_dev0.size * len(ctrls))
    return {
        "grid": f"{grid.n_angle} x {grid.n_speed} x {len(ctrls)}", "vectorised_s": vectorised_s,
        "loop_runs": loop_runs, "loop_s": loop_s, "per_trajectory_ms": per_trajectory_s * 1e3,
        "loop_extrapolated_s": loop_extrapolated_s, "speedup": loop_extrapolated_s / vectorised_s,
        "disagreement_fraction": disagreement_cells / (angle_dev0.size * len(ctrls)), "per_b": per_b,
        "step_s": roa.STEP_S,
    }


def roa_section(r: dict) -> list[str]:
    """Section 3: the sweep beside the extrapolated loop, per b, and issue 5's targets."""
    lines = ["## 3. Region-of-attraction sweep beside a per-trajectory scipy loop", "",
             f"The paper's plant and gains, b in {{0, 0.2, 0.3, inf}}, a {r['grid']} grid of initial "
             "conditions (angle deviation within +-pi rad, speed deviation within +-10 rad/s, x3(0) = 0), "
             f"classified vectorised (`roa.sweep`: RK4 at {r['step_s'] * 1e3:g} ms across all cells at once, "
             "early exits). Baseline: `simulate_continuous` (scipy solve_ivp, DOP853, located switching "
             "events, Filippov sliding) one trajectory at a time on a subsample, half on basin-boundary "
             "cells and half inside, extrapolated to the whole grid (each stratum's time per trajectory "
             "times its cell count; the time per trajectory is that total over all cells). Disagreement: "
             "a stratified estimate over the grid (boundary and interior disagreement rates weighted by "
             "their cell counts).", "",
             "| vectorised, whole grid (s) | scipy loop per trajectory (ms) | scipy loop extrapolated (s) "
             "| speed-up | cells checked | disagreement (of all cells) |",
             "|---:|---:|---:|---:|---:|---:|",
             f"| {r['vectorised_s']:.2f} | {r['per_trajectory_ms']:.1f} | {r['loop_extrapolated_s']:.0f} | "
             f"{r['speedup']:.0f}x | {r['loop_runs']} | {100 * r['disagreement_fraction']:.3f} % |", "",
             "| b (pu) | vectorised (s) | boundary cells: checked / disagree | interior cells: checked / "
             "disagree |", "|---:|---:|---|---|"]
    for row in r["per_b"]:
        lines.append(f"| {row['b']:g} | {row['vectorised_s']:.2f} | {row['boundary']['checked']} of "
                     f"{row['boundary']['cells']} / {row['boundary']['disagree']} | "
                     f"{row['interior']['checked']} of {row['interior']['cells']} / "
                     f"{row['interior']['disagree']} |")
    return lines + ["", f"Targets: {r['vectorised_s']:.2f} s < {ROA_SECONDS_TARGET:g} s: "
                        f"{verdict(r['vectorised_s'] < ROA_SECONDS_TARGET)}; {r['speedup']:.0f}x >= "
                        f"{ROA_SPEEDUP_TARGET:g}x: {verdict(r['speedup'] >= ROA_SPEEDUP_TARGET)}; "
                        f"{100 * r['disagreement_fraction']:.3f} % < {100 * ROA_DISAGREEMENT_TARGET:g} %: "
                        f"{verdict(r['disagreement_fraction'] < ROA_DISAGREEMENT_TARGET)}.", ""]
