"""Rerun bridge node: streams a running loop to Rerun with the project's blueprint.

Subscribes to ``plant/state`` (speed deviation), ``controller/state`` (angle
deviation, battery power, saturation, W_hat, b) and the latched
``plant/invariant_set``; pairs them by stamp (both carry the measurement's stamp)
and logs each sample through :class:`nni_msgs_adapter.rerun_view.LiveLogger`.
Runs are labelled by their battery limit ("b=0.3"); a new label starts its own
time axis, so consecutive runs overlay. A separate process, off the control
path: a slow viewer never delays a command.

``sink`` is ``save`` (to ``path``), ``serve`` (gRPC + web viewer on this
machine; the URL is logged) or ``spawn`` (a native viewer, needs a display).
"""

from __future__ import annotations

import math
import sys

import numpy as np
from rclpy.node import Node

from nni_msgs_adapter import contract
from nni_msgs_adapter.node_main import run_node
from nni_msgs_adapter.ros_params import Spec, check_choices, current_values, declare
from nni_msgs_adapter.rerun_view import LiveLogger, open_recording

PARAMETERS = (
    Spec("sink", "save", "Where the stream goes.", choices=("save", "serve", "spawn"), read_only=True),
    Spec("path", "live.rrd", "Output .rrd file for sink=save.", read_only=True),
    Spec("f0_hz", 50.0, "Nominal frequency, Hz (frequency deviation = speed / 2 pi).", 1.0, 1e3, read_only=True),
)

#: Logged once the subscriptions exist; nni-demo waits for it before the first run.
READY_TEXT = "rerun bridge ready"

#: Plant states kept while waiting for the controller state of the same stamp.
_PENDING_LIMIT = 1000


def run_label(battery_limit_pu: float) -> str:
    """Label of a run in the views: b=0.3, b=inf."""
    return "b=inf" if math.isinf(battery_limit_pu) else f"b={battery_limit_pu:g}"


class RerunBridge(Node):
    """Pairs plant and controller states by stamp and logs them live."""

    def __init__(self, **kwargs):
        super().__init__("rerun_bridge", **kwargs)
        declare(self, PARAMETERS)
        values = current_values(self, PARAMETERS)
        check_choices(values, PARAMETERS)
        sink = (values["sink"], values["path"] if values["sink"] == "save" else None)
        self._recording, url = open_recording("nni_battery_control", sink)
        if url:
            self.get_logger().info(f"Rerun web viewer: {url}")
        self._f0_hz = values["f0_hz"]
        self._boundary = None
        self._loggers: dict[str, tuple[LiveLogger, int]] = {}  # label -> (logger, first stamp ns)
        # stamp -> the half of the sample that arrived first ("plant": speed, "controller": signals)
        self._pending: dict[int, dict] = {}
        for topic, callback in ((contract.TOPIC_PLANT_STATE, self._on_plant),
                                (contract.TOPIC_CONTROLLER_STATE, self._on_controller),
                                (contract.TOPIC_INVARIANT_SET, self._on_invariant_set)):
            msg_type, name, qos = contract.recorder_endpoint(topic)
            self.create_subscription(msg_type, name, callback, qos)
        self.get_logger().info(f"{READY_TEXT} ({values['sink']})")

    def _on_invariant_set(self, msg) -> None:
        self._boundary = np.array([(p.x, p.y) for p in msg.polygon.points])

    def _on_plant(self, msg) -> None:
        stamp_ns, _, speed, _ = contract.plant_state_from_message(msg)
        self._pair(stamp_ns, "plant", speed)

    def _on_controller(self, msg) -> None:
        stamp_ns, signals = contract.controller_state_from_message(msg)
        self._pair(stamp_ns, "controller", signals)

    def _pair(self, stamp_ns: int, half: str, value) -> None:
        """Log the sample once both halves with this stamp are in."""
        sample = self._pending.setdefault(stamp_ns, {})
        sample[half] = value
        if len(sample) < 2:
            if len(self._pending) > _PENDING_LIMIT:  # a half that never came: forget the oldest
                self._pending.pop(next(iter(self._pending)))
            return
        del self._pending[stamp_ns]
        signals, speed = sample["controller"], sample["plant"]
        label = run_label(signals["battery_limit"])
        if label not in self._loggers:
            logger = LiveLogger(self._recording, label, signals["battery_limit"], self._f0_hz,
                                omega_boundary=self._boundary)
            self._loggers[label] = (logger, stamp_ns)
        logger, first_ns = self._loggers[label]
        logger.log((stamp_ns - first_ns) * 1e-9, signals["angle_dev"], speed, signals["battery_power"],
                   signals["saturated"] > 0.5, signals["w_hat"])

    def close(self) -> None:
        """Draw what is pending and flush the stream."""
        for logger, _ in self._loggers.values():
            logger.flush()
        self._recording.flush()


def main(args=None) -> int:
    """``ros2 run nni_msgs_adapter rerun_bridge``."""
    return run_node(RerunBridge, args, prog="rerun_bridge")


if __name__ == "__main__":
    sys.exit(main())
