from glob import glob

from setuptools import find_packages, setup

package_name = "tactile_bringup"

# launch/ and config/ are symbolic links to the repository's top-level folders, the one source of both.
setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/launch", glob("launch/*.launch.py")),
        ("share/" + package_name + "/config", glob("config/*.yaml") + glob("config/*.rviz")),
        ("share/" + package_name + "/config/scenes", glob("config/scenes/*.yaml")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Tactile stack maintainers",
    maintainer_email="maintainers@tactile-stack.org",
    description="Launch files and configuration of the tactile sensor stack.",
    license="Apache-2.0",
    entry_points={"console_scripts": ["tactile-demo = tactile_description.commands:tactile_demo",
                                    "tactile-latency = tactile_description.commands:tactile_latency"]},
)
