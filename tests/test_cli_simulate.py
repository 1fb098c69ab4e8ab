"""``nni-simulate`` as a user runs it: the installed console script in a subprocess.

What the theory says about these runs is checked in test_simulation.py against
the cores; here: the table, the JSON contract of the issue, the figure, and that
every bad input is one line on stderr, a non-zero exit, no traceback and no
output file left behind.
"""

from __future__ import annotations

import json
import math
import subprocess

import numpy as np
import pytest

from nni_battery_controller.simulate import simulate_sampled
from nni_battery_controller.verdicts import assess

JSON_KEYS = {
    "b", "stable", "final_angle_dev_rad", "max_abs_angle_dev_rad", "max_abs_battery_power_pu",
    "last_saturated_s", "settling_time_s",
    # issue 10, section 2: separate verdicts, the settling rule's tolerance and hold, what a run can support
    "in_synchronism", "pole_slip_s", "settled", "settle_band_rad", "settle_hold_s", "too_short_to_judge",
    "equilibrium_moved", "duration_s", "final_battery_power_pu",
}


def run(exe, *args, cwd=None):
    return subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True, timeout=120, cwd=cwd)


@pytest.fixture(scope="module")
def default_run(tmp_path_factory, nni_simulate_exe):
    out = tmp_path_factory.mktemp("default")
    result = run(nni_simulate_exe, "--json", out / "out.json", "--plot", out / "out.png")
    assert result.returncode == 0, result.stderr
    return result, out


def test_default_run_prints_the_four_paper_cases(default_run):
    result, _ = default_run
    rows = [line.split() for line in result.stdout.splitlines()]
    table = {row[0]: row[1] for row in rows if row and row[0] in {"0", "0.2", "0.3", "inf"}}
    assert table == {"0": "NO", "0.2": "yes", "0.3": "yes", "inf": "yes"}
    last_sat = {row[0]: row[5] for row in rows if row and row[0] in {"0", "inf"}}
    assert last_sat == {"0": "-", "inf": "-"}  # no battery: nothing to saturate; b = inf never saturates
    assert result.stderr == ""


def test_json_has_the_issues_keys_and_verdicts(default_run):
    _, out = default_run
    scenarios = json.loads((out / "out.json").read_text())["scenarios"]
    assert [s["b"] for s in scenarios] == [0.0, 0.2, 0.3, "inf"]
    assert all(set(s) == JSON_KEYS for s in scenarios)
    assert [s["stable"] for s in scenarios] == [False, True, True, True]
    for item in scenarios:
        limit = math.inf if item["b"] == "inf" else item["b"]
        assert item["max_abs_battery_power_pu"] <= limit
        if item["stable"]:
            assert abs(item["final_angle_dev_rad"]) <= 0.02 and item["settling_time_s"] < 10.0
        else:
            assert item["max_abs_angle_dev_rad"] > math.pi and item["settling_time_s"] is None
    # Finite batteries leave saturation before the end; the unlimited one never saturates.
    assert 0.0 < scenarios[1]["last_saturated_s"] < 10.0 and 0.0 < scenarios[2]["last_saturated_s"] < 10.0
    assert scenarios[3]["last_saturated_s"] is None


def test_plot_is_a_png_with_two_panels_worth_of_pixels(default_run):
    _, out = default_run
    data = (out / "out.png").read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    import matplotlib.image

    image = matplotlib.image.imread(out / "out.png")
    height, width = image.shape[:2]
    assert height > 400 and width > 400
    # Not a blank canvas: the curves and labels make many distinct colours.
    assert len(np.unique(image.reshape(-1, image.shape[2]), axis=0)) > 50


def test_sampled_rate_option_runs_the_sampled_law(tmp_path, nni_simulate_exe, paper_plant, paper_fault,
                                                  paper_controller):
    result = run(nni_simulate_exe, "--b", "0.3", "--controller-rate", "50", "--duration", "5",
                 "--json", tmp_path / "s.json")
    assert result.returncode == 0, result.stderr
    (item,) = json.loads((tmp_path / "s.json").read_text())["scenarios"]
    expected = assess(simulate_sampled(paper_plant, paper_controller(0.3), paper_fault, 5.0, 50.0)).to_json()
    # Numbers to rounding, the rest (verdicts, None for "never") exactly.
    numbers = {k for k, v in expected.items() if isinstance(v, float)}
    assert {k: item[k] for k in numbers} == pytest.approx({k: expected[k] for k in numbers}, rel=1e-12, abs=1e-15)
    assert {k: item[k] for k in set(expected) - numbers} == {k: expected[k] for k in set(expected) - numbers}


def test_overrides_reach_the_model(tmp_path, nni_simulate_exe):
    """A stronger machine (P_max = 1.5) survives the paper's fault without a battery."""
    result = run(nni_simulate_exe, "--b", "0", "--P-max", "1.5", "--D", "0.05", "--duration", "20",
                 "--json", tmp_path / "o.json")
    assert result.returncode == 0, result.stderr
    (item,) = json.loads((tmp_path / "o.json").read_text())["scenarios"]
    assert item["max_abs_angle_dev_rad"] < math.pi


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--b", "-1"], "b"),
        (["--b", "abc"], "abc"),
        (["--b", "nan"], "nan"),
        (["--duration", "0"], "duration"),
        (["--duration", "-3"], "duration"),
        (["--controller-rate", "fast"], "fast"),
        (["--controller-rate", "0"], "rate"),
        (["--K", "1.2", "--L", "1.1"], "K - L < 0"),
        (["--H", "0"], "H"),
        (["--D", "-0.1"], "D"),
        (["--tau", "0"], "tau"),
        (["--alpha", "0"], "alpha"),
        (["--P-M", "1.2"], "equilibrium"),
        (["--H", "inf"], "H"),
        (["--frobnicate"], "frobnicate"),
    ],
)
def test_bad_input_is_one_line_and_leaves_no_file(tmp_path, nni_simulate_exe, args, fragment):
    result = run(nni_simulate_exe, *args, "--json", tmp_path / "out.json", "--plot", tmp_path / "out.png")
    assert result.returncode == 2
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("nni-simulate: error:") and fragment in lines[0]
    assert "Traceback" not in result.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("target", ["missing_dir/out.json", "a_directory", "/proc/nni-simulate.json"])
def test_unwritable_output_is_refused_before_any_work(tmp_path, nni_simulate_exe, target):
    (tmp_path / "a_directory").mkdir()
    result = run(nni_simulate_exe, "--plot", tmp_path / "fine.png", "--json", target, cwd=tmp_path)
    assert result.returncode == 2
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith("nni-simulate: error:") and "--json" in line
    # Refused before anything ran: not even the valid --plot file was written.
    assert not (tmp_path / "fine.png").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_directory"]
    assert list((tmp_path / "a_directory").iterdir()) == []
