"""Issue 31: the controller acts only on its plant's own measurements, end of run and clock.

A rogue process (tests/rogue_measurements.py) on the demo's domain answers every real measurement with a
same-stamp race (three mirrored copies carrying the real seal), a mirrored copy one period ahead, the real
message sent again and one captured five samples before, a /clock tick 100 s ahead, and now and then a
forged ``run_ended``; its own fakes feed a flood. Each run below, as a user types it (``nni-demo``):

* the controller acts on none of it: in lockstep the recorded run equals the offline sampled run to 1e-12;
* the machine stays in step and the battery within b;
* the run is flagged (exit 3, COMPROMISED naming the controller's counters, summary.json);
* the counters say what happened (unauthenticated and replayed measurements, the foreign /clock writer);
* the recording holds no foreign sample where the loop's are: one /pmu per measurement, the rogue's apart
  on /nni_foreign/..., and ``nni-replay --info`` says how many.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from nni_battery_controller.law import ControllerParams
from nni_battery_controller.network_deployment import default_law
from nni_battery_controller.network_sim import simulate_network
from nni_battery_controller.simulate import simulate_sampled
from nni_msgs_adapter.recording.mcap_io import read_recording
from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.recording.runs import FOREIGN_PREFIX, foreign_counts, generator_runs
from nni_plant_sim.model import SmibParams
from nni_plant_sim.cases import load_network
from nni_plant_sim.network_scenarios import BusFault
from nni_plant_sim.scenarios import InitialAngle
from nni_msgs_adapter.ros import command_auth
from nni_plant_sim.plant_node import SUMMARY_PREFIX
from rosproc import busy_processes, fresh_domain_id, node_processes, printed_json, ros_env, wait_until

pytestmark = pytest.mark.ros

BIN = Path(sys.executable).parent
ROGUE = Path(__file__).with_name("rogue_measurements.py")


def run_attacked_demo(tmp_path, demo_args: list[str], topics: list[str], statuses: list[str]):
    """``nni-demo`` with the rogue on its domain from before the start; (demo result, the rogue's counts)."""
    domain = fresh_domain_id()
    env = ros_env(domain)
    rogue = subprocess.Popen([sys.executable, str(ROGUE), "--topics", *topics,
                              *[arg for status in statuses for arg in ("--status", status)]],
                             env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert rogue.stdout.readline().strip() == "rogue: ready"
        demo = subprocess.run([str(BIN / "nni-demo"), *demo_args, "--out", str(tmp_path), "--domain-id", str(domain)],
                              env=env, capture_output=True, text=True, timeout=300)
    finally:
        rogue.send_signal(subprocess.signal.SIGINT)
        out, err = rogue.communicate(timeout=30)
    counts = json.loads(next(line for line in out.splitlines() if line.startswith("rogue: {"))[len("rogue: "):])
    return demo, counts


def assert_flagged(demo, counts: dict, reasons: dict, measurements_attacked: bool = True):
    """Exit 3, a COMPROMISED line naming the controller's counters, and the counters say what the rogue did."""
    assert demo.returncode == 3, demo.stdout + demo.stderr
    assert "COMPROMISED" in demo.stdout and "compromised" in demo.stderr, demo.stdout
    assert counts["real_seen"] > 0 and counts["clock"] > 0 and counts["statuses"] > 0, counts
    assert reasons.get("foreign_clock_writers", 0) >= 1, reasons
    assert "foreign clock writers" in demo.stdout
    # Its forged run_ended notices: refused and counted, never taken for the plant's end of run (the run went on
    # to its duration, which the callers check in the recording).
    assert reasons.get("unauthenticated_statuses", 0) >= 1, reasons
    assert "unauthenticated statuses" in demo.stdout
    if measurements_attacked:
        assert reasons.get("unauthenticated_measurements", 0) > 0, reasons
        assert reasons.get("replayed_measurements", 0) > 0, reasons
        assert "unauthenticated measurements" in demo.stdout


def assert_recording_holds_only_the_loops(path: str, pmu_topics: list[str], measurements: int | None = None):
    """One recorded measurement per plant step (``measurements`` when given, else one fewer than the plant's
    sealed states), no stamp twice, the rogue's apart and counted by ``nni-replay --info``. /clock: in lockstep
    (``measurements`` given) one tick per measurement, at its stamp; in realtime none (the plant sends none); the
    rogue's ticks apart."""
    recording = read_recording(path)
    stamps: dict[str, list] = {}
    for record in recording.messages:
        if record.topic in pmu_topics:
            stamps.setdefault(record.topic, []).append(contract.pmu_from_bytes(record.cdr_bytes)[0][0])
        else:
            stamps.setdefault(record.topic, []).append(None)
    for topic in pmu_topics:
        expected = measurements if measurements is not None else \
            len(stamps[topic.rsplit("/", 1)[0] + "/" + contract.TOPIC_PLANT_STATE]) - 1
        assert len(stamps[topic]) == expected, (topic, len(stamps[topic]), expected)
        assert len(set(stamps[topic])) == expected, f"{topic}: a stamp recorded twice"
    ticks = [contract.clock_from_bytes(record.cdr_bytes) for record in recording.messages
             if record.topic == contract.TOPIC_CLOCK]
    assert sorted(ticks) == (sorted(stamps[pmu_topics[0]]) if measurements is not None else []), \
        (len(ticks), ticks[:5])
    foreign = foreign_counts(recording)
    assert all(foreign.get(topic, 0) > 0 for topic in [*pmu_topics, contract.TOPIC_CLOCK]), foreign
    info = subprocess.run([str(BIN / "nni-replay"), path, "--info"], capture_output=True, text=True, timeout=120)
    assert info.returncode == 0, info.stderr
    (line,) = [line for line in info.stdout.splitlines() if line.startswith("Foreign messages:")]
    for topic in [*pmu_topics, contract.TOPIC_CLOCK]:
        assert f"{topic} {foreign[topic]}" in line and FOREIGN_PREFIX in line, line
    return recording


def test_smib_lockstep_the_rogue_changes_nothing_and_the_run_is_flagged(tmp_path):
    # 60 s of simulated time (about 10 s of wall time with the rogue beside it): the rogue, up before the run,
    # discovers the plant's writer about a second after the loop has started, and a 10 s lockstep run is over by then.
    b, duration, rate = 0.3, 60.0, 50.0
    demo, counts = run_attacked_demo(tmp_path, ["--mode", "lockstep", "--b", str(b), "--duration", str(duration)],
                                     ["/pmu"], ["/plant"])
    (run,) = json.loads((tmp_path / "summary.json").read_text())["scenarios"]
    assert_flagged(demo, counts, run["compromised"])
    recording = assert_recording_holds_only_the_loops(run["recording"], ["/pmu"], int(duration * rate))
    (generator,) = generator_runs(recording).values()
    offline = simulate_sampled(SmibParams(), ControllerParams(battery_limit_pu=b), InitialAngle(), duration, rate)
    np.testing.assert_allclose(generator.delta_rad, offline.delta_rad, rtol=0, atol=1e-12)
    np.testing.assert_allclose(generator.battery_power_pu[:-1], offline.battery_power_pu[:-1], rtol=0, atol=1e-12)
    assert run["in_synchronism"] and run["max_abs_battery_power_pu"] <= b


def test_smib_realtime_under_load_the_rogue_is_dropped_and_the_machine_stays_in_step(tmp_path):
    b = 0.3
    with busy_processes(2):
        demo, counts = run_attacked_demo(tmp_path, ["--mode", "realtime", "--b", str(b), "--duration", "5"],
                                         ["/pmu"], ["/plant"])
    (run,) = json.loads((tmp_path / "summary.json").read_text())["scenarios"]
    assert_flagged(demo, counts, run["compromised"])
    assert run["in_synchronism"] and run["max_abs_battery_power_pu"] <= b + 1e-12
    assert_recording_holds_only_the_loops(run["recording"], ["/pmu"])


@pytest.mark.parametrize("deployment", ["separate", "composed"])
def test_network_lockstep_the_rogue_on_one_generator_changes_nothing(tmp_path, deployment):
    b, duration = 0.3, 20.0  # long enough for the rogue to discover the plant (as for the SMIB above)
    demo, counts = run_attacked_demo(
        tmp_path, ["--case", "kundur_two_area", "--mode", "lockstep", "--b", str(b), "--duration", str(duration),
                   "--deployment", deployment], ["/gen1/pmu"], ["/gen1/plant"])
    (run,) = json.loads((tmp_path / "summary.json").read_text())["runs"]
    reasons = run["compromised"]["gen1"]
    assert_flagged(demo, counts, reasons)
    assert set(run["compromised"]) == {"gen1", "gen2", "gen3", "gen4"}  # the /clock writer is every one's
    assert run["in_synchronism"]
    recording = assert_recording_holds_only_the_loops(run["recording"], ["/gen1/pmu"], int(duration * 50))
    net = load_network("kundur_two_area")
    offline = simulate_network(net, default_law(net), BusFault(net, 7, 0.1), [np.full(4, b)], duration, 50.0)
    for i, generator in enumerate(generator_runs(recording).values()):
        np.testing.assert_allclose(generator.delta_rad, offline.delta_rad[:, i, 0], rtol=0, atol=1e-12)


def test_a_controller_with_another_runs_key_acts_on_nothing_and_says_so_in_one_line(tmp_path):
    """Started by hand with the key file of another run: no measurement verifies, so none is answered; the first is
    named at ERROR in one line (and counted). It does not exit: a rogue's messages must not be able to stop it."""
    other = command_auth.new_key_file()
    try:
        with node_processes(tmp_path, fresh_domain_id()) as start:
            controller = start("controller", "nni_battery_controller.controller_node", {"battery_limit_pu": 0.3},
                               env={command_auth.KEY_FILE_ENV: str(other)})
            plant = start("plant", "nni_plant_sim.plant_node",
                          {"mode": "lockstep", "duration_s": 0.5, "wait_for_subscribers": 1,
                           "lockstep_timeout_s": 0.05})
            assert plant.wait(timeout=60) == 0, plant.output()
            assert wait_until(lambda: "unauthenticated statuses" in controller.output(), 10.0), controller.output()
            assert controller.proc.poll() is None, "a foreign measurement stopped the controller"
            output = controller.output()
    finally:
        command_auth.remove_key_file(other)
    summary = printed_json(plant.output(), SUMMARY_PREFIX)
    assert summary["measurements"] == 25 and summary["commands"] == 0, summary
    refusals = [line for line in output.splitlines() if "unauthenticated measurements on /pmu" in line]
    assert len(refusals) == 1 and "[ERROR]" in refusals[0] and "not sealed by this run's plant" in refusals[0], output
    assert "Traceback" not in output
