"""Theory checks of the control law (paper sections IV and VI): parameters, Q1/Q2, W_hat, sampled law.

The dynamics and the paper's formulas are written out here from the paper and
DESIGN.md; the module under test is only called, never used to compute the
expected value.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose
from scipy.integrate import quad
from scipy.linalg import expm

from nni_battery_controller.law import (
    ControllerParams,
    SampledController,
    closed_loop_lyapunov,
    is_saturated,
    q1_matrix,
    saturate,
    saturation_input,
    x3_rate,
)
from nni_plant_sim.model import SmibParams

#: Cheap algebraic properties: many examples, no deadline (first calls import scipy).
ALGEBRA = settings(max_examples=200, deadline=None)


def g_paper(d, plant: SmibParams):
    """g(d) = P_max sin(delta_bar) - P_max sin(d + delta_bar), from the paper's section VI."""
    delta_bar = math.asin(plant.p_mech_pu / plant.p_max_pu)
    return plant.p_max_pu * math.sin(delta_bar) - plant.p_max_pu * np.sin(d + delta_bar)


def jump_paper(d, gain_l: float, plant: SmibParams):
    """J(d) = L d^2/2 + g(d) d - G(d): W_hat(saturated F) - W_hat(unsaturated F) on |w| = b.

    Derivation from the paper's F: on w = s b (s = +-1) we have x3 = s b + L d + g(d), so
    F_unsat = x3 d - L d^2/2 = s b d + L d^2/2 + g(d) d and F_sat = G(d) + s b d; hence
    W_sat - W_unsat = F_unsat - F_sat = L d^2/2 + g(d) d - G(d), the same on both sides.
    """
    integral = quad(lambda xi: g_paper(xi, plant), 0.0, d, epsabs=1e-14, epsrel=1e-13)[0]
    return 0.5 * gain_l * d * d + g_paper(d, plant) * d - integral


plants = st.builds(
    lambda h, damping, p_max, ratio: SmibParams(h, damping, ratio * p_max, p_max, 50.0),
    st.floats(0.5, 10.0), st.floats(0.0, 2.0), st.floats(0.2, 3.0), st.floats(0.0, 0.95),
)
gains = st.tuples(st.floats(0.02, 1.0), st.floats(0.05, 5.0), st.floats(1.01, 3.0), st.floats(0.1, 5.0)).map(
    lambda t: {"tau_s": t[0], "gain_k": t[1], "gain_l": t[1] * t[2], "alpha": t[3]}
)


# --- parameter validation -------------------------------------------------------------


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"tau_s": 0.0}, r"tau must be positive"),
        ({"tau_s": -0.1}, r"tau must be positive"),
        ({"gain_k": 0.0}, r"K must be positive"),
        ({"gain_k": -1.0}, r"K must be positive"),
        ({"gain_k": 1.1}, r"K must be less than L.*K - L < 0"),
        ({"gain_k": 2.0}, r"K must be less than L.*K - L < 0"),
        ({"gain_l": 0.0, "gain_k": 1.0}, r"L must be positive"),
        ({"alpha": 0.0}, r"alpha must be positive"),
        ({"alpha": -1.0}, r"alpha must be positive"),
        ({"battery_limit_pu": -0.1}, r"battery limit b must be non-negative"),
        ({"battery_limit_pu": -math.inf}, r"battery limit b must be non-negative"),
        ({"tau_s": math.nan}, r"tau_s must be a finite number, got NaN"),
        ({"gain_k": math.nan}, r"gain_k must be a finite number, got NaN"),
        ({"gain_l": math.nan}, r"gain_l must be a finite number, got NaN"),
        ({"alpha": math.nan}, r"alpha must be a finite number, got NaN"),
        ({"battery_limit_pu": math.nan}, r"battery_limit_pu must be a finite number, got NaN"),
        ({"tau_s": math.inf}, r"tau_s must be finite"),
        ({"gain_l": math.inf}, r"gain_l must be finite"),
    ],
)
def test_invalid_controller_parameters_name_the_violated_condition(overrides, message):
    params = {"tau_s": 0.1, "gain_k": 1.0, "gain_l": 1.1, "alpha": 1.0, "battery_limit_pu": 0.3, **overrides}
    with pytest.raises(ValueError, match=message):
        ControllerParams(**params)


