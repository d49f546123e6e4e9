from glob import glob

from setuptools import find_packages, setup

package_name = "hydro_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "hydro_ros.tooling"]),  # the tools that write docs/ and bench/results stay in the tree
    package_data={"hydro_ros.hmi": ["static/*"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml") + glob("config/*.dbc") + glob("config/*.json")),
        ("share/" + package_name + "/config/params", glob("config/params/*.yaml")),
        ("share/" + package_name + "/config/sros2", glob("config/sros2/*.xml")),
        ("share/" + package_name + "/launch", glob("launch/*.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="hydro_ros developers",
    maintainer_email="hydro-ros@example.org",
    description="Condition monitoring and energy-optimal motion for hydraulic manipulators",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "plant_sim = hydro_ros.nodes.plant_sim:main",
            "crane_sim = hydro_ros.nodes.crane_sim:main",
            "bag_player = hydro_ros.nodes.bag_player:main",
            "fdi_node = hydro_ros.nodes.fdi_node:main",
            "can_bridge = hydro_ros.nodes.can_bridge:main",
            "trajectory_server = hydro_ros.nodes.trajectory_server:main",
            "trajectory_executor = hydro_ros.nodes.trajectory_executor:main",
            "hmi = hydro_ros.nodes.hmi:main",
            "hydro-ros = hydro_ros.cli:main",
        ],
    },
)
