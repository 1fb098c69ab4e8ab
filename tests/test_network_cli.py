"""``nni-simulate --case``: the command a user types, its table, JSON, figure and refusals."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from test_verdicts_options import png_title

SIMULATE = [str(Path(sys.executable).with_name("nni-simulate"))]


def run(*args, check_ok=True):
    result = subprocess.run([*SIMULATE, *args], capture_output=True, text=True, timeout=300)
    if check_ok:
        assert result.returncode == 0, result.stderr
    return result


def test_kundur_fault_run_prints_per_generator_verdicts_and_writes_json_and_figure(tmp_path):
    out_json, out_png = tmp_path / "k.json", tmp_path / "k.png"
    result = run("--case", "kundur_two_area", "--fault-bus", "7", "--clearing-time", "0.1", "--b", "0", "0.3",
                 "--reference", "pmu", "coi", "--duration", "6", "--json", str(out_json), "--plot", str(out_png))
    lines = result.stdout.splitlines()
    assert lines[0].startswith("kundur_two_area: bus fault at bus 7")
    heads = [line for line in lines if line.startswith("b = ")]
    assert len(heads) == 4  # two limits times two references
    assert "reference coi" in heads[-1] and "b = 0.3 pu" in heads[-1]
    rows = [line.split() for line in lines if line.strip().startswith("G")]
    assert [row[0] for row in rows[:4]] == ["G1@1", "G2@2", "G3@3", "G4@4"]
    # b = 0: no battery, so no saturation to leave ("-", not the run's last sample); b = 0.3 saturates and leaves.
    # Tables in order pmu (b = 0, b = 0.3), then coi; G1 and G2 reach 0.3 pu (the JSON below) and leave it.
    assert [row[-1] for row in rows[0:4] + rows[8:12]] == ["-"] * 8
    assert all(0.0 < float(row[-1]) < 6.0 for row in rows[4:6] + rows[12:14])
    data = json.loads(out_json.read_text())
    assert data["generators"] == ["G1@1", "G2@2", "G3@3", "G4@4"]
    first = data["runs"][0]
    assert {"b", "reference", "in_synchronism", "pole_slip_s", "settled", "stable", "max_angle_spread_rad",
            "final_coi_frequency_hz", "generators"} <= set(first)
    assert {"name", "in_synchronism", "settled", "settling_time_s", "max_abs_battery_power_pu",
            "max_abs_battery_power_mw", "limit_pu", "last_saturated_s"} == set(first["generators"][0])
    assert first["b"] == 0 and first["generators"][0]["max_abs_battery_power_mw"] == 0.0
    assert [g["last_saturated_s"] for g in first["generators"]] == [None] * 4
    with_battery = data["runs"][1]["generators"]
    assert max(g["max_abs_battery_power_pu"] for g in with_battery) == pytest.approx(0.3)
    assert max(g["max_abs_battery_power_mw"] for g in with_battery) == pytest.approx(270.0)  # 0.3 of 900 MVA
    assert out_png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert png_title(out_png) == "kundur_two_area: bus fault at bus 7 (Z = 0+0j pu), cleared at 0.1 s; controller 50 Hz, law nni (tau_s 0.1, gain_k 1, gain_l 1.1, alpha 1)"


def test_cct_finds_a_bracket_of_one_millisecond(tmp_path):
    out_json = tmp_path / "cct.json"
    result = run("--case", "kundur_two_area", "--fault-bus", "7", "--trip-line", "7", "8", "--cct", "--b", "0",
                 "0.2", "--duration", "5", "--json", str(out_json))
    assert "critical clearing time" in result.stdout.splitlines()[0]
    cct = json.loads(out_json.read_text())["cct"]
    assert [entry["b"] for entry in cct] == [0, 0.2]
    for entry in cct:
        low, high = entry["bracket_s"]
        assert high - low == pytest.approx(1e-3)
        assert entry["cct_s"] == low
    # A longer clearing time than the CCT without batteries loses synchronism in a plain run.
    lost = run("--case", "kundur_two_area", "--fault-bus", "7", "--trip-line", "7", "8", "--b", "0",
               "--clearing-time", f"{cct[0]['cct_s'] + 0.001:.3f}", "--duration", "5")
    assert "LOST SYNCHRONISM" in lost.stdout
    held = run("--case", "kundur_two_area", "--fault-bus", "7", "--trip-line", "7", "8", "--b", "0",
               "--clearing-time", f"{cct[0]['cct_s']:.3f}", "--duration", "5")
    assert "LOST SYNCHRONISM" not in held.stdout


def test_ieee39_runs():
    result = run("--case", "ieee39", "--b", "0", "inf", "--duration", "3")
    assert result.stdout.startswith("ieee39: bus fault at bus 16")
    assert sum(line.strip().startswith("G") for line in result.stdout.splitlines()) == 20


@pytest.mark.parametrize("args, message", [
    (["--case", "kundur_two_area", "--K", "1", "1", "1", "1.2"], "generator G4@4: K must be less than L"),
    (["--case", "kundur_two_area", "--scenario", "line_trip", "--trip-line", "7", "8", "--clearing-time", "0.1"],
     "--clearing-time does not apply to --scenario line_trip"),
    (["--case", "kundur_two_area", "--H", "4"], "unrecognized arguments: --H"),
    (["--case", "kundur_two_area", "--fault-bus", "99"], "bus 99 is not in the case"),
    (["--case", "kundur_two_area", "--trip-line", "7", "9"], "no circuit 1 between buses 7 and 9"),
    (["--case", "kundur_two_area", "--cct", "--plot", "x.png"], "--plot does not apply to --cct"),
    (["--case", "nowhere.m"], "neither a shipped case"),
    (["--case", "kundur_two_area", "--scenario", "mechanical_step", "--machine", "5", "--step-p-mech", "0.9"],
     "--machine 5: no generator at that bus"),
])
def test_bad_input_is_one_line_and_exit_2(args, message, tmp_path):
    result = subprocess.run([*SIMULATE, *args], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert result.returncode == 2
    assert message in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())


def test_mechanical_step_and_displacement_scenarios_run():
    step = run("--case", "kundur_two_area", "--scenario", "mechanical_step", "--machine", "1", "--step-p-mech",
               "0.9", "--step-duration", "0.5", "--b", "0.1", "--duration", "3")
    assert "P_m of G1@1 to 0.9 pu for 0.5 s" in step.stdout.splitlines()[0]
    moved = run("--case", "kundur_two_area", "--scenario", "angle_displacement", "--machine", "1", "2",
                "--displace", "0.3", "--b", "inf", "--duration", "3")
    assert "angles of G1@1, G2@2 displaced by 0.3 rad" in moved.stdout.splitlines()[0]


def test_the_paper_studys_help_leads_to_the_network_study():
    """``nni-simulate --help`` is where a user starts: it must say how to reach ``--case`` and its options."""
    assert "nni-simulate --case CASE --help" in " ".join(run("--help").stdout.split())
    network_help = run("--case", "ieee39", "--help").stdout
    assert network_help.startswith("usage: nni-simulate [-h] --case CASE") and "--fault-bus" in network_help
