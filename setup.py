"""Packaging only: ship the top-level ``aircraft/`` and ``approaches/`` inside the wheel.

pyproject.toml holds the project's metadata; this file adds what it cannot
say: the repository keeps the shipped aircraft and approaches at its top level
(the layout is fixed), and the wheel needs them as package data, so they are
mapped into ``testbed/_shipped/`` (read through :mod:`testbed.resources`).
"""

from setuptools import find_packages, setup

SHIPPED = {"testbed._shipped.aircraft": "aircraft", "testbed._shipped.approaches": "approaches"}

setup(
    packages=find_packages(include=["testbed", "testbed.*"]) + list(SHIPPED),
    package_dir=SHIPPED,
    package_data={
        "testbed": ["data/*.tsv"],
        "testbed._shipped.aircraft": ["*/*.toml", "*/*.xml", "*/**/*.xml"],
        "testbed._shipped.approaches": ["*.toml", "campaigns/*.toml", "calibration/*.json"],
    },
    include_package_data=False,
)
