from glob import glob

from setuptools import find_packages, setup

package_name = "dlo_policy"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        # the SAC defaults and the policy node's parameters file (tools/gen_node_configs.py)
        ("share/" + package_name + "/config", ["config/sac_default.yaml", "config/policy_node.yaml"]),
        # the shipped policies, one directory each (actor + run config + README): policies/all, the All-modalities
        # policy, is what policy_node runs by default; another is picked by name (--checkpoint shipped:NAME)
        *[
            ("share/" + package_name + "/" + d, sorted(glob(d + "/*")))
            for d in sorted(p.rstrip("/") for p in glob("policies/*/"))
        ],
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="dlo-vitac maintainers",
    maintainer_email="maintainers@dlo-vitac.dev",
    description=(
        "Gymnasium environment, Soft Actor-Critic training and evaluation, scripted baselines, and the ROS 2 policy node."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "dlo-train = dlo_policy.train:main",
            "dlo-evaluate = dlo_policy.evaluate:main",
            "dlo-experiments = dlo_policy.experiments:main",
            "dlo-report = dlo_policy.report:main",
            "dlo-validate-vision = dlo_policy.validate_vision:main",
            "dlo-normalizer-drift = dlo_policy.normalizer_drift:main",
            "dlo-robustness = dlo_policy.robustness:main",
            "policy_node = dlo_policy.policy_node:main",
        ],
    },
)
