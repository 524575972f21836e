"""Issue 25 (last review, items 2 and 7): a directory fieldcal creates is created exclusively.

`run --headless` names its session by the second, so a link planted at the next few names took
the session's writes wherever it pointed; `import --out LINK`, `run --out LINK`, `allan
--plot-dir LINK` followed the link the user named. Now every session or output directory comes
from one helper of fieldcal.atomic: os.mkdir, which fails on any name that exists (a link too,
dangling or not), then the next free name or a one-line refusal.
"""
from __future__ import annotations

import datetime
import os
from pathlib import Path

import pytest
from faultlib import QUICK, SEED
from test_outputs import one_line
from test_write_rule import params_csv  # noqa: F401 (a fixture, fetched by name)

from fieldcal.atomic import NAME_TRIES, RefusedTarget, new_directory, new_named_directory
from fieldcal.cli.main import main
from fieldcal.session import SessionError
from fieldcal.session.capture import SessionReader, SessionWriter


def _victims(tmp_path: Path) -> tuple[Path, Path]:
    """A folder of the user's (empty: anything in it afterwards was written through a link) and
    the path a dangling link aims at (it must never come to exist)."""
    folder = tmp_path / "victim-folder"
    folder.mkdir()
    return folder, tmp_path / "victim-dangling"


def test_a_name_fieldcal_picks_skips_every_planted_name(tmp_path):
    folder, dangling = _victims(tmp_path)
    base = tmp_path / "sessions"
    base.mkdir()
    (base / "run").symlink_to(folder)
    (base / "run-2").symlink_to(dangling)
    (base / "run-3").write_text("a file")
    made = new_named_directory(base, "run")
    assert made == base / "run-4" and made.is_dir() and not made.is_symlink()
    assert list(folder.iterdir()) == [] and not dangling.exists()
    assert (base / "run-3").read_text() == "a file"


def test_a_name_taken_every_time_is_refused_in_one_line(tmp_path):
    _, dangling = _victims(tmp_path)
    for i in range(1, NAME_TRIES + 1):
        (tmp_path / ("run" if i == 1 else f"run-{i}")).symlink_to(dangling)
    with pytest.raises(RefusedTarget) as err:
        new_named_directory(tmp_path, "run")
    assert str(err.value).startswith(f"{tmp_path / 'run'}: this name and the next {NAME_TRIES - 1} are taken")
    assert not dangling.exists()


@pytest.mark.parametrize("target", ["folder", "dangling"])
def test_a_session_is_never_created_through_a_link(tmp_path, target):
    folder, dangling = _victims(tmp_path)
    link = tmp_path / "new-session"
    link.symlink_to(folder if target == "folder" else dangling)
    with pytest.raises(SessionError) as err:
        SessionWriter.create(link, {"by": "test"})
    assert str(err.value).startswith(f"{link}: is a symbolic link; fieldcal never writes through a link")
    assert list(folder.iterdir()) == [] and not dangling.exists()


