"""Shipped configs, procedures, import maps and specs found by name from any directory, and a
user's own file of the same name winning over the shipped one (fieldcal.paths, one rule for all
four kinds). The installed wheel is tested in tests/test_wheel.py."""
from __future__ import annotations

from pathlib import Path

import pytest

from fieldcal.acceptance import SpecError, load_spec
from fieldcal.config import ConfigError, load_config
from fieldcal.paths import SHIPPED_KINDS, shipped_dir, shipped_names
from fieldcal.procedure.positions import ProcedureError, load_procedure
from fieldcal.recording.import_map import ImportMapError, load_import_map

CHECKOUT = Path(__file__).resolve().parent.parent

# the name each kind is asked for by (the README's and the demo's), and its loader
LOADERS = {
    "config": ("sim", load_config, ConfigError),
    "procedure": ("field-18", load_procedure, ProcedureError),
    "import map": ("imu_tk", load_import_map, ImportMapError),
    "product spec": ("paper-mimu", load_spec, SpecError),
}


def test_in_a_checkout_the_shipped_files_are_its_top_level_folders():
    """DESIGN.md's layout: one copy, at the top of the checkout (a wheel copies it in at build)."""
    for kind, folder in SHIPPED_KINDS.items():
        assert shipped_dir(kind) == CHECKOUT / folder
        assert shipped_names(kind) == sorted(p.stem for p in (CHECKOUT / folder).glob("*.yaml"))
        assert shipped_names(kind), kind


@pytest.mark.parametrize("kind", LOADERS)
def test_a_shipped_name_resolves_from_an_unrelated_directory(kind, tmp_path, monkeypatch):
    name, load, _ = LOADERS[kind]
    monkeypatch.chdir(tmp_path)
    loaded = load(name)
    if kind == "procedure":
        assert loaded.name == name
    else:
        assert Path(loaded.path) == CHECKOUT / SHIPPED_KINDS[kind] / f"{name}.yaml"


@pytest.mark.parametrize("kind", ["config", "import map", "product spec"])
def test_a_users_file_of_the_same_name_wins(kind, tmp_path, monkeypatch):
    name, load, _ = LOADERS[kind]
    monkeypatch.chdir(tmp_path)
    (tmp_path / f"{name}.yaml").write_bytes((shipped_dir(kind) / f"{name}.yaml").read_bytes())
    assert Path(load(name).path) == Path(f"{name}.yaml")  # the working directory's, not the shipped
    elsewhere = tmp_path / "mine"
    elsewhere.mkdir()
    (elsewhere / f"{name}.yaml").write_bytes((shipped_dir(kind) / f"{name}.yaml").read_bytes())
    assert Path(load(elsewhere / f"{name}.yaml").path) == elsewhere / f"{name}.yaml"


def test_a_users_procedure_of_a_shipped_name_wins(tmp_path, monkeypatch):
    """Before: a procedure name always meant the shipped file, unlike configs and maps."""
    monkeypatch.chdir(tmp_path)
    own = (shipped_dir("procedure") / "allan.yaml").read_text().replace("name: allan", "name: my-field-18")
    (tmp_path / "field-18.yaml").write_text(own)
    assert load_procedure("field-18").name == "my-field-18"


@pytest.mark.parametrize("kind", LOADERS)
def test_an_unknown_name_is_one_line_listing_the_shipped_ones(kind, tmp_path, monkeypatch):
    _, load, error = LOADERS[kind]
    monkeypatch.chdir(tmp_path)
    with pytest.raises(error) as caught:
        load("no-such-name")
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith(f"no-such-name: no such {kind} (not a file, nor no-such-name.yaml here")
    assert message.endswith(f"the shipped {kind}s: {', '.join(shipped_names(kind))})")
