from glob import glob

from setuptools import find_packages, setup

package_name = "dlo_perception"

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
    description="Tactile and top-view vision distillation of the cable pose, and their ROS 2 nodes.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "tactile_node = dlo_perception.tactile_node:main",
            "vision_node = dlo_perception.vision_node:main",
        ],
    },
)
