"""Shared fixtures: a noise-free field-18 run of the simulated MIMU and its exact noise."""
from __future__ import annotations

import dataclasses
import sys
from functools import lru_cache
from pathlib import Path

# Before numpy: fieldcal's package sets OpenBLAS to one thread, which only counts when set before
# numpy loads. xdist's workers inherit it from the controller's environment; without this a
# `pytest -n 0` process ran threaded BLAS, whose spinning threads took 0.15 s of CPU for a 162x162
# Cholesky factor on the loaded 2-core machine (0.15 ms on one thread).
import fieldcal  # noqa: F401,I001

import numpy as np
import pytest
from hypothesis import settings as hypothesis_settings

from drivers.sim import TriadNoise
from drivers.sim.device import paper_mimu
from fieldcal.solvers.assemble import build_problem
from fieldcal.model import params_from_k
from fieldcal.procedure.positions import load_procedure
from fieldcal.run.simcal import DEFAULT_STATION
from fieldcal.run.simrun import plan_procedure, simulate_averages
from fieldcal.solvers.solve import average_covariance, models_from_truth


# No Hypothesis example may fail for taking long: on a loaded machine (two workers, other jobs)
# the default 200 ms deadline is a wall-clock threshold. Each property test says so too.
hypothesis_settings.register_profile("fieldcal", deadline=None)
hypothesis_settings.load_profile("fieldcal")


@dataclasses.dataclass(frozen=True)
class ExactRun:
    """Noise-free window means and their covariance under the paper's noise, per triad."""

    plan: object
    means: dict  # name -> (n_windows, 3) noise-free
    covariances: dict  # name -> covariance of the problem data
    orders: dict  # name -> window order of the problem data
    truth: dict  # name -> true parameters
    device: dict
    angles: np.ndarray
    # name -> Cholesky factor of covariances[name], made at the first draw: the statistical tests
    # draw hundreds of problems, and factoring the gyro's covariance each time took most of their CPU
    roots: dict = dataclasses.field(default_factory=dict, compare=False, repr=False)

    def problem(self, name, rng=None, **overrides):
        """The triad's problem with averages drawn from their exact distribution."""
        truth = self.device[name]
        means = self.means[name].copy()
        order = self.orders[name]
        if rng is not None:
            if name not in self.roots:
                self.roots[name] = np.linalg.cholesky(self.covariances[name])
            noise = self.roots[name] @ rng.standard_normal(3 * len(order))
            means[order] += noise.reshape(-1, 3)
        problem, _ = build_problem(name, truth.kind, truth.output_unit, list(self.plan.windows),
                                   means, DEFAULT_STATION, field18_ids())
        return dataclasses.replace(problem, **overrides) if overrides else problem


@lru_cache(maxsize=1)
def field18_ids() -> tuple:
    """field-18's position ids, its file parsed once: a parse is 8 ms, and the statistical tests
    draw a problem hundreds of times (test_efficiency's 250 draws spent 2 s of their 5 s on it)."""
    return tuple(p.id for p in load_procedure("field-18").positions)


@lru_cache(maxsize=4)
def exact_run(seed: int = 7, raw_counts: bool = False) -> ExactRun:
    noisy = paper_mimu(raw_counts=raw_counts)
    silent = {n: dataclasses.replace(t, noise=TriadNoise(white=0.0), lsb=0.0) for n, t in noisy.items()}
    plan = plan_procedure(load_procedure("field-18"), 250.0, np.random.default_rng(seed))
    means, angles = simulate_averages(plan, silent, DEFAULT_STATION, 250.0, seed=seed)
    ids = field18_ids()
    covs, orders = {}, {}
    for name, truth in noisy.items():
        _, order = build_problem(name, truth.kind, truth.output_unit, list(plan.windows), means[name],
                                 DEFAULT_STATION, ids)
        orders[name] = order
        covs[name] = average_covariance(models_from_truth(noisy)[name], [plan.windows[i] for i in order],
                                        250.0)
    truth = {n: params_from_k(t.K, t.bias) for n, t in noisy.items()}
    return ExactRun(plan, means, covs, orders, truth, noisy, angles)


@pytest.fixture(scope="session")
def field18():
    return exact_run()


@pytest.fixture(scope="session", autouse=True)
def private_data_home(tmp_path_factory):
    """Runs record their calibrations in the unit registry under $XDG_DATA_HOME: the tests' go
    to a temporary one (subprocesses inherit it), never the developer's."""
    import os

    before = os.environ.get("XDG_DATA_HOME")
    os.environ["XDG_DATA_HOME"] = str(tmp_path_factory.mktemp("xdg-data"))
    yield
    if before is None:
        os.environ.pop("XDG_DATA_HOME", None)
    else:
        os.environ["XDG_DATA_HOME"] = before


