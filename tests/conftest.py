"""Shared fixtures: the paper's SMIB case (section VII) and the ``nni-simulate`` console script.

The paper's values are written out here rather than taken from the dataclass
defaults, so that a changed default cannot silently change what "the paper's
case" means in the tests.
"""

from __future__ import annotations

import signal
import sys
from pathlib import Path

import pytest

#: The test modules of the pure cores: no ROS, no node, no DDS (``./scripts/test --quick`` runs them with
#: the one ``smoke`` test). tests/test_markers.py checks that none of them starts a node or imports rclpy.
CORE_TEST_MODULES = frozenset({
    "test_bench_report", "test_c37118_client", "test_c37118_feed", "test_c37118_frames", "test_c37118_server",
    "test_c37118_stream", "test_clock_ticks", "test_closed_loop", "test_laws", "test_controller_core", "test_controller_law", "test_import_graph",
    "test_input_gate", "test_link", "test_loop_stats", "test_markers", "test_network", "test_network_andes",
    "test_network_law", "test_plant_model", "test_reporting", "test_screening_core", "test_simulation",
    "test_synthetic_case",
})


def pytest_configure(config):
    """Let the children the tests start be interrupted. A suite started in the background of a shell without job
    control (``./.ci/run &``, ``nohup``) inherits SIGINT ignored, and a process exec'd with SIGINT ignored keeps
    it so: the tests that Ctrl-C a screen or a demo then saw it run on to its end (exit 0 where 130 was due,
    or no exit within 60 s). A Python handler, unlike SIG_IGN, is reset to the default at exec."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_collection_modifyitems(items):
    """Mark every test of a :data:`CORE_TEST_MODULES` module ``core``."""
    for item in items:
        if item.module.__name__ in CORE_TEST_MODULES:
            item.add_marker(pytest.mark.core)

from nni_battery_controller.law import ControllerParams
from nni_plant_sim.model import SmibParams
from nni_plant_sim.scenarios import InitialAngle


@pytest.fixture(scope="session")
def paper_plant() -> SmibParams:
    """H = 4 s, D = 0, P_M = 0.8 pu, P_max = 1 pu, f0 = 50 Hz."""
    return SmibParams(inertia_h_s=4.0, damping_pu=0.0, p_mech_pu=0.8, p_max_pu=1.0, f0_hz=50.0)


@pytest.fixture(scope="session")
def paper_fault() -> InitialAngle:
    """delta(0) = 0.2 rad, released at rest (delta'(0) = 0)."""
    return InitialAngle(delta0_rad=0.2, speed0_rad_s=0.0)


@pytest.fixture(scope="session")
def paper_controller():
    """Factory ``b -> ControllerParams`` with the paper's gains tau = 0.1 s, K = 1, L = 1.1, alpha = 1."""

    def make(battery_limit_pu: float) -> ControllerParams:
        return ControllerParams(tau_s=0.1, gain_k=1.0, gain_l=1.1, alpha=1.0, battery_limit_pu=battery_limit_pu)

    return make


@pytest.fixture(scope="session")
def nni_simulate_exe() -> Path:
    """The ``nni-simulate`` console script installed beside this interpreter."""
    return Path(sys.executable).parent / "nni-simulate"


@pytest.fixture
def busy():
    """Two busy processes beside a flow that depends on discovery or timing (shared by the parallel workers)."""
    from rosproc import busy_processes

    with busy_processes(2):
        yield
