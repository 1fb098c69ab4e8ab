"""SROS2 (issue 11): the keystore script and what the nodes do when security is requested.

sros2 and a Fast DDS with the DDS Security plugins are not installable here, so
the test checks what can be checked with openssl and the ROS we have: the
files ``scripts/sros2_keystore`` writes have SROS2's layout, the certificates
verify against the identity CA (and not against the permissions CA), the
governance and permissions documents are S/MIME signed by the permissions CA
over exactly their XML, and the grants say that only the controller publishes
``battery/command`` and only the plant publishes the measurements and the
clock, in any namespace. A real node started with ``ROS_SECURITY_ENABLE=true``
on that keystore finds its enclave, then stops with one line (this Fast DDS
cannot do DDS Security) instead of a traceback.
"""

from __future__ import annotations

import fnmatch
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from rosproc import fresh_domain_id, ros_env

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "sros2_keystore"
NODES = ("plant", "controller", "mcap_logger", "rerun_bridge", "c37118_client", "foxglove_bridge")
ENCLAVE_FILES = {"key.pem", "cert.pem", "identity_ca.cert.pem", "permissions_ca.cert.pem", "governance.p7s",
                 "permissions.p7s", "permissions.xml"}
DOMAIN = 42


def openssl(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["openssl", *args], capture_output=True, text=True, timeout=30)