@pytest.fixture(autouse=True)
def signal_handlers_as_found():
    """A test that leaves SIGINT or SIGTERM handled otherwise than it found them changes what
    every later test in its xdist worker sees, so a failure then depends on the order the tests
    were dealt (issue 26: a Ctrl-C test once failed in a loaded run and nowhere else): the test
    that leaves them changed fails itself, at its teardown."""
    import signal

    found = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    yield
    left = {s: signal.getsignal(s) for s in found}
    changed = {signal.Signals(s).name: (found[s], left[s]) for s in found if left[s] is not found[s]}
    assert not changed, f"the test left these signal handlers changed (found, left): {changed}"


# --------------------------------------------------------------------------------------------
# The fast loop and the parallel run (issue 26)

SLOW_LIST = Path(__file__).parent / "slow_tests.txt"
# Module fixtures that take long to build: every test that uses one is slow, and (xdist
# --dist loadgroup) all of one module's users of it run on one worker, which builds it once.
SLOW_FIXTURES = {"planned"}
SHARED_FIXTURES = {"planned", "session", "serial_session", "pristine_session", "headless_classic12",
                   "headless_field18", "classic12_session", "solved", "xsens", "ferraris", "imucal_result",
                   "mishap_run", "mypy_cache", "clockless_cycled_run",
                   # built on both workers in a measured run (0.2-2 s of CPU each time)
                   "warmup", "jackal", "text_files", "recording", "acc_curves", "half_run", "params_csv",
                   "real_bin", "one_turn_per_rate_step", "seed380", "paper5_first_calibration",
                   # test_wheel's built and installed wheel: built on two workers, 4.3 s of CPU each
                   "installed"}
# Session fixtures shared by several files: their users, whatever the file, run as one group.
SHARED_ACROSS_FILES = {"quick_session"}


def slow_test_ids() -> set[str]:
    """The node ids (relative to the repository) tests/slow_tests.txt names."""
    lines = (line.strip() for line in SLOW_LIST.read_text(encoding="utf-8").splitlines())
    return {f"tests/{line}" for line in lines if line and not line.startswith("#")}


# `-n auto` (make test, make test-fast): one worker per core and one more. A third of the whole
# suite's test time is idle: simulated live units paced on the clock, the TUI's screens drawn in
# real time, pseudo-terminals and subprocesses waited for (152 s of 532 s in a quiet run of
# 7b4dcfa, 2026-11-28); an extra worker fills those waits. Quiet on 2 cores: 274 s with two
# workers, 241 s with three (the same tree, back to back). PYTEST_XDIST_AUTO_NUM_WORKERS still
# sets the count (xdist's own hook reads it).
@pytest.hookimpl(tryfirst=True)
def pytest_xdist_auto_num_workers(config):
    import os

    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None  # xdist's own hook gives the number asked for
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return cores + 1


# tryfirst: xdist's own hook (loadgroup) turns each test's xdist_group mark into its node id's
# "@group" suffix, by which it schedules; run after it, the marks set here came too late and
# every shared fixture was built on both workers.
@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    slow = slow_test_ids()
    for item in items:
        used = set(getattr(item, "fixturenames", ()))
        if item.nodeid in slow or item.nodeid.split("::")[0] in slow or used & SLOW_FIXTURES:
            item.add_marker(pytest.mark.slow)
        shared, across = sorted(used & SHARED_FIXTURES), sorted(used & SHARED_ACROSS_FILES)
        if across:
            item.add_marker(pytest.mark.xdist_group(across[0]))
        elif shared:
            item.add_marker(pytest.mark.xdist_group(f"{item.nodeid.split('::')[0]}:{shared[0]}"))


# The schedule (issue 26): xdist deals the tests out in collection order (loadgroup: each shared
# fixture's group as one unit, the largest groups first, then one test at a time), so a long test
# that happens to come late in the alphabet (test_wheel's 8 s) runs while the other workers have
# nothing left, and the run waits for it. The tests marked slow, and the groups holding one, go
# first; the many short ones then fill the end evenly (a replay of a whole run's per-test times:
# 8 s off a 250 s run on 3 workers). Only in an xdist worker: in one process (-n 0), moving a
# file's slow tests away from the rest would build its module fixtures twice.
class SlowestFirst:
    @staticmethod
    def order(items: list) -> list:
        """The items, those marked slow and every member of a group with a slow one first, each
        part in collection order."""
        slow_groups = {_group(item) for item in items if item.get_closest_marker("slow")}
        slow_groups.discard(None)
        return sorted(items, key=lambda item: not (item.get_closest_marker("slow") or _group(item) in slow_groups))

    @pytest.hookimpl(trylast=True)  # after the marks are made (the hook above)
    def pytest_collection_modifyitems(self, items):
        items[:] = self.order(items)


