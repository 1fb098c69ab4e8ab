"""The controller's core (nni_battery_controller.controller_core) at the end of a run: clock-free, no ROS."""

from __future__ import annotations

from nni_battery_controller.controller_config import ControllerConfig
from nni_battery_controller.controller_core import ControllerCore
from nni_msgs_adapter.ros.defaults import controller_defaults

MS = 1_000_000
NOW = 1_700_000_000_000 * MS


def core_after_one_measurement() -> ControllerCore:
    core = ControllerCore(ControllerConfig(controller_defaults()))  # 50/s, stale after 5 periods: 100 ms
    assert core.measurement(NOW, 0.9, 0.0, NOW, NOW) is not None
    return core


def test_the_silence_after_the_plants_end_of_run_is_no_stale_episode():
    core = core_after_one_measurement()
    assert core.end_of_run() is True and core.end_of_run() is False, "news once"
    assert core.silence(NOW + 500 * MS) is None and not core.gate.stale
    assert core.gate.counts["stale_episodes"] == 0


def test_a_measurement_after_the_end_notice_cancels_it():
    """A false or early notice spares the stand-down only for the silence right after it."""
    core = core_after_one_measurement()
    core.end_of_run()
    assert core.measurement(NOW + 20 * MS, 0.9, 0.0, NOW + 20 * MS, NOW + 20 * MS) is not None
    assert core.silence(NOW + 200 * MS) == NOW + 200 * MS and core.gate.stale


def test_an_end_notice_after_the_watchdog_fired_or_before_any_run_is_no_news():
    core = core_after_one_measurement()
    assert core.silence(NOW + 150 * MS) is not None
    assert core.end_of_run() is False
    idle = ControllerCore(ControllerConfig(controller_defaults()))
    assert idle.end_of_run() is False
