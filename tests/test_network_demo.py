"""``nni-demo --case`` and ``launch/network.launch.py``: a network with one controller per generator, as a user runs it.

The demo runs over real processes and Fast DDS, in lockstep, a few simulated
seconds; the launch file is checked through the node list it would create
(``launch`` is not installable here), and that list is started as processes.
"""

from __future__ import annotations

import importlib.util
import json
import re
import subprocess
import sys
import threading
import time
import uuid
from importlib import metadata
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from nni_msgs_adapter.ros.defaults import controller_defaults

from nni_battery_controller.demo_common import start_when_read_back
from nni_battery_controller.network_common import format_run
from nni_battery_controller.network_deployment import controller_parameters, default_law, generator_limits
from nni_battery_controller.network_sim import NetworkLaw, assess_network, simulate_network
from nni_msgs_adapter.recording.mcap_io import read_recording
from nni_msgs_adapter.recording.runs import generator_runs, run_metadata
from nni_plant_sim.cases import load_network
from nni_plant_sim.network_scenarios import AngleDisplacement, BusFault
from rosproc import busy_processes, fresh_domain_id, node_processes, ros_env
from test_rerun_view import read_entities, scalars

pytestmark = pytest.mark.ros

DEMO = Path(sys.executable).parent / "nni-demo"
LAUNCH_FILE = Path(__file__).resolve().parents[1] / "nni_battery_controller" / "launch" / "network.launch.py"


def start_time(pid: int) -> int | None:
    """A process's start time (clock ticks since boot, /proc/PID/stat field 22), None if it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return None if fields[0] == "Z" else int(fields[19])


def children_of(pid: int) -> set[tuple[int, int]]:
    """(pid, start time) of the live children of ``pid``."""
    found = set()
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            try:
                fields = (proc / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                found.add((int(proc.name), int(fields[19])))
    return found


def marked_env(domain: int) -> tuple[dict, str]:
    """The demo's environment with a marker of this test, which every process it starts inherits."""
    marker = uuid.uuid4().hex
    return ros_env(domain, NNI_TEST_MARKER=marker), marker


