"""Issue 10 sections 2-4 and issue 11's CLI bounds, as a user meets them on ``nni-simulate`` and ``nni-demo``.

Verdicts (in synchronism / settled / stable / too short to judge), the shared
scenario, model and gain options with the nodes' YAML defaults and
``--params-file``, the critical clearing time against the equal-area closed
form, self-describing figures, and the bounds on work (refused at once,
Ctrl-C, a closed pipe). Expected values come from closed forms or independent
integrations written here, never from the code under test.
"""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.integrate import solve_ivp

from rosproc import fresh_domain_id, ros_env

from nni_battery_controller.simulate import simulate_continuous
from nni_battery_controller.verdicts import verdict_text
from nni_msgs_adapter.viewing.palette import colour_hex

ROOT = Path(__file__).resolve().parent.parent
DEMO = Path(sys.executable).parent / "nni-demo"


def run(exe, *args, timeout=120, **kwargs):
    return subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True, timeout=timeout, **kwargs)


def one_error_line(result, prog="nni-simulate") -> str:
    assert result.returncode == 2, (result.stdout, result.stderr)
    assert "Traceback" not in result.stderr
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith(f"{prog}: error:")
    return line


def yaml_defaults(package: str, filename: str, node: str) -> dict:
    text = (ROOT / package / "config" / filename).read_text()
    return yaml.safe_load(text)[f"/**/{node}"]["ros__parameters"]


# --- verdicts -------------------------------------------------------------------------------


def test_no_battery_pole_slip_is_the_rotor_angle_passing_pi(tmp_path, nni_simulate_exe, paper_plant):
    """b = 0: the slip instant is when delta reaches pi, from an independent integration of the swing alone."""
    result = run(nni_simulate_exe, "--b", "0", "--json", tmp_path / "o.json")
    assert result.returncode == 0, result.stderr
    (item,) = json.loads((tmp_path / "o.json").read_text())["scenarios"]
    m, p_m, p_max = paper_plant.inertia_m, 0.8, 1.0

    def swing(t, x):
        return [x[1], (p_m - p_max * math.sin(x[0])) / m]

    def at_pi(t, x):
        return x[0] - math.pi

    at_pi.terminal = True
    reference = solve_ivp(swing, (0, 5), [0.2, 0.0], rtol=1e-12, atol=1e-12, events=at_pi).t_events[0][0]
    assert item["in_synchronism"] is False and item["stable"] is False
    assert item["pole_slip_s"] == pytest.approx(reference, abs=1e-6)
    row = next(line for line in result.stdout.splitlines() if line.split()[:1] == ["0"])
    assert f"POLE SLIP at {reference:.3f} s" in row
    assert "1324" not in row  # the slip instant, not the final angle of a machine long gone


def test_a_cleared_fault_without_battery_stays_in_synchronism_but_does_not_settle(tmp_path, nni_simulate_exe):
    """The issue's measurement: transfer-limit fault cleared at 0.05 s, b = 0, D = 0: it oscillates, never slips."""
    result = run(nni_simulate_exe, "--scenario", "transfer_limit_fault", "--clearing-time", "0.05", "--b", "0",
                 "--json", tmp_path / "o.json")
    assert result.returncode == 0, result.stderr
    (item,) = json.loads((tmp_path / "o.json").read_text())["scenarios"]
    assert item["in_synchronism"] is True and item["pole_slip_s"] is None
    assert item["settled"] is False and item["stable"] is False
    row = next(line for line in result.stdout.splitlines() if line.split()[:1] == ["0"])
    assert row.split()[1:3] == ["yes", "NO"] and "NOT SETTLED" in row


