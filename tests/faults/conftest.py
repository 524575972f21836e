"""Shared by the fault-injection tests: one short procedure run, copied for each test to damage."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from faultlib import fieldcal, run_argv


@pytest.fixture(scope="session")
def quick_session(tmp_path_factory) -> Path:
    """A completed run of the quick procedure (read-only: copy it before changing anything)."""
    out = tmp_path_factory.mktemp("quick")
    proc = fieldcal(*run_argv(out))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    (session,) = out.iterdir()
    return session


@pytest.fixture
def session_copy(quick_session, tmp_path) -> Path:
    d = tmp_path / quick_session.name
    shutil.copytree(quick_session, d)
    return d
