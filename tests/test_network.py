"""Network plant core, shipped cases and the H3-hat at every generator (issue 13).

Expected values come from the published data (Kundur's operating point), from
theory (power balance, decoupling with b = inf, the saturation bound) or from
the existing SMIB code, never from the network code itself.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.integrate import solve_ivp

from nni_battery_controller.law import ControllerParams, SampledController
from nni_battery_controller.network_sim import (
    NetworkController,
    NetworkLaw,
    assess_network,
    simulate_network,
)
from nni_plant_sim.cases import shipped_text, load_network, read_machines, read_matpower
from nni_plant_sim.integrators import advance, rk4
from nni_plant_sim.model import SmibParams, plant_rate
from nni_plant_sim.network import (
    Coupling,
    Network,
    electrical_power,
    network_acceleration,
    solve_load_flow,
)
from nni_plant_sim.network_scenarios import AngleDisplacement, BusFault
from nni_plant_sim.scenarios import InitialAngle


@pytest.fixture(scope="module")
def kundur():
    return load_network("kundur_two_area")


@pytest.fixture(scope="module")
def ieee39():
    return load_network("ieee39")


def test_kundur_load_flow_reproduces_the_published_operating_point():
    """Kundur (1994) Example 12.6 gives Et angles 20.2, 10.5, -6.8, -17.0 deg and Q 185, 235, 176, 202 MVAr."""
    solved = solve_load_flow(read_matpower(shipped_text("kundur_two_area.m")))
    assert_allclose(solved["bus"][:4, 8], [20.2, 10.5, -6.8, -17.0], atol=0.1)
    assert_allclose(solved["gen"][:, 2], [185, 235, 176, 202], atol=1.0)
    assert solved["gen"][2, 1] == pytest.approx(719, abs=1.0)


@pytest.mark.parametrize("case", ["kundur_two_area", "ieee39"])
def test_kron_reduction_balances_power_at_the_load_flow_solution(case):
    """P_e,i(delta_bar) of the reduced network = P_G,i from the load flow + the stator loss ra |I|^2, to 1e-8."""
    net = load_network(case)
    from nni_plant_sim.cases import CASES

    source, machines_file, _ = CASES[case]
    if source.startswith("pypower:"):
        from pypower.api import case39

        ppc = case39()
    else:
        ppc = read_matpower(shipped_text(source))
    solved = solve_load_flow(ppc)
    machines = read_machines(shipped_text(machines_file))
    base = solved["baseMVA"]
    gen_bus = solved["gen"][:, 0].astype(int)
    rows = [np.flatnonzero(solved["bus"][:, 0] == b)[0] for b in gen_bus]
    voltage = solved["bus"][rows, 7] * np.exp(1j * np.radians(solved["bus"][rows, 8]))
    power = (solved["gen"][:, 1] + 1j * solved["gen"][:, 2]) / base
    current = np.conj(power / voltage)
    ra = np.array([m.ra_pu * base / m.mbase_mva for m in machines])
    expected = power.real + ra * np.abs(current) ** 2
    assert_allclose(electrical_power(net.delta_bar_rad, net.coupling), expected, rtol=0, atol=1e-8)
    assert_allclose(net.p_mech_pu, expected, rtol=0, atol=1e-8)
    # The loads' constant impedances consume what the load flow says they do: total balance.
    assert electrical_power(net.delta_bar_rad, net.coupling).sum() > solved["bus"][:, 2].sum() / base


def test_equilibrium_stays_at_rest(kundur, ieee39):
    for net in (kundur, ieee39):
        x = advance(0.0, 2.0, AngleDisplacement(np.zeros(net.size)).initial_state(net), 0.0, net,
                    AngleDisplacement(np.zeros(net.size)))
        assert_allclose(x[0], net.delta_bar_rad, atol=1e-8)
        assert_allclose(x[1], 0.0, atol=1e-8)


def test_smib_is_the_one_generator_case_bit_for_bit():
    """The SMIB's P_max sin(delta) is the network's P_e for one machine against an infinite bus, exactly."""
    plant = SmibParams()
    net = Network.from_smib(plant)
    delta = np.linspace(-7.0, 7.0, 1001)
    assert np.array_equal(electrical_power(delta[None, :], net.coupling)[0], plant.p_max_pu * np.sin(delta))
    smib = advance(0.0, 1.0, [0.2, 0.1], 0.05, plant, InitialAngle(0.2, 0.1))
    network = advance(0.0, 1.0, np.array([[0.2], [0.1]]), 0.05, net,
                      AngleDisplacement(np.array([0.2 - plant.delta_bar_rad])))
    assert_allclose(network[:, 0], smib, rtol=0, atol=1e-12)


@pytest.mark.parametrize("runs", [None, 1, 3])
def test_the_compiled_network_rk4_is_the_generic_rk4_of_plant_rate_to_rounding(kundur, ieee39, runs):
    """advance() of a network (the plant node's call and the offline batches', compiled: network_rk4) is the generic
    RK4 of plant_rate (network_acceleration, numpy) to rounding: the same terms, the double sum in another order.

    Shapes (2, N), (2, N, 1) (the node) and (2, N, R) (the offline batches); the shipped cases (no damping, no
    fixed source) and the same with damping and a source added (every term must be in its place); a fault cleared
    inside the interval (a breakpoint), the intact network, and R runs clearing at their own instants (Switched).
    The states (rad, rad/s, of order 1) agree to 1e-13 after 20 steps of chaotic-looking random starts; a term
    missing or misplaced is off by far more (1e-5 and up).
    """
    rng = np.random.default_rng(7)
    for case in (kundur, ieee39):
        n = case.size
        coupling = Coupling(case.coupling.gc, case.coupling.bs, rng.uniform(-1, 1, n), rng.uniform(0, 2, n))
        for net in (case, replace(case, damping_pu=rng.uniform(0.5, 2.0, n), coupling=coupling)):
            shape = (n,) if runs is None else (n, runs)
            delta, speed, power = (rng.normal(0.0, 2.0, shape), rng.normal(0.0, 3.0, shape),
                                   rng.normal(0.0, 0.1, shape))
            scenarios = [BusFault(net, 7, 0.2), AngleDisplacement(np.zeros(n))]
            if runs == 3:
                scenarios.append(BusFault(net, 7, np.array([0.195, 0.2, 0.205])))
            for scenario in scenarios:
                x = np.stack((net.delta_bar_rad.reshape((n,) + (1,) * (len(shape) - 1)) + delta / 20, speed))
                got = advance(0.19, 0.21, x, power, net, scenario)
                state, cuts = (x[0], x[1]), [0.19, *(t for t in scenario.breakpoints() if 0.19 < t < 0.21), 0.21]
                for start, stop in zip(cuts[:-1], cuts[1:]):
                    steps = max(1, math.ceil((stop - start) / 1e-3 - 1e-9))
                    for _ in range(steps):
                        state = rk4(plant_rate, start, state, (stop - start) / steps, power,
                                    (net, scenario.network(start, net)))
                assert got.shape == x.shape
                assert_allclose(got, np.array(state), rtol=0, atol=1e-13)


def test_one_generator_network_controller_is_the_smib_sampled_controller():
    """The elementwise law agrees with law.SampledController step by step for N = 1."""
    plant = SmibParams()
    net = Network.from_smib(plant)
    ctrl = ControllerParams(battery_limit_pu=0.2)
    smib = SampledController(plant, ctrl, 0.02)
    law = NetworkLaw.uniform(net, ctrl.tau_s, ctrl.gain_k, ctrl.gain_l, ctrl.alpha)
    network = NetworkController(law, 0.02, np.array([[0.2]]), np.zeros((1, 1)))
    for delta in np.concatenate((np.linspace(0.2, 2.5, 40), np.linspace(2.5, 0.5, 40))):
        expected = smib.step(delta - plant.delta_bar_rad)
        power, w, saturated = network.step(np.array([[delta]]), electrical_power(np.array([[delta]]), net.coupling))
        assert power[0, 0] == pytest.approx(expected[0], abs=1e-12)
        assert w[0, 0] == pytest.approx(expected[1], abs=1e-12)
        assert bool(saturated[0, 0]) == expected[2]
        assert network.x3[0, 0] == pytest.approx(smib.x3, abs=1e-12)


@pytest.mark.parametrize("reference", ["pmu", "coi"])
def test_unsaturated_control_decouples_the_generators_in_continuous_time(kundur, reference):
    """b = inf: M_i d_i'' = x3_i - L_i d_i; displacing G1 leaves the others at rest (pmu reference).

    With the COI reference d_i depends on every angle, so the loops couple
    through the reference and the common mode is invisible to the controllers:
    there the test checks the weaker claim that the angles relative to the COI
    return to equilibrium (shifted as a whole by the COI's share of the kick).
    """
    net = kundur
    law = NetworkLaw.uniform(net, 0.1, 1.0, 1.1, 1.0, reference)
    k, ell = net.pu_of_machine(law.gain_k), net.pu_of_machine(law.gain_l)
    n = net.size

    def rhs(t, z):
        delta, speed, x3 = z[:n], z[n:2 * n], z[2 * n:]
        dev = law.angle_dev(delta)
        power = x3 - ell * dev - (net.p_mech_pu - electrical_power(delta, net.coupling))
        accel = network_acceleration(delta, speed, power, net, net.p_mech_pu, net.coupling)
        return np.concatenate((speed, accel, (k * dev - x3) / law.tau_s))

    start = net.delta_bar_rad.copy()
    start[0] += 0.5
    sol = solve_ivp(rhs, (0.0, 10.0), np.concatenate((start, np.zeros(2 * n))), rtol=1e-11, atol=1e-12)
    if reference == "pmu":
        assert np.abs(sol.y[1:n] - net.delta_bar_rad[1:, None]).max() < 1e-8
        assert np.abs(sol.y[0] - net.delta_bar_rad[0]).max() == pytest.approx(0.5, rel=1e-6)
        assert np.abs(sol.y[:n, -1] - net.delta_bar_rad).max() < 0.02
    final = sol.y[:n, -1]
    assert np.abs((final - net.coi(final)) - (net.delta_bar_rad - net.coi(net.delta_bar_rad))).max() < 0.02


def test_k_not_below_l_is_rejected_per_generator(kundur):
    with pytest.raises(ValueError, match=r"generator G4@4: K must be less than L"):
        NetworkLaw.uniform(kundur, 0.1, [1.0, 1.0, 1.0, 1.2], 1.1, 1.0)
    with pytest.raises(ValueError, match="one value or one per generator"):
        NetworkLaw.uniform(kundur, 0.1, [1.0, 1.0], 1.1, 1.0)


@pytest.fixture(scope="module")
def kundur_fault_runs(kundur):
    """Bus 7 fault cleared at 0.1 s (the pre-fault network returns), four limits, COI reference."""
    law = NetworkLaw.uniform(kundur, 0.1, 1.0, 1.1, 1.0, "coi")
    limits = [0.05, 0.1, 0.3, math.inf]
    traj = simulate_network(kundur, law, BusFault(kundur, 7, 0.1), limits, 10.0, 50.0)
    return traj, limits, assess_network(traj)


def test_battery_power_never_exceeds_its_limit(kundur_fault_runs):
    traj, limits, _ = kundur_fault_runs
    assert np.all(np.abs(traj.battery_power_pu) <= traj.limits_pu[None] * (1 + 1e-15))
    assert_allclose(traj.limits_pu[:, 0], 0.05 * 9.0)  # pu of the 900 MVA rating on the 100 MVA base
    # The limits are reached (the bound is not vacuous).
    assert np.isclose(np.abs(traj.battery_power_pu[:, :, 0]).max(), 0.45)


def test_finite_batteries_leave_saturation_in_stable_runs(kundur_fault_runs):
    """After a fault that leaves the network as it was, every finite battery of a stable run leaves saturation.

    (Not so after a line trip: the post-fault equilibrium differs from the
    pre-fault one that g_i refers to, and a small battery can stay saturated
    at the new equilibrium; README reports it.)
    """
    traj, limits, outcomes = kundur_fault_runs
    stable = [(b, o) for b, o in zip(limits, outcomes) if o.stable and math.isfinite(b)]
    assert stable, "no stable run with a finite battery to check"
    assert any(g.last_saturated_s is not None for _b, o in stable for g in o.generators)
    for _b, outcome in stable:
        for g in outcome.generators:
            assert g.last_saturated_s is None or g.last_saturated_s < traj.t_s[-1] - 1.0


def test_pole_slip_is_the_pairwise_180_degree_criterion(kundur):
    """A long bolted fault at bus 8 separates the areas: lost synchronism when a pair passes 180 degrees."""
    law = NetworkLaw.uniform(kundur, 0.1, 1.0, 1.1, 1.0)
    traj = simulate_network(kundur, law, BusFault(kundur, 8, 0.95), [0.0], 5.0, 50.0)
    outcome = assess_network(traj)[0]
    spread = traj.delta_rad[:, :, 0].max(axis=1) - traj.delta_rad[:, :, 0].min(axis=1)
    assert not outcome.in_synchronism and not outcome.stable
    assert outcome.pole_slip_s == pytest.approx(traj.t_s[np.argmax(spread > math.pi)])
    assert not all(g.in_synchronism for g in outcome.generators)


def test_user_matpower_file_gives_the_shipped_network(tmp_path, kundur):
    case = tmp_path / "mine.m"
    case.write_text(shipped_text("kundur_two_area.m"))
    machines = tmp_path / "mine.csv"
    machines.write_text(shipped_text("kundur_two_area_machines.csv"))
    mine = load_network(str(case), str(machines), 60.0)
    assert_allclose(mine.delta_bar_rad, kundur.delta_bar_rad, atol=1e-12)
    assert_allclose(mine.coupling.bs, kundur.coupling.bs, atol=1e-12)
    with pytest.raises(ValueError, match="needs its machine data"):
        load_network(str(case))
    case.write_text("mpc.baseMVA = 100;\nmpc.bus = [1 3 0 0 0 0 1 1 0 20 1 1.1 0.9];\n")
    with pytest.raises(ValueError, match="missing mpc.gen, mpc.branch"):
        load_network(str(case), str(machines), 60.0)


def test_dropping_lost_runs_changes_nothing_before_the_loss(kundur):
    """drop_lost_runs (what --cct uses) stops a lost run at its loss; the other runs are the same floats."""
    law = NetworkLaw.uniform(kundur, 0.1, 1.0, 1.1, 1.0)
    clearing = np.array([0.3, 0.95, 0.5])
    full = simulate_network(kundur, law, BusFault(kundur, 8, clearing), [0.0, 0.0, 0.1], 4.0, 50.0)
    dropped = simulate_network(kundur, law, BusFault(kundur, 8, clearing), [0.0, 0.0, 0.1], 4.0, 50.0,
                               drop_lost_runs=True)
    spread = full.delta_rad.max(axis=1) - full.delta_rad.min(axis=1)
    loss = int(np.argmax(spread[:, 1] > math.pi))
    assert loss > 0 and np.all(spread[:, [0, 2]] <= math.pi)
    assert np.array_equal(dropped.delta_rad[:, :, [0, 2]], full.delta_rad[:, :, [0, 2]])
    assert np.array_equal(dropped.delta_rad[:loss + 1, :, 1], full.delta_rad[:loss + 1, :, 1])
    assert np.all(np.isnan(dropped.delta_rad[loss + 1:, :, 1]))
