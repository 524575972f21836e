"""The build's one step beyond pyproject.toml: the checkout's top-level configs/ and procedures/
(the single copy in git, where DESIGN.md's layout puts them) are copied into the built package as
fieldcal/_shipped/, so an installed wheel finds `sim`, `field-18`, `imu_tk`, `paper-mimu` through
importlib.resources from any directory (fieldcal/paths.py). An editable install copies nothing:
it reads the checkout's own folders."""
import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

SHIPPED = ("configs", "procedures")  # MANIFEST.in grafts the same folders into the sdist


class BuildPyWithShippedFiles(build_py):
    def run(self):
        super().run()
        if self.editable_mode:
            return
        for name in SHIPPED:
            shutil.copytree(Path(name), Path(self.build_lib, "fieldcal", "_shipped", name), dirs_exist_ok=True,
                            ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))


setup(cmdclass={"build_py": BuildPyWithShippedFiles})