def marked_processes(marker: str) -> list[str]:
    """Command lines of live processes whose environment holds ``marker`` (a test's demo and its children)."""
    found = []
    for proc in Path("/proc").iterdir():
        try:
            if proc.name.isdigit() and f"NNI_TEST_MARKER={marker}".encode() in (proc / "environ").read_bytes().split(b"\0"):
                if start_time(int(proc.name)) is not None:
                    found.append((proc / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace"))
        except OSError:
            continue
    return found


def participants_env(pid: int) -> str | None:
    """The NNI_DDS_PARTICIPANTS a process was started with (None: not set, or the process is gone)."""
    try:
        entries = (Path(f"/proc/{pid}") / "environ").read_bytes().split(b"\0")
    except OSError:
        return None
    found = [entry.split(b"=", 1)[1].decode() for entry in entries if entry.startswith(b"NNI_DDS_PARTICIPANTS=")]
    return found[0] if found else None


def run_demo(args: list[str], domain: int, timeout: float = 600) -> tuple[subprocess.CompletedProcess, set, str]:
    """Run nni-demo to the end; its result, every child process (pid, start time) seen while it ran, its marker.

    The result's ``participants`` is the set of NNI_DDS_PARTICIPANTS values the children were started with."""
    env, marker = marked_env(domain)
    proc = subprocess.Popen([str(DEMO), *args, "--domain-id", str(domain)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    seen: set = set()
    counts: dict = {}
    done = threading.Event()

    def watch():
        while not done.is_set():
            seen.update(children_of(proc.pid))
            for child in seen:  # read again until the child has exec'd (a fork shows the demo's own environment)
                if counts.get(child) is None:
                    counts[child] = participants_env(child[0])
            time.sleep(0.05)

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    try:
        out, err = proc.communicate(timeout=timeout)
    finally:
        done.set()
        watcher.join()
    result = subprocess.CompletedProcess(proc.args, proc.returncode, out, err)
    result.participants = set(counts.values())
    return result, seen, marker


def assert_nothing_left(children: set, marker: str) -> None:
    """No child the demo started is alive (same pid and start time), nor any process with its environment."""
    alive = [(pid, started) for pid, started in children if start_time(pid) == started]
    assert alive == [], f"left running: {alive}"
    assert marked_processes(marker) == []


def table_rows(text: str, names) -> dict[str, str]:
    """The per-generator rows of a printed verdict table, by generator name (leading spaces dropped)."""
    return {line.split()[0]: line.strip() for line in text.splitlines() if line.strip().split(" ")[0] in names}


#: The Kundur demo run of the tests below: 2 s lockstep, b = 0.1 with gen2 at 0 (--gen-b).
KUNDUR_DEMO = ["--case", "kundur_two_area", "--b", "0.1", "--gen-b", "2=0", "--duration", "2"]


def kundur_demo(out: Path, deployment: str):
    """The Kundur demo run with ``--deployment``, two busy processes beside it; (result, children, marker)."""
    with busy_processes(2):
        return run_demo([*KUNDUR_DEMO, "--deployment", deployment, "--out", str(out)], fresh_domain_id())


@pytest.fixture(scope="module")
def separate_kundur_demo(tmp_path_factory):
    """The Kundur demo with a controller process per generator (the default deployment, given explicitly)."""
    out = tmp_path_factory.mktemp("separate")
    return out, *kundur_demo(out, "separate")


def test_kundur_demo_prints_each_generator_as_offline_records_every_namespace_and_leaves_nothing(
        separate_kundur_demo):
    """2 s lockstep, b = 0.1 with gen2 at 0 (--gen-b), two busy processes beside it.

    The printed verdict and generator rows are the offline study's (format_run of
    simulate_network with the same limits) except the last-saturated column,
    whose final sample the recording does not have: offline the controllers
    answer the run's final sample too; in the loop nobody answers it.
    """
    tmp_path, result, children, marker = separate_kundur_demo
    assert result.returncode == 0, result.stderr
    assert len(children) == 6, "logger, four controllers, plant"
    assert result.participants == {"6"}, "each child is told how many processes the deployment has"
    assert_nothing_left(children, marker)
    net = load_network("kundur_two_area")
    limits = np.array([0.1, 0.0, 0.1, 0.1])
    offline = simulate_network(net, default_law(net), BusFault(net, 7, 0.1), [limits], 2.0, 50.0)
    expected = format_run(assess_network(offline)[0], 0.1, "pmu", net)
    printed = result.stdout
    assert expected.splitlines()[0] in printed, printed
    got, want = table_rows(printed, net.names), table_rows(expected, net.names)
    assert set(got) == set(net.names)
    for name in net.names:
        assert got[name].split()[:6] == want[name].split()[:6], (got[name], want[name])
    for i in range(4):
        assert f"/gen{i + 1}" in printed and f"G{i + 1}@{i + 1}" in printed

    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["case"] == "kundur_two_area" and summary["namespaces"] == ["gen1", "gen2", "gen3", "gen4"]
    assert summary["deployment"] == "separate"
    (run,) = summary["runs"]
    assert run["b"] == 0.1 and run["gen_b"] == {"gen2": 0.0} and run["in_synchronism"] is True
    assert "compromised" not in run
    assert list(run["generators"]) == ["gen1", "gen2", "gen3", "gen4"]
    for ns, values in run["generators"].items():
        for key in ("name", "in_synchronism", "settled", "max_abs_battery_power_pu", "limit_pu", "latency_ms",
                    "dropped_samples", "late_samples", "trust", "logger_counts"):
            assert key in values, (ns, key)
        assert values["samples"] == 100 and values["dropped_samples"] == 0
        assert values["trust"]["foreign_commands"] == values["trust"]["writer_alarms"] == 0
        assert values["logger_counts"][f"/{ns}/plant/state"] == 101
        assert values["paired_controller"] == f"/{ns}/controller"
    assert run["generators"]["gen2"]["limit_pu"] == 0 and run["generators"]["gen2"]["max_abs_battery_power_pu"] == 0
    assert 0 < run["generators"]["gen1"]["max_abs_battery_power_pu"] <= 0.1

    recording = read_recording(run["recording"])
    runs = generator_runs(recording)
    assert list(runs) == ["/gen1", "/gen2", "/gen3", "/gen4"]
    for i, generator in enumerate(runs.values()):
        np.testing.assert_allclose(generator.delta_rad, offline.delta_rad[:, i, 0], rtol=0, atol=1e-12)
    meta = run_metadata(recording)
    assert meta["case"] == "kundur_two_area" and list(meta["controllers"]) == ["/gen1", "/gen2", "/gen3", "/gen4"]
    assert meta["controllers"]["/gen2"]["battery_limit_pu"] == 0.0
    assert (tmp_path / "figures.png").stat().st_size > 0


def key_paths(value, prefix=()) -> set[tuple]:
    """Every key path of a JSON value (dicts by key; a list's items by index), the values left out."""
    if isinstance(value, dict):
        return {prefix + (key,) for key in value} | {path for key, item in value.items()
                                                     for path in key_paths(item, prefix + (key,))}
    if isinstance(value, list):
        return {path for index, item in enumerate(value) for path in key_paths(item, prefix + (index,))}
    return set()


def test_the_composed_deployment_gives_the_separate_processes_rows_and_trajectory_bit_for_bit(
        tmp_path, separate_kundur_demo):
    """--deployment composed: one composed_controllers process beside the logger and the plant; the same
    verdict table, the same summary.json keys and, at every sample of every generator, the same floats
    in the recording as a controller process per generator; nothing left running."""
    separate_out, separate, _, _ = separate_kundur_demo
    result, children, marker = kundur_demo(tmp_path, "composed")
    assert result.returncode == 0, result.stderr
    assert len(children) == 3, "logger, one composed_controllers process, plant"
    assert result.participants == {"3"}
    assert_nothing_left(children, marker)
    assert "their controllers composed in one process" in result.stdout.splitlines()[0], result.stdout
    names = load_network("kundur_two_area").names
    verdict = [line for line in separate.stdout.splitlines() if "b = 0.1 pu, reference pmu:" in line]
    assert len(verdict) == 1 and verdict[0] in result.stdout.splitlines()
    assert table_rows(result.stdout, names) == table_rows(separate.stdout, names)
    summaries = [json.loads((out / "summary.json").read_text()) for out in (separate_out, tmp_path)]
    assert key_paths(summaries[0]) == key_paths(summaries[1])
    assert summaries[1]["deployment"] == summaries[1]["runs"][0]["deployment"] == "composed"
    recorded = [generator_runs(read_recording(summary["runs"][0]["recording"])) for summary in summaries]
    assert list(recorded[1]) == ["/gen1", "/gen2", "/gen3", "/gen4"]
    for ns, reference in recorded[0].items():
        got = recorded[1][ns]
        for field in ("stamp_ns", "delta_rad", "speed_rad_s", "battery_power_pu"):
            assert np.array_equal(getattr(got, field), getattr(reference, field)), (ns, field)
        assert set(got.signals) == set(reference.signals)
        for name, values in reference.signals.items():  # the controller's state; NaN where it did not report
            assert np.array_equal(got.signals[name], values, equal_nan=True), (ns, name)
    assert sorted(p.name for p in (tmp_path / "logs").glob("*/*.log")) == [
        "composed_controllers.log", "mcap_logger.log", "network_plant.log"]


def test_coi_reference_and_a_displacement_run_as_offline_and_stream_every_generator_to_rerun(tmp_path):
    """--reference coi (every controller reads every PMU) with --scenario angle_displacement and --rerun save,
    two busy processes beside it: the recorded angles are the offline sampled simulation's with the same law
    and scenario to 1e-12, and the .rrd holds every generator's answered samples on the run's time axis."""
    domain, live = fresh_domain_id(), tmp_path / "live.rrd"
    with busy_processes(2):
        result, children, marker = run_demo(["--case", "kundur_two_area", "--reference", "coi", "--scenario",
                                             "angle_displacement", "--machine", "1", "--displace", "0.3", "--b", "0.1",
                                             "--duration", "1", "--rerun", "save", str(live), "--out",
                                             str(tmp_path / "o")], domain)
    assert result.returncode == 0, result.stderr
    assert_nothing_left(children, marker)
    assert "angle reference coi" in result.stdout and str(live) in result.stdout.splitlines()[-1], result.stdout
    net = load_network("kundur_two_area")
    defaults = default_law(net)
    law = NetworkLaw.uniform(net, defaults.tau_s, defaults.gain_k, defaults.gain_l, defaults.alpha, reference="coi")
    offline = simulate_network(net, law, AngleDisplacement(np.array([0.3, 0.0, 0.0, 0.0])), [np.full(4, 0.1)],
                               1.0, 50.0)
    (run,) = json.loads((tmp_path / "o" / "summary.json").read_text())["runs"]
    assert run["reference"] == "coi"
    runs = generator_runs(read_recording(run["recording"]))
    entities = read_entities(live)
    for i, (ns, generator) in enumerate(runs.items()):
        np.testing.assert_allclose(generator.delta_rad, offline.delta_rad[:, i, 0], rtol=0, atol=1e-12)
        t, _ = scalars(entities[f"/angle_coi/{ns[1:]}"])
        assert t.size == generator.answered.sum() == 50, ns
        np.testing.assert_allclose(t, generator.t_s[generator.answered], rtol=0, atol=1e-9)
    assert max(abs(g.battery_power_pu).max() for g in runs.values()) > 0, "the batteries acted"


def test_ieee39_demo_runs_ten_controllers_and_leaves_nothing(tmp_path):
    """The issue's Done-when: ten controller processes, per-generator results, no process left (1 s lockstep).

    No battery but at G10, unlimited there: from 0.32 s on, its controller asks for more than 1 pu, and the
    plant, whose battery there is rated b (unlimited, as the user said), applies it: nothing is clipped.
    """
    domain = fresh_domain_id()
    result, children, marker = run_demo(["--case", "ieee39", "--b", "0", "--gen-b", "10=inf", "--duration", "1",
                                         "--out", str(tmp_path)], domain)
    assert result.returncode == 0, result.stderr
    assert len(children) == 12, "logger, ten controllers, plant"
    assert result.participants == {"12"}
    assert_nothing_left(children, marker)
    net = load_network("ieee39")
    rows = table_rows(result.stdout, net.names)
    assert set(rows) == set(net.names), result.stdout
    loop_rows = [line for line in result.stdout.splitlines() if re.match(r"\s+/gen\d+\s+G\d+@\d+\s", line)]
    assert [row.split()[0] for row in loop_rows] == [f"/gen{i}" for i in range(1, 11)]
    (run,) = json.loads((tmp_path / "summary.json").read_text())["runs"]
    assert list(run["generators"]) == [f"gen{i}" for i in range(1, 11)]
    assert all(g["samples"] == 50 and g["dropped_samples"] == 0 for g in run["generators"].values())
    clipped = [line.split(":")[0].strip() for line in result.stdout.splitlines() if "were clipped to it" in line]
    assert clipped == [], result.stdout
    assert all(g["trust"]["clipped_commands"] == 0 for g in run["generators"].values())
    assert run["generators"]["gen10"]["max_abs_battery_power_pu"] > 1.0
    assert all(run["generators"][f"gen{i}"]["max_abs_battery_power_pu"] == 0.0 for i in range(1, 10)), "b = 0"
    assert sorted(p.name for p in (tmp_path / "logs").glob("*/controller_gen*.log")) == sorted(
        f"controller_gen{i}.log" for i in range(1, 11))


@pytest.mark.parametrize("case, size", [("kundur_ring_52", 52), ("ieee118", 54), ("ieee300", 69)])
def test_the_large_cases_run_through_the_demo_composed_on_this_machine(tmp_path, case, size):
    """kundur_ring_52, IEEE 118 and IEEE 300 with their controllers composed in one process (1 s lockstep, 10 to
    20 s each here): every generator's row and loop row printed, every sample answered, nothing left running.
    IEEE 118's synchronous condensers (dispatched at 0) run as any other machine."""
    result, children, marker = run_demo(["--case", case, "--deployment", "composed", "--b", "0.1",
                                         "--duration", "1", "--out", str(tmp_path)], fresh_domain_id())
    assert result.returncode == 0, result.stderr
    assert len(children) == 3, "logger, composed_controllers, plant"
    assert_nothing_left(children, marker)
    net = load_network(case)
    assert net.size == size and set(table_rows(result.stdout, net.names)) == set(net.names), result.stdout
    (run,) = json.loads((tmp_path / "summary.json").read_text())["runs"]
    assert list(run["generators"]) == [f"gen{i}" for i in range(1, size + 1)]
    short = {ns: (g["samples"], g["dropped_samples"], g["logger_counts"]) for ns, g in run["generators"].items()
             if g["samples"] != 50 or g["dropped_samples"] or g["logger_counts"][f"/{ns}/plant/state"] != 51}
    assert short == {}, short
    assert run["in_synchronism"] is True and "compromised" not in run


@pytest.mark.parametrize("args, message", [
    (["--case", "kundur_two_area", "--H", "4"], "--H does not apply to --case: the machines"),
    (["--case", "ieee39", "--scenario", "angle_displacement", "--displace", "0.3"],
     "--scenario angle_displacement needs --machine BUS"),
    (["--case", "kundur_two_area", "--params-file", "x.yaml"], "--params-file does not apply to --case"),
    (["--case", "kundur_two_area", "--scenario", "line_trip", "--trip-line", "7", "8", "--clearing-time", "0.2"],
     "--clearing-time does not apply to --scenario line_trip"),
    (["--case", "kundur_two_area", "--fault-bus", "99"], "bus 99 is not in the case"),
    (["--case", "kundur_two_area", "--gen-b", "5=0.1"], "--gen-b 5=0.1: no generator 5 (the case has gen1 .. gen4)"),
    (["--case", "kundur_two_area", "--K", "1", "1", "1", "2"], "generator G4@4: K must be less than L"),
    (["--gen-b", "2=0.1"], "--gen-b applies to a network of generators only"),
    (["--deployment", "composed"], "--deployment applies to a network of generators only"),
    (["--case", "kundur_two_area", "--clearing-time", "2000"], "network plant parameter clearing_time = 2000 is outside"),
    (["--case", "kundur_two_area", "--tau", "1e-5"], "controller parameter tau_s = 1e-05 is outside 0.0001..100"),
])
def test_an_option_that_does_not_apply_is_refused_with_one_line(tmp_path, args, message):
    domain = fresh_domain_id()
    result = subprocess.run([str(DEMO), *args, "--out", str(tmp_path / "o"), "--domain-id", str(domain)],
                            env=ros_env(domain), capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert result.returncode == 2, result
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr, result.stderr
    assert message in result.stderr, result.stderr
    assert not (tmp_path / "o").exists(), "nothing started, nothing written"


def test_per_generator_limits_and_the_model_check_of_a_machine_at_full_power():
    assert generator_limits(["3=0.2", "1=inf"], 4) == {2: 0.2, 0: float("inf")}
    for words, message in ((["3"], "takes I=B"), (["0=0.1"], "no generator 0"), (["2=-1"], ">= 0"),
                           (["2=0.1", "2=0.3"], "given twice"), (["x=1"], "takes I=B")):
        with pytest.raises(ValueError, match=message):
            generator_limits(words, 4)
    # A machine at (or above) the controller's default P_max (1 pu): in measured mode the node has no SMIB model to refuse it.
    net = SimpleNamespace(mbase_mva=np.array([500.0]), base_mva=100.0, p_mech_pu=np.array([5.5]),
                          delta_bar_rad=np.array([0.4]), names=("G1",), f0_hz=60.0)
    law = NetworkLaw(net, np.array([0.1]), np.array([1.0]), np.array([1.1]), np.array([1.0]))
    params = controller_parameters(net, 0, 0.1, 50.0, law)
    assert params["p_mech_pu"] == pytest.approx(1.1) and "p_max_pu" not in params
    from nni_battery_controller.controller_config import ControllerConfig, parameters

    ControllerConfig({**{spec.name: spec.default for spec in parameters()}, **params})  # accepted by the node's check


# --- the launch file ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def network_launch():
    """launch/network.launch.py imported as a module (it imports ``launch`` only to build the description)."""
    spec = importlib.util.spec_from_file_location("network_launch", LAUNCH_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert "launch" not in sys.modules
    return module


def console_script_module(executable: str) -> str:
    """The module a ``ros2 run`` executable (a console script of our packages) runs."""
    (entry,) = [e for e in metadata.entry_points(group="console_scripts", name=executable)]
    return entry.value.split(":")[0]


@pytest.mark.parametrize("case", ["kundur_two_area", "ieee39"])
def test_the_launch_file_creates_one_controller_per_generator_of_the_case(network_launch, case):
    net = load_network(case)
    nodes = network_launch.network_nodes({"case": case, "gen_b": "2=inf", "duration_s": "3.0"})
    kinds = [(n["package"], n["executable"]) for n in nodes]
    assert kinds == [("nni_msgs_adapter", "mcap_logger"), *[("nni_battery_controller", "controller_node")] * net.size,
                     ("nni_plant_sim", "network_plant_node")]
    controllers = nodes[1:-1]
    assert [n["namespace"] for n in controllers] == [f"gen{i + 1}" for i in range(net.size)]
    scale = net.mbase_mva / net.base_mva
    for i, node in enumerate(controllers):
        params = node["parameters"]
        assert params["restoring_power"] == "measured"
        assert params["reference_angle_rad"] == net.delta_bar_rad[i]
        assert params["p_mech_pu"] == pytest.approx(net.p_mech_pu[i] / scale[i], rel=1e-15)
        assert params["battery_limit_pu"] == (float("inf") if i == 1 else 0.1)
    plant = nodes[-1]["parameters"]
    assert plant["case"] == case and plant["duration_s"] == 3.0 and plant["wait_for_subscribers"] == 2
    assert plant["fault_bus"] == {"kundur_two_area": 7, "ieee39": 16}[case]
    assert all(node["env"] == {"NNI_DDS_PARTICIPANTS": str(net.size + 2)} for node in nodes), "logger, plant, N"
    for node in nodes:
        module = importlib.import_module(console_script_module(node["executable"]))
        declared = {spec.name for spec in module.parameters()}
        assert set(node["parameters"]) <= declared, (node["executable"], set(node["parameters"]) - declared)


def test_the_launch_file_runs_the_law_asked_for_with_its_gains(network_launch):
    nodes = network_launch.network_nodes({"case": "kundur_two_area", "law": "vsm"})
    defaults = controller_defaults()
    for node in nodes[1:-1]:
        params = node["parameters"]
        assert params["law"] == "vsm" and params["f0_hz"] == 60.0
        assert {k: params[k] for k in ("vsm_h_v_s", "vsm_d_v", "vsm_t_f_s")} == {
            k: defaults[k] for k in ("vsm_h_v_s", "vsm_d_v", "vsm_t_f_s")}
    default = network_launch.network_nodes({"case": "kundur_two_area"})
    assert {node["parameters"]["law"] for node in default[1:-1]} == {"nni"}


def test_the_launch_file_gives_the_plant_a_battery_of_finite_energy_on_request(network_launch):
    assert network_launch.network_nodes({})[-1]["parameters"]["battery_energy_pu_s"] == float("inf")
    plant = network_launch.network_nodes({"battery_energy_pu_s": "0.05"})[-1]
    assert plant["executable"] == "network_plant_node" and plant["parameters"]["battery_energy_pu_s"] == 0.05


def test_the_launch_file_feeds_the_controllers_through_c37118_on_request(network_launch):
    nodes = network_launch.network_nodes({"case": "kundur_two_area", "measurements": "c37118", "pmu_port": "4800"})
    kinds = [(n["package"], n["executable"]) for n in nodes]
    assert kinds == [("nni_msgs_adapter", "mcap_logger"), *[("nni_battery_controller", "controller_node")] * 4,
                     ("nni_msgs_adapter", "c37118_client"), ("nni_plant_sim", "network_plant_node")]
    assert all(n["parameters"]["measurement_topic"] == "c37118/pmu" for n in nodes[1:5])
    client, plant = nodes[5]["parameters"], nodes[-1]["parameters"]
    assert client["pmu_port"] == plant["pmu_port"] == 4800 and client["mode"] == plant["mode"] == "lockstep"
    assert client["namespaces"] == ["/gen1", "/gen2", "/gen3", "/gen4"] and client["wait_for_subscribers"] == 2
    assert plant["wait_for_subscribers"] == 1 and plant["pmu_wait_for_pdcs"] == 1, "the logger on pmu, the client"
    assert all(node["env"] == {"NNI_DDS_PARTICIPANTS": "7"} for node in nodes), "logger, plant, client, 4"
    for node in nodes:
        module = importlib.import_module(console_script_module(node["executable"]))
        assert set(node["parameters"]) <= {spec.name for spec in module.parameters()}
    with pytest.raises(ValueError, match="measurements must be one of ros, c37118, got 'udp'"):
        network_launch.network_nodes({"measurements": "udp"})


#: Each network scenario as launch arguments and as the nni-demo --case options that say the same.
LAUNCH_SCENARIOS = [
    ({"fault_bus": "8", "fault_x": "0.01", "clearing_time": "0.15", "trip_line": "7 8"},
     ["--fault-bus", "8", "--fault-x", "0.01", "--clearing-time", "0.15", "--trip-line", "7", "8"]),
    ({"scenario": "line_trip", "trip_line": "7 8"}, ["--scenario", "line_trip", "--trip-line", "7", "8"]),
    ({"scenario": "mechanical_step", "machine": "2", "step_p_mech": "0.95", "step_duration": "0.2"},
     ["--scenario", "mechanical_step", "--machine", "2", "--step-p-mech", "0.95", "--step-duration", "0.2"]),
    ({"scenario": "angle_displacement", "machine": "1 3", "displace": "0.3"},
     ["--scenario", "angle_displacement", "--machine", "1", "3", "--displace", "0.3"]),
]


@pytest.mark.parametrize("launch_args, demo_options", LAUNCH_SCENARIOS)
def test_every_network_scenario_is_launchable_with_the_plant_parameters_nni_demo_gives(network_launch, launch_args,
                                                                                      demo_options):
    """The launch arguments of each scenario (generated from the network plant node's table) give the plant
    the scenario parameters ``nni-demo --case`` gives it for the same disturbance, and nothing of the others."""
    from nni_battery_controller.network_demo import parse_arguments

    plant = network_launch.network_nodes(launch_args)[-1]["parameters"]
    demo = parse_arguments(["--case", "kundur_two_area", *demo_options]).scenario_values
    launched = {key: value for key, value in plant.items() if key in network_launch.SCENARIO_ARGUMENTS}
    assert set(launched) - {"trip_line"} == set(demo) - {"trip_line"}, (launched, demo)
    assert launched.get("trip_line", "") == demo.get("trip_line", "")
    for key, value in demo.items():
        assert launched[key] == (pytest.approx(value, rel=1e-15) if isinstance(value, float) else value), key


def test_the_launch_file_refuses_what_cannot_work(network_launch):
    for given, message in (({"fault_bus": "99"}, "bus 99 is not in the case"),
                           ({"scenario": "mechanical_step"}, "scenario mechanical_step needs machine"),
                           ({"scenario": "bus_fault", "displace": "0.5"},
                            "not for scenario bus_fault: displace \\(angle_displacement only\\)"),
                           ({"scenario": "mechanical_step", "machine": "1 2"}, "mechanical_step needs one machine"),
                           ({"scenario": "angle_displacement", "machine": "9"}, "machine 9: no generator at that bus"),
                           ({"scenario": "angle_displacement", "machine": "one"}, "machine takes bus numbers"),
                           ({"clearing_time": "soon"}, "clearing_time takes a number, got 'soon'"),
                           ({"scenario": "islanding"}, "scenario must be one of bus_fault, line_trip, "
                                                       "mechanical_step, angle_displacement"),
                           ({"gen_b": "7=0.1"}, "gen_b 7=0.1: no generator 7"),
                           ({"gain_k": "2.0"}, "K must be less than L")):
        with pytest.raises(Exception, match=message):
            network_launch.network_nodes(given)


@pytest.mark.parametrize("launch_args, scenario", [
    ({}, lambda net: BusFault(net, 7, 0.1)),
    ({"scenario": "angle_displacement", "machine": "1", "displace": "0.3"},
     lambda net: AngleDisplacement(np.array([0.3, 0.0, 0.0, 0.0]))),
], ids=["bus_fault", "angle_displacement"])
def test_the_launch_files_nodes_run_the_network_and_record_every_generator(network_launch, tmp_path, launch_args,
                                                                           scenario):
    """The node list, started as the processes ros2 launch would start (their environment too): a 1 s lockstep
    Kundur run, one MCAP, every generator's angles the offline sampled simulation's of the scenario to 1e-12."""
    domain, path = fresh_domain_id(), tmp_path / "network.mcap"
    nodes = network_launch.network_nodes({"duration_s": "1.0", "output_path": str(path), **launch_args})
    with node_processes(tmp_path, domain) as start:
        started = [start(f"{n['executable']}_{n['namespace'] or 'root'}", console_script_module(n["executable"]),
                         {**n["parameters"], **({"discovery_period_s": 0.1} if n["name"] == "mcap_logger" else {})},
                         ("-r", f"__ns:=/{n['namespace']}") if n["namespace"] else (), n["env"])
                   for n in nodes]
        plant, logger = started[-1], started[0]
        # As the launch's output handlers do: the plant's run starts once every node stated what it was given.
        start_when_read_back([(child, passed) for child, passed in zip(started, network_launch.readbacks(nodes))
                              if passed], plant, tmp_path)
        assert plant.wait(timeout=180.0) == 0, plant.output()
        time.sleep(0.5)  # the last reliable messages land
        assert logger.interrupt(15.0) == 0, logger.output()
    runs = generator_runs(read_recording(path))
    assert list(runs) == ["/gen1", "/gen2", "/gen3", "/gen4"]
    assert all(run.stamp_ns.size == 51 for run in runs.values()), "1 s at 50 frames/s: t_0 .. t_50"
    net = load_network("kundur_two_area")
    offline = simulate_network(net, default_law(net), scenario(net), [np.full(4, 0.1)], 1.0, 50.0)
    for i, run in enumerate(runs.values()):
        np.testing.assert_allclose(run.delta_rad, offline.delta_rad[:, i, 0], rtol=0, atol=1e-12)


@pytest.mark.parametrize("deployment, processes", [("separate", 6), ("composed", 3)])
def test_a_killed_network_demo_takes_every_process_with_it(tmp_path, deployment, processes):
    """SIGKILL mid-run (realtime, 60 s): the plant, the controllers (four processes, or the one composed) and
    the logger end with it."""
    domain = fresh_domain_id()
    env, marker = marked_env(domain)
    demo = subprocess.Popen([str(DEMO), "--case", "kundur_two_area", "--mode", "realtime", "--b", "0.1",
                             "--duration", "60", "--deployment", deployment, "--out", str(tmp_path),
                             "--domain-id", str(domain)], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    children: set = set()
    deadline = time.monotonic() + 120
    while len(children) < processes and time.monotonic() < deadline:
        children |= children_of(demo.pid)
        time.sleep(0.2)
    assert len(children) == processes, "the logger, the controllers and the plant should be running"
    demo.kill()
    demo.wait(timeout=60)
    deadline = time.monotonic() + 30
    while any(start_time(pid) == started for pid, started in children) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert_nothing_left(children, marker)


@pytest.mark.parametrize("deployment", ["separate", "composed"])
def test_a_second_writer_on_one_generators_battery_makes_the_run_compromised(tmp_path, deployment):
    """A rogue writer on /gen2/battery/command from before the run, flooding 5 pu commands stamped in the future
    (realtime, 3 s): exit 3, that generator named; its battery kept serving its controller (authenticated
    commands applied, never above b) and every generator stayed in synchronism.

    The cause of the old flake ("the rogue's writer never matched the plant's battery/command subscription"
    after 120 s): the rogue only had to be discovered by the plant within a 1 s run whose plant started at once
    with the controllers; under load the plant's run was over (and the plant gone) before its participant had
    matched the rogue's writer. The plant now holds its run until the demo has read back every node's
    parameters, and the rogue floods from before the demo starts, so the plant discovers it while it waits;
    and 3 s of run leave the last of discovery inside the run.
    """
    import threading

    from nni_msgs_adapter.ros import contract
    from rosproc import Probe

    domain = fresh_domain_id()
    rogue = Probe(domain, (), namespace="gen2", node_name="rogue")
    rogue.advertise(contract.TOPIC_BATTERY_COMMAND)
    stop = threading.Event()

    def flood():
        while not stop.wait(0.01):
            rogue.publish(contract.TOPIC_BATTERY_COMMAND, contract.command_message(time.time_ns() + 10**10, 5.0))

    flooding = threading.Thread(target=flood, daemon=True)
    flooding.start()
    demo = subprocess.Popen([str(DEMO), "--case", "kundur_two_area", "--mode", "realtime", "--b", "0.1",
                             "--duration", "3", "--deployment", deployment, "--out", str(tmp_path),
                             "--domain-id", str(domain)],
                            env=ros_env(domain), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        stdout, stderr = demo.communicate(timeout=300)
    finally:
        demo.kill()
        stop.set()
        flooding.join()
        rogue.close()
    assert demo.returncode == 3, stdout + stderr
    (line,) = [line for line in stdout.splitlines() if "COMPROMISED" in line]
    assert line.strip().startswith("b = 0.1: COMPROMISED (not a valid result): /gen2: ") and "/gen1" not in line
    assert "writer alarms" in line
    assert len(stderr.strip().splitlines()) == 1 and "1 of 1 run(s) compromised" in stderr
    (run,) = json.loads((tmp_path / "summary.json").read_text())["runs"]
    # The plant names the second writer (its graph); its commands reach the plant only once the rogue's own side
    # has matched the plant's reader, not always within the run (seen once in 20 under load): not asserted here,
    # test_command_trust's attack 1 floods a plant that is sure to hear it.
    assert list(run["compromised"]) == ["gen2"] and run["compromised"]["gen2"]["writer_alarms"] > 0
    gen2 = run["generators"]["gen2"]
    assert 0.0 < gen2["max_abs_applied_power_pu"] <= 0.1, "its controller's commands applied, never above b"
    assert gen2["trust"]["foreign_commands"] == 0 and gen2["samples"] >= 140
    assert run["in_synchronism"] and all(g["in_synchronism"] for g in run["generators"].values())


def test_the_launch_file_passes_the_c37118_stream_to_the_network_plant(network_launch):
    plant = network_launch.network_nodes({"pmu_port": "4712", "pmu_idcode": "7"})[-1]["parameters"]
    assert (plant["pmu_port"], plant["pmu_host"], plant["pmu_idcode"]) == (4712, "127.0.0.1", 7)
    assert network_launch.network_nodes({})[-1]["parameters"]["pmu_port"] == -1, "no stream unless asked for"
    with pytest.raises(ValueError, match="pmu_port and pmu_idcode take integers, got 'any'"):
        network_launch.network_nodes({"pmu_port": "any"})


def test_the_launch_file_streams_to_foxglove_on_request(network_launch):
    nodes = network_launch.network_nodes({"case": "kundur_two_area", "foxglove": "true",
                                          "foxglove_address": "0.0.0.0:9000", "battery_limit_pu": ".inf"})
    kinds = [(n["package"], n["executable"]) for n in nodes]
    assert kinds == [("nni_msgs_adapter", "mcap_logger"), *[("nni_battery_controller", "controller_node")] * 4,
                     ("nni_msgs_adapter", "foxglove_bridge"), ("nni_plant_sim", "network_plant_node")]
    bridge, plant = nodes[5]["parameters"], nodes[-1]["parameters"]
    assert bridge["address"] == "0.0.0.0:9000"
    assert json.loads(bridge["run_label"])["case"] == "kundur_two_area"
    assert plant["wait_for_subscribers"] == 3, "the controller, the logger and the bridge on each pmu"
    assert all(node["env"] == {"NNI_DDS_PARTICIPANTS": "7"} for node in nodes), "logger, plant, bridge, 4"
    module = importlib.import_module(console_script_module("foxglove_bridge"))
    assert set(bridge) <= {spec.name for spec in module.parameters()}
    assert "foxglove_bridge" not in [n["executable"] for n in network_launch.network_nodes({})], "off by default"
    with pytest.raises(ValueError, match="foxglove takes true or false, got 'yes please'"):
        network_launch.network_nodes({"foxglove": "yes please"})
    with pytest.raises(ValueError, match="foxglove_address: a Foxglove server address"):
        network_launch.network_nodes({"foxglove": "true", "foxglove_address": "here"})
