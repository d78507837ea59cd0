from glob import glob

from setuptools import find_packages, setup

package_name = "piezo_ff_ros"
executables = ["driver", "compensator", "trajectory", "recorder", "plotter", "reproduce"]

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*", "bench"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/launch", glob("launch/*.py")),
        # Foxglove layouts of the plottable topics (docs/topics.md "Plotting")
        ("share/" + package_name + "/foxglove", glob("share/foxglove/*.json")),
        # `ros2 run` looks in lib/<pkg>/; after a plain `pip install .` scripts live in bin/: tiny shims bridge it.
        ("lib/" + package_name, ["ros2run/" + e for e in executables]),
    ],
    install_requires=["setuptools"],
    # vendor packages of the hardware backends (docs/hardware.md): pip install "piezo_ff_ros[nidaqmx]";
    # `colcon test` runs pytest only for packages that declare it as a test dependency (else: 0 tests, success)
    extras_require={"nidaqmx": ["nidaqmx>=1.0"], "pipython": ["pipython>=2.10"], "test": ["pytest"]},
    zip_safe=True,
    maintainer="piezo_ff_ros developers",
    maintainer_email="piezo_ff_ros@example.com",
    description="Sensorless multivariable feedforward compensation of piezoelectric positioners (ROS 2)",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [f"{e} = {package_name}.entry_points:{e}" for e in executables]
        + [f"piezo-ff = {package_name}.entry_points:piezo_ff"],
        # driver backends as plug-ins: a lab adds its own in this group from its own package
        "piezo_ff_ros.backends": [f"{b} = {package_name}.backends.{m}:SPEC"
                                  for b, m in (("sim", "sim"), ("nidaqmx", "nidaqmx_backend"), ("pi_gcs", "pi_gcs"))],
    },
)
