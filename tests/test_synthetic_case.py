"""The synthetic 52-generator case (13 copies of Kundur's two-area system in a ring), for the scaling benchmark.

Expected values come from Kundur's published data (the machine records, the
voltage set-points), from the load flow itself (pypower's solution, checked
for power balance here) or from physics (an equilibrium stays at rest), never
from the Kron reduction under test.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from nni_plant_sim.cases import CASES, load_network, read_machines, read_matpower, shipped_text
from nni_plant_sim.cases.replicated import ring_of_kundur
from nni_plant_sim.integrators import advance
from nni_plant_sim.network import network_acceleration, solve_load_flow
from nni_plant_sim.network_scenarios import AngleDisplacement

COPIES = 13


@pytest.fixture(scope="module")
def ring():
    return load_network("kundur_ring_52")


@pytest.fixture(scope="module")
def built():
    return ring_of_kundur(read_matpower(shipped_text("kundur_two_area.m")),
                          read_machines(shipped_text("kundur_two_area_machines.csv")), COPIES)


def test_the_ring_loads_by_name_with_52_generators_each_with_kundurs_machine_data(ring):
    assert "kundur_ring_52" in CASES
    assert ring.size == 52 >= 50
    assert list(ring.gen_bus) == [b + 100 * k for k in range(COPIES) for b in (1, 2, 3, 4)]
    kundur = load_network("kundur_two_area")
    assert_allclose(ring.inertia_m, np.tile(kundur.inertia_m, COPIES), rtol=0, atol=0)
    assert ring.f0_hz == 60.0 and set(ring.mbase_mva) == {900.0}


def test_its_load_flow_converges_to_a_balanced_solution_with_one_slack_and_power_on_every_tie(built):
    ppc, machines = built
    assert len(machines) == 52
    assert np.count_nonzero(ppc["bus"][:, 1] == 3) == 1  # copy 0's bus 3 only
    solved = solve_load_flow(ppc)  # raises when it does not converge
    bus, gen, branch = solved["bus"], solved["gen"], solved["branch"]
    # Generator terminals hold Kundur's set-points (1.03 pu at G1 and G3, 1.01 pu at G2 and G4) in every copy.
    terminals = [np.flatnonzero(bus[:, 0] == b)[0] for b in gen[:, 0]]
    assert_allclose(bus[terminals, 7], np.tile([1.03, 1.01, 1.03, 1.01], COPIES), atol=1e-9)
    # Power balance: generation = load + the branches' losses (each branch: sending + receiving end).
    losses = (branch[:, 13] + branch[:, 15]).sum()
    assert gen[:, 1].sum() == pytest.approx(bus[:, 2].sum() + losses, abs=1e-6)
    ties = branch[-COPIES:]
    assert list(ties[:, 0]) == [9 + 100 * k for k in range(COPIES)]
    assert list(ties[:, 1]) == [7 + 100 * ((k + 1) % COPIES) for k in range(COPIES)]
    assert np.all(np.abs(ties[:, 13]) > 50.0)  # every tie carries power: the copies are coupled


def test_its_pre_fault_equilibrium_is_an_equilibrium(ring, built):
    """P_m = P_e at delta_bar (the load flow's P_G plus the stator loss), rates ~0, and 2 s at rest stays at rest."""
    solved = solve_load_flow(built[0])
    base = solved["baseMVA"]
    rows = [np.flatnonzero(solved["bus"][:, 0] == b)[0] for b in solved["gen"][:, 0]]
    voltage = solved["bus"][rows, 7] * np.exp(1j * np.radians(solved["bus"][rows, 8]))
    power = (solved["gen"][:, 1] + 1j * solved["gen"][:, 2]) / base
    ra = 0.0025 * base / 900.0
    assert_allclose(ring.p_mech_pu, power.real + ra * np.abs(np.conj(power / voltage)) ** 2, rtol=0, atol=1e-8)
    rates = network_acceleration(ring.delta_bar_rad, np.zeros(ring.size), 0.0, ring, ring.p_mech_pu, ring.coupling)
    assert np.max(np.abs(rates)) < 1e-9
    rest = AngleDisplacement(np.zeros(ring.size))
    x = advance(0.0, 2.0, rest.initial_state(ring), 0.0, ring, rest)
    assert_allclose(x[0], ring.delta_bar_rad, rtol=0, atol=1e-8)
    assert_allclose(x[1], 0.0, rtol=0, atol=1e-8)


def test_a_ring_of_one_copy_is_refused():
    with pytest.raises(ValueError, match="a ring needs at least 2 copies, got 1"):
        ring_of_kundur(read_matpower(shipped_text("kundur_two_area.m")), [], 1)