@pytest.mark.parametrize("battery_limit_pu", [0.0, 0.2, math.inf])
def test_battery_limit_accepts_no_battery_and_unlimited(battery_limit_pu):
    assert ControllerParams(battery_limit_pu=battery_limit_pu).battery_limit_pu == battery_limit_pu


@pytest.mark.parametrize("period_s", [0.0, -0.02, math.nan, math.inf])
def test_sampled_controller_rejects_bad_period(paper_plant, paper_controller, period_s):
    with pytest.raises(ValueError, match=r"sampling period must be finite and positive"):
        SampledController(paper_plant, paper_controller(0.3), period_s)


# --- saturation --------------------------------------------------------------------------


@ALGEBRA
@given(w=st.floats(-1e3, 1e3), b=st.floats(0.0, 10.0))
def test_saturation_is_the_papers_sat_b(w, b):
    expected = -b if w <= -b else (w if w < b else b)  # the paper's three cases
    assert saturate(w, b) == expected
    assert bool(is_saturated(w, b)) == (abs(w) >= b)


def test_saturation_edge_cases():
    # |w| = b counts as saturated (the paper's ">= b"); b = inf never saturates, b = 0 always.
    assert is_saturated(0.3, 0.3) and is_saturated(-0.3, 0.3)
    assert not is_saturated(1e300, math.inf)
    assert is_saturated(0.0, 0.0)
    assert saturate(1e300, math.inf) == 1e300
    assert saturate(-5.0, 0.0) == 0.0
    assert saturate(math.nan, 0.3) == 0.0  # a NaN request must become "no power", not NaN


# --- Q1, Q2 and the unsaturated loop (Theorem 2) -------------------------------------------


@settings(max_examples=300, deadline=None)
@given(inertia_m=st.floats(1e-3, 10.0), gain_k=st.floats(1e-3, 10.0), gain_l=st.floats(1e-3, 10.0))
def test_q1_positive_definite_exactly_when_k_below_l(inertia_m, gain_k, gain_l):
    # Near K = L the smallest eigenvalue ~ (L - K)/(K L + 1) vanishes; outside a 1e-6*L band it is
    # >= ~1e-11, far above eigvalsh's rounding (~1e-16 * ||Q1|| <= 1e-13).
    assume(abs(gain_k - gain_l) >= 1e-6 * gain_l)
    q1 = q1_matrix(inertia_m, gain_k, gain_l)
    assert_allclose(q1, q1.T, rtol=0, atol=0)
    assert (np.linalg.eigvalsh(q1).min() > 0) == (gain_k < gain_l)


def _unsaturated_loop_matrix(plant: SmibParams, tau_s, gain_k, gain_l):
    """z' = A z for z = [d', d, x3] of (H1, H3): M d'' = -D d' + x3 - L d, x3' = (K d - x3)/tau.

    (With P_ST = w = x3 - L d - g(d) the g(d) of the plant cancels.)
    """
    m = 2.0 * plant.inertia_h_s / (2.0 * math.pi * plant.f0_hz)
    return np.array([
        [-plant.damping_pu / m, -gain_l / m, 1.0 / m],
        [1.0, 0.0, 0.0],
        [0.0, gain_k / tau_s, -1.0 / tau_s],
    ])


@ALGEBRA
@given(plant=plants, gains=gains, b=st.just(math.inf),
       z=st.tuples(st.floats(-5, 5), st.floats(-3, 3), st.floats(-5, 5)))
def test_unlimited_w_hat_is_half_z_q1_z_and_decreases_at_z_q2_z(plant, gains, b, z):
    ctrl = ControllerParams(battery_limit_pu=b, **gains)
    speed, d, x3 = z
    z = np.array(z)
    q1 = q1_matrix(plant.inertia_m, ctrl.gain_k, ctrl.gain_l)
    w_hat = closed_loop_lyapunov(d, speed, x3, plant, ctrl)
    # Same quadratic form computed two ways: rounding only (scale = the largest term; below the smallest normal
    # float, where z @ z underflows, rounding is absolute).
    scale = float(np.abs(q1).max() * z @ z) + np.finfo(float).tiny
    assert_allclose(w_hat, 0.5 * z @ q1 @ z, rtol=0, atol=1e-13 * scale)
    # Theorem 2: W' = z^T Q2 z with the paper's Q2.
    k, tau = ctrl.gain_k, ctrl.tau_s
    q2 = np.array([[-plant.damping_pu, 0, 0], [0, -k / tau, 1 / tau], [0, 1 / tau, -1 / (tau * k)]])
    z_dot = _unsaturated_loop_matrix(plant, tau, k, ctrl.gain_l) @ z
    # (Subnormal states round absolutely too: z = (0, 2.2e-313, 0) differed in its last subnormal bit.)
    assert_allclose(z_dot[2], x3_rate(x3, d, False, ctrl), rtol=1e-13,
                    atol=1e-13 * np.abs(z).max() + np.finfo(float).tiny)
    assert_allclose((q1 @ z) @ z_dot, z @ q2 @ z, rtol=0, atol=1e-12 * scale / tau)


