"""Where the project's data folders are: ``configs/``, ``migrations/`` and ``usd_templates/``.

In a source checkout they sit at the top of the repository (the design card's layout). A built wheel
carries copies inside the package (``mixcount/_data/<name>``, put there by ``setup.py``'s build step),
found through :mod:`importlib.resources`, so ``pip install mixcount`` works outside any checkout.
The packaged copy wins when it exists; a source checkout (including an editable install) uses the
top-level folders.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

DATA_FOLDERS = ("configs", "migrations", "usd_templates")
SOURCE_ROOT = Path(__file__).resolve().parent.parent


def data_dir(name: str) -> Path:
    """The folder ``name`` (one of :data:`DATA_FOLDERS`) as a real directory on disk."""
    if name not in DATA_FOLDERS:
        raise ValueError(f"unknown data folder {name!r}; expected one of {DATA_FOLDERS}")
    packaged = resources.files("mixcount") / "_data" / name
    if packaged.is_dir():
        return Path(str(packaged))
    source = SOURCE_ROOT / name
    if source.is_dir():
        return source
    raise FileNotFoundError(
        f"mixcount data folder {name!r} is missing: neither {packaged} (wheel) nor {source} (checkout) exists"
    )
