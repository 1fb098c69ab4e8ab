"""Closed-loop simulations against the paper's claims and against independent numerics.

Covers the paper's four cases (section VII), the battery limit, leaving
saturation (Remark 2), W_hat along trajectories (section IV, Theorem 3),
continuous vs sampled-data convergence, and an independent fine-step
integration of the loop written here from DESIGN.md.
"""

from __future__ import annotations

import json
import math
import signal
import subprocess
from contextlib import contextmanager

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose
from scipy.integrate import solve_ivp

from nni_battery_controller.law import ControllerParams, SampledController, q1_matrix
from nni_battery_controller.simulate import simulate_continuous, simulate_sampled
from nni_battery_controller.verdicts import assess
from nni_plant_sim.integrators import advance
from nni_plant_sim.model import SmibParams
from nni_plant_sim.scenarios import InitialAngle

PAPER_LIMITS = (0.0, 0.2, 0.3, math.inf)
DURATION_S = 10.0
SAMPLED_RATE_HZ = 50.0
#: simulate_continuous's default relative tolerance (DOP853), the yardstick for "exact" checks.
CONTINUOUS_RTOL = 1e-10
#: |w| this close to b on a saturated sample means the run is sliding on the surface (the
#: sliding field holds w constant; the integrator keeps it there to ~1e-11 in these runs).
ON_SURFACE_PU = 1e-8


