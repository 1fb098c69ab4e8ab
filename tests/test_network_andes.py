"""The network plant against an independent simulator: ANDES with classical GENCLS generators.

tests/network_reference/andes_reference.json was made by
tests/network_reference/make_andes_reference.py (ANDES 2.0.0 in its own venv;
ANDES is GPL-3 and not a dependency): ANDES's own load flow and its trapezoidal
DAE simulation at 1 ms of the same case data, two faults per case. Here the
project's network core (RK4 at 1 ms, no batteries) runs the same faults.

Stated tolerances: COI-relative rotor angles within 2e-3 rad over the 5 s after
the fault (different integrators, ANDES's fault as a 1e-4 pu reactance in both),
critical clearing times within 2 ms (both on a 1 ms grid).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from nni_battery_controller.network_sim import NetworkLaw, critical_clearing_times, simulate_network
from nni_plant_sim.cases import load_network
from nni_plant_sim.network_scenarios import BusFault

REFERENCE = json.loads((Path(__file__).parent / "network_reference" / "andes_reference.json").read_text())
ANGLE_TOLERANCE_RAD = 2e-3
CCT_TOLERANCE_S = 2e-3
FAULTS = REFERENCE["faults"]


def fault_of(net, entry):
    def factory(clearing_s):
        trip = () if entry["trip"] is None else (net.bus_model.branch_index(*entry["trip"]),)
        return BusFault(net, entry["bus"], clearing_s, complex(0.0, entry["fault_reactance_pu"]), trip)

    return factory


def label(entry):
    return f"{entry['case']}-bus{entry['bus']}{'-trip' if entry['trip'] else ''}"


@pytest.fixture(scope="module")
def networks():
    return {name: load_network(name) for name in {entry["case"] for entry in FAULTS}}


@pytest.mark.parametrize("entry", FAULTS, ids=label)
def test_coi_angles_agree_with_andes(entry, networks):
    net = networks[entry["case"]]
    law = NetworkLaw.uniform(net, 0.1, 1.0, 1.1, 1.0)
    t_ref = np.array(entry["t_s"])
    traj = simulate_network(net, law, fault_of(net, entry)(entry["clearing_time_s"]), [0.0], t_ref[-1], 100.0)
    assert np.allclose(traj.t_s, t_ref, atol=1e-9)
    mine = traj.coi_angles()[:, :, 0]
    theirs = np.array(entry["coi_angles_rad"])
    assert np.abs(theirs).max() > 0.1  # the fault does move the rotors
    assert np.abs(mine - theirs).max() < ANGLE_TOLERANCE_RAD


def test_critical_clearing_times_agree_with_andes(networks):
    for entry in FAULTS:
        assert entry["cct_s"] is not None, f"{label(entry)}: ANDES found no stable clearing time"
        net = networks[entry["case"]]
        law = NetworkLaw.uniform(net, 0.1, 1.0, 1.1, 1.0)
        (cct, _bracket, at_limit), = critical_clearing_times(net, law, fault_of(net, entry), [0.0], 5.0, 100.0,
                                                              high_s=entry["cct_search_high_s"])
        assert not at_limit
        assert cct == pytest.approx(entry["cct_s"], abs=CCT_TOLERANCE_S), label(entry)
