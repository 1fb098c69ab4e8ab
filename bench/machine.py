"""The machine a run measured on (CPU, kernel, Python, packages, RMW, executor, load) and the report's section on it."""

from __future__ import annotations

import os
import platform
from importlib import metadata
from pathlib import Path


def machine_description(domain_id: int) -> dict:
    """The machine at the start of a run (``load_average_at_end`` is the caller's to add when it ends)."""
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    packages = {}
    for name in ("ros-jazzy-rclpy", "ros-rmw-fastrtps-cpp", "ros-fastrtps", "numpy", "scipy", "matplotlib"):
        try:
            packages[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            pass
    return {
        "cpu": cpu, "cores": os.cpu_count(), "kernel": platform.release(),
        "python": platform.python_version(), "packages": packages,
        "rmw": os.environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp (default)"),
        "load_average_at_start": os.getloadavg(), "domain_id": domain_id, "executor": executor_name(),
    }


def executor_name() -> str:
    """The executor class the nodes (and the ping-pong) spin, from ``node_main.make_executor``."""
    import rclpy

    from nni_msgs_adapter.ros.node_main import make_executor

    rclpy.init()
    try:
        return type(make_executor()).__name__
    finally:
        rclpy.shutdown()


def machine_section(machine: dict) -> list[str]:
    """The machine, and a warning when it was loaded at the start of the run."""
    packages = ", ".join(f"{name} {version}" for name, version in machine["packages"].items())
    lines = ["## Machine", "",
             f"- CPU: {machine['cpu']}, {machine['cores']} cores; Linux {machine['kernel']}",
             f"- Python {machine['python']}; {packages}",
             f"- RMW: {machine['rmw']}; executor {machine['executor']}; localhost discovery, ROS domain "
             f"{machine['domain_id']}",
             f"- load average (1, 5, 15 min) at start {fmt_load(machine['load_average_at_start'])}, "
             f"at end {fmt_load(machine['load_average_at_end'])} (other work on the machine shows at the start; "
             "at the end, the last section's own processes too)", ""]
    # The start only: the network sections run 10 to 20 processes of their own, which the end's load average holds.
    if machine["load_average_at_start"][0] > 0.5 * machine["cores"]:
        lines += [f"> **Measured on a loaded machine**: a 1-minute load average above half the {machine['cores']} "
                  "cores at the start of the run (other work ran before or beside the benchmarks); the numbers are "
                  "noisy, the ratios (each against a baseline measured back to back) less so.", ""]
    return lines


def fmt_load(load) -> str:
    return ", ".join(f"{value:.2f}" for value in load)
