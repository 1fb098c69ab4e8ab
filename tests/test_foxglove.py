"""nni-demo --foxglove, tried as a Foxglove user's client would (issue 34).

An independent WebSocket client (tests/foxglove_client.py: the ``websockets`` package and the protocol's
published spec, none of the project's code) connects to a running demo, subscribes to the measurements and
the battery commands, decodes the CDR with ``rosbags`` from the schemas the server advertised (an empty
typestore: nothing but what the stream says), and compares with the recording the demo wrote. A second
client sends what a broken or hostile one would; the loop must not notice.
"""

from __future__ import annotations

import asyncio
import json
import re
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from foxglove_client import misbehave, record
from rosproc import busy_processes, fresh_domain_id, ros_env

pytestmark = pytest.mark.ros

DEMO = Path(sys.executable).parent / "nni-demo"
LAYOUTS = Path(__file__).resolve().parent.parent / "docs" / "foxglove"
#: The panel types the layouts use, and the settings each may have with their types (Foxglove's Plot,
#: Diagnostics summary and Raw Messages panels, as their documentation describes them).
PANEL_SETTINGS = {
    "Plot": {"title": str, "paths": list, "showLegend": bool, "legendDisplay": str, "showXAxisLabels": bool,
             "showYAxisLabels": bool, "isSynced": bool, "xAxisVal": str, "xAxisPath": dict},
    "DiagnosticSummary": {"topicToRender": str, "pinnedIds": list, "hardwareIdFilter": str, "sortByLevel": bool},
    "RawMessages": {"topicPath": str, "diffEnabled": bool, "diffMethod": str, "diffTopicPath": str,
                    "showFullMessageForDiff": bool},
}
_STEP = re.compile(r"\.(@negative|[A-Za-z_]\w*)|\[(\d+|:)\]")
SMIB_TOPICS = {"/pmu": "sensor_msgs/msg/JointState", "/battery/command": "sensor_msgs/msg/JointState",
               "/plant/state": "sensor_msgs/msg/JointState", "/controller/state": "sensor_msgs/msg/JointState",
               "/plant/invariant_set": "geometry_msgs/msg/PolygonStamped",
               "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray"}


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def recorded(path: Path, topic: str) -> list[bytes]:
    """The CDR bytes of ``topic`` in the recording, in log order."""
    with path.open("rb") as stream:
        return [message.data for _, _, message in make_reader(stream).iter_messages(topics=[topic])]


def stream_typestore(channels: dict):
    """A typestore knowing only the types the server advertised (their ros2msg schemas)."""
    store = get_typestore(Stores.EMPTY)
    for channel in channels.values():
        if channel["schemaEncoding"] == "ros2msg":
            store.register(get_types_from_msg(channel["schema"], channel["schemaName"]))
    return store


def check_layout_reads(layout: dict, recording: Path) -> int:
    """Every message path of ``layout`` resolves to numbers (or, for a topic alone, a topic) in the first
    message of its topic in ``recording``, decoded with rosbags' Jazzy types; returns how many were checked."""
    with recording.open("rb") as stream:
        summary = make_reader(stream).get_summary()
        types = {channel.topic: summary.schemas[channel.schema_id].name for channel in summary.channels.values()}
    store = get_typestore(Stores.ROS2_JAZZY)
    paths = [path for path in layout_paths(layout) if path != "/nni/run"]  # the live label, not recorded
    for path in paths:
        topic = max((t for t in types if path == t or path.startswith(t + ".")), key=len, default=None)
        assert topic is not None, f"{path}: no such topic in {recording.name}"
        rest = path[len(topic):]
        assert "".join(m.group(0) for m in _STEP.finditer(rest)) == rest, f"{path}: not a message path"
        values = [store.deserialize_cdr(recorded(recording, topic)[0], types[topic])]
        for field, index in (m.groups() for m in _STEP.finditer(rest)):
            if field == "@negative":
                values = [-v for v in values]
            elif field:
                values = [getattr(v, field) for v in values]
            elif index == ":":
                values = [item for v in values for item in v]
            else:
                assert all(int(index) < len(v) for v in values), f"{path}: index out of range"
                values = [v[int(index)] for v in values]
        if rest:
            assert values and all(isinstance(v, float) for v in values), (path, values[:3])
    return len(paths)


