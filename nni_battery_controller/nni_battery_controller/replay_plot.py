"""``nni-replay --plot OUT.png``: the run's figure, as ``nni-simulate --plot`` draws it, from the recorded samples.

::

    nni-replay run.mcap --plot out.png    # the run's figure (nni-simulate's, from the recorded samples)

No ROS graph, no Rerun. It needs the run's parameters (the plant's equilibrium and the
controller's limit): a recording without them is refused with one line. It draws
single-machine runs only.
"""

from __future__ import annotations

from nni_msgs_adapter.ros.cli_support import CliError
from nni_msgs_adapter.recording.mcap_io import Recording
from nni_msgs_adapter.recording.network_runs import CASE_KEY
from nni_battery_controller.replay_load import PROG, load, readable_runs, recorded_network, recorded_scenario, trajectories
from nni_msgs_adapter.recording.runs import run_metadata


def plot(args) -> int:
    """``--plot OUT.png``: the run's figure, as ``nni-simulate --plot`` draws it, from the recorded samples."""
    from nni_battery_controller.figures import plot_runs
    from nni_battery_controller.verdicts import assess

    recording = load(args)
    runs = readable_runs(recording)
    parameters = require_parameters(recording, "--plot")
    if recorded_network(recording, runs, parameters) is not None:
        raise CliError(f"--plot draws single-machine runs; {args.recording} is a run of case {parameters[CASE_KEY]}: "
                       "view it with --rrd OUT.rrd (or --info for its verdicts)")
    trajs = list(trajectories(recording, runs, parameters).values())
    scenario, scenario_values = recorded_scenario(parameters, recording.path)
    outcomes = [assess(traj, scenario=scenario).to_json() for traj in trajs]
    rate_hz = recorded_setting(parameters, "rate_hz", recording.path)
    plot_runs(trajs, outcomes, args.plot, scenario_values, f"sampled at {rate_hz:g} Hz",
              recorded_setting(parameters, "mode", recording.path))
    print(f"{PROG}: wrote {args.plot} ({len(trajs)} generator run(s))")
    return 0


def require_parameters(recording: Recording, what: str) -> dict:
    """The run's parameters, or CliError naming what needs them."""
    parameters = run_metadata(recording)
    if parameters is None:
        raise CliError(f"{recording.path} holds no run parameters (no nni_run metadata: recorded before they were, "
                       f"or by a logger started without run_metadata): {what} needs them")
    return parameters


def recorded_setting(parameters: dict, key: str, path):
    """One top-level run parameter (mode, rate_hz), or CliError naming it."""
    if key not in parameters:
        raise CliError(f"{path}: run parameters lack {key!r}")
    return parameters[key]
