from glob import glob

from setuptools import find_packages, setup

package_name = "dlo_bringup"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        # ros2 launch dlo_bringup graph.launch.py
        ("share/" + package_name + "/launch", sorted(glob("launch/*.launch.py"))),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="dlo-vitac maintainers",
    maintainer_email="maintainers@dlo-vitac.dev",
    description="Starts the dlo-vitac graph: one description of its nodes, from which the launcher "
    "(scripts/launch_graph.sh) and the ROS 2 launch file are built.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "launch_graph = dlo_bringup.launcher:main",
            "topic_list = dlo_bringup.topic_list:main",
        ],
    },
)
