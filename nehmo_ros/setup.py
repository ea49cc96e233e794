"""ament_python build script of the `nehmo_ros` package (colcon and pip both use it)."""

from glob import glob

from setuptools import find_packages, setup

package_name = "nehmo_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{package_name}"]),
        (f"share/{package_name}", ["package.xml"]),
        (f"share/{package_name}/launch", sorted(glob("launch/*.launch.py"))),
        (f"share/{package_name}/config", sorted(glob("config/*.yaml"))),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="NeHMO maintainers",
    maintainer_email="nehmo@example.org",
    description="ROS 2 nodes of NeHMO: arm_planner, recorder, launch files, orchestration.",
    license="MIT",
    entry_points={
        "console_scripts": [
            "arm_planner = nehmo_ros.arm_planner:main",
            "arm_planners = nehmo_ros.planner_group:main",
            "command_watchdog = nehmo_ros.command_watchdog:main",
            "lifecycle_manager = nehmo_ros.lifecycle_manager:main",
            "recorder = nehmo_ros.recorder:main",
            "orchestrate = nehmo_ros.orchestrate:main",
        ],
    },
)
