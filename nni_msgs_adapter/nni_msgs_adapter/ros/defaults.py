"""The package YAML files as the one source of default parameter values.

Every entry point reads its defaults from here: the nodes (through
:mod:`nni_msgs_adapter.ros.ros_params`), ``nni-simulate``, ``nni-demo`` and the
assessment of a demo run. Files are read on first use, not at import, and
cached. Pure python: no rclpy, no rcl_interfaces.
"""

from __future__ import annotations

import functools
import importlib
from pathlib import Path

import yaml


def config_path(package: str, filename: str) -> Path:
    """``config/<filename>`` of ``package``.

    Looks in the installed share directory (colcon install, found through the
    ament index) first, then beside the package's source (editable install).
    """
    candidates = []
    try:
        from ament_index_python.packages import get_package_share_directory

        candidates.append(Path(get_package_share_directory(package)) / "config" / filename)
    except (ImportError, LookupError, OSError, ValueError):
        pass  # not in an ament index (plain venv): use the source tree
    module_file = importlib.import_module(package).__file__
    candidates.append(Path(module_file).resolve().parent.parent / "config" / filename)
    for path in candidates:
        if path.is_file():
            return path
    raise FileNotFoundError(f"no config/{filename} for {package} in {', '.join(map(str, candidates))}")


@functools.cache
def _read_defaults(package: str, filename: str, node_name: str) -> dict:
    with open(config_path(package, filename)) as handle:
        return yaml.safe_load(handle)[f"/**/{node_name}"]["ros__parameters"]


def load_defaults(package: str, filename: str, node_name: str) -> dict:
    """A node's default parameter values from its package's ``config/<filename>`` (:func:`config_path`).

    The file is a ROS params file keyed ``/**/<node_name>``. Read once, then
    cached; each call returns a fresh copy, so callers may change it.
    """
    return dict(_read_defaults(package, filename, node_name))


def plant_defaults() -> dict:
    """The plant node's defaults (``nni_plant_sim/config/plant.yaml``)."""
    return load_defaults("nni_plant_sim", "plant.yaml", "plant")


def controller_defaults() -> dict:
    """The controller node's defaults (``nni_battery_controller/config/controller.yaml``)."""
    return load_defaults("nni_battery_controller", "controller.yaml", "controller")


def logger_defaults() -> dict:
    """The MCAP logger's defaults (``nni_msgs_adapter/config/mcap_logger.yaml``)."""
    return load_defaults("nni_msgs_adapter", "mcap_logger.yaml", "mcap_logger")
