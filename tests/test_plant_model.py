"""Theory checks of the SMIB plant (paper section V): swing equation, W, EAC, invariant set Omega.

Expected values are computed here from the paper's formulas or by independent
numerics (quad, solve_ivp, bisection over simulations), never read back from
the module under test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose
from scipy.integrate import quad, solve_ivp
from scipy.optimize import brentq, minimize_scalar

from nni_battery_controller.law import ControllerParams
from nni_battery_controller.simulate import simulate_continuous
from nni_plant_sim.integrators import advance, rk4_step
from nni_plant_sim.model import (
    SmibParams,
    held_acceleration,
    critical_angles_rad,
    eac_stable,
    equal_area_margin,
    in_invariant_set,
    invariant_set_boundary,
    invariant_set_level,
    lyapunov_w,
    restoring_energy,
    restoring_power,
    swing_acceleration,
    swing_rhs,
)
from nni_plant_sim.scenarios import InitialAngle, MechanicalPowerStep, TransferLimitFault

ALGEBRA = settings(max_examples=150, deadline=None)

plants = st.builds(
    lambda h, damping, p_max, ratio, f0: SmibParams(h, damping, ratio * p_max, p_max, f0),
    st.floats(0.5, 10.0), st.floats(0.0, 2.0), st.floats(0.2, 3.0), st.floats(0.0, 0.95), st.sampled_from([50.0, 60.0]),
)


def delta_bar(plant: SmibParams) -> float:
    return math.asin(plant.p_mech_pu / plant.p_max_pu)


def gamma_paper(d, plant: SmibParams):
    """The paper's Gamma(d) = -P d sin(delta_bar) + P cos(delta_bar) - P cos(d + delta_bar)."""
    db, p = delta_bar(plant), plant.p_max_pu
    return -p * d * math.sin(db) + p * math.cos(db) - p * np.cos(d + db)


def slips_without_battery(plant: SmibParams, delta0_rad: float, duration_s: float = 6.0) -> bool:
    """Simulated b = 0 run released at rest from delta0: does |d| ever pass pi?"""
    no_battery = ControllerParams(battery_limit_pu=0.0)
    run = simulate_continuous(plant, no_battery, InitialAngle(delta0_rad, 0.0), duration_s, output_step_s=1e-2)
    return bool(np.max(np.abs(run.angle_dev_rad)) > math.pi)


# --- parameters -----------------------------------------------------------------------------


