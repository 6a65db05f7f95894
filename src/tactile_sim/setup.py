from setuptools import find_packages, setup

package_name = "tactile_sim"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Tactile stack maintainers",
    maintainer_email="maintainers@tactile-stack.org",
    description="Simulator of the multi-camera tactile sensor (pure Python).",
    license="Apache-2.0",
    entry_points={"console_scripts": ["tactile-sim = tactile_description.commands:tactile_sim"]},
)
