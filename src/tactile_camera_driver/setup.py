from setuptools import find_packages, setup

package_name = "tactile_camera_driver"

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
    description="Camera drivers of the tactile sensor: real cameras and video files through OpenCV, and the simulator.",
    license="Apache-2.0",
    entry_points={"console_scripts": [
        "camera_node = tactile_description.commands:camera_node",
        "sim_camera_node = tactile_description.commands:sim_camera_node",
    ]},
)