def test_an_empty_folder_the_user_made_is_taken_and_a_full_one_refused(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert new_directory(empty) == empty
    (empty / "x").write_text("mine")
    with pytest.raises(RefusedTarget, match="already exists and is not empty"):
        new_directory(empty)
    made = new_directory(tmp_path / "made", empty_ok=False)
    with pytest.raises(RefusedTarget, match="already exists and is not empty"):
        new_directory(made, empty_ok=False)  # created by another: not taken, even empty


def test_run_headless_skips_links_planted_at_its_session_names(capsys, tmp_path, monkeypatch, quick_procedure):
    """The attack of the review: links at this second's session name and the next; the run's
    session goes to the next free name, and nothing lands in the linked folder."""
    from fieldcal.cli import sessions

    now = datetime.datetime(2026, 11, 27, 10, 0, 0)

    class Frozen(datetime.datetime):
        @classmethod
        def now(cls, tz=None):
            return now

    monkeypatch.setattr(sessions, "datetime", type("M", (), {"datetime": Frozen}))
    folder, dangling = _victims(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    name = f"{quick_procedure.stem}-seed{SEED}-{now:%Y%m%d-%H%M%S}"
    (out / name).symlink_to(folder)
    (out / f"{name}-2").symlink_to(dangling)
    assert main(["run", "--headless", "--quiet", "--seed", str(SEED), "--procedure", str(quick_procedure),
                 "--out", str(out)]) == 0
    assert f"session {out / f'{name}-3'}" in capsys.readouterr().out
    SessionReader(out / f"{name}-3")
    assert list(folder.iterdir()) == [] and not dangling.exists()


@pytest.mark.parametrize("command", ["import", "run", "allan"])
@pytest.mark.parametrize("target", ["folder", "dangling", "file"])
def test_a_directory_the_user_names_that_is_a_link_is_refused(capsys, tmp_path, command, target, quick_session):
    folder, dangling = _victims(tmp_path)
    victim_file = tmp_path / "victim-file"
    victim_file.write_text("mine")
    link = tmp_path / "link"
    link.symlink_to({"folder": folder, "dangling": dangling, "file": victim_file}[target])
    text = tmp_path / "rec.csv"
    text.write_text("time_ms,ax_mg,ay_mg,az_mg,gx_dps,gy_dps,gz_dps\n"
                    + "".join(f"{10 * i},1,2,1000,0.5,0,0\n" for i in range(50)))
    argv = {"import": ["import", text, "--map", "single-csv", "--out", link],
            "run": ["run", "--headless", "--quiet", "--procedure", QUICK, "--out", link],
            "allan": ["allan", quick_session, "--plot-dir", link]}[command]
    flag = "--plot-dir" if command == "allan" else "--out"
    line = one_line(capsys, argv, 2)
    assert line == (f"fieldcal: {flag} {link}: is a symbolic link; fieldcal never writes through a link "
                    "(give the directory it points at, or another path)")
    assert list(folder.iterdir()) == [] and not dangling.exists() and victim_file.read_text() == "mine"
    assert os.path.islink(link)


# ------------------------------------------------------------------------------------------
# item 7: a link slipped in after the check


def test_a_link_slipped_in_after_the_last_check_is_replaced_not_written_through(tmp_path, monkeypatch):
    from fieldcal import atomic

    victim = tmp_path / "victim.txt"
    victim.write_text("mine")
    target = tmp_path / "out" / "p.yaml"
    target.parent.mkdir()
    checks = []
    real_check = atomic.check_target

    def check_then_plant(path, **kw):
        result = real_check(path, **kw)
        checks.append(path)
        if len(checks) == 2:  # the last check before the rename has passed: the attacker's turn
            Path(path).symlink_to(victim)
        return result

    monkeypatch.setattr(atomic, "check_target", check_then_plant)
    atomic.write_atomically(target, b"new\n")
    assert len(checks) == 2 and victim.read_text() == "mine"
    assert not target.is_symlink() and target.read_bytes() == b"new\n"


def test_a_folder_swapped_for_a_link_during_the_write_does_not_move_the_write(tmp_path):
    """The folder is held open from the start: the file lands in the folder that was checked,
    not in the one a link swapped in for it points at."""
    from fieldcal import atomic

    elsewhere = tmp_path / "victim-folder"
    elsewhere.mkdir()
    folder = tmp_path / "out"
    folder.mkdir()
    with atomic.atomic_file(folder / "p.yaml") as pending:
        pending.file.write(b"new\n")
        folder.rename(tmp_path / "out-moved")
        folder.symlink_to(elsewhere)
    assert list(elsewhere.iterdir()) == []
    assert (tmp_path / "out-moved" / "p.yaml").read_bytes() == b"new\n"
    assert [p.name for p in (tmp_path / "out-moved").iterdir()] == ["p.yaml"]  # no temp left


def test_apply_into_a_folder_that_is_a_link_is_refused(capsys, tmp_path, request):
    """Several inputs go into the folder --out names: a link to a folder is refused like any other."""
    params, csv = request.getfixturevalue("params_csv")
    folder, _ = _victims(tmp_path)
    link = tmp_path / "link"
    link.symlink_to(folder)
    second = tmp_path / "two.csv"
    second.write_bytes(csv.read_bytes())
    line = one_line(capsys, ["apply", params, csv, second, "--map", "single-csv", "--out", link], 2)
    assert line.startswith(f"fieldcal: --out {link}: is a symbolic link; fieldcal never writes through a link")
    assert list(folder.iterdir()) == []
