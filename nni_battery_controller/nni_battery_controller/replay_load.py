"""What every ``nni-replay`` job reads: the recording and its runs, with what is wrong with them said.

A recording cut short is refused unless ``--allow-partial`` (``--info`` describes it
either way); a repeated chunk, a cut-short file used anyway and every sample left
out (a malformed message) are one warning line each on stderr. The recorded run
parameters (the ``nni_run`` metadata) give the network a run is, if any, and each
generator's run as the sampled trajectory the assessments judge, every field present.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from dataclasses import replace

from nni_msgs_adapter.ros.cli_support import CliError
from nni_msgs_adapter.recording.mcap_io import Recording, read_recording
from nni_msgs_adapter.recording.network_runs import network_run, recorded_case
from nni_msgs_adapter.recording.runs import GeneratorRun, generator_runs

#: The program name, at the start of every line nni-replay prints about its input and output.
PROG = "nni-replay"


def warn(text: str) -> None:
    """A warning line on stderr (the run goes on)."""
    print(f"{PROG}: warning: {text}", file=sys.stderr, flush=True)


def load(args, *, whole: bool = True) -> Recording:
    """The recording, with what is wrong with it said: refused if cut short, unless ``--allow-partial`` (or not ``whole``)."""
    recording = read_recording(args.recording)
    if recording.duplicate_chunks:
        warn(f"{args.recording}: {recording.duplicate_chunks} chunk(s) repeat an earlier one: each read once")
    if not recording.complete:
        if whole and not args.allow_partial:
            raise CliError(f"{recording.incompleteness()}; refused: --allow-partial uses what it holds")
        warn(recording.incompleteness())
    return recording


def readable_runs(recording: Recording) -> dict[str, GeneratorRun]:
    """The recording's generator runs; each sample left out (a malformed message) said on stderr."""
    runs = generator_runs(recording)
    for run in runs.values():
        for line in run.skipped:
            warn(f"{recording.path}: sample left out: {line}")
    return runs


def recorded_network(recording: Recording, runs: dict[str, GeneratorRun], parameters: dict | None):
    """The recording as a :class:`network_runs.NetworkRun` if its parameters name a case; None otherwise."""
    from nni_plant_sim.cases import load_network

    try:
        case = recorded_case(parameters)
        return None if case is None else network_run(load_network(case), runs)
    except ValueError as error:
        raise CliError(f"{recording.path}: {error}") from None


def _dataclass_from(cls, values, section: str, path) -> object:
    """``cls`` from the recorded section's values, every field present (none silently defaulted)."""
    if not isinstance(values, dict):
        raise CliError(f"{path}: run parameters hold no {section!r} section")
    names = [f.name for f in dataclasses.fields(cls)]
    missing = [name for name in names if name not in values]
    if missing:
        raise CliError(f"{path}: run parameters lack {section}.{', '.join(missing)}")
    try:
        return cls(**{name: float(values[name]) for name in names})
    except (TypeError, ValueError) as error:
        raise CliError(f"{path}: recorded {section} parameters are invalid: {error}") from None


def recorded_scenario(parameters: dict, path) -> tuple:
    """The run's scenario as an object and as ``{"name": ..., <its values>}``, from the recorded plant parameters."""
    from nni_plant_sim.scenarios import SCENARIO_FIELDS, from_values

    plant = parameters.get("plant")
    try:
        scenario = from_values(plant)
        return scenario, {"name": plant["scenario"], **{k: plant[k] for k in SCENARIO_FIELDS[plant["scenario"]]}}
    except (KeyError, TypeError, ValueError) as error:
        raise CliError(f"{path}: the recorded plant parameters name no valid scenario ({error})") from None


def trajectories(recording: Recording, runs: dict[str, GeneratorRun], parameters: dict) -> dict:
    """Per namespace, the run as a sampled :class:`simulate.Trajectory` with the recorded parameters.

    b is the one the controller reported in the run (``controller/state``), where it did.
    """
    from nni_battery_controller.law import ControllerParams
    from nni_battery_controller.recorded_runs import sampled_trajectory
    from nni_plant_sim.model import SmibParams

    plant = _dataclass_from(SmibParams, parameters.get("plant"), "plant", recording.path)
    ctrl = _dataclass_from(ControllerParams, parameters.get("controller"), "controller", recording.path)
    out = {}
    for namespace, run in runs.items():
        b = run.battery_limit_pu
        run_ctrl = ctrl if math.isnan(b) else replace(ctrl, battery_limit_pu=b)
        out[namespace] = sampled_trajectory(run, plant, run_ctrl)
    return out
