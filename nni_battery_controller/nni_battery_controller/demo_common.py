"""What the SMIB demo (``nni-demo``) and the network demo (``nni-demo --case``) share.

A run's key (:func:`nni_msgs_adapter.ros.command_auth.run_key`, in the plant's
and the controllers' environment only) and its start: the read-back of every
node's parameters against what was passed, then the plant's release
(:func:`start_when_read_back`); waiting for it to finish (a realtime run's progress shown on a
terminal), its final diagnostics, its clean exit; the recording's
completeness (the logger's counts against the plant's); whether a run can be
trusted (the plant's trust counters, the power applied against b) and the
words that say why not; the children's environment and ROS domain; the
summary JSON and the exit status. The Rerun viewer is
:mod:`nni_battery_controller.demo_viewer`'s. A demo creates no ROS node of its
own: its processes are started through the project's supervisor.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from pathlib import Path

import numpy as np

from nni_msgs_adapter.recording.mcap_logger import COUNTS_PREFIX
from nni_msgs_adapter.recording.runs import MATCHED_PREFIX, GeneratorRun
from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.cli_support import CliError, write_json
from nni_msgs_adapter.ros.command_auth import KEY_FILE_ENV, remove_key_file
from nni_msgs_adapter.ros.processes import ChildError
from nni_msgs_adapter.ros.readback import mismatch, stated_parameters
from nni_plant_sim.plant_node import SUMMARY_PREFIX
from nni_battery_controller.controller_core import TRUST_COUNTERS as CONTROLLER_TRUST_COUNTERS
from nni_plant_sim.reporting import COMPROMISING_KEYS

#: Seconds the logger gets after the plant ends, for the last reliable messages to land.
DRAIN_S = 0.5
#: Exit status of a call with a compromised run (the battery commanded by a stranger, or beyond b).
EXIT_COMPROMISED = 3
#: The plant's trust counters (INTERFACES.md item 1) of which any non-zero one compromises a run.
TRUST_COUNTERS = COMPROMISING_KEYS
#: Longest wait, s, for a node to state the parameters it runs with (its process starting, imports included).
READBACK_WAIT_S = 120.0


def compromised_reasons(plant_summary: dict, run: GeneratorRun, b: float) -> dict:
    """Why a run cannot be trusted (empty if it can): non-zero trust counters (the plant's, and the controller's
    in its last status recorded: inputs that were not its plant's), or |P_ST| applied above b.

    The largest power applied is the plant's own count where it reports one, and
    in any case the largest ``plant/state`` battery power in the recording.
    """
    missing = [key for key in (*TRUST_COUNTERS, "max_abs_applied_power_pu") if key not in plant_summary]
    if missing:
        raise CliError(f"the plant's final diagnostics lack {', '.join(missing)}: the run cannot be judged")
    reasons = {key: int(plant_summary[key]) for key in TRUST_COUNTERS if int(plant_summary[key])}
    reasons.update({key: int(run.controller_diagnostics[key]) for key in CONTROLLER_TRUST_COUNTERS
                    if int(run.controller_diagnostics.get(key, 0))})
    recorded = float(np.max(np.abs(run.battery_power_pu))) if run.battery_power_pu.size else 0.0
    applied = max(recorded, float(plant_summary["max_abs_applied_power_pu"]))
    if applied > b + 1e-12:
        reasons["max_abs_applied_power_pu"] = applied
    return reasons


#: How a compromised run is printed instead of its verdict.
COMPROMISED_PREFIX = "COMPROMISED (not a valid result): "


def compromised_words(b: float, reasons: dict) -> list[str]:
    """Why a run is compromised, one phrase per reason."""
    words = []
    if "max_abs_applied_power_pu" in reasons:
        words.append(f"|P_ST| {reasons['max_abs_applied_power_pu']:.4f} pu applied, above b = {b:g} pu")
    return words + [f"{reasons[key]} {key.replace('_', ' ')}" for key in (*TRUST_COUNTERS, *CONTROLLER_TRUST_COUNTERS)
                    if key in reasons]


def compromised_text(b: float, reasons: dict) -> str:
    """One line saying why a run is compromised."""
    return COMPROMISED_PREFIX + "; ".join(compromised_words(b, reasons))


def key_environment(key_file) -> dict:
    """What the plant's and the controllers' processes get beside the run's environment: the run's key file."""
    return {KEY_FILE_ENV: str(key_file)}


def stated_only(logger, client=None) -> list:
    """The read-back entries of the run's logger and C37.118 client (None: none): nothing of theirs to compare, but
    they have to have stated their parameters, so have read the run's key, before it is removed."""
    return [(logger, {"/mcap_logger": {}}), *([(client, {"/c37118_client": {}})] if client is not None else [])]


def start_when_read_back(started: list, plant, logs: Path, key_file=None) -> None:
    """Release the ``plant`` (SIGUSR1: it holds its run) once every child of ``started`` (``(child, {node:
    expected parameters})``) has stated them; CliError (one line: nothing runs) if one states others, exits or
    says nothing within READBACK_WAIT_S.

    ``key_file``: the run's key, removed before the release: every node that states its parameters has read it
    at start, so that not even a demo killed mid-run (SIGKILL) leaves it behind."""
    deadline = time.monotonic() + READBACK_WAIT_S
    for child, passed in started:
        while True:
            stated = stated_parameters(child.output())
            wrong = mismatch(passed, stated)
            if wrong is not None:
                raise CliError(f"not started: {wrong} (logs in {logs})")
            if set(passed) <= set(stated):
                break
            if child.poll() is not None:
                raise CliError(f"the {child.name} {child.how_it_ended()} before stating its parameters: "
                               f"{child.tail()}")
            if time.monotonic() > deadline:
                raise CliError(f"the {child.name} did not state its parameters within {READBACK_WAIT_S:g} s "
                               f"(logs in {logs})")
            time.sleep(0.05)
    if key_file is not None:
        remove_key_file(key_file)
    plant.proc.send_signal(signal.SIGUSR1)


def plant_summary(output: str, prefix: str = SUMMARY_PREFIX) -> dict:
    """The final diagnostics values the plant printed at exit (the line starting with ``prefix``)."""
    for line in output.splitlines():
        if line.startswith(prefix):
            return json.loads(line[len(prefix):])
    raise CliError("the plant did not report its final diagnostics")


def wait_for_plant(plant, args, label: str, limit_s: float, prefix: str = SUMMARY_PREFIX, watch=None) -> None:
    """Wait for the plant's final summary line (``prefix``); on a terminal, show a realtime run's progress.

    ``watch`` (a :class:`.demo_pmu.StreamWatch`): its C37.118 stream's events printed as they come.
    """
    show = args.mode == "realtime" and sys.stderr.isatty()
    deadline, started, shown = time.monotonic() + limit_s, None, ""
    while prefix not in plant.output():
        if plant.poll() is not None:
            return
        if time.monotonic() > deadline:
            raise CliError(f"the plant did not finish within {limit_s:.0f} s (logs in {plant.log_path.parent})")
        events = watch.follow() if watch is not None else []
        if events:
            if shown:  # the progress line is redrawn below the events
                print("\r\033[K", end="", file=sys.stderr, flush=True)
                shown = ""
            print("\n".join(events), flush=True)
        if show:
            if started is None and "started in" in plant.output():
                started = time.monotonic()
            if started is not None:
                # Realtime: simulated time runs with the wall clock from the plant's start.
                elapsed_s = min(time.monotonic() - started, args.duration)
                text = f"\r  {label} t = {elapsed_s:5.1f} of {args.duration:g} s"
                if text != shown:
                    print(text, end="", file=sys.stderr, flush=True)
                    shown = text
        time.sleep(0.05)
    if show:
        print("\r\033[K", end="", file=sys.stderr, flush=True)


def finish_plant(procs, plant, args, label: str, prefix: str = SUMMARY_PREFIX, watch=None) -> None:
    """The plant's run to its end (bounded wait), its clean exit, then the drain for the recorders; else CliError.

    ``watch``: the plant's C37.118 stream, whose events are printed as they come, the last ones at its exit.
    """
    wait_for_plant(plant, args, label, run_time_limit_s(args), prefix, watch)
    try:
        status = plant.wait_exit(procs.grace_s)
    except ChildError as error:
        raise CliError(str(error)) from None
    for line in watch.follow() if watch is not None else []:
        print(line, flush=True)
    if status != 0:
        raise CliError(f"the {plant.name} {plant.how_it_ended()}: {plant.tail()}")
    time.sleep(DRAIN_S)


#: Longest wait, s, for the logger to subscribe to every controller's topics before the plant starts.
RECORDER_WAIT_S = 120.0
#: Each controller's topics the logger must record from the first sample on (the plant's it waits for itself).
CONTROLLER_TOPICS = (contract.TOPIC_BATTERY_COMMAND, contract.TOPIC_CONTROLLER_STATE)


#: What the plant writes per generator that a run's recording must hold from its first sample.
PLANT_TOPICS = (contract.TOPIC_PMU, contract.TOPIC_PLANT_STATE)


def loop_writers(spaces, controller_node, plant_node: str) -> dict:
    """``{absolute topic: the node that writes it}`` for each namespace of ``spaces`` (``[""]``: the SMIB's root):
    ``pmu`` and ``plant/state`` by ``plant_node``, the controller's topics by ``controller_node(namespace)`` (fully
    qualified names). Every one: IEEE 300's composed run once recorded 4 of 51 plant states of /gen69, the logger
    having matched its ``pmu`` writer but not yet its ``plant/state`` one when the plant was released."""
    return {"/" + "/".join(filter(None, (ns, topic))): plant_node if topic in PLANT_TOPICS else controller_node(ns)
            for ns in spaces for topic in (*PLANT_TOPICS, *CONTROLLER_TOPICS)}


def wait_for_recorder(recorder, writers: dict, logs: Path, what: str = "the logger") -> None:
    """Wait until the ``recorder`` (the MCAP logger, the Foxglove bridge: ``what``) has matched the loop's
    ``writers`` (``{topic: node}``, :func:`loop_writers`), else CliError naming those it has not.

    The plant counts its readers on each ``pmu``, and that count cannot tell a recorder from any other process
    subscribed there: under load, with a rogue reading ``/pmu`` on the domain, the plant found its two readers
    (the controller and the rogue) before the logger had matched its writer, and the logger recorded 229 of
    250 commands; earlier, with the composed deployment's one participant of many endpoints, it found /gen3's
    and /gen4's writers only after 70 samples. The recorder logs which writers each subscription has matched
    (:data:`~nni_msgs_adapter.recording.runs.MATCHED_PREFIX`); the plant's run is released only once every
    loop writer is among them (call this before :func:`start_when_read_back`).
    """
    deadline = time.monotonic() + RECORDER_WAIT_S
    while True:
        matched: dict[str, set] = {}
        for line in recorder.output().splitlines():
            if MATCHED_PREFIX in line:
                topic, _, names = line.split(MATCHED_PREFIX, 1)[1].partition(" <- ")
                matched[topic.strip()] = set(names.strip().split(", "))
        missing = sorted(f"{topic} from {node}" for topic, node in writers.items() if node not in matched.get(topic, ()))
        if not missing:
            return
        if recorder.poll() is not None:
            raise CliError(f"{what} exited before it matched every loop writer: {recorder.last_line()} "
                           f"(logs in {logs})")
        if time.monotonic() > deadline:
            raise CliError(f"{what} did not match {len(missing)} loop writer(s) within "
                           f"{RECORDER_WAIT_S:g} s ({', '.join(missing[:3])} ...; logs in {logs})")
        time.sleep(0.05)


def run_time_limit_s(args) -> float:
    """Longest wall time a plant may take for one run (start-up and discovery included)."""
    return 60.0 + (args.duration if args.mode == "realtime" else args.duration * 2)


def check_complete(recording: Path, recorded: int, sent: int, logs: Path, where: str = "",
                   what: str = "measurements the plant sent") -> None:
    """CliError unless the logger recorded every one of ``what`` (``where``: to or from which namespace)."""
    if recorded < sent:
        raise CliError(f"the recording {recording} is partial: the logger recorded {recorded} of the {sent} "
                       f"{what}{where} (logs in {logs})")


def logger_counts(output: str) -> dict:
    """The per-topic counts the logger printed at exit."""
    for line in output.splitlines():
        if line.startswith(COUNTS_PREFIX):
            return json.loads(line[len(COUNTS_PREFIX):])["counts"]
    raise CliError("the logger did not report its message counts")


def run_environment(args) -> tuple[dict, int]:
    """The children's environment and ROS domain (``--domain-id``, else $ROS_DOMAIN_ID, else 42); ``--out`` made.

    CliError for a domain outside 0..232 or an output folder that cannot be written.
    """
    domain = args.domain_id if args.domain_id is not None else int(os.environ.get("ROS_DOMAIN_ID", "42"))
    if not 0 <= domain <= 232:
        raise CliError(f"ROS domain id must be within 0..232, got {domain}")
    args.out.mkdir(parents=True, exist_ok=True)
    if not os.access(args.out, os.W_OK):
        raise CliError(f"output folder {args.out} is not writable")
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED="1")
    return env, domain


