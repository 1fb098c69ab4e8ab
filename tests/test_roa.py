"""Region of attraction (nni_battery_controller.roa, ``nni-simulate --roa``).

Cross-checks the vectorised fixed-step classifier against the event-located
``simulate_continuous`` (a different integrator with located switches and
Filippov sliding), checks the theory's claims on the grid instead of assuming
them, and runs the command line end to end.
"""

from __future__ import annotations

import json
import math
import re
import subprocess

import numpy as np
import pytest

from nni_battery_controller import roa
from nni_battery_controller.simulate import simulate_continuous
from nni_plant_sim.model import in_invariant_set, lyapunov_w
from nni_plant_sim.scenarios import InitialAngle

PAPER_LIMITS = (0.0, 0.2, 0.3, math.inf)
#: Coarse enough to stay fast, fine enough that every basin has a boundary of many cells.
GRID = roa.RoaGrid(n_angle=60, n_speed=60)


@pytest.fixture(scope="module")
def basins(paper_plant, paper_controller):
    """The paper's four battery limits on GRID, keyed by b."""
    ctrls = [paper_controller(b) for b in PAPER_LIMITS]
    return {basin.b: basin for basin in roa.sweep(paper_plant, ctrls, GRID)}


@pytest.mark.parametrize("b, expected", [(0.0, roa.SLIPS), (0.2, roa.RETURNS), (0.3, roa.RETURNS),
                                         (math.inf, roa.RETURNS)])
def test_paper_case_returns_with_any_battery_and_slips_without(paper_plant, paper_controller, paper_fault, b,
                                                               expected):
    """delta(0) = 0.2 rad at rest: the paper's figure 3, by both classifiers."""
    angle_dev0 = paper_fault.delta0_rad - paper_plant.delta_bar_rad
    vectorised, _ = roa.classify(paper_plant, paper_controller(b), [angle_dev0], [0.0])
    per_trajectory, _ = roa.classify_continuous(paper_plant, paper_controller(b), [angle_dev0], [0.0])
    assert vectorised[0] == expected
    assert per_trajectory[0] == expected


@pytest.mark.parametrize("b", PAPER_LIMITS)
def test_vectorised_classifier_agrees_with_simulate_continuous(paper_plant, paper_controller, basins, b):
    """On boundary cells (where a numerical error shows first) and random cells, with a fixed seed.

    Tolerance: at most one boundary cell of 16 may differ. The fixed 10 ms RK4
    step makes an O(h) error where a step straddles a switch of |w| = b; on a
    200 x 200 grid that is measured at about 0.05 % of all cells, all on the
    boundary (BENCHMARKS.md). Interior cells must all agree.
    """
    basin = basins[b]
    angle_dev0, speed0 = GRID.initial_conditions()
    rng = np.random.default_rng(5)
    edge = np.flatnonzero(roa.boundary_cells(basin.outcome).ravel())
    interior = np.flatnonzero(~roa.boundary_cells(basin.outcome).ravel())
    assert edge.size >= 16, "every paper basin has a boundary on this grid"
    picks = {"edge": rng.choice(edge, 16, replace=False), "interior": rng.choice(interior, 8, replace=False)}
    for kind, pick in picks.items():
        reference, _ = roa.classify_continuous(paper_plant, paper_controller(b), angle_dev0[pick], speed0[pick])
        differ = np.count_nonzero(reference != basin.outcome.ravel()[pick])
        assert differ <= (1 if kind == "edge" else 0), (kind, angle_dev0[pick], speed0[pick], reference)


def test_no_cell_is_left_undecided(basins):
    for basin in basins.values():
        assert basin.count(roa.UNDECIDED) == 0, basin.b


def test_certificate_levels_grow_with_b_and_basins_nest(paper_plant, paper_controller, basins):
    """Theory: {|w| < b} grows with b, so the certified sublevel sets of W nest. The basins are checked."""
    levels = [roa.returns_level(paper_plant, paper_controller(b)) for b in PAPER_LIMITS]
    assert levels[0] == 0.0
    assert levels == sorted(levels) and len(set(levels)) == len(levels)
    returns = {b: basin.outcome == roa.RETURNS for b, basin in basins.items()}
    in_sync = {b: basin.outcome != roa.SLIPS for b, basin in basins.items()}
    assert not np.any(returns[0.2] & ~returns[0.3])
    assert not np.any(returns[0.3] & ~returns[math.inf])
    # Everything the machine survives without a battery, any battery brings back.
    assert not np.any(in_sync[0.0] & ~returns[0.2])
    # And the battery enlarges the basin a lot: measured 2.9x (b = 0.2) the no-battery set.
    assert returns[0.2].sum() > 2 * in_sync[0.0].sum()
    # With D = 0 a battery-free machine never returns.
    assert basins[0.0].count(roa.RETURNS) == 0


def test_certificate_region_is_inside_the_unsaturated_set(paper_plant, paper_controller):
    """Points of the sublevel set {W <= level} keep |w| < b and |d| < pi (what makes it a certificate)."""
    from nni_battery_controller.law import saturation_input

    for b in (0.2, 0.3, math.inf):
        ctrl = paper_controller(b)
        level = roa.returns_level(paper_plant, ctrl)
        rng = np.random.default_rng(1)
        angle_dev, x3 = rng.uniform(-4, 4, (2, 200_000))
        inside = roa.linear_loop_lyapunov(angle_dev, 0.0, x3, paper_plant, ctrl) <= level
        assert inside.sum() > 100
        assert np.all(np.abs(angle_dev[inside]) < math.pi)
        assert np.all(np.abs(saturation_input(x3[inside], angle_dev[inside], ctrl, paper_plant)) < b)


