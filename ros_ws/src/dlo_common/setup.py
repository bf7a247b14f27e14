from setuptools import find_packages, setup

package_name = "dlo_common"

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
    description="Base of the dlo-vitac nodes: declared and checked parameters, --help, parameter files, "
    "the shared main() (init, spin, clean shutdown, exit codes), and the process's one Taichi runtime.",
    license="Apache-2.0",
)
