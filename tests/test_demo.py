"""nni-demo: the distributed loop as a user runs it, end to end."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyarrow as pa
import pytest

from nni_battery_controller.demo_common import compromised_reasons
from nni_battery_controller.smib_demo import (
    build_parser,
    controller_parameters,
    parse_arguments,
    plant_parameters,
    recording_name,
    run_metadata,
)
from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.cli_support import CliError
from nni_msgs_adapter.recording.runs import read_generator_run
from nni_msgs_adapter.viewing.bridge_protocol import PROGRESS_PREFIX
from nni_msgs_adapter.viewing.rerun_layout import run_paths
from rosproc import Probe, busy_processes, fresh_domain_id, node_processes, ros_env, wait_until

pytestmark = pytest.mark.ros

DEMO = Path(sys.executable).parent / "nni-demo"


def processes_in_domain(domain_id: int) -> list[str]:
    """Command lines of live processes of this project started with ROS_DOMAIN_ID=domain_id."""
    found = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            environ = (proc / "environ").read_bytes().split(b"\0")
            cmdline = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if f"ROS_DOMAIN_ID={domain_id}".encode() in environ and "nni_" in cmdline:
            found.append(cmdline)
    return found


def test_lockstep_demo_is_complete_and_leaves_nothing_running(tmp_path):
    """The issue's command: summary.json written, no process left. (Its speed is the bench's to measure,
    `bench/run_all`'s lockstep rows; a wall-time bound here failed on a loaded machine, not on a regression.)"""
    domain = fresh_domain_id()
    result = subprocess.run([str(DEMO), "--mode", "lockstep", "--b", "0.3", "--duration", "10",
                             "--out", str(tmp_path), "--domain-id", str(domain)],
                            env=ros_env(domain), capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert processes_in_domain(domain) == []
    summary = json.loads((tmp_path / "summary.json").read_text())
    (run,) = summary["scenarios"]
    for key in ("b", "stable", "final_angle_dev_rad", "max_abs_angle_dev_rad", "max_abs_battery_power_pu",
                "last_saturated_s", "settling_time_s"):
        assert key in run
    assert run["b"] == 0.3 and run["stable"] is True
    assert run["max_abs_battery_power_pu"] <= 0.3
    assert set(run["latency_ms"]) == {"p50", "p99", "max"}
    assert 0 < run["latency_ms"]["p50"] <= run["latency_ms"]["p99"] <= run["latency_ms"]["max"]
    assert run["dropped_samples"] == 0 and run["late_samples"] == 0
    assert run["samples"] == 500
    assert run["logger_counts"]["/plant/state"] == 501
    for value in (*run["latency_ms"].values(), run["wall_time_s"]):  # no float noise
        assert len(repr(value).split(".")[-1]) <= 6, value
    assert Path(run["recording"]).is_file()


def test_demo_bad_input_is_one_line(tmp_path):
    """Bad options: one line on stderr, non-zero exit, nothing started."""
    for args in (["--b", "-1"], ["--rate", "5"], ["--mode", "fast"], ["--rerun", "save"],
                 ["--domain-id", "999"]):
        result = subprocess.run([str(DEMO), *args, "--out", str(tmp_path / "o")], capture_output=True,
                                text=True, timeout=60)
        assert result.returncode != 0, args
        assert len(result.stderr.strip().splitlines()) == 1, (args, result.stderr)
        assert "Traceback" not in result.stderr
        assert not (tmp_path / "o" / "summary.json").exists()


# --- the live Rerun stream ----------------------------------------------------------------


def rrd_scalars(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per entity of a .rrd: the sim_time stamps (s) and values of its Scalars, sorted by time."""
    from rerun.chunk import RrdReader

    times: dict[str, list] = {}
    values: dict[str, list] = {}
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        if "sim_time" in batch.schema.names and "Scalars:scalars" in batch.schema.names:
            times.setdefault(chunk.entity_path, []).append(batch.column("sim_time").cast(pa.int64()).to_numpy())
            values.setdefault(chunk.entity_path, []).extend(v[0] for v in batch.column("Scalars:scalars").to_pylist())
    out = {}
    for entity, parts in times.items():
        t = np.concatenate(parts) * 1e-9
        order = np.argsort(t, kind="stable")
        out[entity] = (t[order], np.asarray(values[entity])[order])
    return out


def run_demo(args: list[str], domain: int, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([str(DEMO), *args, "--domain-id", str(domain)], env=ros_env(domain),
                          capture_output=True, text=True, timeout=timeout)


def assert_stream_holds_every_sample(rrd: Path, summary_path: Path, labels: list[str]) -> None:
    """Every answered sample of every run's recording is in the .rrd, at its simulated time from the run's start."""
    series = rrd_scalars(rrd)
    runs = json.loads(summary_path.read_text())["scenarios"]
    assert len(runs) == len(labels)
    for run, label in zip(runs, labels):
        recorded = read_generator_run(run["recording"])
        answered = recorded.answered
        # The recording's own clock: t = 0 at the plant's first state, the run's start.
        expected_t = recorded.t_s[answered]
        assert expected_t[0] == 0.0
        paths = run_paths(label)
        t, angle = series[paths.angle]
        assert t.size == answered.sum(), f"{label}: {t.size} of {answered.sum()} samples in the stream"
        np.testing.assert_allclose(t, expected_t, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(angle, recorded.signals["angle_dev"][answered])
        t_power, power = series[paths.power]
        np.testing.assert_allclose(t_power, expected_t, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(power, recorded.signals["battery_power"][answered])
        t_sat, saturated = series[paths.saturation]
        np.testing.assert_allclose(t_sat, expected_t, rtol=0, atol=1e-9)
        assert set(np.unique(saturated)) <= {0.0, 1.0}


def test_live_rerun_lockstep_keeps_every_run_under_load(tmp_path):
    """The issue's command on a loaded machine: all four runs, every sample, on simulated time from 0."""
    domain = fresh_domain_id()
    rrd = tmp_path / "live.rrd"
    with busy_processes(2):
        result = run_demo(["--rerun", "save", str(rrd), "--out", str(tmp_path)], domain)
    assert result.returncode == 0, result.stdout + result.stderr
    assert f"{rrd}" in result.stdout.splitlines()[-1]  # the final "wrote" line lists the .rrd
    assert processes_in_domain(domain) == []
    assert_stream_holds_every_sample(rrd, tmp_path / "summary.json", ["b=0", "b=0.2", "b=0.3", "b=inf"])
    t, _ = rrd_scalars(rrd)[run_paths("b=0.3").angle]
    np.testing.assert_allclose(t, np.arange(500) / 50.0, rtol=0, atol=1e-9)  # 10 s at 50/s, from 0


def test_live_rerun_realtime_starts_at_zero_under_load(tmp_path):
    """Realtime: the saturation phase at the start is there, t = 0 at the run's start (not the first sample seen)."""
    domain = fresh_domain_id()
    rrd = tmp_path / "live.rrd"
    with busy_processes(2):
        result = run_demo(["--mode", "realtime", "--b", "0.2", "0.3", "--duration", "3", "--rerun", "save", str(rrd),
                           "--out", str(tmp_path)], domain)
    assert result.returncode == 0, result.stdout + result.stderr
    assert_stream_holds_every_sample(rrd, tmp_path / "summary.json", ["b=0.2", "b=0.3"])
    t, saturated = rrd_scalars(rrd)[run_paths("b=0.2").saturation]
    assert t[0] == 0.0 and saturated[t < 0.5].any()  # the saturation phase at the start is in the stream


def test_demo_waits_for_the_bridge_before_the_plant_starts():
    """With a bridge the plant waits for three pmu subscribers: controller, logger and the bridge."""
    args = parse_arguments(build_parser(), [])
    assert plant_parameters(args, 0.3, with_bridge=True)["wait_for_subscribers"] == 3
    assert plant_parameters(args, 0.3, with_bridge=False)["wait_for_subscribers"] == 2


def test_through_c37118_the_plant_waits_for_the_logger_on_pmu_and_for_the_client_on_its_stream():
    """The controller reads c37118/pmu: the plant's pmu has the logger (and a bridge); the client turns data on."""
    args = parse_arguments(build_parser(), ["--measurements", "c37118"])
    plant = plant_parameters(args, 0.3, with_bridge=False)
    assert plant["wait_for_subscribers"] == 1 and plant_parameters(args, 0.3, with_bridge=True)["wait_for_subscribers"] == 2
    assert plant["pmu_port"] == 0 and plant["pmu_host"] == "127.0.0.1" and plant["pmu_wait_for_pdcs"] == 1
    assert controller_parameters(args, 0.3)["measurement_topic"] == "c37118/pmu"
    assert recording_name(0.3, plant) == "paper_b0.3.mcap", "the stream is the run's set-up, not its case"


def test_rerun_serve_prints_a_localhost_url_and_binds_to_localhost(tmp_path):
    domain = fresh_domain_id()
    demo = subprocess.Popen([str(DEMO), "--b", "0.3", "--duration", "1", "--rerun", "serve", "--out", str(tmp_path),
                             "--domain-id", str(domain)], env=ros_env(domain), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        lines = []
        deadline = time.monotonic() + 120
        while not any(line.startswith("serving") for line in lines) and time.monotonic() < deadline:
            lines.append(demo.stdout.readline())
        (url,) = [line for line in lines if line.startswith("Rerun web viewer:")]
        assert "http://127.0.0.1:9090/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9876%2Fproxy" in url
        listening = Path("/proc/net/tcp").read_text() + Path("/proc/net/tcp6").read_text()
        # Local address column: 0100007F:2694 is 127.0.0.1:9876; nobody listens on 0.0.0.0:9876.
        assert "0100007F:2694" in listening and "00000000:2694" not in listening
    finally:
        demo.send_signal(signal.SIGINT)
        try:
            out, err = demo.communicate(timeout=60)
        except subprocess.TimeoutExpired:  # seen once in a loaded suite: say where it stood, for the next time
            demo.kill()
            out, err = demo.communicate()
            logs = {path.name: path.read_text(errors="replace")[-1500:] for path in sorted(tmp_path.glob("*.log"))}
            pytest.fail(f"the demo did not exit within 60 s of SIGINT; stdout {out[-1500:]!r}, stderr {err[-1500:]!r}, "
                        f"its children's logs {logs}")
    assert demo.returncode == 0, err
    assert processes_in_domain(domain) == []


# --- the demo's children die with it ------------------------------------------------------


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGKILL])
def test_killed_demo_leaves_no_process_running(tmp_path, signum):
    domain = fresh_domain_id()
    printed = tmp_path / "demo.out"
    with printed.open("w") as out:
        demo = subprocess.Popen([str(DEMO), "--mode", "realtime", "--b", "0.3", "--duration", "60", "--out",
                                 str(tmp_path), "--domain-id", str(domain)], env=ros_env(domain),
                                stdout=out, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 60
    while len(processes_in_domain(domain)) < 3 and time.monotonic() < deadline:
        time.sleep(0.2)
    assert len(processes_in_domain(domain)) == 3, "logger, controller and plant should be running"
    demo.send_signal(signum)
    try:
        demo.wait(timeout=60)
    except subprocess.TimeoutExpired:  # say where it stuck: what it printed, what each child logged last
        demo.kill()
        logs = {path.name: path.read_text(errors="replace")[-400:] for path in tmp_path.rglob("*.log")}
        pytest.fail(f"the demo did not exit within 60 s of {signal.Signals(signum).name}: "
                    f"{printed.read_text(errors='replace')[-800:]!r}; children: {logs}; "
                    f"left in its domain: {processes_in_domain(domain)}")
    deadline = time.monotonic() + 30
    while processes_in_domain(domain) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert processes_in_domain(domain) == []


# --- a run the battery's controller did not command alone ---------------------------------


def test_rogue_commands_make_the_run_compromised(tmp_path):
    """A stranger re-sending 5 pu right after each real command: non-zero exit, one line saying what, in summary.json.

    Realtime, so that the rogue's command is the one in force until the next reporting
    instant (issue 11, attacks 1 and 2): today the plant applies it; once it pairs with its
    controller it drops it as foreign. Either way the run is compromised.
    """
    domain = fresh_domain_id()
    rogue = Probe(domain, [contract.TOPIC_BATTERY_COMMAND])

    def follow(msg):
        stamp_ns, power = contract.command_from_message(msg)
        if power != 5.0:  # the controller's command, not the rogue's own
            rogue.publish(contract.TOPIC_BATTERY_COMMAND, contract.command_message(stamp_ns + 1_000_000, 5.0))

    rogue.on_message(contract.TOPIC_BATTERY_COMMAND, follow)
    rogue.advertise(contract.TOPIC_BATTERY_COMMAND)  # a writer on the battery's topic from the start
    demo = subprocess.Popen([str(DEMO), "--mode", "realtime", "--b", "0.3", "--duration", "5", "--out", str(tmp_path),
                             "--domain-id", str(domain)], env=ros_env(domain), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        # The attack needs the rogue in the loop: its writer matched with the plant's command subscription.
        # (Twice on a clean clone, the demo's 2 s run ended before the rogue had discovered the plant.)
        in_loop = rogue.wait_matched(contract.TOPIC_BATTERY_COMMAND, 1, 60.0)
        stdout, stderr = demo.communicate(timeout=300)
    finally:
        demo.kill()
        rogue.close()
    assert in_loop, "the rogue never matched the plant's battery/command subscription (discovery)"
    result = subprocess.CompletedProcess(demo.args, demo.returncode, stdout, stderr)
    assert result.returncode == 3, result.stdout + result.stderr
    (line,) = [line for line in result.stdout.splitlines() if "b = 0.3" in line]
    assert "COMPROMISED" in line and "stable" not in line and "SYNCHRONISM" not in line
    assert len(result.stderr.strip().splitlines()) == 1 and "compromised" in result.stderr
    (run,) = json.loads((tmp_path / "summary.json").read_text())["scenarios"]
    reasons = run["compromised"]
    # The plant names the rogue (a second writer on battery/command) and applies none of its commands.
    assert reasons.get("writer_alarms", 0) > 0 or reasons.get("foreign_commands", 0) > 0, reasons
    assert run["max_abs_battery_power_pu"] <= 0.3


def test_compromised_reasons():
    run = SimpleNamespace(battery_power_pu=np.array([0.0, 0.3, -0.3]), controller_diagnostics={})
    clean = {"unauthenticated_commands": 0, "replayed_commands": 0, "foreign_commands": 0, "unsolicited_commands": 0,
             "writer_alarms": 0, "max_abs_applied_power_pu": 0.3}
    assert compromised_reasons(clean, run, 0.3) == {}
    assert compromised_reasons({**clean, "foreign_commands": 2}, run, 0.3) == {"foreign_commands": 2}
    assert compromised_reasons({**clean, "unauthenticated_commands": 7}, run, 0.3) == {"unauthenticated_commands": 7}
    assert compromised_reasons(clean, run, 0.2) == {"max_abs_applied_power_pu": 0.3}
    assert compromised_reasons({**clean, "max_abs_applied_power_pu": 5.0}, run, 0.3) == {"max_abs_applied_power_pu": 5.0}
    # The controller's own counters (its last recorded status): inputs that were not its plant's.
    attacked = SimpleNamespace(battery_power_pu=run.battery_power_pu, controller_diagnostics={
        "unauthenticated_measurements": "12", "replayed_measurements": "0", "foreign_clock_writers": "1"})
    assert compromised_reasons(clean, attacked, 0.3) == {"unauthenticated_measurements": 12,
                                                         "foreign_clock_writers": 1}
    # A plant that does not report its trust counters cannot be judged: never taken as clean.
    with pytest.raises(CliError, match="writer_alarms"):
        compromised_reasons({"foreign_commands": 0, "unsolicited_commands": 0}, run, 0.3)


# --- names and metadata -------------------------------------------------------------------


def test_recording_names_follow_the_scenario():
    args = parse_arguments(build_parser(), [])
    paper = plant_parameters(args, 0.3, with_bridge=False)
    assert recording_name(0.3, paper) == "paper_b0.3.mcap"
    assert recording_name(math.inf, {**paper, "mode": "realtime", "duration_s": 3.0}) == "paper_binf.mcap"
    fault = {**paper, "scenario": "transfer_limit_fault", "clearing_time_s": 0.2}
    assert recording_name(0.2, fault) == "transfer_limit_fault_b0.2.mcap"
    assert recording_name(0.2, {**paper, "delta0_rad": 0.5}) == "initial_angle_b0.2.mcap"


def test_run_metadata_holds_every_node_parameter():
    args = parse_arguments(build_parser(), ["--b", "0.3"])
    plant = plant_parameters(args, 0.3, with_bridge=False)
    meta = run_metadata(args, plant, controller_parameters(args, 0.3))
    assert plant["battery_rating_pu"] == 0.3 and plant["hold_until_released"] is True, "the battery is rated b"
    assert set(meta) == {"scenario", "plant", "controller", "mode", "rate_hz", "measurements", "software_version"}
    assert meta["measurements"] == "ros"
    assert meta["scenario"] == {"name": "initial_angle", "delta0_rad": 0.2, "speed0_rad_s": 0.0}
    assert meta["plant"]["mode"] == "lockstep" and meta["plant"]["p_mech_pu"] == 0.8
    assert meta["controller"]["battery_limit_pu"] == 0.3 and meta["controller"]["gain_l"] == 1.1
    json.dumps(meta)  # it goes to the logger as JSON text


def test_help_states_the_domain_id():
    result = subprocess.run([str(DEMO), "--help"], capture_output=True, text=True, timeout=60)
    text = " ".join(result.stdout.split())
    assert "$ROS_DOMAIN_ID, else 42" in text and "domain of its own" not in text


def test_realtime_run_shows_its_progress_on_a_terminal(tmp_path):
    """On a terminal a realtime run counts its simulated time up to the duration; off a terminal it prints nothing."""
    import pty

    domain = fresh_domain_id()
    master, slave = pty.openpty()
    try:
        result = subprocess.run([str(DEMO), "--mode", "realtime", "--b", "0.3", "--duration", "2", "--out",
                                 str(tmp_path), "--domain-id", str(domain)], env=ros_env(domain),
                                stdout=subprocess.PIPE, stderr=slave, text=True, timeout=120)
        os.close(slave)
        shown = b""
        while True:
            try:
                chunk = os.read(master, 4096)
            except OSError:  # the terminal's other end is closed and drained
                break
            if not chunk:
                break
            shown += chunk
    finally:
        os.close(master)
    assert result.returncode == 0
    text = shown.decode(errors="replace")
    # Counted from the plant's start line to its end, then the line is cleared.
    assert "t =   0.0 of 2 s" in text and "t =   1.5 of 2 s" in text and text.endswith("\r\x1b[K"), text
    assert "of 2 s" not in result.stdout


def test_a_plant_told_to_wait_for_a_recorder_starts_only_when_its_state_writer_sees_one_and_it_gets_every_state(
        tmp_path):
    """``wait_for_recorders``: the plant counts plant/state's subscribers as its writer sees them (a recorder that
    has matched the writer may not yet be matched by it: IEEE 118's composed demo once lost the first 4 states of
    13 generators that way). With none the run waits, and says for what; the probe that comes gets every state."""
    from nni_msgs_adapter.ros import contract

    domain = fresh_domain_id()
    with node_processes(tmp_path, domain) as start:
        start("controller", "nni_battery_controller.controller_node", {"battery_limit_pu": 0.3})
        plant = start("plant", "nni_plant_sim.plant_node", {"mode": "lockstep", "duration_s": 1.0,
                                                            "wait_for_subscribers": 1, "wait_for_recorders": 1})
        assert wait_until(lambda: "1 recorder(s) on /plant/state (has 0)" in plant.output(), 30.0), plant.output()
        assert "started in" not in plant.output()
        probe = Probe(domain, (contract.TOPIC_PLANT_STATE,))
        try:
            assert plant.wait(timeout=60) == 0
            time.sleep(0.5)
            states = probe.take(contract.TOPIC_PLANT_STATE)
        finally:
            probe.close()
    assert [contract.plant_state_from_message(m)[0] for m in states] == [k * 20_000_000 for k in range(51)]


def test_a_plant_told_to_wait_for_the_bridge_starts_only_when_the_bridge_hears_it(tmp_path):
    """The bridge is counted on pmu only once it hears the plant and the controller; then it gets the whole run."""
    domain = fresh_domain_id()
    with node_processes(tmp_path, domain) as start:
        start("controller", "nni_battery_controller.controller_node", {"battery_limit_pu": 0.3})
        plant = start("plant", "nni_plant_sim.plant_node", {"mode": "lockstep", "duration_s": 1.0,
                                                            "wait_for_subscribers": 2})
        time.sleep(3.0)
        assert "started in" not in plant.output(), "two subscribers were asked for: the controller and the bridge"
        bridge = start("rerun_bridge", "nni_msgs_adapter.viewing.rerun_bridge", {"sink": "save",
                                                                           "path": str(tmp_path / "live.rrd")})
        assert plant.wait(timeout=60) == 0
        line = bridge.wait_for_line(PROGRESS_PREFIX, 30.0, lambda line: '"samples": 50,' in line)
    assert json.loads(line[len(PROGRESS_PREFIX):]) == {"run": 1, "label": "b=0.3", "samples": 50, "first_t_s": 0.0,
                                                       "last_t_s": 0.98}