def test_paper_equilibrium_and_inertia(paper_plant):
    # The paper: delta_bar = 0.927 rad (3 digits); M = 2H/omega0 = 8/(100 pi).
    assert_allclose(paper_plant.delta_bar_rad, 0.927, atol=5e-4)
    assert_allclose(paper_plant.inertia_m, 8.0 / (100.0 * math.pi), rtol=1e-15)
    assert_allclose(paper_plant.omega0_rad_s, 100.0 * math.pi, rtol=1e-15)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"p_mech_pu": 1.0}, r"P_M must be less than P_max"),
        ({"p_mech_pu": 1.5}, r"P_M must be less than P_max"),
        ({"p_mech_pu": -0.1}, r"P_M must be non-negative"),
        ({"inertia_h_s": 0.0}, r"H must be positive"),
        ({"inertia_h_s": -4.0}, r"H must be positive"),
        ({"damping_pu": -0.01}, r"D must be non-negative"),
        ({"p_max_pu": 0.0}, r"P_max must be positive"),
        ({"p_max_pu": -1.0}, r"P_max must be positive"),
        ({"f0_hz": 0.0}, r"f0 must be positive"),
        ({"f0_hz": -50.0}, r"f0 must be positive"),
        ({"inertia_h_s": math.nan}, r"inertia_h_s must be a finite number, got NaN"),
        ({"damping_pu": math.nan}, r"damping_pu must be a finite number, got NaN"),
        ({"p_mech_pu": math.nan}, r"p_mech_pu must be a finite number, got NaN"),
        ({"p_max_pu": math.nan}, r"p_max_pu must be a finite number, got NaN"),
        ({"f0_hz": math.nan}, r"f0_hz must be a finite number, got NaN"),
        ({"inertia_h_s": math.inf}, r"inertia_h_s must be finite"),
        ({"damping_pu": math.inf}, r"damping_pu must be finite"),
        ({"p_max_pu": math.inf}, r"p_max_pu must be finite"),
        ({"f0_hz": -math.inf}, r"f0_hz must be finite"),
    ],
)
def test_invalid_plant_parameters_name_the_violated_condition(overrides, message):
    params = {"inertia_h_s": 4.0, "damping_pu": 0.0, "p_mech_pu": 0.8, "p_max_pu": 1.0, "f0_hz": 50.0, **overrides}
    with pytest.raises(ValueError, match=message):
        SmibParams(**params)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: InitialAngle(math.nan, 0.0), r"delta0_rad must be a finite number, got NaN"),
        (lambda: InitialAngle(0.2, math.nan), r"speed0_rad_s must be a finite number, got NaN"),
        (lambda: InitialAngle(math.inf, 0.0), r"delta0_rad and speed0_rad_s must be finite"),
        (lambda: InitialAngle(0.2, -math.inf), r"delta0_rad and speed0_rad_s must be finite"),
        (lambda: MechanicalPowerStep(-0.1), r"p_mech_pu during the step must be finite and >= 0"),
        (lambda: MechanicalPowerStep(math.inf), r"p_mech_pu during the step must be finite and >= 0"),
        (lambda: MechanicalPowerStep(math.nan), r"p_mech_pu must be a finite number, got NaN"),
        (lambda: MechanicalPowerStep(0.95, 0.0), r"duration_s of the power step must be positive"),
        (lambda: MechanicalPowerStep(0.95, -1.0), r"duration_s of the power step must be positive"),
        (lambda: MechanicalPowerStep(0.95, math.nan), r"duration_s must be a finite number, got NaN"),
        (lambda: TransferLimitFault(-0.5), r"p_max_fault_pu must be finite and >= 0"),
        (lambda: TransferLimitFault(math.inf), r"p_max_fault_pu must be finite and >= 0"),
        (lambda: TransferLimitFault(0.0, 0.0), r"clearing_time_s must be finite and positive"),
        (lambda: TransferLimitFault(0.0, -0.1), r"clearing_time_s must be finite and positive"),
        (lambda: TransferLimitFault(0.0, math.inf), r"clearing_time_s must be finite and positive"),
        (lambda: TransferLimitFault(0.0, math.nan), r"clearing_time_s must be a finite number, got NaN"),
    ],
)
def test_invalid_scenarios_name_the_violated_condition(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_invariant_set_level_out_of_range_is_refused(paper_plant):
    c_max = invariant_set_level(paper_plant)
    for level in (0.0, -0.1, 1.01 * c_max):
        with pytest.raises(ValueError, match=r"invariant set level c must satisfy 0 < c <="):
            in_invariant_set(0.0, 0.0, paper_plant, level)


# --- swing equation and W -----------------------------------------------------------------------


@ALGEBRA
@given(plant=plants, d=st.floats(-3.0, 3.0))
def test_restoring_energy_is_the_integral_of_g(plant, d):
    db, p = delta_bar(plant), plant.p_max_pu
    assert_allclose(restoring_power(d, plant), p * math.sin(db) - p * math.sin(d + db), rtol=1e-13, atol=1e-14)
    integral = quad(lambda xi: p * math.sin(db) - p * math.sin(xi + db), 0.0, d, epsabs=1e-14, epsrel=1e-13)[0]
    # quad reaches ~1e-13 relative on this analytic integrand; G's own rounding is ~1e-16 * P.
    assert_allclose(restoring_energy(d, plant), integral, rtol=1e-11, atol=1e-13)


@ALGEBRA
@given(plant=plants, d=st.lists(st.floats(-3, 3), min_size=1, max_size=5),
       speed=st.floats(-10, 10), battery_pu=st.floats(-1, 1))
def test_swing_rhs_is_the_deviation_form_of_the_swing_equation(plant, d, speed, battery_pu):
    """M d'' + D d' = g(d) + P_ST, with P_M = P_max sin(delta_bar) (pre-fault network), vectorised."""
    d = np.array(d)
    x = np.vstack((d + delta_bar(plant), np.full_like(d, speed)))
    rhs = swing_rhs(x, battery_pu, plant, plant.p_mech_pu, plant.p_max_pu)
    assert rhs.shape == x.shape
    m = 2.0 * plant.inertia_h_s / (2.0 * math.pi * plant.f0_hz)
    expected_accel = (gamma_prime_negated(d, plant) + battery_pu - plant.damping_pu * speed) / m
    assert_allclose(rhs[0], speed, rtol=0, atol=0)
    # Two algebraically equal forms: rounding of P_M - P sin(delta) vs P sin(db) - P sin(d + db) / M.
    assert_allclose(rhs[1], expected_accel, rtol=1e-10, atol=1e-12 * plant.p_max_pu / m)


def gamma_prime_negated(d, plant: SmibParams):
    """-Gamma'(d) = g(d) = P sin(delta_bar) - P sin(d + delta_bar)."""
    db, p = delta_bar(plant), plant.p_max_pu
    return p * math.sin(db) - p * np.sin(d + db)


@ALGEBRA
@given(plant=plants, d=st.floats(-3, 3), speed=st.floats(-10, 10))
def test_w_is_the_papers_lyapunov_function_and_decays_at_minus_d_speed_squared(plant, d, speed):
    m = 2.0 * plant.inertia_h_s / (2.0 * math.pi * plant.f0_hz)
    expected = 0.5 * m * speed**2 + gamma_paper(d, plant)
    assert_allclose(lyapunov_w(d, speed, plant), expected, rtol=1e-12, atol=1e-13 * plant.p_max_pu)
    # W' = (dW/dd) d' + (dW/dd') d'' with dW/dd = -g(d), dW/dd' = M d'; must equal -D d'^2.
    accel = swing_rhs(np.array([d + delta_bar(plant), speed]), 0.0, plant, plant.p_mech_pu, plant.p_max_pu)[1]
    w_dot = -gamma_prime_negated(d, plant) * speed + m * speed * accel
    assert_allclose(w_dot, -plant.damping_pu * speed**2, rtol=1e-9, atol=1e-10 * plant.p_max_pu * (1 + abs(speed)))


@ALGEBRA
@given(plant=plants, fraction=st.floats(1e-3, 1.0), side=st.sampled_from([-1.0, 1.0]))
def test_w_is_positive_on_the_angle_range_of_omega(plant, fraction, side):
    """W(d, 0) = Gamma(d) > 0 for 0 < |d| <= pi - 2 delta_bar (the paper's domain D)."""
    d = side * fraction * (math.pi - 2 * delta_bar(plant))
    assert lyapunov_w(d, 0.0, plant) > 0.0
    assert lyapunov_w(0.0, 0.0, plant) == 0.0


# --- equal area criterion ---------------------------------------------------------------------------


def test_paper_case_fails_the_equal_area_criterion(paper_plant):
    # delta(0) = 0.2 rad: margin = (pi - 0.927 - 0.2) 0.8 - 0.6 - cos 0.2 = +0.0314 > 0.
    assert_allclose(equal_area_margin(0.2, paper_plant), 0.0313714, atol=1e-7)
    assert not eac_stable(0.2, paper_plant)
    assert eac_stable(0.3, paper_plant)


def test_eac_critical_angle_matches_bisection_over_simulated_runs(paper_plant):
    """Bisection on delta0 (at rest, D = 0, b = 0) between slip and synchronism.

    The stopping width 2e-5 rad gives a 1e-5 rad half-width; the simulation decides
    offsets far smaller than that (a release 1e-8 rad below the critical angle
    still slips within 4.5 s of a 6 s run; rtol = 1e-10). Hence atol = 1.2e-5 rad.
    """
    low, high = critical_angles_rad(paper_plant)
    slipping, synchronous = 0.2, 0.6
    assert slips_without_battery(paper_plant, slipping) and not slips_without_battery(paper_plant, synchronous)
    while synchronous - slipping > 2e-5:
        middle = 0.5 * (slipping + synchronous)
        if slips_without_battery(paper_plant, middle):
            slipping = middle
        else:
            synchronous = middle
    assert_allclose(0.5 * (slipping + synchronous), low, rtol=0, atol=1.2e-5)
    assert_allclose(low, 0.2545887, atol=1e-7)  # root of the paper's eq. (eac) by brentq below
    assert_allclose(low, brentq(lambda d0: equal_area_margin(d0, paper_plant), 0.0, delta_bar(paper_plant),
                                xtol=1e-15), atol=1e-12)
    # The high edge is the unstable equilibrium pi - delta_bar: just below it stays, just above slips.
    assert_allclose(high, math.pi - delta_bar(paper_plant), rtol=1e-15)
    assert not slips_without_battery(paper_plant, high - 1e-3)
    assert slips_without_battery(paper_plant, high + 1e-3)


@pytest.mark.parametrize(
    "delta0_rad",
    [0.1, 0.25, 0.26, 1.0, 2.0, 2.2, 2.5, 3.0],  # 2.5 and 3.0: beyond pi - delta_bar, where the margin is < 0 again
)
def test_eac_stable_agrees_with_simulation(paper_plant, delta0_rad):
    assert eac_stable(delta0_rad, paper_plant) == (not slips_without_battery(paper_plant, delta0_rad))


@ALGEBRA
@given(plant=plants, delta0=st.floats(-3.0, 3.0))
def test_papers_invariant_set_condition_is_the_eac(plant, delta0):
    """Eq. (delta_invariant_set), the set written in d and shifted, is eq. (eac); and both say W(d0, 0) < c."""
    db = delta_bar(plant)
    d0 = delta0 - db
    in_d_form = (math.pi - 2 * db - d0) * math.sin(db) - math.cos(db) - math.cos(db + d0)
    assert_allclose(in_d_form, equal_area_margin(delta0, plant), rtol=1e-12, atol=1e-13)
    # W(d0, 0) - Gamma(pi - 2 delta_bar) = P_max * margin: the EAC is "released inside W < c".
    assert_allclose(lyapunov_w(d0, 0.0, plant) - invariant_set_level(plant),
                    plant.p_max_pu * equal_area_margin(delta0, plant), rtol=1e-10, atol=1e-12 * plant.p_max_pu)


@ALGEBRA
@given(plant=plants, fraction=st.floats(0.0, 1.0))
def test_release_at_rest_is_in_omega_exactly_when_eac_holds_below_the_unstable_equilibrium(plant, fraction):
    """For -pi < delta0 < pi - delta_bar the |d| <= pi - 2 delta_bar bound never binds (Gamma(-x) > Gamma(x))."""
    db = delta_bar(plant)
    delta0 = -math.pi + 1e-6 + fraction * (2 * math.pi - db - 2e-6)
    margin = equal_area_margin(delta0, plant)
    if abs(margin) > 1e-9:  # leave out the boundary itself, decided by rounding
        assert bool(in_invariant_set(delta0 - db, 0.0, plant)) == eac_stable(delta0, plant)


# --- invariant set Omega ------------------------------------------------------------------------------------


@ALGEBRA
@given(plant=plants)
def test_invariant_set_level_is_gamma_at_pi_minus_two_delta_bar(plant):
    db = delta_bar(plant)
    c = invariant_set_level(plant)
    assert_allclose(c, gamma_paper(math.pi - 2 * db, plant), rtol=1e-12, atol=1e-14)
    # ... which is the local maximum of Gamma right of the origin, found numerically,
    best = minimize_scalar(lambda d: -gamma_paper(d, plant), bounds=(0.0, math.pi), method="bounded",
                           options={"xatol": 1e-10})
    # (a maximum is flat: a 1e-10 rad location error costs ~1e-20 in value; 1e-12 covers rounding)
    assert_allclose(-best.fun, c, rtol=1e-10, atol=1e-12)
    # ... and the lower of the two maxima next to the origin.
    assert c <= gamma_paper(-math.pi - 2 * db, plant) + 1e-12


@ALGEBRA
@given(plant=plants, fraction=st.floats(0.02, 1.0))
def test_invariant_set_boundary_lies_on_w_equals_c(plant, fraction):
    level = fraction * invariant_set_level(plant)
    curve = invariant_set_boundary(plant, level, points=200)
    assert curve.shape == (401, 2)
    assert_allclose(curve[0], curve[-1], rtol=0, atol=0)
    # The edges come from a bisection to 1e-13 rad: |G'| <= 2 P_max, so W is off by <= ~1e-12 * P_max.
    assert_allclose(lyapunov_w(curve[:, 0], curve[:, 1], plant), level, rtol=1e-12, atol=2e-12 * plant.p_max_pu)
    assert np.all(np.abs(curve[:, 0]) <= math.pi - 2 * delta_bar(plant) + 1e-12)


@settings(max_examples=12, deadline=None)
@given(plant=plants, damping=st.floats(0.05, 1.0), level_fraction=st.floats(0.05, 1.0), seed=st.integers(0, 2**32 - 1))
def test_damped_plant_started_in_omega_stays_in_omega(plant, damping, level_fraction, seed):
    """W' = -D d'^2 <= 0 and the angle bound make Omega_c forward invariant (section V)."""
    plant = SmibParams(plant.inertia_h_s, damping, plant.p_mech_pu, plant.p_max_pu, plant.f0_hz)
    level = level_fraction * invariant_set_level(plant)
    rng = np.random.default_rng(seed)
    # 64 starts strictly inside Omega_c: an angle between the set's edges, a speed inside the level curve.
    edges = invariant_set_boundary(plant, level, points=2)[:2, 0]
    d0 = rng.uniform(edges[0], edges[1], 64)
    speed_max = np.sqrt(np.maximum(2 * (0.999 * level - gamma_paper(d0, plant)), 0) / plant.inertia_m)
    speed0 = rng.uniform(-1, 1, 64) * speed_max
    assert np.all(in_invariant_set(d0, speed0, plant, level))
    x = np.vstack((d0 + delta_bar(plant), speed0))
    start_w = lyapunov_w(d0, speed0, plant)
    no_fault = InitialAngle()
    previous_w = start_w
    for step in range(3000):  # 3 s at the plant's 1 ms RK4 step
        x = rk4_step(step * 1e-3, x, 1e-3, 0.0, plant, no_fault)
        d, speed = x[0] - delta_bar(plant), x[1]
        assert np.all(in_invariant_set(d, speed, plant, level))
        w_now = lyapunov_w(d, speed, plant)
        # RK4's energy error per 1 ms step is ~(omega h)^5 ~ 1e-11 relative: far below 1e-9 * c.
        assert np.all(w_now <= previous_w + 1e-9 * level)
        previous_w = w_now
    assert np.all(previous_w <= start_w)


# --- scenarios and the fixed-step integrator ------------------------------------------------------------------


def test_scenarios_switch_network_at_their_breakpoints(paper_plant):
    step = MechanicalPowerStep(0.95, 0.5)
    assert step.breakpoints() == (0.5,)
    assert step.network(0.499, paper_plant) == (0.95, 1.0)
    assert step.network(0.5, paper_plant) == (0.8, 1.0)
    assert MechanicalPowerStep(0.95).breakpoints() == ()
    fault = TransferLimitFault(0.2, 0.1)
    assert fault.network(0.05, paper_plant) == (0.8, 0.2)
    assert fault.network(0.1, paper_plant) == (0.8, 1.0)
    for scenario in (step, fault):
        assert_allclose(scenario.initial_state(paper_plant), [paper_plant.delta_bar_rad, 0.0], rtol=0, atol=0)
    assert_allclose(InitialAngle(0.2, 0.1).initial_state(paper_plant), [0.2, 0.1], rtol=0, atol=0)


def test_one_trajectory_on_floats_equals_the_same_trajectory_in_a_batch(paper_plant):
    """advance() runs one state on Python floats (math.sin) and a batch on arrays (np.sin): same RK4.

    The two sines may differ in the last bit, so after 2 s of a slipping rotor
    (b = 0, delta0 = 0.4 rad beyond the EAC limit) the states agree to a few
    hundred ulps of their magnitude, not exactly.
    """
    fault = TransferLimitFault(0.2, 0.15)
    starts = np.array([[0.2, 0.9273, 1.3, 2.5], [0.0, 0.5, -1.0, 3.0]])
    batch = advance(0.0, 2.0, starts, 0.0, paper_plant, fault)
    assert batch.shape == starts.shape
    for column in range(starts.shape[1]):
        one = advance(0.0, 2.0, starts[:, column], 0.0, paper_plant, fault)
        assert one.shape == (2,)
        assert_allclose(one, batch[:, column], rtol=1e-13, atol=1e-13)
        assert_allclose(rk4_step(0.0, starts[:, column], 1e-3, 0.1, paper_plant, fault),
                        rk4_step(0.0, starts, 1e-3, 0.1, paper_plant, fault)[:, column], rtol=1e-15, atol=1e-15)


@ALGEBRA
@given(plant=plants, delta=st.floats(-1e3, 1e3), speed=st.floats(-1e3, 1e3), battery_pu=st.floats(-5, 5),
       p_mech=st.floats(0, 3), p_max=st.floats(0, 3))
def test_the_float_form_of_the_swing_equation_is_the_general_one_bit_for_bit(plant, delta, speed, battery_pu,
                                                                             p_mech, p_max):
    """held_acceleration on floats (the plant node's path) is swing_acceleration, to the last bit.

    Both against M delta'' = P_M + P_ST - P_max sin(delta) - D delta', evaluated here left to right.
    """
    fast = held_acceleration(plant, p_mech, p_max, battery_pu, delta)(delta, speed)
    general = swing_acceleration(delta, speed, battery_pu, plant, p_mech, p_max)
    m = 2.0 * plant.inertia_h_s / (2.0 * math.pi * plant.f0_hz)
    assert fast == general == (p_mech + battery_pu - p_max * math.sin(delta) - plant.damping_pu * speed) / m


def test_an_infinite_angle_integrates_to_nan_on_floats_as_in_a_batch(paper_plant):
    """math.sin raises at an infinite angle where np.sin gives NaN: advance() gives NaN on both paths."""
    fault = TransferLimitFault(0.2, 0.15)
    one = advance(0.0, 0.01, np.array([math.inf, 0.0]), 0.1, paper_plant, fault)
    with np.errstate(invalid="ignore"):  # numpy's warning for sin(inf), the NaN it gives is what is checked
        batch = advance(0.0, 0.01, np.array([[math.inf], [0.0]]), 0.1, paper_plant, fault)
    assert np.isnan(one).all() and np.isnan(batch).all()


def test_advance_through_a_fault_matches_an_adaptive_reference(paper_plant):
    """A bolted fault cleared at 0.1 s, integrated to 0.5 s, across the breakpoint."""
    fault = TransferLimitFault(0.0, 0.1)
    x0 = fault.initial_state(paper_plant)

    def rhs(t, x, p_max):
        return swing_rhs(x, 0.0, paper_plant, paper_plant.p_mech_pu, p_max)

    during = solve_ivp(rhs, (0.0, 0.1), x0, args=(0.0,), rtol=1e-12, atol=1e-13)
    after = solve_ivp(rhs, (0.1, 0.5), during.y[:, -1], args=(1.0,), rtol=1e-12, atol=1e-13)
    # RK4 at 1 ms: global error ~ (omega h)^4 * |x| ~ 1e-10 here; 1e-8 leaves margin.
    assert_allclose(advance(0.0, 0.5, x0, 0.0, paper_plant, fault), after.y[:, -1], rtol=0, atol=1e-8)
    # Fourth order: halving the step divides the error by ~16.
    errors = [np.abs(advance(0.0, 0.5, x0, 0.0, paper_plant, fault, max_step_s=h) - after.y[:, -1]).max()
              for h in (0.01, 0.005)]
    assert 12.0 < errors[0] / errors[1] < 20.0
    with pytest.raises(ValueError, match=r"max_step_s must be positive"):
        advance(0.0, 0.5, x0, 0.0, paper_plant, fault, max_step_s=0.0)
