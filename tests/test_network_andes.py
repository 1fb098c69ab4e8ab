"""The network plant against an independent simulator: ANDES with classical GENCLS generators.

tests/network_reference/andes_reference_<case>.json were made by
tests/network_reference/make_andes_reference.py (ANDES 2.0.0 in its own venv;
ANDES is GPL-3 and not a dependency): ANDES's own load flow and its trapezoidal
DAE simulation at 1 ms of the same case data, two faults per case. Here the
project's network core (RK4 at 1 ms, no batteries) runs the same faults.

Stated tolerances: COI-relative rotor angles within 1e-3 rad over the 5 s after
the fault (measured: 4.8e-5 to 1.8e-4 rad; different integrators, the fault a 1e-4 pu reactance in both),
critical clearing times within 2 ms (both on a 1 ms grid): the same plain
bisection as the script's, run on the project's simulator, and the same verdict
as ANDES at every clearing time ANDES visited (except within 2 ms of its CCT).
Stability need not be monotone in the clearing time (IEEE 39 bus 16 is not), so
the bisection's CCT is not nni-simulate --cct's first loss; both are reported.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from nni_battery_controller.network_sim import NetworkLaw, angle_spread, simulate_network
from nni_plant_sim.cases import load_network
from nni_plant_sim.network_scenarios import BusFault

REFERENCES = sorted((Path(__file__).parent / "network_reference").glob("andes_reference_*.json"))
FAULTS = [fault for path in REFERENCES for fault in json.loads(path.read_text())["faults"]]
ANGLE_TOLERANCE_RAD = 1e-3
CCT_TOLERANCE_S = 2e-3
DURATION_S = 5.0


def test_both_cases_have_two_faults():
    assert sorted(f["case"] for f in FAULTS) == ["ieee39", "ieee39", "kundur_two_area", "kundur_two_area"]


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


def in_step(net, entry, clearing_s):
    """The project's verdict for each clearing time: no pair beyond 180 degrees over the 5 s."""
    law = NetworkLaw.uniform(net, 0.1, 1.0, 1.1, 1.0)
    clearing = np.atleast_1d(clearing_s)
    traj = simulate_network(net, law, fault_of(net, entry)(clearing), [0.0] * clearing.size, DURATION_S, 100.0)
    return angle_spread(traj.delta_rad).max(axis=0) <= np.pi


@pytest.mark.parametrize("entry", FAULTS, ids=label)
def test_critical_clearing_times_agree_with_andes(entry, networks):
    net = networks[entry["case"]]
    assert entry["cct_s"] is not None, f"{label(entry)}: ANDES found no stable clearing time"
    visited = np.array([t for t, _ in entry["cct_visited"]])
    theirs = np.array([ok for _, ok in entry["cct_visited"]])
    mine = in_step(net, entry, visited)
    near = np.abs(visited - entry["cct_s"]) <= CCT_TOLERANCE_S
    assert np.array_equal(mine[~near], theirs[~near]), list(zip(visited, mine, theirs))
    # The script's plain bisection, on the project's simulator.
    lo, hi = 0, int(round(entry["cct_search_high_s"] / 1e-3)) + 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if in_step(net, entry, mid * 1e-3)[0] else (lo, mid)
    assert lo * 1e-3 == pytest.approx(entry["cct_s"], abs=CCT_TOLERANCE_S)
