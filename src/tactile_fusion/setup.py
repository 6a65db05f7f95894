from glob import glob

from setuptools import find_packages, setup

package_name = "tactile_fusion"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/models/default", glob("models/default/*")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Tactile stack maintainers",
    maintainer_email="maintainers@tactile-stack.org",
    description="Force-distribution learning and inference for the multi-camera tactile sensor.",
    license="Apache-2.0",
    entry_points={"console_scripts": [
        "tactile-fusion = tactile_description.commands:tactile_fusion",
        "bundle_node = tactile_description.commands:bundle_node",
        "fusion_node = tactile_description.commands:fusion_node",
    ]},
)