def layout_paths(layout: dict) -> list[str]:
    """The message paths a layout's panels read (series, x paths, topics), read from the JSON as Foxglove would."""
    found = []
    for config in layout["configById"].values():
        found += [series["value"] for series in config.get("paths", [])]
        found += [config["xAxisPath"]["value"]] if "xAxisPath" in config else []
        found += [config[key] for key in ("topicToRender", "topicPath") if key in config]
    return found


def start_demo(args: list[str], out: Path, domain: int) -> subprocess.Popen:
    return subprocess.Popen([str(DEMO), *args, "--out", str(out), "--domain-id", str(domain)], env=ros_env(domain),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def is_slice(received: list[bytes], recording: list[bytes]) -> bool:
    """Whether ``received`` is a contiguous run of ``recording`` (a client that joined late misses the start)."""
    if not received or len(received) > len(recording):
        return False
    start = recording.index(received[0]) if received[0] in recording else -1
    return start >= 0 and recording[start:start + len(received)] == received


def is_subsequence(received: list[bytes], recording: list[bytes]) -> bool:
    """Whether ``received`` appears in ``recording`` in order (a slow client may lose some, never reorder)."""
    remaining = iter(recording)
    return bool(received) and all(any(item == other for other in remaining) for item in received)


def test_a_client_sees_the_smib_run_live_as_recorded_and_a_hostile_one_disturbs_nothing(tmp_path):
    domain, port = fresh_domain_id(), free_port()
    url = f"ws://127.0.0.1:{port}"

    async def clients():
        good = asyncio.create_task(record(url, {"/pmu", "/battery/command", "/nni/run", "/nni/verdict"}, 120.0))
        await asyncio.sleep(1.0)
        bad = await misbehave(url)
        return await good, bad

    with busy_processes(2):
        demo = start_demo(["--foxglove", f"127.0.0.1:{port}", "--mode", "realtime", "--b", "0.3",
                           "--duration", "4"], tmp_path, domain)
        try:
            seen, hostile = asyncio.run(clients())
            out, err = demo.communicate(timeout=120)
        finally:
            demo.kill()
    assert demo.returncode == 0, err
    assert f"Foxglove: {url} " in out and "b = 0.3   in sync" in out, out
    # What Foxglove's panels need: every loop topic as CDR with its ROS 2 schema, and which run is on.
    channels = seen["channels"]
    assert {topic: (channels[topic]["encoding"], channels[topic]["schemaEncoding"], channels[topic]["schemaName"])
            for topic in SMIB_TOPICS} == {topic: ("cdr", "ros2msg", name) for topic, name in SMIB_TOPICS.items()}
    label = json.loads(seen["messages"]["/nni/run"][0][1])
    assert (label["run"], label["b"], label["law"], label["mode"]) == (1, 0.3, "nni", "realtime"), label
    # The stream ends with the verdict the demo printed, on its channel and in the last label.
    (verdict,) = [json.loads(data) for _, data in seen["messages"]["/nni/verdict"]]
    assert (verdict["run"], verdict["b"], verdict["in_synchronism"], verdict["compromised"]) == (1, 0.3, True, False)
    assert f"b = 0.3   {verdict['verdict']}" in out, (verdict, out)
    assert json.loads(seen["messages"]["/nni/run"][-1][1])["verdict"] == verdict["verdict"]
    store = stream_typestore(channels)
    recording = tmp_path / "paper_b0.3.mcap"
    summary = json.loads((tmp_path / "summary.json").read_text())["scenarios"][0]
    # Beside two busy processes a realtime plant may skip a reporting instant; it says how many.
    sent = 200 - summary["skipped_reports"]
    assert sent >= 190, summary
    for topic in ("/pmu", "/battery/command"):
        got = [data for _, data in seen["messages"][topic]]
        kept = recorded(recording, topic)
        assert len(kept) == sent and len(got) >= 180, (topic, len(got), len(kept), sent)
        assert is_slice(got, kept), topic
        first, same = (store.deserialize_cdr(data, "sensor_msgs/msg/JointState") for data in (got[0], kept[kept.index(got[0])]))
        assert list(first.position) == list(same.position) and first.name == same.name
        assert (first.header.stamp.sec, first.header.stamp.nanosec) == (same.header.stamp.sec, same.header.stamp.nanosec)
    # The hostile client: each bad message answered with an error status, the oversized frame ends its connection.
    statuses = [answer["message"] for answer in hostile if isinstance(answer, dict) and answer.get("op") == "status"
                and answer["level"] == 2]
    assert any("Invalid message" in text for text in statuses), hostile
    assert any("Unknown channel ID: 987654321" in text for text in statuses), hostile
    assert hostile[-1][0] == "closed", hostile
    assert summary["samples"] == 200 and summary["max_abs_battery_power_pu"] <= 0.3
    # The shipped layout reads this recording's topics and fields by name.
    assert check_layout_reads(json.loads((LAYOUTS / "nni_smib.json").read_text()), recording) == 14


def test_a_client_sees_every_run_of_a_composed_network_live(tmp_path):
    """Kundur's case, composed controllers, two runs in lockstep held by --foxglove-wait: the client reconnects
    per run (as Foxglove does), each run waits for it, and each run's measurements and commands of every generator
    reach it in the recording's order. (Without the hold a lockstep run is over before a loaded client has
    subscribed: CI once saw no /gen1/pmu message at all.)"""
    domain, port = fresh_domain_id(), free_port()
    url = f"ws://127.0.0.1:{port}"
    topics = {f"/gen{k}/{name}" for k in range(1, 5) for name in ("pmu", "battery/command")}
    own = {"/nni/run", "/nni/verdict"}  # the bridge's channels, not the loop's

    async def two_runs():
        return [await record(url, topics | own, 120.0) for _ in range(2)]

    with busy_processes(2):
        demo = start_demo(["--case", "kundur_two_area", "--deployment", "composed", "--mode", "lockstep",
                           "--b", "0", "0.3", "--duration", "2", "--foxglove", f"127.0.0.1:{port}",
                           "--foxglove-wait"], tmp_path, domain)
        try:
            runs = asyncio.run(two_runs())
            out, err = demo.communicate(timeout=240)
        finally:
            demo.kill()
    assert demo.returncode == 0, err
    assert all(f"run {index} waits for a Foxglove client at {url} to subscribe" in out for index in (1, 2)), out
    for index, (seen, b) in enumerate(zip(runs, ("0", "0.3")), start=1):
        label = json.loads(seen["messages"]["/nni/run"][0][1])
        assert (label["run"], label["case"], label["deployment"], label["b"]) == (index, "kundur_two_area",
                                                                                  "composed", float(b)), label
        (verdict,) = [json.loads(data) for _, data in seen["messages"]["/nni/verdict"]]
        assert (verdict["run"], verdict["case"], verdict["compromised"]) == (index, "kundur_two_area", False)
        assert f"reference pmu: {verdict['verdict']} (max angle spread" in out, (verdict, out)
        recording = tmp_path / f"kundur_two_area_bus_fault_b{b}.mcap"
        for topic in topics:
            got = [data for _, data in seen["messages"].get(topic, [])]
            assert is_subsequence(got, recorded(recording, topic)), (b, topic, len(got))
        bridge = (tmp_path / "logs" / recording.stem / "foxglove_bridge.log").read_text()
        counts = json.loads(bridge.split("foxglove_bridge counts: ", 1)[1].splitlines()[0])
        assert counts["foreign"] == {}
        assert all(counts["counts"][topic] == len(recorded(recording, topic)) for topic in topics)
    assert check_layout_reads(json.loads((LAYOUTS / "nni_kundur_two_area.json").read_text()), recording) == 28


@pytest.mark.parametrize("address, expected", [
    ("nohost:abc", "a Foxglove server address is [HOST:]PORT"),
    ("127.0.0.1:70000", "a Foxglove server address is [HOST:]PORT"),
    ("0", "needs a port a client can be told"),
])
@pytest.mark.parametrize("case", [[], ["--case", "kundur_two_area"]], ids=["smib", "network"])
def test_a_bad_foxglove_address_is_one_line_and_starts_nothing(tmp_path, address, expected, case):
    out = tmp_path / "out"
    done = subprocess.run([str(DEMO), *case, "--foxglove", address, "--out", str(out)], env=ros_env(fresh_domain_id()),
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and done.stdout == ""
    assert len(done.stderr.splitlines()) == 1 and expected in done.stderr, done.stderr
    assert not out.exists()


@pytest.mark.parametrize("case", [[], ["--case", "kundur_two_area"]], ids=["smib", "network"])
def test_foxglove_wait_without_foxglove_is_refused_in_one_line(tmp_path, case):
    out = tmp_path / "out"
    done = subprocess.run([str(DEMO), *case, "--foxglove-wait", "--out", str(out)], env=ros_env(fresh_domain_id()),
                          capture_output=True, text=True, timeout=60)
    assert (done.returncode, done.stdout, done.stderr.strip()) == (
        2, "", "nni-demo: error: --foxglove-wait applies only with --foxglove"), done.stderr
    assert not out.exists()


def test_a_port_in_use_stops_the_demo_with_the_bridge_s_reason(tmp_path):
    domain = fresh_domain_id()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = subprocess.run([str(DEMO), "--foxglove", f"127.0.0.1:{port}", "--b", "0.3", "--duration", "2",
                               "--out", str(tmp_path), "--domain-id", str(domain)], env=ros_env(domain),
                              capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "Address already in use" in done.stderr, done.stderr
    assert not list(tmp_path.glob("*.mcap")), "no recording of a run that did not start"


@pytest.mark.parametrize("name, generators", [("nni_smib", 0), ("nni_kundur_two_area", 4), ("nni_ieee39", 10)])
def test_the_shipped_layouts_are_what_the_layout_command_writes_and_use_known_panels_only(tmp_path, name,
                                                                                          generators):
    written = tmp_path / f"{name}.json"
    done = subprocess.run([sys.executable, "-m", "nni_msgs_adapter.viewing.foxglove_layout", "--generators",
                           str(generators), str(written)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout == f"wrote {written}\n", done.stderr
    shipped = json.loads((LAYOUTS / f"{name}.json").read_text())
    assert json.loads(written.read_text()) == shipped, "docs/foxglove is stale: rewrite it with the command"
    assert set(shipped) == {"configById", "globalVariables", "userNodes", "playbackConfig", "layout"}
    for panel_id, config in shipped["configById"].items():
        kind = panel_id.split("!")[0]
        assert kind in PANEL_SETTINGS and set(config) <= set(PANEL_SETTINGS[kind]), (panel_id, set(config))
        assert all(isinstance(config[key], PANEL_SETTINGS[kind][key]) for key in config), panel_id
        if kind == "Plot":
            assert config["xAxisVal"] in ("timestamp", "custom") and ("xAxisPath" in config) == (
                config["xAxisVal"] == "custom"), panel_id
            assert config["paths"] and all(set(series) == {"value", "enabled", "timestampMethod", "label"}
                                           and series["timestampMethod"] in ("receiveTime", "headerStamp")
                                           for series in config["paths"]), panel_id

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(shipped["layout"])) == sorted(shipped["configById"]), "each panel placed once"
    per_generator = {path.split("/")[1] for path in layout_paths(shipped) if path.startswith("/gen")}
    assert per_generator == {f"gen{k}" for k in range(1, generators + 1)}


@pytest.mark.parametrize("args, message", [(["--generators", "-1", "x.json"], "--generators must be 0"),
                                           (["/no/such/folder/x.json"], "output folder /no/such/folder does not exist")])
def test_the_layout_command_refuses_bad_input_in_one_line(tmp_path, args, message):
    done = subprocess.run([sys.executable, "-m", "nni_msgs_adapter.viewing.foxglove_layout", *args], cwd=tmp_path,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and len(done.stderr.splitlines()) == 1 and message in done.stderr, done.stderr
    assert list(tmp_path.iterdir()) == []
