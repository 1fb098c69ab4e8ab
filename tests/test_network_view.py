"""A network run as the user looks at it: `nni-replay --info`, `nni-replay --rrd` and the live Rerun bridge (issue 14).

One Kundur lockstep run over real DDS (network plant, a controller process per
generator, the MCAP logger given the run's case in ``run_metadata``, the Rerun
bridge with ``namespaces``), recorded once for the module. Expected values come
from the file read with the mcap library (counts), from the case
(machine names) and from the offline network simulation (verdicts, angles), never
from the code under test.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from nni_battery_controller.network_sim import NetworkLaw, assess_network, simulate_network
from nni_msgs_adapter.viewing.bridge_protocol import PROGRESS_PREFIX
from nni_plant_sim.cases import load_network
from nni_plant_sim.network_scenarios import BusFault
from rosproc import fresh_domain_id, node_processes
from test_network_loop import CONTROLLER, FAULT, PLANT, RATE_HZ, controller_parameters
from test_rerun_view import read_entities, scalars, static_value

pytestmark = pytest.mark.ros

NNI_REPLAY = Path(sys.executable).parent / "nni-replay"
LOGGER = "nni_msgs_adapter.recording.mcap_logger"
BRIDGE = "nni_msgs_adapter.viewing.rerun_bridge"
CASE = "kundur_two_area"
B, DURATION_S = 0.1, 2.0
NAMESPACES = [f"/gen{i + 1}" for i in range(4)]


@pytest.fixture(scope="module")
def kundur():
    return load_network(CASE)


@pytest.fixture(scope="module")
def offline(kundur):
    law = NetworkLaw.uniform(kundur, 0.1, 1.0, 1.1, 1.0)
    fault = BusFault(kundur, 7, 0.1, trip=(kundur.bus_model.branch_index(7, 8),))
    return simulate_network(kundur, law, fault, [B], DURATION_S, RATE_HZ)


@pytest.fixture(scope="module")
def network_run(tmp_path_factory, kundur) -> dict:
    """The run: its MCAP, the live bridge's .rrd and the bridge's last progress line."""
    tmp = tmp_path_factory.mktemp("network_view")
    path, live = tmp / "network.mcap", tmp / "live.rrd"
    metadata = {"case": CASE, "mode": "lockstep", "rate_hz": RATE_HZ}
    with node_processes(tmp, fresh_domain_id()) as start:
        logger = start("logger", LOGGER, {"output_path": str(path), "discovery_period_s": 0.1,
                                          "run_metadata": json.dumps(metadata)})
        bridge = start("bridge", BRIDGE, {"sink": "save", "path": str(live), "namespaces": NAMESPACES, "case": CASE,
                                          "coi_weights": [float(m) for m in kundur.inertia_m], "f0_hz": kundur.f0_hz})
        for i, ns in enumerate(NAMESPACES):
            start(f"controller_{ns[1:]}", CONTROLLER, controller_parameters(kundur, i, B), ("-r", f"__ns:={ns}"))
        # Each pmu: its controller, the logger and the bridge.
        plant = start("plant", PLANT, {**FAULT, "duration_s": DURATION_S, "pmu_rate_hz": RATE_HZ,
                                       "wait_for_subscribers": 3})
        assert plant.wait(timeout=120.0) == 0, plant.output()
        answered = int(DURATION_S * RATE_HZ) * len(NAMESPACES)
        line = bridge.wait_for_line(PROGRESS_PREFIX, 30.0, lambda line: f'"samples": {answered},' in line)
        time.sleep(0.5)  # the last reliable messages land
        assert logger.interrupt(timeout=15) == 0, logger.output()
        assert bridge.interrupt(timeout=15) == 0, bridge.output()
    return {"mcap": path, "live": live, "progress": json.loads(line[len(PROGRESS_PREFIX):])}


def topic_counts(path: Path) -> Counter:
    """Messages per topic, read with the mcap library."""
    with path.open("rb") as stream:
        return Counter(channel.topic for _, channel, _ in make_reader(stream).iter_messages())


def info_blocks(text: str) -> dict[str, dict[str, str]]:
    """``--info`` output after its topic list: block title -> {key: value} of its indented lines."""
    blocks, current = {}, None
    for line in text.splitlines():
        if line.startswith(("Generator", "Verdicts")) and line.endswith(":"):
            current = blocks.setdefault(line[:-1], {})
        elif current is not None and line.startswith("  "):
            key, _, value = line.strip().partition(": ")
            current[key] = value
        else:
            current = None
    return blocks


def test_info_prints_one_block_per_generator_with_its_samples_trust_and_verdicts(network_run, kundur, offline):
    result = subprocess.run([str(NNI_REPLAY), str(network_run["mcap"]), "--info"], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0 and result.stderr == "", result.stderr
    blocks = info_blocks(result.stdout)
    counts = topic_counts(network_run["mcap"])
    expected = assess_network(offline)[0]
    system = blocks[f"Verdicts of the network ({CASE}, {offline.t_s.size} instants every generator reported)"]
    assert system["in_synchronism"] == json.dumps(expected.in_synchronism) == "true"
    assert system["stable"] == json.dumps(expected.stable)
    assert float(system["max_angle_spread_rad"]) == pytest.approx(expected.max_angle_spread_rad, abs=1e-9)
    for i, ns in enumerate(NAMESPACES):
        block = blocks[f"Generator {ns} (machine {kundur.names[i]})"]
        assert block["samples"] == (f"{counts[ns + '/plant/state']} plant states, "
                                    f"{counts[ns + '/controller/state']} answered by the controller")
        assert counts[ns + "/plant/state"] == offline.t_s.size
        assert block["battery limit b"] == f"{B:g} pu"
        peak = np.max(np.abs(offline.battery_power_pu[:, i, 0])) * kundur.base_mva / kundur.mbase_mva[i]
        assert float(block["max|P_ST|"].split()[0]) == pytest.approx(peak, rel=1e-5) and peak > 0.05
        trust = dict(item.rsplit(" ", 1) for item in block["trust (plant diagnostics, last status)"].split(", "))
        assert trust["foreign_commands"] == trust["unsolicited_commands"] == trust["writer_alarms"] == "0"
        assert trust["deadline_misses"] == "0" and "clipped_commands" in trust
        verdicts = blocks[f"Verdicts of {ns}"]
        assert verdicts["name"] == json.dumps(kundur.names[i])
        assert verdicts["in_synchronism"] == json.dumps(expected.generators[i].in_synchronism)
        assert float(verdicts["max_abs_battery_power_pu"]) == pytest.approx(peak, abs=1e-9)


def check_network_rrd(path: Path, counts: Counter, kundur, offline) -> None:
    """Every generator's entities, one row per sample its controller answered, angles relative to the COI."""
    entities = read_entities(path)
    colours = set()
    coi = offline.coi_angles()[:, :, 0]
    for i, ns in enumerate(NAMESPACES):
        gen = ns[1:]
        answered = counts[ns + "/controller/state"]
        assert answered == offline.t_s.size - 1  # the last state answers no sample
        for entity in (f"/angle_coi/{gen}", f"/frequency_deviation/{gen}", f"/battery/{gen}/power",
                       f"/saturation/{gen}"):
            t, values = scalars(entities[entity])
            assert t.size == answered, entity
        t, angle = scalars(entities[f"/angle_coi/{gen}"])
        np.testing.assert_allclose(t, offline.t_s[:-1], rtol=0, atol=1e-9)
        np.testing.assert_allclose(angle, coi[:-1, i], rtol=0, atol=1e-12)
        _, frequency = scalars(entities[f"/frequency_deviation/{gen}"])
        np.testing.assert_allclose(frequency, offline.speed_rad_s[:-1, i, 0] / (2 * math.pi), rtol=0, atol=1e-12)
        for limit, sign in (("limit_upper", 1.0), ("limit_lower", -1.0)):
            _, values = scalars(entities[f"/battery/{gen}/{limit}"])
            assert np.all(values == sign * B)
        _, power = scalars(entities[f"/battery/{gen}/power"])
        assert np.all(np.abs(power) <= B + 1e-12) and np.any(np.abs(power) > 0.5 * B)
        names = static_value(entities[f"/angle_coi/{gen}"], "SeriesLines:names")
        assert names == [f"δ-δ_COI (rad) {gen}"]
        colours.add(static_value(entities[f"/angle_coi/{gen}"], "SeriesLines:colors")[0])
        assert f"/angle_deviation/{gen}" not in entities and not any(e.startswith("/phase_portrait") for e in entities)
    assert len(colours) == len(NAMESPACES), "one colour per generator"