def test_no_battery_omega_is_invariant_and_its_cells_never_slip(paper_plant, paper_controller, basins):
    """b = 0: the classifier calls Omega's cells STAYS at once; an independent simulation confirms they stay."""
    angle_dev0, speed0 = GRID.initial_conditions()
    inside = in_invariant_set(angle_dev0, speed0, paper_plant)
    assert inside.sum() > 20
    outcome = basins[0.0].outcome.ravel()
    assert np.all(outcome[inside] == roa.STAYS)
    assert np.all(outcome[~inside] != roa.STAYS)
    pick = np.random.default_rng(2).choice(np.flatnonzero(inside), 5, replace=False)
    limit = math.pi - 2 * paper_plant.delta_bar_rad
    for index in pick:
        run = simulate_continuous(paper_plant, paper_controller(0.0),
                                  InitialAngle(angle_dev0[index] + paper_plant.delta_bar_rad, speed0[index]), 8.0)
        assert np.max(np.abs(run.angle_dev_rad)) <= limit + 1e-6
        w = lyapunov_w(run.angle_dev_rad, run.speed_rad_s, paper_plant)
        np.testing.assert_allclose(w, w[0], atol=1e-6)  # D = 0: W is conserved, the machine never returns


def test_a_pole_slip_between_two_steps_is_caught(paper_plant, paper_controller):
    """b = inf, released toward pi: the rotor angle delta peaks at pi + 5e-4 rad 24.6 ms in, between the
    10 ms steps (3.14097 and 3.14128 rad at their ends, both below pi).

    The peak was found with solve_ivp at rtol 1e-12 (issue 10: the slip rule is now the rotor angle passing
    +-pi, so the grazing case moved from d = pi to delta = pi); the step ends alone would miss it.
    """
    ctrl = paper_controller(math.inf)
    outcome, decided_at = roa.classify(paper_plant, ctrl, [2.1899076490095384], [2.1])
    assert outcome[0] == roa.SLIPS
    assert decided_at[0] <= 0.05


def test_step_peak_angle_is_exact_for_a_cubic():
    """The interpolant is cubic Hermite: exact for d(t) = t^3 - t around its minimum at 1/sqrt(3)."""
    t0, t1 = 0.5, 0.7

    def angle(t):
        return t**3 - t

    def speed(t):
        return 3 * t**2 - 1

    peak = roa.step_peak_angle(np.array([angle(t0)]), np.array([speed(t0)]), np.array([angle(t1)]),
                               np.array([speed(t1)]), t1 - t0)
    np.testing.assert_allclose(peak, angle(3**-0.5), rtol=1e-12)


def test_bad_inputs_are_rejected(paper_plant, paper_controller):
    ctrl = paper_controller(0.3)
    with pytest.raises(ValueError, match="same size"):
        roa.classify(paper_plant, ctrl, [0.0, 0.1], [0.0])
    with pytest.raises(ValueError, match="finite"):
        roa.classify(paper_plant, ctrl, [math.nan], [0.0])
    with pytest.raises(ValueError, match="min < max"):
        roa.RoaGrid(angle_min_rad=1.0, angle_max_rad=-1.0)
    with pytest.raises(ValueError, match="n_angle"):
        roa.RoaGrid(n_angle=1)


def test_cli_writes_png_and_json_with_progress(nni_simulate_exe, tmp_path):
    prefix = tmp_path / "roa"
    result = subprocess.run([str(nni_simulate_exe), "--roa", str(prefix), "--roa-grid", "30"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    done = re.findall(r"region of attraction (\d/\d) \(b = [^)]*\): \d+ of 900 initial conditions return",
                      result.stderr)
    assert done == ["1/4", "2/4", "3/4", "4/4"]  # one line as each b is done (and more on long sweeps)
    assert (tmp_path / "roa.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = json.loads((tmp_path / "roa.json").read_text())
    assert {"grid", "time_model", "outcomes", "plant", "controller", "invariant_set", "eac", "basins"} <= set(summary)
    assert [item["b"] for item in summary["basins"]] == [0.0, 0.2, 0.3, "inf"]
    for item in summary["basins"]:
        assert {"returns_area_rad2_per_s", "returns_fraction", "synchronism_area_rad2_per_s", "cells"} <= set(item)
        assert sum(item["cells"].values()) == 30 * 30
    areas = [item["returns_area_rad2_per_s"] for item in summary["basins"]]
    assert areas[0] == 0.0 and areas[1] < areas[2] < areas[3]
    assert summary["invariant_set"]["area_rad2_per_s"] == pytest.approx(9.93, abs=0.01)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["roa.json", "roa.png"]  # no temporary left


@pytest.mark.parametrize("args, complaint", [
    (["--roa-grid", "5"], "--roa-grid"),
    (["--roa-grid", "many"], "--roa-grid"),
    (["--roa-speed-max", "-1"], "--roa-speed-max"),
    (["--controller-rate", "50"], "continuous law"),
])
def test_cli_bad_input_is_one_line_and_writes_nothing(nni_simulate_exe, tmp_path, args, complaint):
    result = subprocess.run([str(nni_simulate_exe), "--roa", str(tmp_path / "roa"), *args],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("nni-simulate: error:") and complaint in lines[0]
    assert "Traceback" not in result.stderr
    assert list(tmp_path.iterdir()) == []
