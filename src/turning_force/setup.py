# colcon's ament_python build needs a setup.py; the metadata is in pyproject.toml.
from setuptools import setup

setup()
