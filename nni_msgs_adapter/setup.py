"""ament_python package nni_msgs_adapter: Message contract (topics, QoS, conversions), MCAP logger, replay and Rerun bridge for the NNI battery control system."""
from glob import glob

from setuptools import find_packages, setup

package_name = "nni_msgs_adapter"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml") + glob("config/*.xml")),
        ("share/" + package_name + "/launch", glob("launch/*.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="NNI battery control maintainers",
    maintainer_email="nni-maintainers@example.org",
    description="Message contract (topics, QoS, conversions), MCAP logger, replay and Rerun bridge for the NNI battery control system.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "mcap_logger = nni_msgs_adapter.recording.mcap_logger:main",
            "rerun_bridge = nni_msgs_adapter.viewing.rerun_bridge:main",
            "foxglove_bridge = nni_msgs_adapter.viewing.foxglove_bridge:main",
            "c37118_client = nni_msgs_adapter.c37118.client_node:main",
        ],
    },
)
