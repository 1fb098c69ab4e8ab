"""``nni-simulate`` with a communication link and ``--delay-margin``, as a user types them (SMIB and --case)."""

from __future__ import annotations

import json
import subprocess

import pytest

from nni_battery_controller.law import ControllerParams
from nni_battery_controller.network_sim import NetworkLaw, assess_network, simulate_network
from nni_battery_controller.simulate import simulate_sampled
from nni_battery_controller.verdicts import assess
from nni_plant_sim.cases import load_network
from nni_plant_sim.link import Link
from nni_plant_sim.model import SmibParams
from nni_plant_sim.network_scenarios import BusFault
from nni_plant_sim.scenarios import InitialAngle

MARGIN_KEYS = {"b", "delay_margin_s", "bracket_s", "slip_found", "in_synchronism_up_to_s", "searched_up_to_s", "runs"}


def run(exe, *args, timeout=300):
    return subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True, timeout=timeout)


def smib_in_sync(b: float, delay_s: float, duration_s: float) -> bool:
    return assess(simulate_sampled(SmibParams(), ControllerParams(battery_limit_pu=b), InitialAngle(), duration_s,
                                   50.0, 1e-3, Link(delay_s))).in_synchronism


def test_smib_delay_margin_table_and_json(tmp_path, nni_simulate_exe):
    result = run(nni_simulate_exe, "--delay-margin", "--b", "0", "0.3", "--duration", "5", "--json", tmp_path / "m.json")
    assert result.returncode == 0, result.stderr
    assert "controller sampled at 50 Hz" in result.stdout, "the plant node's PMU rate by default"
    rows = {line.split()[0]: line for line in result.stdout.splitlines() if line.split()[:1] in (["0"], ["0.3"])}
    assert "none: out of synchronism even without delay" in rows["0"]
    out = json.loads((tmp_path / "m.json").read_text())
    assert {"delay_margin", "tolerance_s", "scan_step_s", "searched_up_to_s", "duration_s", "controller", "scenario",
            "criterion", "link"} <= set(out)
    no_battery, battery = out["delay_margin"]
    assert set(battery) == MARGIN_KEYS and battery["b"] == 0.3 and no_battery["delay_margin_s"] is None
    low, high = battery["bracket_s"]
    assert battery["delay_margin_s"] == low and 0 < high - low <= out["tolerance_s"]
    assert f"{low * 1e3:.1f} ms (slips at {high * 1e3:.1f} ms)" in rows["0.3"]
    assert smib_in_sync(0.3, low, 5.0) and not smib_in_sync(0.3, high, 5.0), "the bracket, checked on the core"


def test_kundur_delay_margin_table_and_json(tmp_path, nni_simulate_exe):
    result = run(nni_simulate_exe, "--case", "kundur_two_area", "--delay-margin", "--b", "0.3", "--duration", "3",
                 "--delay-max", "0.6", "--json", tmp_path / "k.json")
    assert result.returncode == 0, result.stderr
    (row,) = [line for line in result.stdout.splitlines() if line.split()[:2] == ["pmu", "0.3"]]
    out = json.loads((tmp_path / "k.json").read_text())
    (margin,) = out["delay_margin"]
    assert set(margin) == MARGIN_KEYS | {"reference"} and out["searched_up_to_s"] == 0.6
    net = load_network("kundur_two_area")
    law = NetworkLaw.uniform(net, 0.1, 1.0, 1.1, 1.0)

    def in_sync(delay_s):
        traj = simulate_network(net, law, BusFault(net, 7, 0.1, 0j, ()), [0.3], 3.0, 50.0, link=Link(delay_s))
        return assess_network(traj)[0].in_synchronism

    if margin["slip_found"]:
        low, high = margin["bracket_s"]
        assert f"{low * 1e3:.1f} ms (slips at {high * 1e3:.1f} ms)" in row
        assert in_sync(low) and not in_sync(high)
    else:
        assert "no margin found up to 0.6 s" in row and margin["delay_margin_s"] is None
        assert in_sync(0.6)


def test_a_run_through_a_link_prints_it_and_its_verdict_is_the_cores(tmp_path, nni_simulate_exe):
    result = run(nni_simulate_exe, "--controller-rate", "50", "--b", "0.3", "--link-delay", "0.45",
                 "--link-jitter", "0.01", "--link-loss", "0.05", "--link-seed", "4", "--json", tmp_path / "r.json")
    assert result.returncode == 0, result.stderr
    assert "link: delay 450 ms, jitter 10 ms (uniform), loss 0.05, seed 4" in result.stdout
    out = json.loads((tmp_path / "r.json").read_text())
    assert out["link"] == {"delay_s": 0.45, "jitter_s": 0.01, "loss": 0.05, "seed": 4,
                            "jitter_distribution": "uniform [0, jitter_s)",
                            "lost_answer": "the command in force stays"}
    core = assess(simulate_sampled(SmibParams(), ControllerParams(battery_limit_pu=0.3), InitialAngle(), 10.0, 50.0,
                                   1e-3, Link(0.45, 0.01, 0.05, 4)))
    assert out["scenarios"][0]["in_synchronism"] == core.in_synchronism is False


@pytest.mark.parametrize("args, fragment", [
    (["--link-delay", "0.1"], "--controller-rate HZ"),
    (["--delay-margin", "--controller-rate", "continuous"], "continuous"),
    (["--delay-margin", "--link-delay", "0.1"], "--link-delay"),
    (["--delay-margin", "--cct"], "--cct"),
    (["--delay-max", "0.5"], "--delay-margin only"),
    (["--delay-margin", "--delay-step", "0.5", "--delay-max", "0.2"], "longer than --delay-max"),
    (["--link-loss", "1.5", "--controller-rate", "50"], "--link-loss"),
    (["--link-seed", "x", "--controller-rate", "50"], "--link-seed"),
    (["--case", "kundur_two_area", "--delay-margin", "--plot", "k.png"], "--plot"),
    (["--case", "kundur_two_area", "--delay-step", "0.1"], "--delay-margin only"),
])
def test_link_options_where_they_do_not_apply_are_refused(tmp_path, nni_simulate_exe, args, fragment):
    result = run(nni_simulate_exe, *[tmp_path / a if a.endswith(".png") else a for a in args],
                 "--json", tmp_path / "out.json")
    assert result.returncode == 2, (result.stdout, result.stderr)
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith("nni-simulate: error:") and fragment in line and "Traceback" not in result.stderr
    assert list(tmp_path.iterdir()) == []