def test_a_run_settling_before_its_last_swing_period_is_settled(tmp_path, nni_simulate_exe, paper_plant):
    """The issue's 5 s run (settling after 4 s): settled, |d| stayed within 0.02 rad for half a swing period."""
    result = run(nni_simulate_exe, "--b", "0.3", "--duration", "5", "--controller-rate", "50",
                 "--json", tmp_path / "o.json")
    assert result.returncode == 0, result.stderr
    (item,) = json.loads((tmp_path / "o.json").read_text())["scenarios"]
    half_period = math.pi * math.sqrt(paper_plant.inertia_m / (1.0 * math.cos(math.asin(0.8))))
    assert item["settle_hold_s"] == pytest.approx(half_period, abs=1e-3) and item["settle_band_rad"] == 0.02
    assert 4.0 < item["settling_time_s"] < 5.0 - half_period
    assert item["in_synchronism"] and item["settled"] and item["stable"]
    assert "stable, settled at" in result.stdout


def test_a_run_too_short_to_judge_gets_no_verdict(tmp_path, nni_simulate_exe):
    result = run(nni_simulate_exe, "--duration", "1e-9", "--json", tmp_path / "o.json")
    assert result.returncode == 0, result.stderr
    for item in json.loads((tmp_path / "o.json").read_text())["scenarios"]:
        assert item["too_short_to_judge"] is True
        assert item["stable"] is False and item["settled"] is False
    rows = [line for line in result.stdout.splitlines() if line.split()[:1] in (["0"], ["0.2"], ["0.3"], ["inf"])]
    assert len(rows) == 4 and all("too short to judge" in row for row in rows)
    assert "stable," not in result.stdout and "NOT SETTLED" not in result.stdout


def test_verdict_text_says_one_thing_per_case():
    base = {"in_synchronism": True, "pole_slip_s": None, "too_short_to_judge": False, "stable": False,
            "settled": False, "settling_time_s": None, "settle_hold_s": 0.647, "equilibrium_moved": False,
            "final_angle_dev_rad": 0.3, "final_battery_power_pu": -0.1}
    assert verdict_text({**base, "in_synchronism": False, "pole_slip_s": 1.1173}) == "POLE SLIP at 1.117 s"
    assert verdict_text({**base, "too_short_to_judge": True}).startswith("too short to judge")
    assert verdict_text({**base, "stable": True, "settled": True, "settling_time_s": 3.62}) == \
        "stable, settled at 3.62 s"
    assert "NEW EQUILIBRIUM" in verdict_text({**base, "equilibrium_moved": True})
    assert verdict_text(base) == "in sync, NOT SETTLED (|d| 0.300 rad at the end)"


def test_a_permanent_step_says_the_equilibrium_moved(tmp_path, nni_simulate_exe):
    """With the unsaturated law the new equilibrium is d = (P_M,step - P_M) / (L - K): g(d) cancels P_E's change."""
    result = run(nni_simulate_exe, "--scenario", "mechanical_step", "--step-duration", "inf", "--b", "inf",
                 "--duration", "60", "--json", tmp_path / "o.json")
    assert result.returncode == 0, result.stderr
    (item,) = json.loads((tmp_path / "o.json").read_text())["scenarios"]
    assert item["equilibrium_moved"] is True and item["in_synchronism"] is True and item["stable"] is False
    assert item["final_angle_dev_rad"] == pytest.approx((0.95 - 0.8) / (1.1 - 1.0), abs=0.02)
    assert "NEW EQUILIBRIUM" in result.stdout and "the equilibrium moves away from delta_bar" in result.stdout
    assert "(P_M,step - P_M)/(L - K) = 1.500 rad" in result.stdout


def test_the_default_step_is_temporary_and_recovers(tmp_path, nni_simulate_exe):
    result = run(nni_simulate_exe, "--scenario", "mechanical_step", "--b", "0.2", "inf", "--json", tmp_path / "o.json")
    assert result.returncode == 0, result.stderr
    summary = json.loads((tmp_path / "o.json").read_text())
    step = yaml_defaults("nni_plant_sim", "plant.yaml", "plant")["step_duration_s"]
    assert math.isfinite(step) and summary["scenario"]["step_duration_s"] == step
    assert all(item["stable"] and not item["equilibrium_moved"] for item in summary["scenarios"])
    assert f"for {step:g} s" in result.stdout.splitlines()[0]


