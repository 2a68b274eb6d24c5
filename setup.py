"""ament_python package setup (also installable with plain pip)."""

from glob import glob

from setuptools import Extension, find_packages, setup

package_name = "rollergear_ros"

setup(
    name=package_name,
    version="0.2.0",
    packages=find_packages(exclude=["test", "test.*", "bench"]),
    # the FMU's C source, compiled into each unit at export (outputs/fmu.py)
    package_data={"rollergear_ros.outputs": ["fmu_gearbox.c"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/launch", glob("launch/*.launch.py") + glob("launch/*.launch.xml")),
        ("share/" + package_name + "/docs", glob("docs/*.md")),
        ("share/" + package_name + "/layouts", glob("layouts/*.json") + glob("layouts/*.xml")),
    ],
    # the MCAP record layout in C; optional: without a compiler the package installs and lays the
    # records out with numpy (the same bytes, slower)
    ext_modules=[Extension("rollergear_ros.recordings._records", ["rollergear_ros/recordings/_records.c"],
                           optional=True)],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="rollergear_ros maintainers",
    maintainer_email="rollergear@example.com",
    description="Roller gearing gearbox loss estimation: model, replay, calibration, ROS 2 node.",
    license="Apache-2.0",
    extras_require={"test": ["pytest", "hypothesis"]},
    entry_points={
        "console_scripts": [
            "rollergear = rollergear_ros.cli.main:main",
            "loss_estimator = rollergear_ros.ros.node:main",
        ],
    },
)