def _group(item):
    mark = item.get_closest_marker("xdist_group")
    return mark.args[0] if mark and mark.args else None


def pytest_configure(config):
    # an xdist worker, unless --failed-first asks for another order
    if hasattr(config, "workerinput") and not getattr(config.option, "failedfirst", False):
        config.pluginmanager.register(SlowestFirst(), "fieldcal-slowest-first")
    if _starts_workers(config) and not sys.dont_write_bytecode and config.getoption("assertmode") == "rewrite":
        rewrite_test_modules_once(config, sorted(_test_modules(config)))


# Each xdist worker imports every test module, and pytest rewrites a test module's asserts
# (parse, rewrite, compile) unless its __pycache__ holds the rewritten code of that source. In a
# fresh clone, or after a test file is edited, the workers all did that work at once: 6 s of CPU
# each for the whole suite (`pytest --collect-only`: 8.8 s cold, 3.0 s with the cache; at a load of
# 11, 2026-11-28), and a fresh clone's `make test` spent 7.7 s of CPU per worker before its first
# test. The controller writes the missing ones once, before the workers start; they then read them.
# pytest's own (private) rewrite and cache writer do it, the version pinned in constraints.txt;
# test_suite_lists judges the result with pytest's cache reader.
def _starts_workers(config) -> bool:
    return (not hasattr(config, "workerinput") and bool(config.getoption("numprocesses", None))
            and config.getoption("dist", "no") != "no")


def _test_modules(config) -> set:
    """The test modules the workers will import: those of the paths given (testpaths by default),
    and every conftest.py."""
    tests = Path(__file__).parent
    modules = set(tests.rglob("conftest.py"))
    for arg in config.args:
        path = Path(config.invocation_params.dir, arg.split("::")[0]).resolve()
        found = path.rglob("test_*.py") if path.is_dir() else [path]
        modules.update(module for module in found if module.name.startswith("test_") and module.suffix == ".py"
                       and tests in module.parents and module.is_file())
    return modules


def rewrite_test_modules_once(config, paths) -> list:
    """Write pytest's rewritten code of each test module whose cache is missing or stale; the
    ones written. Stale as pytest's own reader judges it: the source's mtime and size in the
    header (the header alone is read here, not the code)."""
    import importlib.util
    import os
    import struct

    from _pytest.assertion import rewrite

    state = config.stash[rewrite.assertstate_key]
    written = []
    for source in paths:
        pyc = rewrite.get_cache_dir(source) / (source.name[:-3] + rewrite.PYC_TAIL)
        stat = os.stat(source)
        expected = importlib.util.MAGIC_NUMBER + bytes(4) + struct.pack(
            "<LL", int(stat.st_mtime) & 0xFFFFFFFF, stat.st_size & 0xFFFFFFFF)
        try:
            with open(pyc, "rb") as cached:
                if cached.read(16) == expected:
                    continue
        except OSError:
            pass
        try:
            source_stat, code = rewrite._rewrite_test(source, config)
        except SyntaxError:
            continue  # the worker's import says where
        if rewrite.try_makedirs(pyc.parent) and rewrite._write_pyc(state, code, source_stat, pyc):
            written.append(source)
    return written


# The cyclic collector and the long-lived objects of a test process (issue 26): collecting 2100
# tests makes about a million tracked objects (modules, scipy's parsed docstrings, the items) that
# are never garbage, and every full collection scans them all again; pytest's unraisable-exception
# check ends each process with five full collections, 2.6 s of CPU in a worker. Frozen
# (gc.freeze), they are skipped. Objects are still freed when nothing refers to them; only cyclic
# garbage alive at the freeze would stay uncollected, and each freeze below follows a collection
# that found none. (fieldcal.cli.main's thaw, after an in-process command, unfreezes them.)
def _collect_then_freeze() -> None:
    import gc

    for _ in range(5):  # a collection's finalizers can leave more garbage for the next
        if gc.collect() == 0:
            break
    gc.freeze()


@pytest.hookimpl(trylast=True)
def pytest_collection_finish(session):
    _collect_then_freeze()


# Before the unraisable-exception plugin's own collections (a cleanup run after this hook): the
# garbage the tests left is collected here, its finalizers' errors are still caught and reported
# by that plugin (its hook is in place until then), and its five collections skip the rest.
def pytest_unconfigure(config):
    _collect_then_freeze()
