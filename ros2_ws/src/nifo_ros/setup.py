"""ament_python package: entry points for the nifo nodes, launch files, parameter files.

The node code lives in the ``nifo`` Python package (``nifo_nodes``), installed into the ROS
Python with pip; this package only makes ``ros2 run`` / ``ros2 launch`` find it.
"""

from glob import glob

from setuptools import setup

package_name = "nifo_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=[package_name],
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{package_name}"]),
        (f"share/{package_name}", ["package.xml"]),
        (f"share/{package_name}/launch", glob("launch/*.launch.py")),
        (f"share/{package_name}/config", glob("config/*.yaml") + glob("config/*.xml")),
    ],
    install_requires=["setuptools"],
    tests_require=["pytest"],
    zip_safe=True,
    maintainer="nifo maintainers",
    maintainer_email="nifo@example.com",
    description="ROS 2 nodes of nifo (acquisition, integrator, identifier)",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "acquisition = nifo_ros.entry:acquisition",
            "integrator = nifo_ros.entry:integrator",
            "identifier = nifo_ros.entry:identifier",
            "rerun_viewer = nifo_ros.entry:rerun_viewer",
        ],
    },
)
