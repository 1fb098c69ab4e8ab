"""What both launch files do so that a launched run can be trusted: the run's key, and the read-back before it starts.

* :func:`run_key_environment`: a fresh command key for the launch
  (:func:`.command_auth.new_key_file`: a folder of mode 0700, a file of 0600),
  the environment that hands it to the plant and its controllers (never a
  parameter, never to the logger), and the shutdown handler that removes it
  (a normal end, Ctrl-C, a failed node: ``ros2 launch`` shuts down in each
  case; the process's exit too, should the launch itself fail).
* :func:`readback_release`: output handlers on every started node's process
  that feed a :class:`.readback.ReadbackGate`; once every node has stated the
  parameters it was given (each has read the key: it is removed then) the
  plant (``hold_until_released``) gets SIGUSR1 and its run starts, and on a difference the launch logs one line and shuts
  down before any sample.

``launch`` is imported inside the functions only, so that the module imports
where launch is not installed (as the launch files' own node tables do).
"""

from __future__ import annotations

import atexit
import signal
from pathlib import Path

from nni_msgs_adapter.ros import command_auth
from nni_msgs_adapter.ros.readback import ReadbackGate


def run_key_environment() -> tuple[dict, list]:
    """``(environment, actions)``: a fresh key's ``NNI_COMMAND_KEY_FILE`` for the plant's and the controllers'
    processes, and the handler that removes the key when the launch shuts down."""
    from launch.actions import OpaqueFunction, RegisterEventHandler
    from launch.event_handlers import OnShutdown

    path = command_auth.new_key_file()
    atexit.register(command_auth.remove_key_file, path)
    remove = OpaqueFunction(function=lambda context: command_auth.remove_key_file(path))
    return {command_auth.KEY_FILE_ENV: str(path)}, [RegisterEventHandler(OnShutdown(on_shutdown=[remove]))]


def readback_release(started: list, plant, key_environment: dict) -> list:
    """Handlers releasing ``plant`` (a launch_ros Node) once every node of ``started`` (``(action, {node: the
    parameters it must state})``) has stated them, the run's key (``key_environment``'s) removed first (each of
    them read it at start); a shutdown (one line) on the first difference."""
    from launch.actions import EmitEvent, LogInfo, RegisterEventHandler
    from launch.event_handlers import OnProcessIO
    from launch.events import Shutdown, matches_action
    from launch.events.process import SignalProcess

    gate = ReadbackGate({node: values for _, passed in started for node, values in passed.items()})

    def on_stdout(event):
        decision = gate.feed(event.name, event.text.decode(errors="replace"))
        if decision == ReadbackGate.RELEASE:
            command_auth.remove_key_file(Path(key_environment[command_auth.KEY_FILE_ENV]))
            return [EmitEvent(event=SignalProcess(signal_number=signal.SIGUSR1,
                                                  process_matcher=matches_action(plant)))]
        if decision is not None:
            return [LogInfo(msg=f"not started: {decision}"), EmitEvent(event=Shutdown(reason=decision))]
        return None

    return [RegisterEventHandler(OnProcessIO(target_action=action, on_stdout=on_stdout)) for action, _ in started]
