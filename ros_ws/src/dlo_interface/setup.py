from setuptools import find_packages, setup

package_name = "dlo_interface"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml", "README.md"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="dlo-vitac maintainers",
    maintainer_email="maintainers@dlo-vitac.dev",
    description="The contract of the dlo-vitac graph (pure Python): world, commands, task rules, grip law, camera, "
    "point-cloud layout, simulator backends.",
    license="Apache-2.0",
)
