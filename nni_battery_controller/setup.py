"""ament_python package nni_battery_controller: Saturated nonlinear negative-imaginary (NNI) battery controller: control law, offline closed loop, analysis and the controller node."""
from glob import glob

from setuptools import find_packages, setup

package_name = "nni_battery_controller"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/launch", glob("launch/*.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="NNI battery control maintainers",
    maintainer_email="nni-maintainers@example.org",
    description="Saturated nonlinear negative-imaginary (NNI) battery controller: control law, offline closed loop, analysis and the controller node.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "controller_node = nni_battery_controller.controller_node:main",
            "composed_controllers = nni_battery_controller.composed_controllers:main",
            "nni-simulate = nni_battery_controller.simulate_command:main",
            "nni-demo = nni_battery_controller.demo_command:main",
            "replay = nni_battery_controller.replay:main",
            "nni-replay = nni_battery_controller.replay:main",
        ],
    },
)
