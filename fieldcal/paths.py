"""Where the station's shipped files live, and the one rule that finds a file by name; stdlib
only, so a command's --help can list them.

The checkout keeps them at the top (``configs/``, ``procedures/``, DESIGN.md's layout), the single
copy in git; a built wheel carries that copy inside the package as ``fieldcal/_shipped/`` (see
setup.py), read through ``importlib.resources`` so ``sim``, ``field-18`` and ``imu_tk`` resolve
from any directory once installed. An editable install or a checkout on sys.path has no
``_shipped``: the checkout's own folders are the shipped files.
"""
from __future__ import annotations

import os
from importlib.resources import files
from pathlib import Path

# kind -> its folder under the shipped root (the checkout's top, or the package's _shipped/)
SHIPPED_KINDS = {
    "config": "configs",
    "procedure": "procedures",
    "import map": "configs/recordings",
    "product spec": "configs/specs",
}


def _shipped_root() -> Path:
    packaged = files("fieldcal") / "_shipped"
    if isinstance(packaged, Path) and packaged.is_dir():  # an installed wheel (pip unpacks it to files)
        return packaged
    return Path(__file__).resolve().parent.parent  # the checkout: its top-level configs/, procedures/


SHIPPED_ROOT = _shipped_root()


def shipped_dir(kind: str) -> Path:
    """The folder of the shipped files of one kind (a key of SHIPPED_KINDS)."""
    return SHIPPED_ROOT / SHIPPED_KINDS[kind]


def shipped_names(kind: str) -> list[str]:
    """The names (file stems) of the shipped files of one kind, sorted."""
    return sorted(p.stem for p in shipped_dir(kind).glob("*.yaml") if p.is_file())


def find_named(name_or_path: str | os.PathLike, kind: str) -> Path | None:
    """The file a command's argument names, or None. A user's own file wins: the path as given,
    then (for a bare name) NAME.yaml in the working directory, then the shipped NAME.yaml."""
    given = Path(name_or_path)
    if given.suffix:
        candidates = [given]
    else:
        candidates = [given, given.with_suffix(".yaml"), shipped_dir(kind) / f"{given.name}.yaml"]
    return next((c for c in candidates if c.is_file()), None)


def not_found(name_or_path: str | os.PathLike, kind: str) -> str:
    """One line saying where a name was looked for and which shipped names there are (the folder
    named, so a user of an installed fieldcal can copy a shipped file to edit)."""
    given = Path(name_or_path)
    where = "" if given.suffix else f", nor {given}.yaml here, nor in {shipped_dir(kind)}"
    known = ", ".join(shipped_names(kind)) or "none"
    return f"{given}: no such {kind} (not a file{where}; the shipped {kind}s: {known})"


CONFIGS_DIR = shipped_dir("config")
RECORDINGS_DIR = shipped_dir("import map")  # import maps
PROCEDURES_DIR = shipped_dir("procedure")
SPECS_DIR = shipped_dir("product spec")
