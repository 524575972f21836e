"""Shared by the fault-injection tests: one short procedure run, copied for each test to damage."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from brisk_quick import brisk_quick
from faultlib import fieldcal, run_argv


@pytest.fixture(scope="session")
def quick_procedure(tmp_path_factory) -> Path:
    """The quick procedure with brisk rate steps (brisk_quick): 645 s of samples, not 1565 s, in
    a session that the tests copy, damage, kill, resume, replay and plot again; none of them is
    about the rate steps' speed."""
    return brisk_quick(tmp_path_factory.mktemp("procedure"))


@pytest.fixture(scope="session")
def quick_session(tmp_path_factory, quick_procedure) -> Path:
    """A completed run of the quick procedure (read-only: copy it before changing anything)."""
    out = tmp_path_factory.mktemp("quick")
    proc = fieldcal(*run_argv(out, quick_procedure))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    (session,) = out.iterdir()
    return session


@pytest.fixture
def session_copy(quick_session, tmp_path) -> Path:
    d = tmp_path / quick_session.name
    shutil.copytree(quick_session, d)
    return d
