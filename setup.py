"""The repository's data folders ship inside the package (``dyno.resources.hardware``,
``dyno.resources.calibration``): pyproject.toml cannot map a folder outside the package tree, so this file
adds those mappings; the rest of the configuration is in pyproject.toml."""

from pathlib import Path

from setuptools import find_packages, setup

# The repository's own folders as subpackages of dyno.resources, read by dyno.resources.resource.
RESOURCES = {"dyno.resources.hardware": "hardware", "dyno.resources.calibration": "calibration"}
# The prebuilt firmware (`make -C firmware release`: two HEX files and their stamp), when it was built.
if (Path(__file__).parent / "firmware" / "build" / "firmware.json").is_file():
    RESOURCES["dyno.resources.firmware"] = "firmware/build"

setup(packages=find_packages(include=["dyno*"]) + list(RESOURCES), package_dir=RESOURCES)