@ALGEBRA
@given(plant=plants, gains=gains)
def test_q2_is_only_negative_semidefinite(plant, gains):
    """The paper writes Q2 < 0; its lower block has determinant 0, so Q2 <= 0 only.

    W' = 0 along x3 = K d (and d' = 0 when D = 0); asymptotic stability still follows by
    LaSalle, see test_unsaturated_loop_is_hurwitz_exactly_when_k_below_l.
    """
    k, tau = gains["gain_k"], gains["tau_s"]
    q2 = np.array([[-plant.damping_pu, 0, 0], [0, -k / tau, 1 / tau], [0, 1 / tau, -1 / (tau * k)]])
    eigenvalues = np.linalg.eigvalsh(q2)
    scale = k / tau + 1 / (tau * k) + plant.damping_pu
    assert eigenvalues.max() <= 1e-13 * scale
    null_vector = np.array([0.0, 1.0, k])
    assert_allclose(q2 @ null_vector, 0.0, atol=1e-13 * scale * k)


@settings(max_examples=300, deadline=None)
@given(
    h=st.floats(0.5, 10.0), damping=st.floats(0.0, 2.0), tau_s=st.floats(0.01, 1.0),
    gain_k=st.floats(0.01, 10.0), gain_l=st.floats(0.01, 10.0),
)
def test_unsaturated_loop_is_hurwitz_exactly_when_k_below_l(h, damping, tau_s, gain_k, gain_l):
    """Theorem 2 (b = inf): the closed loop is asymptotically stable iff K < L (for K > 0).

    The characteristic polynomial is M tau s^3 + (M + D tau) s^2 + (D + L tau) s + (L - K);
    the eigenvalue nearest 0 is ~ (L - K)/(D + L tau), so a 1e-3*L band around K = L keeps it
    >= ~1e-7, well above the eigenvalue solver's error.
    """
    assume(abs(gain_k - gain_l) >= 1e-3 * gain_l)
    plant = SmibParams(h, damping, 0.8, 1.0, 50.0)
    eigenvalues = np.linalg.eigvals(_unsaturated_loop_matrix(plant, tau_s, gain_k, gain_l))
    assert (eigenvalues.real.max() < 0) == (gain_k < gain_l)


# --- W_hat with saturation (section IV) ---------------------------------------------------


@ALGEBRA
@given(plant=plants, gains=gains, b=st.floats(0.0, 2.0),
       d=st.floats(-2.5, 2.5), speed=st.floats(-5, 5), x3=st.floats(-3, 3))
def test_w_hat_is_v1_plus_v3_minus_the_papers_f(plant, gains, b, d, speed, x3):
    """F is the paper's integral of the controller output over the angle, by the mode of w."""
    ctrl = ControllerParams(battery_limit_pu=b, **gains)
    k, gain_l = ctrl.gain_k, ctrl.gain_l
    w = x3 - gain_l * d - g_paper(d, plant)
    if w <= -b:
        integrand = lambda xi: g_paper(xi, plant) - b  # noqa: E731
    elif w < b:
        integrand = lambda xi: x3 - gain_l * xi  # noqa: E731
    else:
        integrand = lambda xi: g_paper(xi, plant) + b  # noqa: E731
    f = quad(integrand, 0.0, d, epsabs=1e-13, epsrel=1e-12)[0]
    m = 2.0 * plant.inertia_h_s / (2.0 * math.pi * plant.f0_hz)
    expected = 0.5 * m * speed**2 + x3**2 / (2 * k) - f
    assert_allclose(saturation_input(x3, d, ctrl, plant), w, rtol=1e-12, atol=1e-12)
    # quad is good to ~1e-12 relative; the terms are O(10), so 1e-10 absolute is ample.
    assert_allclose(closed_loop_lyapunov(d, speed, x3, plant, ctrl), expected, rtol=1e-10, atol=1e-10)


