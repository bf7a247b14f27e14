from glob import glob

from setuptools import find_packages, setup

package_name = "dlo_sim"

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
    description="Taichi particle-rope simulator of a cable with a two-finger tactile gripper, and its ROS 2 sim node.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "sim_node = dlo_sim.sim_node:main",
        ],
        # the simulator backend the gym env steps (dlo_interface.simulator): env option simulator=taichi
        "dlo_interface.simulators": [
            "taichi = dlo_sim.episode:TaskSim",
        ],
    },
)