# --- options and defaults -------------------------------------------------------------------


@pytest.mark.parametrize("exe", ["nni-simulate", "nni-demo"])
@pytest.mark.parametrize(("args", "flag"), [
    (["--clearing-time", "0.2"], "--clearing-time"),
    (["--scenario", "mechanical_step", "--delta0", "0.3"], "--delta0"),
    (["--scenario", "transfer_limit_fault", "--step-p-mech", "0.9"], "--step-p-mech"),
])
def test_an_option_of_another_scenario_is_refused_naming_it(tmp_path, exe, args, flag):
    result = run(Path(sys.executable).parent / exe, *args, "--out" if exe == "nni-demo" else "--json",
                 tmp_path / "o", timeout=60)
    line = one_error_line(result, exe)
    assert flag in line
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("exe", ["nni-simulate", "nni-demo"])
def test_help_shows_every_default_from_the_package_yaml(exe):
    result = run(Path(sys.executable).parent / exe, "--help", timeout=60)
    assert result.returncode == 0
    text = " ".join(result.stdout.split())
    plant = yaml_defaults("nni_plant_sim", "plant.yaml", "plant")
    ctrl = yaml_defaults("nni_battery_controller", "controller.yaml", "controller")
    for flag, value in [("--delta0", plant["delta0_rad"]), ("--step-p-mech", plant["step_p_mech_pu"]),
                        ("--step-duration", plant["step_duration_s"]), ("--fault-p-max", plant["fault_p_max_pu"]),
                        ("--clearing-time", plant["clearing_time_s"]), ("--H", plant["inertia_h_s"]),
                        ("--P-M", plant["p_mech_pu"]), ("--P-max", plant["p_max_pu"]), ("--f0", plant["f0_hz"]),
                        ("--tau", ctrl["tau_s"]), ("--K", ctrl["gain_k"]), ("--L", ctrl["gain_l"]),
                        ("--alpha", ctrl["alpha"])]:
        start = text.index(f" {flag} ", text.index("scenario (what happens"))
        assert f"(default: {value:g})" in text[start:start + 200], flag
    assert f"default: {plant['scenario']}" in text
    # Every option of the parser says its default (or that it has none).
    blocks = result.stdout.split("\n  -")[1:]
    for block in blocks:
        flag = block.split()[0]
        if flag in ("h,", "-help", "-cct", "-params-file"):
            continue
        assert "default" in block, f"-{flag} shows no default"


def test_params_file_in_the_nodes_format_reaches_the_model_and_the_options_win(tmp_path, nni_simulate_exe):
    params = tmp_path / "params.yaml"
    params.write_text("/**/plant:\n  ros__parameters:\n    p_max_pu: 1.5\n    damping_pu: 0.05\n"
                      "    scenario: transfer_limit_fault\n    clearing_time_s: 0.3\n"
                      "/**/controller:\n  ros__parameters:\n    gain_l: 1.3\n")
    result = run(nni_simulate_exe, "--params-file", params, "--clearing-time", "0.2", "--b", "0",
                 "--json", tmp_path / "o.json")
    assert result.returncode == 0, result.stderr
    header = result.stdout.splitlines()[0]
    assert "transfer_limit_fault (P_max = 0 pu until cleared at 0.2 s)" in header
    assert "P_max 1.5" in header and "D 0.05" in header and "L 1.3" in header
    summary = json.loads((tmp_path / "o.json").read_text())
    assert summary["scenario"] == {"name": "transfer_limit_fault", "fault_p_max_pu": 0.0, "clearing_time_s": 0.2}


