"""The read-back (nni_msgs_adapter.ros.readback): what nodes state at start against what their starter passed."""

from __future__ import annotations

import math

from nni_msgs_adapter.ros.readback import ReadbackGate, mismatch, parameters_line, stated_parameters


def test_a_stated_line_reads_back_and_a_partial_or_foreign_one_does_not():
    line = parameters_line("plant_node", "/plant", {"battery_rating_pu": 0.3, "mode": "lockstep"})
    output = f"[INFO] starting\n{line}\nplant_node parameters: {{\"node\": \"/x\", \"parameters\""
    assert stated_parameters(output) == {"/plant": {"battery_rating_pu": 0.3, "mode": "lockstep"}}
    assert stated_parameters("[INFO] [plant]: the parameters: {} were\n") == {}


def test_values_compare_as_parameters_and_a_difference_is_named():
    stated = {"/controller": {"battery_limit_pu": 0.3, "gain_k": 1.0, "coi": [1.0, math.nan], "on": True}}
    assert mismatch({"/controller": {"gain_k": 1, "coi": [1.0, math.nan], "on": True}}, stated) is None
    assert mismatch({"/controller": {"battery_limit_pu": 100.0}}, stated) == (
        "/controller runs with other parameters than it was given (battery_limit_pu: passed 100.0, runs with 0.3)")
    assert "tau_s: passed 0.1, not declared" in mismatch({"/controller": {"tau_s": 0.1}}, stated)
    assert mismatch({"/controller": {"on": 1}}, stated) is not None  # a bool is not a number
    assert mismatch({"/gen1/controller": {"gain_k": 2.0}}, stated) is None  # not stated yet: not judged


def test_the_gate_releases_once_every_node_stated_what_it_was_given():
    passed = {"/plant": {"mode": "lockstep"}, "/controller": {"gain_k": 1.0}}
    gate = ReadbackGate(passed)
    assert gate.feed("plant", parameters_line("plant_node", "/plant", {"mode": "lockstep"})[:20]) is None
    assert gate.feed("plant", parameters_line("plant_node", "/plant", {"mode": "lockstep"})[20:] + "\n") is None
    assert gate.feed("controller", parameters_line("controller_node", "/controller", {"gain_k": 1.0}) + "\n") \
        == ReadbackGate.RELEASE
    assert gate.feed("controller", "anything\n") is None  # decided once
    wrong = ReadbackGate(passed)
    assert wrong.feed("controller", parameters_line("controller_node", "/controller", {"gain_k": 9.0}) + "\n") \
        .startswith("/controller runs with other parameters")
