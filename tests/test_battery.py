"""A battery of finite energy (issue 32): its charge where the power flows, cut exactly where it runs empty or
full, offline and in the plant's reporting core; ``nni-simulate --battery-energy-pu-s`` and what it refuses."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from nni_battery_controller.law import ControllerParams
from nni_battery_controller.simulate import simulate_sampled
from nni_plant_sim.battery import EnergyStore
from nni_plant_sim.link import NO_LINK, DelayLine
from nni_plant_sim.model import SmibParams
from nni_plant_sim.reporting import LockstepStepper, RealtimeReporter
from nni_plant_sim.scenarios import TransferLimitFault
from test_link import MS, integrate, paired_channel  # the reporting core's recording integrator and channel

pytestmark = pytest.mark.core
SIMULATE = [sys.executable, "-m", "nni_battery_controller.simulate_command"]


def held(power: float, energy: float, t1: float = 1.0):
    """The pieces of [0, t1] with ``power`` asked of a battery of ``energy``, the powers given over each."""
    line = DelayLine(NO_LINK, [power], store=EnergyStore([energy]))
    pieces = [(start, stop, line.applied_powers()[0]) for start, stop in line.pieces(0.0, t1)]
    return pieces, line.store


def test_a_battery_asked_for_more_than_it_holds_delivers_until_empty_then_nothing():
    # From half charge 0.1 pu s, at 0.5 pu: empty after 0.1 / 0.5 = 0.2 s.
    pieces, store = held(0.5, 0.1)
    assert pieces == [(0.0, pytest.approx(0.2, abs=1e-15), 0.5), (pytest.approx(0.2, abs=1e-15), 1.0, 0.0)]
    assert store.charge_pu_s == [0.0] and store.empty_at_s[0] == pytest.approx(0.2) and store.full_at_s == [None]


def test_a_battery_absorbing_fills_its_room_then_absorbs_nothing():
    # Room 0.1 pu s above half charge, at -0.25 pu: full after 0.4 s, at 0.2 pu s.
    pieces, store = held(-0.25, 0.1)
    assert [(round(a, 12), round(b, 12), p) for a, b, p in pieces] == [(0.0, 0.4, -0.25), (0.4, 1.0, 0.0)]
    assert store.charge_pu_s == [0.2] and store.full_at_s[0] == pytest.approx(0.4)


def test_without_an_energy_limit_the_run_is_bit_for_bit_today_s():
    plant, ctrl = SmibParams(), ControllerParams(battery_limit_pu=0.3)
    fault = TransferLimitFault(0.5, 0.15)
    today = simulate_sampled(plant, ctrl, fault, 4.0, 50.0)
    unlimited = simulate_sampled(plant, ctrl, fault, 4.0, 50.0, battery_energy_pu_s=math.inf)
    assert np.array_equal(today.delta_rad, unlimited.delta_rad) and unlimited.charge_pu_s is None


def test_a_small_battery_s_charge_follows_its_power_and_an_empty_one_delivers_nothing():
    plant, ctrl, period = SmibParams(), ControllerParams(battery_limit_pu=0.3), 1.0 / 50.0
    traj = simulate_sampled(plant, ctrl, TransferLimitFault(0.5, 0.15), 6.0, 50.0, battery_energy_pu_s=0.02)
    charge, power = traj.charge_pu_s, traj.battery_power_pu
    assert np.all((charge >= 0.0) & (charge <= 0.04)) and traj.empty_at_s is not None
    assert np.all(power[charge == 0.0] <= 0.0) and np.all(power[charge == 0.04] >= 0.0)
    inside = (charge[:-1] > 0) & (charge[:-1] < 0.04) & (charge[1:] > 0) & (charge[1:] < 0.04)
    # Where no bound is met within a period, the charge moves by the held power times the period.
    assert np.allclose(charge[1:][inside], (charge[:-1] - power[:-1] * period)[inside], rtol=0, atol=1e-12)
    assert inside.sum() > 100


# --- the plant's reporting core, which the plant nodes run ---------------------------------------

def test_the_lockstep_core_cuts_the_period_where_the_battery_runs_empty_and_reports_the_charge():
    # Half charge 0.005 pu s, asked for 0.5 pu from sample 0: empty at 0.01 s, nothing from there.
    loop = LockstepStepper(integrate, [], [paired_channel()], 0.04, 0.02, 1.0, NO_LINK, EnergyStore([0.005]))
    first = loop.start(0).measurement
    assert first.powers == (0.0,) and loop.store.charge_pu_s == [0.005]
    loop.sent(MS)
    _, output = loop.command(0, 0, 0.5, 2 * MS)
    assert loop.state == [(0.0, 0.01, (0.5,)), (0.01, 0.02, (0.0,))]
    assert output.measurement.powers == (0.0,) and loop.store.charge_pu_s == [0.0]
    assert loop.store.empty_at_s == [pytest.approx(0.01)]


def test_the_realtime_core_s_redo_of_a_piece_integrated_ahead_takes_the_charge_back():
    # The answer arrives at 5 ms: integrated ahead to 20 ms at 0.5 pu, the battery empty at 15 ms. A fault at
    # 12 ms redoes the piece from 5 ms: the charge there is 0.005 - 0.5 x 0.007, not the empty battery's 0.
    loop = RealtimeReporter(integrate, [], [paired_channel()], 0.0, 1_000 * MS, 20 * MS, 0.1, NO_LINK,
                            EnergyStore([0.005]))
    loop.start(1_000 * MS)
    loop.command(0, 1_000 * MS, 0.5, 1_005 * MS)
    assert loop.state[-2:] == [(0.005, 0.015, (0.5,)), (0.015, 0.02, (0.0,))] and loop.store.charge_pu_s == [0.0]
    loop.interrupt(1_012 * MS)
    assert loop.state[-1] == (0.005, 0.012, (0.5,))
    assert loop.store.charge_pu_s == [pytest.approx(0.0015, abs=1e-15)] and loop.store.empty_at_s == [None]


def test_a_networks_batteries_fill_exactly_their_room_and_then_absorb_nothing():
    """Kundur's case, a battery of 0.05 pu s at each generator: the NNI law's first answers absorb; each battery is
    full (at twice its energy) where the offline network run says, gives nothing into it after, and without a
    finite energy the run is bit for bit the unlimited one's. More than one run at a time is refused."""
    from nni_battery_controller.network_deployment import default_law
    from nni_battery_controller.network_sim import simulate_network
    from nni_plant_sim.cases import load_network
    from nni_plant_sim.network_scenarios import BusFault

    net = load_network("kundur_two_area")
    run = lambda **energy: simulate_network(net, default_law(net), BusFault(net, 7, 0.1),  # noqa: E731
                                            [np.full(4, 0.3)], 1.0, 50.0, **energy)
    unlimited, limited = run(), run(battery_energy_pu_s=0.05)
    assert np.array_equal(run(battery_energy_pu_s=math.inf).delta_rad, unlimited.delta_rad)
    assert limited.charge_pu_s == pytest.approx((0.1,) * 4, abs=1e-15) and all(limited.full_at_s)
    for i, full_at in enumerate(limited.full_at_s):
        k = int(full_at * 50.0)  # the period it ran full in: absorbing until then, nothing after
        assert np.all(limited.battery_power_pu[:k, i, 0] < 0) and np.all(limited.battery_power_pu[k + 1:, i, 0] >= 0)
        # Its room, on the system base: what it absorbed up to then (each power held over its period).
        absorbed = -np.sum(limited.battery_power_pu[:k, i, 0]) / 50.0 \
            - limited.battery_power_pu[k, i, 0] * (full_at - k / 50.0)
        assert absorbed == pytest.approx(0.05 * net.pu_of_machine(np.ones(4))[i], rel=1e-12)
    with pytest.raises(ValueError, match="a battery of finite energy takes one run at a time, got 2"):
        simulate_network(net, default_law(net), BusFault(net, 7, 0.1), [0.3, 0.2], 1.0, 50.0,
                         battery_energy_pu_s=0.05)