@pytest.mark.parametrize(("content", "fragment"), [
    ("/**/plant:\n  ros__parameters:\n    noise_angle_std_rad: 0.01\n", "does not apply"),
    ("/**/plant:\n  ros__parameters:\n    frobnicate: 1\n", "no parameter 'frobnicate'"),
    ("/**/controller:\n  ros__parameters:\n    p_mech_pu: 0.7\n", "differs from the plant"),
    ("/**/plant:\n  ros__parameters:\n    inertia_h_s: fast\n", "must be a number"),
    ("/**/observer:\n  ros__parameters:\n    x: 1\n", "observer"),
    ("[unclosed", "not YAML"),
])
def test_a_bad_params_file_is_one_line(tmp_path, nni_simulate_exe, content, fragment):
    params = tmp_path / "params.yaml"
    params.write_text(content)
    line = one_error_line(run(nni_simulate_exe, "--params-file", params))
    assert fragment in line


# --- critical clearing time -----------------------------------------------------------------


def test_cct_brackets_the_equal_area_closed_form_for_b0(tmp_path, nni_simulate_exe, paper_plant):
    """Bolted fault, D = 0, b = 0: cos(delta_cr) = (pi - 2 delta_bar) sin(delta_bar) - cos(delta_bar),
    t_cr = sqrt(2 M (delta_cr - delta_bar) / P_M) (0.1127 s), within the bisection's 1 ms bracket."""
    result = run(nni_simulate_exe, "--cct", "--b", "0", "0.3", "--duration", "5", "--json", tmp_path / "c.json")
    assert result.returncode == 0, result.stderr
    delta_bar = math.asin(0.8)
    delta_cr = math.acos((math.pi - 2 * delta_bar) * math.sin(delta_bar) - math.cos(delta_bar))
    t_cr = math.sqrt(2 * paper_plant.inertia_m * (delta_cr - delta_bar) / 0.8)
    assert t_cr == pytest.approx(0.1127, abs=1e-4)
    summary = json.loads((tmp_path / "c.json").read_text())
    no_battery, battery = summary["cct"]
    low, high = no_battery["bracket_s"]
    assert high - low <= 1e-3 + 1e-12 and low <= t_cr <= high and no_battery["cct_s"] == low
    assert battery["cct_s"] > no_battery["cct_s"] + 0.01  # the battery buys clearing time
    assert summary["equal_area_cct_s"] == pytest.approx(t_cr, abs=1e-6)
    assert "bisection to 1 ms: bracket [0, 0.001] s" in result.stdout
    assert f"{t_cr:.4f} s" in result.stdout


@pytest.mark.parametrize(("args", "flag"), [(["--roa", "x", "--duration", "5"], "--duration"),
                                             (["--roa-grid", "50"], "--roa-grid"),
                                             (["--roa-speed-max", "5"], "--roa-speed-max")])
def test_an_option_of_another_mode_is_refused(tmp_path, nni_simulate_exe, args, flag):
    line = one_error_line(run(nni_simulate_exe, *args, cwd=tmp_path))
    assert flag in line
    assert list(tmp_path.iterdir()) == []


def test_cct_refuses_a_clearing_time_or_another_scenario(nni_simulate_exe):
    assert "--clearing-time" in one_error_line(run(nni_simulate_exe, "--cct", "--clearing-time", "0.1"))
    assert "--scenario" in one_error_line(run(nni_simulate_exe, "--cct", "--scenario", "mechanical_step"))


# --- figures --------------------------------------------------------------------------------


def png_title(path: Path) -> str:
    from PIL import Image

    return Image.open(path).text["Title"]


def test_figure_title_names_scenario_controller_mode_and_shades_the_fault(tmp_path, nni_simulate_exe):
    result = run(nni_simulate_exe, "--scenario", "transfer_limit_fault", "--clearing-time", "0.15",
                 "--controller-rate", "100", "--b", "0.3", "0", "--duration", "3", "--plot", tmp_path / "f.png")
    assert result.returncode == 0, result.stderr
    title = png_title(tmp_path / "f.png")
    assert "transfer-limit fault: P_max = 0 pu, cleared at 0.15 s (shaded)" in title
    assert "controller sampled at 100 Hz" in title and "offline" in title