def write_summary(out: Path, content: dict) -> Path:
    """``OUT/summary.json`` (written whole or not at all); its path."""
    summary = out / "summary.json"
    write_json(summary, content)
    return summary


def exit_status(prog: str, runs: list[dict], what: str) -> int:
    """0, or EXIT_COMPROMISED with one line on stderr naming the b of the compromised runs (``what`` was not ...)."""
    compromised = [run for run in runs if "compromised" in run]
    if not compromised:
        return 0
    limits = ", ".join(str(run["b"]) for run in compromised)
    print(f"{prog}: error: {len(compromised)} of {len(runs)} run(s) compromised (b = {limits}): {what} not under "
          "its controller's command alone; see summary.json", file=sys.stderr)
    return EXIT_COMPROMISED


def battery_block(energy_pu_s: float, summary: dict) -> dict:
    """summary.json's ``battery`` of a generator whose battery holds ``energy_pu_s``: the plant's own account of it
    (its exit summary for that generator: the charge at the end, when it ran empty and full)."""
    reported = {key: summary[f"battery_{key}"] for key in ("charge_pu_s", "empty_at_s", "full_at_s")
                if f"battery_{key}" in summary}
    return {"energy_pu_s": energy_pu_s, **reported}


def battery_text(battery: dict | None) -> str:
    """``  battery empty at 1.234 s`` (or full, or neither) for a battery of finite energy; nothing without one."""
    if battery is None:
        return ""
    ends = [f"{word} at {battery[f'{word}_at_s']:.3f} s" for word in ("empty", "full") if f"{word}_at_s" in battery]
    return f"  battery {', '.join(ends) or 'never empty or full'}"
