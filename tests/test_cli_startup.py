"""fieldcal.cli.startup: a command's imports made with the cyclic collector paused, then frozen."""
from __future__ import annotations

import gc

import pytest

from fieldcal.cli.startup import imports_uncollected


@pytest.fixture
def collector():
    """The collector as the test found it, and nothing left frozen."""
    enabled = gc.isenabled()
    yield
    gc.unfreeze()
    (gc.enable if enabled else gc.disable)()


def test_the_collector_is_paused_inside_and_what_was_made_is_frozen(collector):
    gc.enable()
    gc.unfreeze()
    with imports_uncollected():
        assert not gc.isenabled()
        made = [[] for _ in range(100)]  # tracked objects, as an import makes them
    assert gc.isenabled()
    assert gc.get_freeze_count() >= len(made)


def test_a_disabled_collector_stays_disabled(collector):
    gc.disable()
    with imports_uncollected():
        pass
    assert not gc.isenabled()


def test_the_collector_comes_back_when_an_import_fails(collector):
    gc.enable()
    with pytest.raises(ImportError):
        with imports_uncollected():
            import fieldcal.no_such_module  # noqa: F401
    assert gc.isenabled()


def test_main_gives_what_a_command_froze_back_to_the_collector(collector, tmp_path):
    """A test (or any process) calling main again and again keeps nothing frozen after it."""
    from fieldcal.cli.main import main

    gc.unfreeze()
    main(["calibrate", str(tmp_path / "missing.csv"), "--out", str(tmp_path)])  # refused, after its imports
    assert gc.get_freeze_count() == 0
