"""ament_python package nni_plant_sim: Single-machine-infinite-bus generator: swing-equation physics, fault scenarios and the PMU plant node."""
from glob import glob

from setuptools import find_packages, setup

package_name = "nni_plant_sim"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={"nni_plant_sim.cases": ["*.m", "*.csv"]},
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
    description="Single-machine-infinite-bus generator: swing-equation physics, fault scenarios and the PMU plant node.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "plant_node = nni_plant_sim.plant_node:main",
            "network_plant_node = nni_plant_sim.network_plant_node:main",
        ],
    },
)