def test_replay_to_rrd_shows_every_generator_relative_to_the_centre_of_inertia(network_run, kundur, offline, tmp_path):
    out = tmp_path / "network.rrd"
    result = subprocess.run([str(NNI_REPLAY), str(network_run["mcap"]), "--rrd", str(out)], capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0 and result.stderr == "", result.stderr
    assert result.stdout.strip() == f"nni-replay: wrote {out} (4 generator run(s))"
    check_network_rrd(out, topic_counts(network_run["mcap"]), kundur, offline)


def test_the_live_bridge_with_namespaces_shows_every_generator_as_the_replay_does(network_run, kundur, offline):
    counts = topic_counts(network_run["mcap"])
    progress = network_run["progress"]
    assert progress["generators"] == {ns: counts[ns + "/controller/state"] for ns in NAMESPACES}
    assert progress["label"] == CASE and progress["first_t_s"] == 0.0
    check_network_rrd(network_run["live"], counts, kundur, offline)


WEIGHTS = [1.0, 2.0, 3.0, 4.0]


@pytest.mark.parametrize("params, expected", [
    ({"namespaces": NAMESPACES, "coi_weights": WEIGHTS},
     "namespaces needs case (the view's label) and coi_weights (the machines' inertias weigh the centre of inertia)"),
    ({"namespaces": NAMESPACES, "case": CASE},
     "namespaces needs case (the view's label) and coi_weights (the machines' inertias weigh the centre of inertia)"),
    ({"case": CASE}, "case needs namespaces (the generators to show)"),
    ({"coi_weights": WEIGHTS}, "coi_weights needs namespaces (the generators to show)"),
    ({"namespaces": ["/gen1", "/gen3"], "case": CASE, "coi_weights": [1.0, 2.0]},
     "namespaces are ['/gen1', '/gen2'] ... in case order (the network plant's), got ['/gen1', '/gen3']"),
    ({"namespaces": NAMESPACES, "case": CASE, "coi_weights": [1.0, 2.0]}, "coi_weights has 2 values for 4 namespaces"),
    ({"namespaces": NAMESPACES, "case": CASE, "coi_weights": [1.0, 2.0, -3.0, 4.0]},
     "coi_weights must be positive and finite, got [1.0, 2.0, -3.0, 4.0]"),
])
def test_the_bridge_refuses_namespaces_it_cannot_show_with_one_line(tmp_path, params, expected):
    with node_processes(tmp_path, fresh_domain_id()) as start:
        bridge = start("bridge", BRIDGE, {"sink": "save", "path": str(tmp_path / "x.rrd"), **params})
        assert bridge.wait(timeout=60.0) == 2
        output = bridge.output()
    # The node's own output is the one line (Fast DDS may add its own shared-memory notices on a shared machine).
    assert [line for line in output.splitlines() if "rerun_bridge" in line] == [f"rerun_bridge: error: {expected}"]
    assert "Traceback" not in output
    assert not (tmp_path / "x.rrd").exists()