@ALGEBRA
@given(plant=plants, gains=gains, b=st.floats(0.01, 2.0), d=st.floats(-2.5, 2.5), side=st.sampled_from([-1, 1]))
def test_w_hat_jumps_by_j_across_the_switching_surface(plant, gains, b, d, side):
    """Double-check of J(d) (see jump_paper): by quad, on both sides w = +-b."""
    ctrl = ControllerParams(battery_limit_pu=b, **gains)
    gain_l = ctrl.gain_l
    x3 = side * b + gain_l * d + g_paper(d, plant)  # on the surface w = side * b
    f_unsat = quad(lambda xi: x3 - gain_l * xi, 0.0, d, epsabs=1e-14)[0]
    f_sat = quad(lambda xi: g_paper(xi, plant) + side * b, 0.0, d, epsabs=1e-14)[0]
    assert_allclose(f_unsat - f_sat, jump_paper(d, gain_l, plant), rtol=1e-9, atol=1e-12)
    # J(0) = 0 and J'(d) = d (L + g'(d)), g'(d) = -P_max cos(d + delta_bar): a second route.
    delta_bar = plant.delta_bar_rad
    via_derivative = quad(lambda xi: xi * (gain_l - plant.p_max_pu * math.cos(xi + delta_bar)), 0.0, d,
                          epsabs=1e-14)[0]
    assert_allclose(jump_paper(d, gain_l, plant), via_derivative, rtol=1e-9, atol=1e-12)
    # With L >= P_max, J >= 0: entering saturation never lowers W_hat, it raises it.
    if gain_l >= plant.p_max_pu:
        assert jump_paper(d, gain_l, plant) >= -1e-12


# --- the sampled-data law --------------------------------------------------------------------


@ALGEBRA
@given(plant=plants, gains=gains, b=st.one_of(st.floats(0.0, 2.0), st.just(math.inf)),
       x3=st.floats(-3, 3), d=st.floats(-3, 3), period_s=st.floats(1e-4, 0.1))
def test_sampled_x3_update_is_the_exact_solution_of_the_held_mode(plant, gains, b, x3, d, period_s):
    ctrl = ControllerParams(battery_limit_pu=b, **gains)
    w = x3 - ctrl.gain_l * d - g_paper(d, plant)
    saturated = abs(w) >= b
    if saturated:  # x3' = -(alpha/K) x3
        x3_next = float(expm(np.array([[-ctrl.alpha / ctrl.gain_k]]) * period_s)[0, 0] * x3)
    else:  # [x3, d]' = [[-1/tau, K/tau], [0, 0]] [x3, d], d held by the zero-order hold
        generator = np.array([[-1.0 / ctrl.tau_s, ctrl.gain_k / ctrl.tau_s], [0.0, 0.0]])
        x3_next = float((expm(generator * period_s) @ np.array([x3, d]))[0])
    controller = SampledController(plant, ctrl, period_s, x3=x3)
    power, w_out, saturated_out = controller.step(d)
    assert saturated_out == saturated
    assert_allclose(w_out, w, rtol=1e-12, atol=1e-12)
    assert power == (max(-b, min(b, w_out)) if saturated else w_out)
    # expm (Pade) and exp agree to ~1e-15 relative; states are O(1).
    assert_allclose(controller.x3, x3_next, rtol=1e-12, atol=1e-14)


def test_sampled_law_reaches_the_unsaturated_steady_state(paper_plant, paper_controller):
    """With d held, unsaturated x3 -> K d, so the output -> K d - L d - g(d) (held every period)."""
    ctrl = paper_controller(math.inf)
    controller = SampledController(paper_plant, ctrl, 0.02)
    d = 0.05
    outputs = [controller.step(d)[0] for _ in range(500)]  # 10 s = 100 time constants
    assert_allclose(controller.x3, ctrl.gain_k * d, rtol=1e-12)
    assert_allclose(outputs[-1], (ctrl.gain_k - ctrl.gain_l) * d - g_paper(d, paper_plant), rtol=1e-10)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_sampled_controller_refuses_non_finite_angle_and_keeps_its_state(paper_plant, paper_controller, bad):
    controller = SampledController(paper_plant, paper_controller(0.3), 0.02, x3=0.123)
    with pytest.raises(ValueError, match=r"angle deviation must be finite"):
        controller.step(bad)
    assert controller.x3 == 0.123
    controller.reset()
    assert controller.x3 == 0.0
