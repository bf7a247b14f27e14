from glob import glob

from setuptools import find_packages, setup

package_name = "dlo_tools"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        # parameters files of the nodes (tools/gen_node_configs.py): --ros-args --params-file
        ("share/" + package_name + "/config", sorted(glob("config/*.yaml"))),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="dlo-vitac maintainers",
    maintainer_email="maintainers@dlo-vitac.dev",
    description="Recording (rosbag2 MCAP), playback and bag inspection tools for the dlo-vitac ROS 2 graph.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "recorder_node = dlo_tools.recorder_node:main",
            "playback_node = dlo_tools.playback_node:main",
            "dlo-bag-info = dlo_tools.bag_info:main",
            "dlo-bag-recover = dlo_tools.recover:main",
            "dlo-analyze = dlo_tools.analysis:main",
            "mock_driver_node = dlo_tools.mock_driver_node:main",
            "dlo-driver-check = dlo_tools.driver_check:main",
            "foxglove_bridge = dlo_tools.foxglove_bridge_node:main",
        ],
    },
)
