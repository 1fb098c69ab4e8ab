"""``nni-replay --info``: what a recording holds, the run's parameters and its verdicts (no ROS graph, no Rerun).

::

    nni-replay run.mcap --info            # what `ros2 bag info` shows, the run's parameters, its verdicts

``--info`` prints the file, its size, ROS distro, duration, start and end, message count,
each topic's type, count, serialization format and QoS, whether the file is complete, the
run's parameters key by key and, per generator, one block (its samples, b, the largest
battery power applied, the trust counters of the plant's last ``gen<i>/plant`` status) followed by
the verdicts of :func:`nni_battery_controller.verdicts.assess` key by key; for a network run (the
parameters name its ``case``) the verdicts of :func:`nni_battery_controller.network_sim.assess_network`,
the system's first, then each generator's. Verdicts need the run's parameters (the
plant's equilibrium and the controller's limit): a recording without them is described
without verdicts. A recording cut short is described up to its last flush, and says so.
"""

from __future__ import annotations

import datetime
import math

import numpy as np

from nni_msgs_adapter.recording.mcap_io import Recording, parse_qos_profiles_yaml
from nni_msgs_adapter.recording.network_runs import CASE_KEY, namespace_order
from nni_battery_controller.replay_load import load, readable_runs, recorded_network, recorded_scenario, trajectories
from nni_msgs_adapter.recording.runs import FOREIGN_PREFIX, GeneratorRun, foreign_counts, run_metadata
from nni_battery_controller.controller_core import TRUST_COUNTERS as CONTROLLER_TRUST_COUNTERS

#: Diagnostics keys of the plant's status that count what it did not trust or could not do, in this order.
TRUST_COUNTERS = ("unauthenticated_commands", "replayed_commands", "foreign_commands", "unsolicited_commands", "expired_commands", "invalid_commands",
                  "clipped_commands", "writer_alarms", "stand_down_commands", "re_pairings", "deadline_misses",
                  "command_timeouts")


def describe(args) -> int:
    """``--info``: print what the recording holds (complete or not: it says which)."""
    recording = load(args, whole=False)
    runs = readable_runs(recording)
    print("\n".join(info_lines(recording, runs, run_metadata(recording))))
    return 0


def info_lines(recording: Recording, runs: dict[str, GeneratorRun], parameters: dict | None) -> list[str]:
    """What ``--info`` prints: ``ros2 bag info``'s fields, completeness, parameters, verdicts."""
    from nni_msgs_adapter.recording.mcap_io import describe_qos

    from nni_battery_controller.verdicts import assess

    messages = recording.messages
    first, last = messages[0].log_time_ns, messages[-1].log_time_ns
    rosbag2 = recording.metadata.get("rosbag2", {})
    topics: dict[str, list] = {}
    for record in messages:
        topics.setdefault(record.topic, [record.type_name, 0, record.qos_yaml])[1] += 1
    size = recording.path.stat().st_size
    lines = [
        f"Files:             {recording.path.name}",
        f"Bag size:          {size / 1024:.1f} KiB",
        "Storage id:        mcap",
        f"ROS Distro:        {rosbag2.get('ROS_DISTRO', 'unknown')}",
        f"Duration:          {(last - first) * 1e-9:.9f}s",
        f"Start:             {_time_text(first)}",
        f"End:               {_time_text(last)}",
        f"Messages:          {len(messages)}",
    ]
    for index, (topic, (type_name, count, qos_yaml)) in enumerate(sorted(topics.items())):
        qos = "; ".join(describe_qos(profile) for profile in parse_qos_profiles_yaml(qos_yaml)) or "not recorded"
        lines.append(f"{'Topic information: ' if index == 0 else ' ' * 19}Topic: {topic} | Type: {type_name} | "
                     f"Count: {count} | Serialization Format: cdr | QoS: {qos}")
    lines.append(f"Complete:          {'yes' if recording.complete else 'no: ' + recording.incompleteness()}")
    foreign = foreign_counts(recording)
    lines.append("Foreign messages:  " + (", ".join(f"{topic} {count}" for topic, count in sorted(foreign.items()))
                                          + f" (not sealed by the run's nodes: recorded apart on {FOREIGN_PREFIX}, "
                                            "never read as the loop's)" if foreign else "none"))
    if parameters is not None:
        lines.append(f"Law:               {law_text(parameters)}")
    if parameters is None:
        lines.append("Run parameters:    not recorded (no nni_run metadata): no verdicts")
        verdicts = {}
    else:
        lines.append("Run parameters:")
        lines += [f"  {key}: {json_text(value)}" for key, value in parameters.items()]
        network = recorded_network(recording, runs, parameters)
        if network is None:
            scenario, _ = recorded_scenario(parameters, recording.path)
            verdicts = {namespace: assess(traj, scenario=scenario).to_json()
                        for namespace, traj in trajectories(recording, runs, parameters).items()}
        else:
            verdicts = network_verdicts(network)
            lines.append(f"Verdicts of the network ({parameters[CASE_KEY]}, {network.stamp_ns.size} instants "
                         "every generator reported):")
            lines += [f"  {key}: {json_text(value)}" for key, value in verdicts.pop("").items()]
    for namespace, run in sorted(runs.items(), key=lambda item: namespace_order(item[0])):
        lines += generator_lines(namespace, run)
        if namespace in verdicts:
            lines.append(f"Verdicts{' of ' + namespace if namespace else ''}:")
            lines += [f"  {key}: {json_text(value)}" for key, value in verdicts[namespace].items()]
    return lines