@pytest.fixture(scope="module")
def keystore(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("sros2") / "keystore"
    done = subprocess.run([str(SCRIPT), str(path), "--domain", str(DOMAIN)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stderr == "" and done.stdout.startswith(f"wrote {path}: enclaves /nni/plant"), done
    return path


def enclave(keystore: Path, node: str) -> Path:
    return keystore / "enclaves" / "nni" / node


def test_the_keystore_has_sros2s_layout(keystore):
    assert {p.name for p in (keystore / "public").iterdir()} == {"identity_ca.cert.pem", "permissions_ca.cert.pem"}
    assert {p.name for p in (keystore / "private").iterdir()} == {"identity_ca.key.pem", "permissions_ca.key.pem"}
    assert {p.name for p in (keystore / "enclaves").iterdir()} == {"governance.xml", "governance.p7s", "nni"}
    assert {p.name for p in (keystore / "enclaves" / "nni").iterdir()} == set(NODES)
    for node in NODES:
        folder = enclave(keystore, node)
        assert {p.name for p in folder.iterdir()} == ENCLAVE_FILES
        for name, target in (("identity_ca.cert.pem", keystore / "public" / "identity_ca.cert.pem"),
                             ("permissions_ca.cert.pem", keystore / "public" / "permissions_ca.cert.pem"),
                             ("governance.p7s", keystore / "enclaves" / "governance.p7s")):
            assert (folder / name).is_symlink() and (folder / name).resolve() == target.resolve()
    assert not any(p.name.startswith(".sros2_keystore") for p in keystore.parent.iterdir())


@pytest.mark.parametrize("node", NODES)
def test_each_enclave_certificate_is_issued_by_the_identity_ca_to_its_enclave(keystore, node):
    folder = enclave(keystore, node)
    assert openssl("verify", "-CAfile", str(keystore / "public" / "identity_ca.cert.pem"),
                   str(folder / "cert.pem")).returncode == 0
    assert openssl("verify", "-CAfile", str(keystore / "public" / "permissions_ca.cert.pem"),
                   str(folder / "cert.pem")).returncode != 0, "identity and permissions CAs must be distinct"
    subject = openssl("x509", "-in", str(folder / "cert.pem"), "-noout", "-subject", "-nameopt", "RFC2253").stdout
    assert subject.strip() == f"subject=CN=/nni/{node}"
    text = openssl("x509", "-in", str(folder / "cert.pem"), "-noout", "-text").stdout
    assert "ASN1 OID: prime256v1" in text and "ecdsa-with-SHA256" in text and "CA:FALSE" in text
    cert_key = openssl("x509", "-in", str(folder / "cert.pem"), "-noout", "-pubkey").stdout
    own_key = openssl("pkey", "-in", str(folder / "key.pem"), "-pubout").stdout
    assert cert_key and cert_key == own_key, "key.pem is not the key of cert.pem"


@pytest.mark.parametrize("document", ["governance", *NODES])
def test_governance_and_permissions_are_signed_by_the_permissions_ca_over_their_xml(keystore, document, tmp_path):
    if document == "governance":
        signed, xml = keystore / "enclaves" / "governance.p7s", keystore / "enclaves" / "governance.xml"
    else:
        signed, xml = enclave(keystore, document) / "permissions.p7s", enclave(keystore, document) / "permissions.xml"
    content = tmp_path / "content.xml"
    done = openssl("smime", "-verify", "-in", str(signed), "-CAfile", str(keystore / "public" / "permissions_ca.cert.pem"),
                   "-text", "-out", str(content))
    assert done.returncode == 0, done.stderr
    # S/MIME text mode signs the canonical form, with CRLF line ends.
    assert content.read_bytes().replace(b"\r\n", b"\n") == xml.read_bytes()
    wrong_ca = openssl("smime", "-verify", "-in", str(signed), "-CAfile",
                       str(keystore / "public" / "identity_ca.cert.pem"), "-text", "-out", os.devnull)
    assert wrong_ca.returncode != 0
    assert signed.read_text().startswith("MIME-Version: 1.0\nContent-Type: multipart/signed;")


def grants(keystore: Path) -> dict:
    """Per enclave: the domains, default, subject and the publish / subscribe topic expressions."""
    result = {}
    for node in NODES:
        grant = ET.parse(enclave(keystore, node) / "permissions.xml").getroot().find("permissions/grant")
        rules = grant.findall("allow_rule")
        result[f"/nni/{node}"] = {
            "name": grant.get("name"), "subject": grant.findtext("subject_name"),
            "default": grant.findtext("default"), "deny_rules": grant.findall("deny_rule"),
            "domains": {rule.findtext("domains/id") for rule in rules},
            "publish": [t.text for rule in rules for t in rule.findall("publish/topics/topic")],
            "subscribe": [t.text for rule in rules for t in rule.findall("subscribe/topics/topic")],
        }
    return result


def allowed(grant_table: dict, action: str, dds_topic: str) -> set:
    """Enclaves whose grant allows ``action`` on ``dds_topic`` (DDS Security matches with fnmatch)."""
    return {name for name, grant in grant_table.items()
            if any(fnmatch.fnmatchcase(dds_topic, pattern) for pattern in grant[action])}


@pytest.mark.parametrize("namespace", ["", "/gen1"])
def test_only_the_controller_commands_the_battery_and_only_the_plant_publishes_measurements(keystore, namespace):
    table = grants(keystore)
    for name, grant in table.items():
        assert grant["name"] == name and grant["subject"] == f"CN={name}"
        assert grant["default"] == "DENY" and grant["deny_rules"] == [] and grant["domains"] == {str(DOMAIN)}
    publishers = {
        "battery/command": {"/nni/controller"}, "controller/state": {"/nni/controller"},
        "pmu": {"/nni/plant"}, "plant/state": {"/nni/plant"}, "plant/invariant_set": {"/nni/plant"},
        "diagnostics": {"/nni/plant", "/nni/controller", "/nni/c37118_client"},
        # The plant's rt/*/pmu matches it too (DDS Security's fnmatch lets * cross a /): the plant is trusted.
        "c37118/pmu": {"/nni/c37118_client", "/nni/plant"},
    }
    for topic, expected in publishers.items():
        assert allowed(table, "publish", f"rt{namespace}/{topic}") == expected, topic
    assert allowed(table, "publish", "rt/clock") == {"/nni/plant"}
    recorders = {"/nni/mcap_logger", "/nni/foxglove_bridge"}  # they read every contract topic, publish none
    subscribers = {"battery/command": {"/nni/plant", *recorders}, "pmu": {"/nni/controller", *recorders},
                   "c37118/pmu": {"/nni/controller", *recorders},
                   "plant/state": {*recorders, "/nni/rerun_bridge"}}
    for topic, expected in subscribers.items():
        assert allowed(table, "subscribe", f"rt{namespace}/{topic}") == expected, topic
    # A node serves its own parameter services and nobody else's.
    assert allowed(table, "publish", f"rr{namespace}/plant/set_parametersReply") == {"/nni/plant"}
    assert allowed(table, "subscribe", f"rq{namespace}/controller/set_parametersRequest") == {"/nni/controller"}
    assert allowed(table, "publish", f"rq{namespace}/plant/set_parametersRequest") == set()
    assert allowed(table, "publish", "ros_discovery_info") == set(table)


def test_governance_protects_every_topic_on_the_domain(keystore):
    rule = ET.parse(keystore / "enclaves" / "governance.xml").getroot().find("domain_access_rules/domain_rule")
    assert rule.findtext("domains/id") == str(DOMAIN)
    assert rule.findtext("allow_unauthenticated_participants") == "false"
    assert rule.findtext("enable_join_access_control") == "true"
    topic_rule = rule.find("topic_access_rules/topic_rule")
    assert topic_rule.findtext("topic_expression") == "*"
    assert topic_rule.findtext("enable_write_access_control") == "true"
    assert topic_rule.findtext("enable_read_access_control") == "true"
    assert topic_rule.findtext("data_protection_kind") == "ENCRYPT"


@pytest.mark.parametrize("args, expected", [
    ([], "no KEYSTORE given"),
    (["KS", "--domain", "300"], "--domain must be a ROS domain id 0..232, got '300'"),
    (["KS", "--colour"], "unknown option --colour"),
    (["EXISTING"], "exists and is not an empty folder: refusing to overwrite a keystore"),
])
def test_bad_use_of_the_script_is_one_line_and_writes_nothing(tmp_path, args, expected):
    existing = tmp_path / "EXISTING"
    existing.mkdir()
    (existing / "mine.txt").write_text("keep")
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    done = subprocess.run([str(SCRIPT), *args], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.count("\n") == 1 and expected in done.stderr, done.stderr
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


def test_the_script_describes_itself_on_help():
    done = subprocess.run([str(SCRIPT), "--help"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout.startswith("usage: sros2_keystore KEYSTORE [--domain ID]")
    assert "only the controller may command the" in done.stdout


def start_secure_node(tmp_path: Path, keystore: Path, enclave_name: str, **env) -> subprocess.CompletedProcess:
    environment = ros_env(fresh_domain_id(), ROS_SECURITY_ENABLE="true", ROS_SECURITY_KEYSTORE=str(keystore), **env)
    environment.pop("ROS_SECURITY_STRATEGY", None)
    return subprocess.run([sys.executable, "-m", "nni_plant_sim.plant_node", "--ros-args", "--enclave", enclave_name,
                           "-p", "duration_s:=1.0"], env=environment, capture_output=True, text=True, timeout=60,
                          cwd=tmp_path)


def test_a_node_asked_for_security_on_the_pip_path_stops_with_one_line(tmp_path, keystore):
    done = start_secure_node(tmp_path, keystore, "/nni/plant")
    assert done.returncode == 2
    assert f"Found security directory: {enclave(keystore, 'plant')}" in done.stderr, "rcl did not find the enclave"
    errors = [line for line in done.stderr.splitlines() if "error" in line.lower()]
    assert errors == ["plant_node: error: DDS security requested (ROS_SECURITY_ENABLE=true) but not supported: "
                      "this Fast DDS is built without the DDS Security plugins (as the PyPI wheels are); SROS2 "
                      "needs a ROS 2 Jazzy install (README, Security)"], done.stderr
    assert "Traceback" not in done.stderr and "Warning" not in done.stderr and "plant_node summary" not in done.stdout


def test_a_missing_enclave_is_refused_not_run_insecurely(tmp_path, keystore):
    """ROS's default strategy (Permissive) would run without security; ours defaults to Enforce."""
    done = start_secure_node(tmp_path, keystore, "/nni/no_such_node")
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines() == [
        "plant_node: error: DDS security requested (ROS_SECURITY_ENABLE=true, ROS_SECURITY_STRATEGY=Enforce) but the "
        f"node cannot start securely: failed to initialize rcl: SECURITY ERROR: directory "
        f"'{keystore / 'enclaves' / 'nni' / 'no_such_node'}' does not exist."], done.stderr
