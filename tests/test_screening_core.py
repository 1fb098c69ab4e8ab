"""The screen's pure parts: which contingencies a case has, which trips island it, their names; the new cases.

IEEE 118 and 300 carry typical machine data from a rule (nni_plant_sim/cases/typical.py): the shipped
files must be that rule's output, their load flows must converge, and their pre-fault state must be an
equilibrium (nothing moves in an undisturbed run).
"""

from __future__ import annotations

import numpy as np
import pytest

from nni_msgs_adapter.ros.defaults import controller_defaults

from nni_battery_controller.network_sim import NetworkLaw, simulate_network
from nni_battery_controller.screening import (
    CaseSpec,
    ScreenSettings,
    enumerate_contingencies,
    islanding_reason,
    network_of,
    parse_contingency,
    screen_law,
)
from nni_plant_sim.cases import CASES, DEFAULT_FAULT_BUS, case_data, case_digest, load_network, shipped_text
from nni_plant_sim.cases.typical import TITLES, machine_file_text
from nni_plant_sim.network_scenarios import AngleDisplacement


@pytest.fixture(scope="module")
def kundur():
    return network_of(CaseSpec("kundur_two_area"))


def test_kundur_has_a_fault_at_every_bus_and_at_both_ends_of_every_circuit(kundur):
    found = enumerate_contingencies(kundur)
    buses = [c for c in found if c.kind == "bus"]
    lines = [c for c in found if c.kind == "line"]
    assert [c.name for c in buses] == [f"bus:{b}" for b in range(1, 12)]
    assert len(lines) == 2 * len(kundur.bus_model.branch_ends)
    # The 7-8 corridor has two circuits, each with a fault at each end.
    assert [c.name for c in lines if c.line[:2] == (7, 8)] == ["line:7-8:1@7", "line:7-8:1@8", "line:7-8:2@7",
                                                               "line:7-8:2@8"]
    assert all(parse_contingency(kundur, c.name) == c for c in found)


def test_a_trip_that_islands_the_network_is_named_with_what_it_cuts_off(kundur):
    step_up = parse_contingency(kundur, "line:1-5@5")
    assert islanding_reason(kundur, step_up) == \
        "the trip of 1-5 islands the network: bus 1 with generator G1@1 cut off"
    assert "buses 1, 2, 5, 6 with generators G1@1, G2@2 cut off" in islanding_reason(
        kundur, parse_contingency(kundur, "line:6-7@7"))
    # One of two parallel circuits and every bus fault leave the network whole.
    assert islanding_reason(kundur, parse_contingency(kundur, "line:7-8:2@8")) is None
    assert islanding_reason(kundur, parse_contingency(kundur, "bus:7")) is None


@pytest.mark.parametrize("text, words", [
    ("bus:99", "bus 99 is not in the case"), ("line:7-9@7", "no circuit 1 between buses 7 and 9"),
    ("line:7-8:3@7", "no circuit 3 between buses 7 and 8"), ("line:7-8@9", "bus 9 is not an end"),
    ("gen:1", "expected bus:B or line:F-T[:C]@E"), ("line:7-8", "expected bus:B"),
])
def test_a_contingency_the_case_does_not_have_is_refused_naming_it(kundur, text, words):
    with pytest.raises(ValueError, match=f"contingency '{text}'") as error:
        parse_contingency(kundur, text)
    assert words in str(error.value)


def test_the_law_dimension_builds_every_law_and_refuses_an_unknown_one_in_one_place(kundur):
    settings = ScreenSettings(limits_pu=(0.0,), laws=("nni",))
    law = screen_law("nni", kundur, settings)
    assert isinstance(law, NetworkLaw) and law.reference == "pmu" and law.name == "nni"
    droop = screen_law("droop", kundur, settings)
    assert droop.name == "droop" and droop.gains.k_f == controller_defaults()["droop_k_f"]
    with pytest.raises(ValueError, match="unknown law 'bogus'"):
        screen_law("bogus", kundur, settings)


def test_a_case_digest_names_its_data():
    kundur = case_digest(*case_data("kundur_two_area"))
    assert kundur == case_digest(*case_data("kundur_two_area"))
    assert kundur != case_digest(*case_data("ieee39"))
    ppc, machines, f0 = case_data("kundur_two_area")
    ppc["bus"][6, 2] += 1.0  # one more MW at bus 7
    assert case_digest(ppc, machines, f0) != kundur
    assert case_digest(*case_data("kundur_two_area"))[:12] == CaseSpec("kundur_two_area").digest()[:12]


@pytest.mark.parametrize("case, source", [("ieee118", "case118"), ("ieee300", "case300")])
def test_the_typical_machine_files_are_the_rules_output(case, source):
    assert CASES[case][0] == f"pypower:{source}"
    assert shipped_text(CASES[case][1]) == machine_file_text(source, TITLES[source])
    assert "TYPICAL values from a" in shipped_text(CASES[case][1])


@pytest.mark.parametrize("case, generators", [("ieee118", 54), ("ieee300", 69)])
def test_the_large_cases_solve_and_rest_at_their_equilibrium(case, generators):
    net = load_network(case)  # raises when the load flow does not converge
    assert net.size == generators
    ppc, machines, _ = case_data(case)
    slack = np.isin(ppc["gen"][:, 0], ppc["bus"][ppc["bus"][:, 1] == 3, 0])
    # Every unit but the slack at its dispatch (the load flow's PG: the mechanical power of the equilibrium).
    assert np.allclose(net.p_mech_pu[~slack], ppc["gen"][~slack, 1] / 100.0, atol=1e-8)
    law = NetworkLaw.uniform(net, 0.1, 1.0, 1.1, 1.0)
    traj = simulate_network(net, law, AngleDisplacement(np.zeros(net.size)), [0.0, 0.1], 1.0, 50.0)
    assert np.abs(traj.delta_rad - net.delta_bar_rad[None, :, None]).max() < 1e-9
    assert np.abs(traj.speed_rad_s).max() < 1e-9
    net.bus_model.bus_index(DEFAULT_FAULT_BUS[case])