def law_text(parameters: dict) -> str:
    """The law that ran and its gains, from a recording's ``nni_run`` record (a network's: the same at every
    generator, or per generator where they differ): ``pss (pss_k_s 100, ...)``."""
    from nni_battery_controller.laws import GAIN_PARAMETERS
    from nni_battery_controller.options import NNI_GAINS

    def one(controller: dict) -> str:
        name = controller.get("law", "nni")
        keys = GAIN_PARAMETERS.get(name, NNI_GAINS)
        text = f"{name} (" + ", ".join(f"{key} {controller[key]:g}" for key in keys if key in controller) + ")"
        return text if "law" in controller else f"{text}; no law recorded: the recording predates the law " \
                                                  "parameter, when nni was the only law"

    if "controller" in parameters:
        return one(parameters["controller"])
    texts = {namespace: one(controller) for namespace, controller in parameters.get("controllers", {}).items()}
    if not texts:
        return "not recorded"
    if len(set(texts.values())) == 1:
        return f"{next(iter(texts.values()))} at every generator"
    return "; ".join(f"{namespace}: {text}" for namespace, text in texts.items())


def generator_lines(namespace: str, run: GeneratorRun) -> list[str]:
    """One generator's block of ``--info``: its samples, b, the largest battery power, the plant's trust counters."""
    answered = int(run.answered.sum())
    machine = run.diagnostics.get("machine")
    b = run.battery_limit_pu
    lines = [f"Generator{' ' + namespace if namespace else ''}{f' (machine {machine})' if machine else ''}:",
             f"  samples: {run.stamp_ns.size} plant states, {answered} answered by the controller",
             f"  battery limit b: {'not reported' if math.isnan(b) else f'{b:g} pu'}",
             f"  max|P_ST|: {float(np.max(np.abs(run.battery_power_pu))):.6g} pu (applied, recorded plant states)"]
    if "battery_charge_pu_s" in run.diagnostics:  # a battery of finite energy, as the plant accounted for it
        ends = [f"{word} at {float(run.diagnostics[f'battery_{word}_at_s']):.3f} s" for word in ("empty", "full")
                if f"battery_{word}_at_s" in run.diagnostics]
        lines.append(f"  battery charge: {float(run.diagnostics['battery_charge_pu_s']):.6g} pu s from empty at the "
                     f"last status; {', '.join(ends) or 'never empty or full'}")
    counters = [f"{key} {run.diagnostics[key]}" for key in TRUST_COUNTERS if key in run.diagnostics]
    lines.append(f"  trust (plant diagnostics, last status): {', '.join(counters)}" if counters
                 else "  trust: no plant diagnostics recorded for this generator")
    inputs = [f"{key} {run.controller_diagnostics[key]}" for key in CONTROLLER_TRUST_COUNTERS
              if key in run.controller_diagnostics]
    if inputs:
        lines.append(f"  trust (controller diagnostics, last status): {', '.join(inputs)}")
    return lines


def network_verdicts(network) -> dict:
    """``{"": the system's verdicts, namespace: that generator's}`` of :func:`network_sim.assess_network`."""
    from nni_battery_controller.network_sim import assess_network
    from nni_battery_controller.recorded_runs import network_run_trajectory

    outcome = assess_network(network_run_trajectory(network))[0].to_json()
    generators = outcome.pop("generators")
    return {"": outcome, **dict(zip(network.namespaces, generators))}


def json_text(value) -> str:
    """A parameter or verdict value as JSON text (``inf`` as JSON's Infinity, as recorded)."""
    import json

    return json.dumps(value)


def _time_text(ns: int) -> str:
    stamp = datetime.datetime.fromtimestamp(ns / 1e9, tz=datetime.timezone.utc)
    return f"{stamp:%b %d %Y %H:%M:%S}.{ns % 1_000_000_000:09d} UTC ({ns // 1_000_000_000}.{ns % 1_000_000_000:09d})"
