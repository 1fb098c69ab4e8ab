"""Node parameters: declared with ranges, validated at start-up and on every runtime change."""

from __future__ import annotations

import math
import time

import pytest

from rosproc import fresh_domain_id, node_processes

pytestmark = pytest.mark.ros

CONTROLLER = "nni_battery_controller.controller_node"
PLANT = "nni_plant_sim.plant_node"


@pytest.mark.parametrize("module, params, reason", [
    (CONTROLLER, {"gain_k": 2.0}, "K must be less than L"),
    (CONTROLLER, {"battery_limit_pu": -0.1}, "battery_limit_pu out of range Min: 0.0"),
    (PLANT, {"p_mech_pu": 1.5}, "P_M must be less than P_max"),
    (PLANT, {"mode": "fast"}, "mode must be one of realtime, lockstep"),
    (PLANT, {"pmu_rate_hz": 5.0}, "pmu_rate_hz"),
    # A misspelt choice ran silently as the default choice (restoring_power as model, reference as pmu).
    (CONTROLLER, {"restoring_power": "measurd"}, "restoring_power must be one of model, measured, got 'measurd'"),
    (CONTROLLER, {"reference": "centre"}, "reference must be one of pmu, coi, got 'centre'"),
])
def test_invalid_start_up_values_stop_the_node_with_one_line(tmp_path, module, params, reason):
    with node_processes(tmp_path, fresh_domain_id()) as start:
        node = start("node", module, params)
        status = node.wait(timeout=30)
        output = node.output()
    assert status != 0
    assert reason in output
    assert "Traceback" not in output
    assert len([line for line in output.splitlines() if line.strip()]) == 1, output


def parameter_client(domain_id: int, node_name: str):
    """An rclpy AsyncParameterClient in its own context, with its executor thread."""
    import threading

    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter_client import AsyncParameterClient

    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = rclpy.create_node("param_probe", context=context)
    client = AsyncParameterClient(node, node_name)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    thread = threading.Thread(target=lambda: _spin(executor, context), daemon=True)
    thread.start()

    def close():
        rclpy.try_shutdown(context=context)
        thread.join(timeout=2)
        node.destroy_node()

    return client, close


def _spin(executor, context):
    while context.ok():
        try:
            executor.spin_once(timeout_sec=0.05)
        except Exception:
            return


def _call(future, timeout=10.0):
    deadline = time.monotonic() + timeout
    while not future.done() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert future.done(), "parameter service did not answer"
    return future.result()


def test_runtime_change_is_revalidated_and_rejected_with_reason(tmp_path):
    from rclpy.parameter import Parameter

    domain = fresh_domain_id()
    with node_processes(tmp_path, domain) as start:
        start("controller", CONTROLLER, {"battery_limit_pu": 0.3})
        client, close = parameter_client(domain, "controller")
        try:
            assert client.wait_for_services(timeout_sec=20.0)
            bad = _call(client.set_parameters([Parameter("gain_k", value=1.5)]))
            assert not bad.results[0].successful
            assert "K must be less than L" in bad.results[0].reason
            out_of_range = _call(client.set_parameters([Parameter("tau_s", value=-1.0)]))
            assert not out_of_range.results[0].successful
            good = _call(client.set_parameters([Parameter("battery_limit_pu", value=math.inf)]))
            assert good.results[0].successful, good.results[0].reason
            values = _call(client.get_parameters(["gain_k", "tau_s", "battery_limit_pu"])).values
            assert [v.double_value for v in values] == [1.0, 0.1, math.inf], "old values kept after rejections"
        finally:
            close()


def test_a_waiting_plant_takes_changes_but_not_of_its_mode(tmp_path):
    """Before its run the plant's parameters are validated and applied; the mode chose its publishers at start."""
    from rclpy.parameter import Parameter

    domain = fresh_domain_id()
    with node_processes(tmp_path, domain) as start:
        start("plant", PLANT, {"wait_for_subscribers": 1})
        client, close = parameter_client(domain, "plant")
        try:
            assert client.wait_for_services(timeout_sec=20.0)
            mode = _call(client.set_parameters([Parameter("mode", value="lockstep")])).results[0]
            assert not mode.successful and "mode cannot change once the node is up" in mode.reason
            noise = _call(client.set_parameters([Parameter("noise_angle_std_rad", value=0.01)])).results[0]
            assert noise.successful, noise.reason
            values = _call(client.get_parameters(["mode", "noise_angle_std_rad"])).values
            assert (values[0].string_value, values[1].double_value) == ("realtime", 0.01)
        finally:
            close()
