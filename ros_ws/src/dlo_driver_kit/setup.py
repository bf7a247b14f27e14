from glob import glob

from setuptools import find_packages, setup

package_name = "dlo_driver_kit"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    # the shipped policy's robustness envelope, read by dlo-driver-check beside its module (dlo_driver_kit.envelope)
    package_data={package_name: ["shipped_envelope.json"]},
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
    description="The reference driver for a real robot (mock_driver_node) and the checker of the driver contract "
    "(dlo-driver-check).",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "mock_driver_node = dlo_driver_kit.mock_driver_node:main",
            "dlo-driver-check = dlo_driver_kit.driver_check:main",
        ],
    },
)