def test_compare_laws_says_which_laws_run_the_battery_empty(tmp_path):
    out = tmp_path / "cmp.json"
    done = subprocess.run([*SIMULATE, "--compare-laws", "--b", "0.3", "--battery-energy-pu-s", "0.1", "--duration",
                           "6", "--json", str(out)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "every law with a battery of 0.1 pu s to deliver and as much room to absorb" in done.stdout
    assert "empty at (s)" in done.stdout
    assert "ROA: not swept ('-'): the sweep models an unlimited battery" in done.stdout
    data = json.loads(out.read_text())
    assert data["battery_energy_pu_s"] == 0.1
    assert data["roa"] is None and all(row["roa_synchronism_area_rad2_per_s"] is None for row in data["rows"])
    empties = {row["law"]: row["battery_empty_at_s"] for row in data["rows"]}
    assert empties["nni"] is None and empties["droop"] is not None  # the NNI law absorbs first, droop delivers
    assert all(row["energy_pu_s"] <= 0.2 + 2 * 0.1 * 6 for row in data["rows"])


@pytest.mark.parametrize("argv, message", [
    (["--battery-energy-pu-s", "-1"], "a battery's energy must be > 0 pu s (inf: unlimited), got -1.0"),
    (["--battery-energy-pu-s", "nan"], "a battery's energy must be > 0 pu s (inf: unlimited), got nan"),
    (["--battery-energy-pu-s", "0"], "a battery's energy must be > 0 pu s"),
    (["--battery-energy-pu-s", "lots"], "expected a number, got 'lots'"),
    (["--battery-energy-pu-s", "1", "--tune-laws"], "--tune-laws tunes with an unlimited battery"),
    (["--battery-energy-pu-s", "1", "--controller-rate", "continuous"], "--controller-rate continuous is the paper's continuous law"),
    (["--case", "kundur_two_area", "--battery-energy-pu-s", "1"], "unrecognized arguments: --battery-energy-pu-s"),
])
def test_a_bad_or_inapplicable_energy_is_one_line_and_exit_2(argv, message, tmp_path):
    done = subprocess.run([*SIMULATE, *argv, "--json", str(tmp_path / "x.json")], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 2 and message in done.stderr and len(done.stderr.splitlines()) == 1, done.stderr
    assert not (tmp_path / "x.json").exists()