@contextmanager
def time_limit(seconds: float):
    """Raise TimeoutError in the block after ``seconds`` of wall time (SIGALRM, main thread)."""

    def expire(signum, frame):
        raise TimeoutError(f"did not finish within {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


@pytest.fixture(scope="module")
def paper_runs(paper_plant, paper_fault, paper_controller):
    """The paper's four cases, 10 s: continuous (1 ms output) and sampled at 50 Hz."""
    runs = {}
    for b in PAPER_LIMITS:
        ctrl = paper_controller(b)
        runs["continuous", b] = simulate_continuous(paper_plant, ctrl, paper_fault, DURATION_S)
        runs["sampled", b] = simulate_sampled(paper_plant, ctrl, paper_fault, DURATION_S, SAMPLED_RATE_HZ)
    return runs


def restoring_energy_paper(d, plant: SmibParams):
    """G(d) = int_0^d g = P_max (d sin(delta_bar) + cos(d + delta_bar) - cos(delta_bar))."""
    db = math.asin(plant.p_mech_pu / plant.p_max_pu)
    return plant.p_max_pu * (d * math.sin(db) + np.cos(d + db) - math.cos(db))


def restoring_power_paper(d, plant: SmibParams):
    db = math.asin(plant.p_mech_pu / plant.p_max_pu)
    return plant.p_max_pu * (math.sin(db) - np.sin(d + db))


def w_hat_by_mode(run):
    """W_hat = V1 + V3 - F with the paper's F chosen by the mode the run reports at each sample."""
    ctrl, plant = run.ctrl, run.plant
    d, speed, x3, b = run.angle_dev_rad, run.speed_rad_s, run.x3, ctrl.battery_limit_pu
    f_unsat = x3 * d - 0.5 * ctrl.gain_l * d**2
    if math.isinf(b):
        f = f_unsat
    else:
        f = np.where(run.saturated, restoring_energy_paper(d, plant) + np.sign(run.w) * b * d, f_unsat)
    return 0.5 * plant.inertia_m * speed**2 + x3**2 / (2 * ctrl.gain_k) - f


def jump_j(d, run):
    """J(d) = L d^2/2 + g(d) d - G(d): W_hat(saturated F) - W_hat(unsaturated F) on |w| = b.

    Derived in test_controller_law.jump_paper and checked there against quad.
    """
    plant = run.plant
    return 0.5 * run.ctrl.gain_l * d**2 + restoring_power_paper(d, plant) * d - restoring_energy_paper(d, plant)


def mode_labels(run):
    """0 = unsaturated, 1 = saturated off the surface, 2 = sliding on |w| = b."""
    sliding = run.saturated & (np.abs(np.abs(run.w) - run.ctrl.battery_limit_pu) <= ON_SURFACE_PU)
    return np.where(sliding, 2, np.where(run.saturated, 1, 0))


# --- 1. the paper's case --------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["continuous", "sampled"])
def test_paper_case_without_battery_loses_synchronism(paper_runs, paper_plant, kind):
    run = paper_runs[kind, 0.0]
    d = run.angle_dev_rad
    assert np.max(np.abs(d)) > math.pi
    assert d[-1] > 100.0  # slipping pole after pole, not an excursion
    assert np.all(run.battery_power_pu == 0.0)
    assert not assess(run).stable


@pytest.mark.parametrize("kind", ["continuous", "sampled"])
@pytest.mark.parametrize("b", [0.2, 0.3, math.inf])
def test_paper_case_with_battery_returns_to_equilibrium(paper_runs, paper_plant, kind, b):
    run = paper_runs[kind, b]
    d = run.angle_dev_rad
    # The first swing never reaches the unstable equilibrium pi - 2 delta_bar = 1.287 rad.
    assert np.max(d) < math.pi - 2 * paper_plant.delta_bar_rad
    last_second = run.t_s >= DURATION_S - 1.0
    assert np.all(np.abs(d[last_second]) <= 0.02)
    # Measured at 10 s: |d| <= 4.4e-4 rad and |d'| <= 1e-2 rad/s in all six runs (50 Hz b = 0.2 is slowest).
    assert abs(d[-1]) < 1e-3
    assert abs(run.speed_rad_s[-1]) < 2e-2
    assert assess(run).stable


# --- 2. the battery limit ----------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["continuous", "sampled"])
@pytest.mark.parametrize("b", PAPER_LIMITS)
def test_battery_power_never_exceeds_the_limit_in_the_paper_case(paper_runs, kind, b):
    power = paper_runs[kind, b].battery_power_pu
    assert np.all(np.abs(power) <= b)
    if 0 < b < math.inf:
        assert np.max(np.abs(power)) == b  # the limit is reached: the runs do saturate


@settings(max_examples=15, deadline=None)
@given(b=st.floats(0.0, 1.0), delta0=st.floats(-0.6, 1.5), speed0=st.floats(-2.0, 2.0),
       rate_hz=st.sampled_from([50.0, 100.0, 1000.0]))
def test_sampled_battery_power_never_exceeds_a_random_limit(paper_plant, paper_controller, b, delta0, speed0,
                                                            rate_hz):
    run = simulate_sampled(paper_plant, paper_controller(b), InitialAngle(delta0, speed0), 3.0, rate_hz)
    assert np.all(np.abs(run.battery_power_pu) <= b)


@settings(max_examples=15, deadline=None, derandomize=True)
@given(b=st.floats(0.01, 1.0))
@example(b=0.179)
def test_continuous_battery_power_never_exceeds_a_random_limit(paper_plant, paper_fault, paper_controller, b):
    with time_limit(5.0):  # a normal 10 s run takes < 0.5 s
        run = simulate_continuous(paper_plant, paper_controller(b), paper_fault, DURATION_S)
    assert np.all(np.abs(run.battery_power_pu) <= b)


# --- 3. leaving saturation (Remark 2) -------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["continuous", "sampled"])
@pytest.mark.parametrize("b", [0.2, 0.3])
def test_finite_battery_leaves_saturation_for_good(paper_runs, kind, b):
    run = paper_runs[kind, b]
    last = assess(run).last_saturated_s
    # Measured: continuous 2.543 s (b = 0.2), 0.559 s (b = 0.3); 50 Hz 2.86 s, 1.20 s.
    assert last is not None and last < 3.5
    after = run.t_s > last
    assert after.sum() > 0.6 * after.size
    assert not np.any(run.saturated[after])
    assert np.all(np.abs(run.w[after]) < b)
    if kind == "continuous":
        assert last == run.switch_times_s[-1]  # the located instant of the last exit


# --- 5. W_hat along trajectories ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def fine_output_runs(paper_plant, paper_fault, paper_controller):
    """4 s continuous runs with a 0.1 ms output grid, to resolve W_hat around switches."""
    return {b: simulate_continuous(paper_plant, paper_controller(b), paper_fault, 4.0, output_step_s=1e-4)
            for b in (0.15, 0.2, 0.25, 0.3)}


@pytest.mark.parametrize("b", [0.15, 0.2, 0.25, 0.3])
def test_w_hat_never_increases_within_a_mode(fine_output_runs, b):
    """Theorem 3's W_hat' <= 0, checked inside each unsaturated and each (off-surface) saturated stretch.

    Tolerance: the integrator keeps each state's local error within rtol = 1e-10 of its size,
    W_hat is smooth in the state, so a numerical increase between samples can be at most
    ~rtol * |W_hat|; we allow rtol * max|W_hat| (measured worst: 5e-12 relative).
    """
    run = fine_output_runs[b]
    w_hat = w_hat_by_mode(run)
    labels = mode_labels(run)
    segment = np.searchsorted(run.switch_times_s, run.t_s)
    same_stretch = (labels[1:] == labels[:-1]) & (segment[1:] == segment[:-1])
    increase = np.diff(w_hat)
    tolerance = CONTINUOUS_RTOL * np.max(np.abs(w_hat))
    for label in (0, 1):
        pairs = same_stretch & (labels[:-1] == label)
        assert pairs.sum() > 500
        assert increase[pairs].max() <= tolerance


@pytest.mark.parametrize("b", [0.15, 0.2, 0.25, 0.3])
def test_w_hat_jumps_by_j_at_each_switch(fine_output_runs, b):
    """The paper's F is discontinuous on |w| = b: entering saturation raises W_hat by J(d) > 0,
    leaving lowers it by J(d).

    One-sided limits come from linear extrapolation of the two samples on each side over less
    than one output step h = 0.1 ms: error <= h^2 max|W_hat''| ~ 1e-7; atol = 1e-6 pu rad.
    """
    run = fine_output_runs[b]
    w_hat = w_hat_by_mode(run)
    h = run.t_s[1] - run.t_s[0]
    assert run.switch_times_s.size >= 2
    for t_switch in run.switch_times_s:
        i = int(np.searchsorted(run.t_s, t_switch, side="right"))  # first sample after the switch
        before, after = w_hat[i - 1] + (w_hat[i - 1] - w_hat[i - 2]) * (t_switch - run.t_s[i - 1]) / h, \
            w_hat[i] - (w_hat[i + 1] - w_hat[i]) * (run.t_s[i] - t_switch) / h
        entering = bool(run.saturated[i])
        assert entering != bool(run.saturated[i - 1])
        j = jump_j(np.interp(t_switch, run.t_s, run.angle_dev_rad), run)
        assert j > 0  # L = 1.1 > P_max: J(d) > 0 for d != 0
        assert_allclose(after - before, j if entering else -j, rtol=0, atol=1e-6)


@pytest.mark.parametrize("b", [0.2, 0.3])
def test_sliding_on_the_surface_is_a_filippov_solution(fine_output_runs, b):
    """On |w| = b the law chatters; the continuous run follows the Filippov convex combination:
    x3' lies between the saturated field -(alpha/K) x3 and the unsaturated (K d - x3)/tau.

    x3' comes from central differences on the 0.1 ms grid (error ~ h^2 |x3'''| / 6 < 1e-6 pu/s);
    lambda = (x3' - f_sat)/(f_unsat - f_sat) must lie in [0, 1] up to 1e-3.
    """
    run = fine_output_runs[b]
    ctrl = run.ctrl
    labels = mode_labels(run)
    interior = np.flatnonzero((labels[1:-1] == 2) & (labels[:-2] == 2) & (labels[2:] == 2)) + 1
    assert interior.size > 100  # the paper's case slides (b = 0.2: three times, b = 0.3: once)
    assert_allclose(np.abs(run.battery_power_pu[interior]), b, rtol=0, atol=0)
    h = run.t_s[1] - run.t_s[0]
    x3_rate = (run.x3[interior + 1] - run.x3[interior - 1]) / (2 * h)
    d, x3 = run.angle_dev_rad[interior], run.x3[interior]
    f_unsat, f_sat = (ctrl.gain_k * d - x3) / ctrl.tau_s, -(ctrl.alpha / ctrl.gain_k) * x3
    weight = (x3_rate - f_sat) / (f_unsat - f_sat)
    assert weight.min() >= -1e-3 and weight.max() <= 1 + 1e-3


def test_trajectory_w_hat_uses_the_mode_in_force(paper_runs):
    run = paper_runs["continuous", 0.2]
    # Same formula, same state: only rounding may differ.
    assert_allclose(run.w_hat, w_hat_by_mode(run), rtol=1e-12, atol=1e-14)


def test_unlimited_battery_w_hat_is_half_z_q1_z_and_never_increases(paper_runs, paper_plant):
    run = paper_runs["continuous", math.inf]
    ctrl = run.ctrl
    z = np.vstack((run.speed_rad_s, run.angle_dev_rad, run.x3))
    quadratic = 0.5 * np.einsum("in,ij,jn->n", z, q1_matrix(paper_plant.inertia_m, ctrl.gain_k, ctrl.gain_l), z)
    assert_allclose(run.w_hat, quadratic, rtol=1e-12, atol=1e-15)
    # Tolerance as in test_w_hat_never_increases_within_a_mode.
    assert np.diff(run.w_hat).max() <= CONTINUOUS_RTOL * run.w_hat.max()
    assert run.w_hat[-1] < 1e-8 * run.w_hat[0]  # and it decays to the equilibrium


# --- 7. sampled-data vs continuous ----------------------------------------------------------------------


@pytest.mark.parametrize("b", [0.3, math.inf])
def test_sampled_law_converges_to_the_continuous_law_at_first_order(paper_plant, paper_fault, paper_controller, b):
    """max |d_sampled - d_continuous| on the sample grid over 4 s.

    Measured (b = 0.3 / inf), rad: 50 Hz 6.5e-2 / 6.2e-2, 100 Hz 3.4e-2 / 3.2e-2, 200 Hz 1.6e-2 / 1.6e-2,
    500 Hz 7.6e-3 / 6.5e-3, 1 kHz 2.3e-3 / 3.3e-3, 2 kHz 1.6e-3 / 1.6e-3: error ~ 3.2 rad Hz / rate,
    the zero-order hold's half-period delay.
    """
    ctrl = paper_controller(b)
    duration, output_step = 4.0, 5e-4
    continuous = simulate_continuous(paper_plant, ctrl, paper_fault, duration, output_step_s=output_step)
    rates = np.array([50, 100, 200, 500, 1000, 2000])
    errors = []
    for rate in rates:
        sampled = simulate_sampled(paper_plant, ctrl, paper_fault, duration, float(rate))
        every = int(round(1.0 / (rate * output_step)))
        assert_allclose(continuous.t_s[::every], sampled.t_s, rtol=0, atol=1e-9)
        errors.append(np.max(np.abs(sampled.angle_dev_rad - continuous.angle_dev_rad[::every])))
    errors = np.array(errors)
    assert np.all(np.diff(errors) < 0)
    for low, high in ((50, 500), (100, 1000), (200, 2000)):
        assert errors[rates == low][0] / errors[rates == high][0] > 5.0
    slope = np.polyfit(np.log(rates), np.log(errors), 1)[0]
    assert -1.3 < slope < -0.75
    assert errors[-1] < 2.5e-3


# --- 10. the sampled loop holds the law's output ----------------------------------------------------------


def test_sampled_run_holds_the_controller_output_over_each_period(paper_runs, paper_plant):
    run = paper_runs["sampled", 0.3]
    period = 1.0 / SAMPLED_RATE_HZ
    controller = SampledController(paper_plant, run.ctrl, period)
    for k in range(run.t_s.size):
        assert controller.x3 == run.x3[k]  # same law, same samples: bit for bit
        power, w, saturated = controller.step(float(run.angle_dev_rad[k]))
        assert (power, w, saturated) == (run.battery_power_pu[k], run.w[k], run.saturated[k])
    # Between samples the plant sees P_ST held: an adaptive reference with the sample's power
    # reproduces the next sample (RK4 at 1 ms over 20 ms: error ~1e-11; atol 1e-9).
    for k in (0, 5, 7, 20, 60, 200):
        reference = solve_ivp(
            lambda t, x: [x[1], (paper_plant.p_mech_pu + run.battery_power_pu[k] - paper_plant.p_max_pu * math.sin(x[0])
                                 - paper_plant.damping_pu * x[1]) / paper_plant.inertia_m],
            (0.0, period), [run.delta_rad[k], run.speed_rad_s[k]], rtol=1e-12, atol=1e-14,
        )
        assert_allclose(reference.y[:, -1], [run.delta_rad[k + 1], run.speed_rad_s[k + 1]], rtol=0, atol=1e-9)


# --- 11. an independent fine-step integration ------------------------------------------------------------


def fine_step_closed_loop(plant: SmibParams, ctrl, delta0: float, speed0: float, duration_s: float,
                          step_s: float = 5e-5, record_every_s: float = 1e-3):
    """Classical RK4 of the closed loop, written from DESIGN.md; the mode is decided at each step.

        M delta'' = P_M + P_ST - P_max sin(delta) - D delta'
        w = x3 - L d - g(d);  |w| < b: P_ST = w, x3' = (K d - x3)/tau
                              |w| >= b: P_ST = b sign(w), x3' = -(alpha/K) x3

    On a sliding surface this chatters at the step rate, approximating the Filippov solution
    to O(step). Returns the 1 ms samples of d and P_ST, and the last saturated step time.
    """
    m = 2 * plant.inertia_h_s / (2 * math.pi * plant.f0_hz)
    p_mech, p_max, damping = plant.p_mech_pu, plant.p_max_pu, plant.damping_pu
    db = math.asin(p_mech / p_max)
    k_gain, l_gain, tau, alpha, b = ctrl.gain_k, ctrl.gain_l, ctrl.tau_s, ctrl.alpha, ctrl.battery_limit_pu
    sin = math.sin
    steps, every = round(duration_s / step_s), round(record_every_s / step_s)
    delta, speed, x3 = delta0, speed0, 0.0
    angle_dev, power_out, last_saturated = [], [], None

    def field(delta, speed, x3, saturated, held_power):
        d = delta - db
        if saturated:
            power, x3_dot = held_power, -(alpha / k_gain) * x3
        else:
            power, x3_dot = x3 - l_gain * d - (p_max * sin(db) - p_max * sin(delta)), (k_gain * d - x3) / tau
        return speed, (p_mech + power - p_max * sin(delta) - damping * speed) / m, x3_dot

    for n in range(steps + 1):
        w = x3 - l_gain * (delta - db) - (p_max * sin(db) - p_max * sin(delta))
        saturated = abs(w) >= b
        held_power = math.copysign(b, w) if saturated and b > 0 else 0.0
        if saturated:
            last_saturated = n * step_s
        if n % every == 0:
            angle_dev.append(delta - db)
            power_out.append(held_power if saturated else w)
        if n == steps:
            break
        a1, b1, c1 = field(delta, speed, x3, saturated, held_power)
        a2, b2, c2 = field(delta + 0.5 * step_s * a1, speed + 0.5 * step_s * b1, x3 + 0.5 * step_s * c1,
                           saturated, held_power)
        a3, b3, c3 = field(delta + 0.5 * step_s * a2, speed + 0.5 * step_s * b2, x3 + 0.5 * step_s * c2,
                           saturated, held_power)
        a4, b4, c4 = field(delta + step_s * a3, speed + step_s * b3, x3 + step_s * c3, saturated, held_power)
        delta += step_s / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
        speed += step_s / 6 * (b1 + 2 * b2 + 2 * b3 + b4)
        x3 += step_s / 6 * (c1 + 2 * c2 + 2 * c3 + c4)
    return np.array(angle_dev), np.array(power_out), last_saturated


def test_independent_fine_step_integration_agrees_with_nni_simulate(tmp_path, nni_simulate_exe, paper_plant,
                                                                     paper_fault, paper_controller):
    summary = tmp_path / "paper.json"
    subprocess.run([str(nni_simulate_exe), "--json", str(summary)], check=True, capture_output=True, timeout=120)
    scenarios = json.loads(summary.read_text())["scenarios"]
    assert [s["b"] for s in scenarios] == [0.0, 0.2, 0.3, "inf"]
    for scenario in scenarios:
        b = math.inf if scenario["b"] == "inf" else scenario["b"]
        ctrl = paper_controller(b)
        angle_dev, power, last_saturated = fine_step_closed_loop(
            paper_plant, ctrl, paper_fault.delta0_rad, paper_fault.speed0_rad_s, DURATION_S)
        last_second = angle_dev[-1001:]
        stable = bool(np.max(np.abs(angle_dev)) < math.pi and np.all(np.abs(last_second) <= 0.02))
        assert scenario["stable"] == stable
        # Chattering vs Filippov: the trajectories differ by O(step) = 2e-4 rad at most (measured, b = 0.2
        # near t = 2.95 s; 5.7e-4 at a 0.1 ms step), and by 1e-10 * |d| (the DOP853 rtol) without a surface.
        assert_allclose(scenario["final_angle_dev_rad"], angle_dev[-1], rtol=1e-9, atol=1e-6)
        assert_allclose(scenario["max_abs_angle_dev_rad"], np.max(np.abs(angle_dev)), rtol=1e-9, atol=1e-6)
        assert_allclose(scenario["max_abs_battery_power_pu"], np.max(np.abs(power)), rtol=1e-6, atol=0)
        if math.isinf(b):
            assert scenario["last_saturated_s"] is None and last_saturated is None
        elif b == 0:  # |w| >= 0 at every step, but with no battery there is no saturation to leave
            assert scenario["last_saturated_s"] is None and last_saturated == pytest.approx(DURATION_S)
        else:
            # The chattering run's last saturated step leads a tangential Filippov exit by
            # ~sqrt(2 w'_sat step / |w'_unsat'|) ~ 1 ms (measured 0.64 ms at b = 0.2); allow 3 ms.
            assert_allclose(scenario["last_saturated_s"], last_saturated, rtol=0, atol=3e-3)
        # Whole trajectory against the core's event-located run.
        continuous = simulate_continuous(paper_plant, ctrl, paper_fault, DURATION_S)
        tolerance = 1e-3 if 0 < b < math.inf else 1e-9 * np.max(np.abs(angle_dev)) + 1e-9
        assert np.max(np.abs(continuous.angle_dev_rad - angle_dev)) <= tolerance


def test_a_diverging_sampled_design_is_reported_unstable_not_raised(paper_plant, paper_fault, paper_controller):
    """L = 100 at 10 samples/s is far outside what the sampled loop tolerates: it overflows to inf.

    The simulation then reports no state and no battery power from the
    overflow on, and assess() calls the run unstable; a diverged one-state RK4
    gives NaN (as numpy's sine would) rather than math's domain error.
    """
    ctrl = ControllerParams(gain_l=100.0, battery_limit_pu=math.inf)
    run = simulate_sampled(paper_plant, ctrl, paper_fault, 60.0, 10.0)
    diverged = np.isnan(run.delta_rad)
    assert diverged.any() and diverged[-1] and np.all(np.isfinite(run.delta_rad[~diverged]))
    assert np.all(run.battery_power_pu[diverged] == 0.0)
    assert not assess(run).stable
    assert np.all(np.isnan(advance(0.0, 0.01, [math.inf, 0.0], 0.0, paper_plant, paper_fault)))