def test_figure_legends_and_colours_follow_b_not_order(paper_plant, paper_controller):
    from nni_battery_controller.figures import runs_figure
    from nni_battery_controller.verdicts import assess
    from nni_plant_sim.scenarios import TransferLimitFault

    fault = TransferLimitFault(0.0, 0.15)
    scenario = {"name": "transfer_limit_fault", "fault_p_max_pu": 0.0, "clearing_time_s": 0.15}
    runs = {b: simulate_continuous(paper_plant, paper_controller(b), fault, 8.0) for b in (0.2, 0.3)}
    colours = []
    for order in ((0.2, 0.3), (0.3, 0.2)):
        trajs = [runs[b] for b in order]
        fig = runs_figure(trajs, [assess(t, scenario=fault).to_json() for t in trajs], scenario, "continuous",
                          "offline")
        ax_angle = fig.axes[0]
        texts = [t.get_text() for t in ax_angle.get_legend().get_texts()]
        assert any(t.startswith("b = 0.3: stable, settled at") for t in texts), texts
        assert "fault" in texts
        colours.append({line.get_label().split(":")[0]: line.get_color() for line in ax_angle.get_lines()})
    assert colours[0]["b = 0.3"] == colours[1]["b = 0.3"] == colour_hex(0.3)
    assert colours[0]["b = 0.2"] == colours[1]["b = 0.2"] != colour_hex(0.3)


def test_colour_is_a_pure_function_of_b():
    paper = [colour_hex(b) for b in (0.0, 0.2, 0.3, math.inf)]
    assert len(set(paper)) == 4
    assert colour_hex(0.25) == colour_hex(0.25) != colour_hex(0.3)
    assert len({colour_hex(b) for b in (0.05, 0.1, 0.15, 0.25, 0.4, 0.5)}) == 6
    with pytest.raises(ValueError):
        colour_hex(-1.0)


def test_roa_figure_shows_the_no_battery_basin_inside_omega(paper_plant, paper_controller):
    """A point well inside Omega (d0 = 0, d0' = 1.5 rad/s) is drawn in b = 0's fill, not another basin's."""
    from matplotlib.colors import to_rgb

    from nni_battery_controller import roa
    from nni_battery_controller.figures import roa_figure

    grid = roa.RoaGrid(n_angle=40, n_speed=40)
    ctrls = [paper_controller(b) for b in (0.0, 0.2)]
    basins = roa.sweep(paper_plant, ctrls, grid)
    fig = roa_figure(paper_plant, grid, basins, (0.2 - paper_plant.delta_bar_rad, 0.0), "model; H 4 s")
    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba())[:, :, :3].astype(float) / 255
    x, y = fig.axes[0].transData.transform((0.0, 1.5))
    patch = image[image.shape[0] - int(y) - 4:image.shape[0] - int(y) + 4, int(x) - 4:int(x) + 4].reshape(-1, 3)
    fill = np.array([0.45 * c + 0.55 for c in to_rgb(colour_hex(0.0))])
    other = np.array([0.45 * c + 0.55 for c in to_rgb(colour_hex(0.2))])
    near_fill = np.linalg.norm(patch - fill, axis=1) < 0.05
    assert near_fill.mean() > 0.5  # the hatch lines cover the rest
    assert not np.any(np.linalg.norm(patch - other, axis=1) < 0.05)
    assert "outside every basin: a pole slip" in " ".join(t.get_text() for t in fig.legends[0].get_texts())


# --- bounds, Ctrl-C, closed pipe ------------------------------------------------------------


@pytest.mark.parametrize("args", [["--duration", "1e9"], ["--H", "1e-9"], ["--tau", "1e-12"],
                                  ["--H", "1e-9", "--controller-rate", "50"],
                                  ["--duration", "1e6", "--controller-rate", "50"]])
def test_work_out_of_reach_is_refused_at_once(tmp_path, nni_simulate_exe, args):
    line = one_error_line(run(nni_simulate_exe, *args, "--json", tmp_path / "o.json", timeout=30))
    assert "out of reach" in line
    assert list(tmp_path.iterdir()) == []


