"""Issue 32: every law through ``nni-demo`` as a user runs it, and what the recording says ran.

``nni-demo --law LAW``, the SMIB with its controller in its own process and Kundur's network with the four
controllers composed in one: the recording equals the offline sampled run of the same law and shipped gains to
1e-12 (lockstep), the demo's header names the law and its gains, and ``nni-replay --info`` prints the law.
(Each law's lockstep = offline at the node level: tests/test_distributed_loop.py.)
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from nni_battery_controller.law import ControllerParams
from nni_battery_controller.laws import GAIN_PARAMETERS, law_from_parameters
from nni_battery_controller.network_deployment import default_law
from nni_battery_controller.network_sim import NetworkLaw, simulate_network
from nni_battery_controller.simulate import simulate_sampled
from nni_msgs_adapter.recording.mcap_io import read_recording
from nni_msgs_adapter.recording.runs import generator_runs
from nni_msgs_adapter.ros.defaults import controller_defaults
from nni_plant_sim.cases import load_network
from nni_plant_sim.model import SmibParams
from nni_plant_sim.network_scenarios import BusFault
from nni_plant_sim.scenarios import InitialAngle
from nni_msgs_adapter.viewing.rerun_layout import CHARGE_ROOT
from rerun.chunk import RrdReader
from rosproc import busy_processes, fresh_domain_id, ros_env
from test_demo import rrd_scalars

pytestmark = pytest.mark.ros

BIN = Path(sys.executable).parent
B, DURATION_S, RATE_HZ = 0.3, 2.0, 50.0


def shipped_law(name: str):
    """The law ``name`` with the gains the package ships (config/controller.yaml), b = B."""
    return law_from_parameters(name, controller_defaults(), ControllerParams(battery_limit_pu=B))


def gains_text(name: str) -> str:
    defaults = controller_defaults()
    return ", ".join(f"{key} {defaults[key]:g}" for key in GAIN_PARAMETERS[name])


@pytest.mark.parametrize("name, case, deployment", [("vsm", None, "separate"),
                                                    ("pss", "kundur_two_area", "composed")])
def test_the_demo_runs_the_law_asked_for_as_offline_and_the_recording_says_which(tmp_path, name, case, deployment):
    domain = fresh_domain_id()
    where = ["--case", case, "--deployment", deployment] if case else []
    with busy_processes(2):
        done = subprocess.run([str(BIN / "nni-demo"), *where, "--law", name, "--b", str(B), "--duration",
                               str(DURATION_S), "--mode", "lockstep", "--out", str(tmp_path), "--domain-id",
                               str(domain)], env=ros_env(domain), capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    (recording,) = tmp_path.glob("*.mcap")
    runs = list(generator_runs(read_recording(recording)).values())
    law = shipped_law(name)
    if case is None:
        assert f"law {name}: {gains_text(name)}" in done.stdout, done.stdout
        offline = simulate_sampled(SmibParams(), law.ctrl, InitialAngle(), DURATION_S, RATE_HZ, law=law)
        (run,) = runs
        np.testing.assert_allclose(run.delta_rad, offline.delta_rad, rtol=0, atol=1e-12)
        np.testing.assert_allclose(run.battery_power_pu[:-1], offline.battery_power_pu[:-1], rtol=0, atol=1e-12)
        nni = simulate_sampled(SmibParams(), law.ctrl, InitialAngle(), DURATION_S, RATE_HZ)
        assert np.max(np.abs(nni.delta_rad - offline.delta_rad)) > 1e-3, "another law, another run"
    else:
        net = load_network(case)
        nni = default_law(net)
        network_law = NetworkLaw.uniform(net, nni.tau_s, nni.gain_k, nni.gain_l, nni.alpha, name=name,
                                         gains=law.gains)
        offline = simulate_network(net, network_law, BusFault(net, 7, 0.1), [np.full(4, B)], DURATION_S, RATE_HZ)
        assert len(runs) == 4
        for i, run in enumerate(runs):
            np.testing.assert_allclose(run.delta_rad, offline.delta_rad[:, i, 0], rtol=0, atol=1e-12)
    info = subprocess.run([str(BIN / "nni-replay"), str(recording), "--info"], capture_output=True, text=True,
                          timeout=120)
    assert info.returncode == 0, info.stderr
    expected = f"Law:               {name} ({gains_text(name)})" + (" at every generator" if case else "")
    assert expected in info.stdout.splitlines(), info.stdout


def test_the_network_demos_batteries_of_finite_energy_run_full_in_the_plant_as_offline(tmp_path):
    """``nni-demo --case kundur_two_area --battery-energy-pu-s``: every generator's battery runs full (the NNI law's
    first answers absorb) at the instant the offline network run's does, and the recording equals that offline run
    to 1e-12."""
    energy, duration = 0.05, 2.0
    net = load_network("kundur_two_area")
    offline = simulate_network(net, default_law(net), BusFault(net, 7, 0.1), [np.full(4, B)], duration, RATE_HZ,
                               battery_energy_pu_s=energy)
    assert all(at is not None for at in offline.full_at_s), "the case runs every battery full"
    domain = fresh_domain_id()
    with busy_processes(2):
        done = subprocess.run([str(BIN / "nni-demo"), "--case", "kundur_two_area", "--deployment", "composed", "--b",
                               str(B), "--battery-energy-pu-s", str(energy), "--duration", str(duration),
                               "--out", str(tmp_path), "--domain-id", str(domain)], env=ros_env(domain),
                              capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    (recording,) = tmp_path.glob("*.mcap")
    runs = list(generator_runs(read_recording(recording)).values())
    scale = net.pu_of_machine(np.ones(4))
    (summary,) = json.loads((tmp_path / "summary.json").read_text())["runs"]
    for i, run in enumerate(runs):
        np.testing.assert_allclose(run.delta_rad, offline.delta_rad[:, i, 0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(run.battery_power_pu[:-1] * scale[i], offline.battery_power_pu[:-1, i, 0],
                                   rtol=0, atol=1e-12)
        battery = summary["generators"][f"gen{i + 1}"]["battery"]
        assert battery["full_at_s"] == pytest.approx(offline.full_at_s[i], abs=1e-12), battery
        assert battery["charge_pu_s"] == pytest.approx(offline.charge_pu_s[i], abs=1e-12), battery
        assert f"  /gen{i + 1}  battery full at {offline.full_at_s[i]:.3f} s" in done.stdout, done.stdout
    # The Rerun view of the recording draws each battery's charge: full (2E) from the first sample after the
    # offline run's full instant on, and what the plant's summary says at the end.
    rrd = tmp_path / "run.rrd"
    view = subprocess.run([str(BIN / "nni-replay"), str(recording), "--rrd", str(rrd)], capture_output=True,
                          text=True, timeout=120)
    assert view.returncode == 0, view.stderr
    series = rrd_scalars(rrd)
    for i in range(4):
        t, charge = series[f"{CHARGE_ROOT}/gen{i + 1}"]
        assert np.all(charge[t <= offline.full_at_s[i]] < 2 * energy)
        np.testing.assert_allclose(charge[t > offline.full_at_s[i]], 2 * energy, rtol=0, atol=1e-12)
        assert charge[-1] == pytest.approx(offline.charge_pu_s[i], abs=1e-12)


def test_the_demos_battery_of_finite_energy_runs_empty_in_the_plant_as_offline(tmp_path):
    """``nni-demo --battery-energy-pu-s``: the plant node's battery runs empty where the offline run's does, the
    recording equals the offline run to 1e-12 (the angle, and the power the battery gave: none once empty), and
    the demo's line, summary.json and ``nni-replay --info`` say when it ran empty, and ``nni-replay --rrd`` draws
    the charge as offline."""
    energy, duration = 0.05, 4.0
    offline = simulate_sampled(SmibParams(), ControllerParams(battery_limit_pu=B), InitialAngle(), duration, RATE_HZ,
                               battery_energy_pu_s=energy)
    assert offline.empty_at_s is not None and np.any(offline.charge_pu_s == 0.0), "the case runs the battery empty"
    unlimited = simulate_sampled(SmibParams(), ControllerParams(battery_limit_pu=B), InitialAngle(), duration, RATE_HZ)
    assert np.max(np.abs(unlimited.delta_rad - offline.delta_rad)) > 0.1, "the energy limit changes the run"
    domain = fresh_domain_id()
    with busy_processes(2):
        done = subprocess.run([str(BIN / "nni-demo"), "--b", str(B), "--battery-energy-pu-s", str(energy),
                               "--duration", str(duration), "--mode", "lockstep", "--out", str(tmp_path),
                               "--domain-id", str(domain)], env=ros_env(domain), capture_output=True, text=True,
                              timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"battery empty at {offline.empty_at_s:.3f} s" in done.stdout, done.stdout
    (recording,) = tmp_path.glob("*.mcap")
    (run,) = generator_runs(read_recording(recording)).values()
    np.testing.assert_allclose(run.delta_rad, offline.delta_rad, rtol=0, atol=1e-12)
    np.testing.assert_allclose(run.battery_power_pu[:-1], offline.battery_power_pu[:-1], rtol=0, atol=1e-12)
    (summary,) = json.loads((tmp_path / "summary.json").read_text())["scenarios"]
    assert summary["battery"]["energy_pu_s"] == energy
    assert summary["battery"]["empty_at_s"] == pytest.approx(offline.empty_at_s, abs=1e-12)
    assert summary["battery"]["charge_pu_s"] == pytest.approx(offline.charge_pu_s[-1], abs=1e-12)
    info = subprocess.run([str(BIN / "nni-replay"), str(recording), "--info"], capture_output=True, text=True,
                          timeout=120)
    assert info.returncode == 0, info.stderr
    assert any(line.startswith("  battery charge: ") and f"empty at {offline.empty_at_s:.3f} s" in line
               for line in info.stdout.splitlines()), info.stdout
    # The Rerun view draws the charge, in a view of its own: the offline run's to 1e-12 at every answered sample.
    rrd = tmp_path / "run.rrd"
    view = subprocess.run([str(BIN / "nni-replay"), str(recording), "--rrd", str(rrd)], capture_output=True,
                          text=True, timeout=120)
    assert view.returncode == 0, view.stderr
    t, charge = rrd_scalars(rrd)[f"{CHARGE_ROOT}/b\\={B:g}"]
    np.testing.assert_allclose(t, offline.t_s[:-1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(charge, offline.charge_pu_s[:-1], rtol=0, atol=1e-12)
    assert charge.min() == 0.0 and charge.max() == 2 * energy, "empty and full, as the plant's battery was"
    reader = RrdReader(rrd)
    origins = [chunk.to_record_batch().column("ViewBlueprint:space_origin").to_pylist()[-1][0]
               for chunk in reader.stream(store=reader.blueprints()[0])
               if "ViewBlueprint:space_origin" in chunk.to_record_batch().schema.names]
    assert CHARGE_ROOT in origins, origins
