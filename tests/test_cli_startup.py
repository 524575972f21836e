"""fieldcal.cli.startup: a command's imports made with the cyclic collector paused, then frozen."""
from __future__ import annotations

import gc
import platform
import subprocess
import sys

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


def test_the_command_entry_point_keeps_the_imports_frozen_for_the_shutdown(tmp_path):
    """`fieldcal` ends its process: what its imports froze stays frozen, so the collection at
    interpreter shutdown skips it (the objects the command made are collected as ever)."""
    import subprocess
    import sys
    from importlib.metadata import entry_points

    (script,) = entry_points(group="console_scripts", name="fieldcal")
    assert script.value == "fieldcal.cli.main:run"
    body = ("import gc, sys\nfrom fieldcal.cli.main import run\n"
            f"sys.argv = ['fieldcal', 'calibrate', {str(tmp_path / 'missing.csv')!r}, '--out', {str(tmp_path)!r}]\n"
            "code = run()\nprint(code, gc.get_freeze_count())")
    proc = subprocess.run([sys.executable, "-c", body], capture_output=True, text=True, timeout=120)
    code, frozen = map(int, proc.stdout.split())
    assert code == 2 and "text files need --map" in proc.stderr  # refused, after its imports
    assert frozen > 10_000


_FAULTS_OF_A_SECOND_TEMPORARY = """
import resource, sys
import numpy as np
from fieldcal.cli.startup import reuse_freed_memory
if sys.argv[1] == "reuse":
    reuse_freed_memory()
def faults():
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
first = np.ones(3 << 20)  # 24 MiB, touched: a calibration's n x 3 column at imu_tk's recording joined 16x
small = np.ones(1 << 10)  # something live above it on the heap, as there always is
del first
before = faults()
second = np.ones(3 << 20)  # the next temporary of that size
print(faults() - before)
"""


@pytest.mark.skipif(not platform.libc_ver()[0] == "glibc", reason="the setting is glibc malloc's")
def test_reuse_freed_memory_makes_the_next_big_temporary_reuse_the_last_ones_pages():
    """A fresh process each (the setting is the process's for good); the kernel's count of page
    faults says whether the second 24 MiB temporary got pages anew (thousands of 4 KiB, or
    hundreds with transparent huge pages) or the first one's."""
    def faults(mode):
        out = subprocess.run([sys.executable, "-c", _FAULTS_OF_A_SECOND_TEMPORARY, mode], check=True,
                             capture_output=True, text=True).stdout
        return int(out)

    anew, reused = faults("plain"), faults("reuse")
    assert anew > 100  # without it the pages come anew: the test can tell
    assert reused < 20 and reused * 10 < anew
