"""The wheel's packages: the code's, and the shipped data as package data under bench.data.

The repository keeps the robots' URDFs and the configs at its top (``urdf/``,
``hil_configs/``: the folders a checkout edits and the README's commands name); the
wheel maps them to ``bench/data/urdf`` and ``bench/data/hil_configs``, where
:mod:`bench.paths` finds them through importlib.resources once installed.
"""

from setuptools import find_packages, setup

DATA = {"bench.data.urdf": "urdf", "bench.data.hil_configs": "hil_configs"}

setup(packages=find_packages(include=["bench*", "drivers*", "trajectories*"]) + list(DATA), package_dir=DATA)
