from glob import glob

from setuptools import find_packages, setup

package_name = "dlo_bag"

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
    description="Recording (rosbag2 MCAP, crash-safe), playback, recovery, inspection and analysis (plots, videos) "
    "of the dlo-vitac graph's topics.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "recorder_node = dlo_bag.recorder_node:main",
            "playback_node = dlo_bag.playback_node:main",
            "dlo-bag-info = dlo_bag.bag_info:main",
            "dlo-bag-recover = dlo_bag.recover:main",
            "dlo-analyze = dlo_bag.analysis:main",
        ],
    },
)
