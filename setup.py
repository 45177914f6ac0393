"""Build step that ships the top-level data folders inside the wheel (metadata lives in pyproject.toml).

``configs/``, ``migrations/`` and ``usd_templates/`` stay at the top of the repository and are copied to
``mixcount/_data/`` in the build; :mod:`mixcount.resources` finds them there with importlib.resources.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

DATA_FOLDERS = ("configs", "migrations", "usd_templates")


class BuildPyWithData(build_py):
    def run(self) -> None:
        super().run()
        if self.editable_mode:  # an editable install reads the folders from the checkout
            return
        root = Path(__file__).resolve().parent
        for name in DATA_FOLDERS:
            target = Path(self.build_lib) / "mixcount" / "_data" / name
            if target.exists():
                shutil.rmtree(target)
            shutil.copytree(root / name, target, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))


setup(cmdclass={"build_py": BuildPyWithData})