def test_ctrl_c_stops_a_long_run_with_one_line(nni_simulate_exe, tmp_path):
    proc = subprocess.Popen([str(nni_simulate_exe), "--roa", str(tmp_path / "r"), "--roa-grid", "1000"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        first = proc.stderr.readline()  # the sweep is under way
        assert "region of attraction" in first, first
        proc.send_signal(signal.SIGINT)
        _, rest = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130
    assert rest.strip() == "nni-simulate: interrupted"
    assert list(tmp_path.iterdir()) == []


def test_a_closed_pipe_ends_quietly(nni_simulate_exe):
    """``nni-simulate | head``: the reader is gone before the table is written; no Broken pipe message."""
    proc = subprocess.Popen([str(nni_simulate_exe), "--b", "0.3", "--duration", "1"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    proc.stdout.close()
    _, err = proc.communicate(timeout=60)
    assert err == b""
    assert proc.returncode == 141


def test_reported_grid_instants_carry_no_float_noise(tmp_path, nni_simulate_exe):
    result = run(nni_simulate_exe, "--controller-rate", "1000", "--b", "0.2", "0.3", "--duration", "5",
                 "--json", tmp_path / "o.json")
    assert result.returncode == 0, result.stderr
    text = (tmp_path / "o.json").read_text()
    for item in json.loads(text)["scenarios"]:
        for key in ("settling_time_s", "last_saturated_s"):
            assert len(repr(item[key])) <= 6, (key, item[key])  # k / 1000 s: at most "4.321"


# --- nni-demo: the same options reach the nodes and the assessment ---------------------------


def test_demo_runs_a_fault_scenario_with_its_model_and_says_so(tmp_path, busy, paper_controller):
    """A stronger line (P_max 1.2, delta_bar = asin(0.8/1.2)): the nodes run it and the assessment models it.

    The lockstep run matches the offline sampled run of the same model; assessed with SmibParams() it would
    end 0.2 rad off its equilibrium and never be called settled.
    """
    from nni_battery_controller.simulate import simulate_sampled
    from nni_plant_sim.model import SmibParams
    from nni_plant_sim.scenarios import TransferLimitFault

    domain = fresh_domain_id()
    result = run(DEMO, "--b", "0.3", "--duration", "8", "--scenario", "transfer_limit_fault",
                 "--clearing-time", "0.15", "--P-max", "1.2", "--out", tmp_path, "--domain-id", domain,
                 env=ros_env(domain), timeout=180)
    assert result.returncode == 0, result.stderr
    assert "transfer_limit_fault (P_max = 0 pu until cleared at 0.15 s)" in result.stdout
    assert "P_max 1.2" in result.stdout
    (item,) = json.loads((tmp_path / "summary.json").read_text())["scenarios"]
    offline = simulate_sampled(SmibParams(4.0, 0.0, 0.8, 1.2, 50.0), paper_controller(0.3),
                               TransferLimitFault(0.0, 0.15), 8.0, 50.0)
    assert item["final_angle_dev_rad"] == pytest.approx(offline.angle_dev_rad[-1], abs=1e-9)
    assert abs(item["final_angle_dev_rad"]) < 0.02
    assert item["in_synchronism"] and item["settled"] and item["stable"]
    assert "stable, settled at" in result.stdout
    title = png_title(tmp_path / "figures.png")
    assert "transfer-limit fault: P_max = 0 pu, cleared at 0.15 s" in title and "lockstep" in title
    assert "sampled at 50 Hz" in title


def test_demo_run_too_short_to_judge(tmp_path, busy):
    domain = fresh_domain_id()
    result = run(DEMO, "--b", "0.3", "--duration", "1e-9", "--out", tmp_path, "--domain-id", domain,
                 env=ros_env(domain), timeout=180)
    assert result.returncode == 0, result.stderr
    assert "too short to judge" in result.stdout
    (item,) = json.loads((tmp_path / "summary.json").read_text())["scenarios"]
    assert item["too_short_to_judge"] is True and item["stable"] is False
