"""More than 32 ROS processes on one host discover each other (issue 14: kundur_ring_52's 54 processes).

rmw_fastrtps (Jazzy) under ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST announces a participant to the discovery
ports of the host's first 32 participants only, so the 33rd and 34th never discover each other. A deployment
says how many it starts in NNI_DDS_PARTICIPANTS and the nodes widen the loopback profile's range to cover them
(nni_msgs_adapter.ros.node_main.select_dds_profile). Real participants: 34 rclpy Contexts in one process
(tests/many_participants.py), with two busy processes beside it; the control is the same run without the count.
"""

from __future__ import annotations

import json
import subprocess
import sys
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import pytest

from nni_msgs_adapter.ros.node_main import (
    FASTDDS_PROFILES_ENV,
    NETWORK_ENV,
    StartupError,
    network_profile,
    select_dds_profile,
)
from nni_msgs_adapter.ros.processes import PARTICIPANTS_ENV
from rosproc import busy_processes, fresh_domain_id, ros_env

pytestmark = pytest.mark.ros

HELPER = Path(__file__).with_name("many_participants.py")
COUNT = 34


def discovery(domain: int, wait_s: float, **env) -> dict:
    """The helper's report: the nodes each of COUNT participants sees, and how long it waited."""
    done = subprocess.run([sys.executable, str(HELPER), str(COUNT), str(wait_s)], env=ros_env(domain, **env),
                          capture_output=True, text=True, timeout=120 + wait_s)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_participants_beyond_the_32nd_discover_each_other_when_the_deployment_says_how_many():
    first, everyone = {f"p{i}" for i in range(32)}, {f"p{i}" for i in range(COUNT)}
    with busy_processes(2):
        widened = discovery(fresh_domain_id(), 60.0, **{PARTICIPANTS_ENV: COUNT})
        assert [set(names) for names in widened["seen"]] == [everyone] * COUNT, widened
        # The control, waiting three times as long as discovery took above: without the count, the 33rd and
        # 34th participant (p32, p33) see the first 32 and themselves, never each other.
        control = discovery(fresh_domain_id(), max(3.0, 3 * widened["waited_s"]))
    seen = [set(names) for names in control["seen"]]
    assert seen[:32] == [everyone] * 32, control
    assert seen[32] == first | {"p32"} and seen[33] == first | {"p33"}, control


def test_the_widened_profile_is_the_loopback_profile_with_a_wider_range_only(tmp_path):
    environ = {PARTICIPANTS_ENV: "54"}
    assert select_dds_profile(environ) is None
    widened = Path(environ[FASTDDS_PROFILES_ENV])
    assert widened.parent.stat().st_mode & 0o777 == 0o700, "a folder no other local user can write to"
    namespace = "{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}"

    def without_range(path):
        root = ElementTree.parse(path).getroot()
        ranges = [(parent, child) for parent in root.iter() for child in parent
                  if child.tag == f"{namespace}maxInitialPeersRange"]
        for parent, child in ranges:
            parent.remove(child)
        return [ElementTree.tostring(element) for element in root], [child.text for _, child in ranges]

    shipped, shipped_ranges = without_range(network_profile("loopback"))
    copy, copy_ranges = without_range(widened)
    assert shipped_ranges == [] and copy_ranges == ["64"]
    assert copy == shipped, "the whitelist (127.0.0.1), the transports, lease and publisher settings as shipped"
    for count in ("", "0", "32"):
        environ = {PARTICIPANTS_ENV: count} if count else {}
        select_dds_profile(environ)
        assert environ[FASTDDS_PROFILES_ENV] == str(network_profile("loopback")), count


@pytest.mark.parametrize("env, message", [
    ({PARTICIPANTS_ENV: "many"}, "NNI_DDS_PARTICIPANTS must be a count of processes, 0 to 120"),
    ({PARTICIPANTS_ENV: "121"}, "NNI_DDS_PARTICIPANTS must be a count of processes, 0 to 120"),
    ({PARTICIPANTS_ENV: "40", NETWORK_ENV: "multihost"},
     "NNI_DDS_PARTICIPANTS=40: more than 32 participants on a host are discovered with the loopback profile only"),
    ({PARTICIPANTS_ENV: "40", FASTDDS_PROFILES_ENV: "/etc/my_profile.xml"},
     "NNI_DDS_PARTICIPANTS=40 needs the loopback profile with a wider discovery range, but "
     "FASTRTPS_DEFAULT_PROFILES_FILE=/etc/my_profile.xml is set"),
])
def test_a_count_that_cannot_be_honoured_stops_a_node_with_one_line(tmp_path, env, message):
    with pytest.raises(StartupError, match=message):
        select_dds_profile(dict(env))
    done = subprocess.run([sys.executable, "-m", "nni_plant_sim.plant_node"], env=ros_env(fresh_domain_id(), **env),
                          capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert done.returncode == 2 and done.stdout == "", done
    assert done.stderr.count("\n") == 1 and message in done.stderr, done.stderr
