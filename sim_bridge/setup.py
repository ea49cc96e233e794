"""ament_python build script of the `sim_bridge` package (colcon and pip both use it)."""

from setuptools import find_packages, setup

package_name = "sim_bridge"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{package_name}"]),
        (f"share/{package_name}", ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="NeHMO maintainers",
    maintainer_email="nehmo@example.org",
    description="PyBullet simulation bridge node of NeHMO.",
    license="MIT",
    entry_points={
        "console_scripts": [
            "sim_bridge = sim_bridge.bridge:main",
        ],
    },
)
