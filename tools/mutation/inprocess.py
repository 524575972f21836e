"""pytest plugin: run many of mutmut's mutants in one pytest process.

`mutmut run` starts a process per mutant, which on this suite (seconds to import numpy, scipy and
the project, fixtures built again each time) means days on 2 cores. Here one process runs a
module's mutants, each switched on by mutmut's own switch (`set_mutant_under_test`, which the
generated trampolines read on every call).

Environment: MUTANTS_NAMES (a file of mutant names, one a line), MUTANTS_OUT (results, appended:
`name<TAB>verdict<TAB>killing test<TAB>tests run<TAB>CPU s`), MUTANTS_FLOOR (the least CPU time a
test may take, in seconds; default 10).

1. A clean pass runs every collected test with the switch on "stats", so the trampolines record
   which functions each test reaches, and times it (CPU). Session fixtures are built then, once.
2. Per mutant: the tests that reach its function, those that killed its neighbours first, then
   fastest first, stopped at the first failure (killed) or after all passed (survived). A test
   may use max(floor, 20x its clean CPU time) of CPU time (ITIMER_PROF: on a shared machine wall
   time says more about the load than about the mutant); over that, the mutant is a timeout.
"""
from __future__ import annotations

import os
import signal
import time

import pytest
from _pytest.runner import runtestprotocol


class MutantTimeout(Exception):
    pass


def _stop(signum, frame):
    raise MutantTimeout("mutant timed out")


def _next_item_keeping_session(item, items):
    """An item of another test module, given to pytest as the next item, so its teardown after
    `item` stops at the session: session fixtures stay built (from the clean pass) while module
    and function fixtures are built afresh for every run."""
    top_level = [other for other in items if other.path.parent.name == "tests"]
    for other in top_level or items:
        if other.module is not item.module:
            return other
    return None


class _Runner:
    def __init__(self, items):
        self.items = items
        self.following = {item: _next_item_keeping_session(item, items) for item in items}
        self.reports = []

    def passes(self, item) -> bool:
        self.reports = runtestprotocol(item, nextitem=self.following[item], log=False)
        ran = any(r.when == "call" and r.passed for r in self.reports)
        return ran and all(r.passed or r.skipped for r in self.reports)

    def timed_out(self) -> bool:
        return any("MutantTimeout" in str(r.longrepr) for r in self.reports if not r.passed)


def _quiet_failures():
    """A mutant's failure needs no report: pytest's would parse the mutated module (thousands of
    functions) for its source lines, and Hypothesis would shrink its example: seconds each."""
    import _pytest.nodes

    _pytest.nodes.Node._repr_failure_py = (
        lambda self, excinfo, style=None: f"{excinfo.typename}: {str(excinfo.value)[:300]}")
    try:
        from hypothesis import Phase, settings
    except ImportError:
        return
    settings.register_profile("mutants", phases=(Phase.explicit, Phase.reuse, Phase.generate),
                              database=None)
    settings.load_profile("mutants")


@pytest.hookimpl(tryfirst=True)
def pytest_runtestloop(session):
    from mutmut import state
    from mutmut.mutation.trampoline import set_mutant_under_test

    with open(os.environ["MUTANTS_NAMES"], encoding="utf-8") as f:
        names = [line.strip() for line in f if line.strip()]
    floor = float(os.environ.get("MUTANTS_FLOOR", "10"))
    out = open(os.environ["MUTANTS_OUT"], "a", buffering=1, encoding="utf-8")
    runner = _Runner(session.items)

    reaches, clean_cpu = {}, {}
    set_mutant_under_test("stats")
    for item in session.items:
        state()._stats.clear()
        start = time.process_time()
        passed = runner.passes(item)
        clean_cpu[item] = time.process_time() - start
        reaches[item] = set(state()._stats)
        if not passed:  # its mutants would count as killed: say so, and leave it out
            out.write(f"#CLEAN-FAIL {item.nodeid}\n")
            reaches[item] = set()
    out.write(f"#STATS {sum(clean_cpu.values()):.1f} s of CPU over {len(session.items)} tests\n")

    _quiet_failures()
    signal.signal(signal.SIGPROF, _stop)
    signal.signal(signal.SIGALRM, _stop)
    killers: dict[str, list] = {}
    for name in names:
        function = name.rsplit("__mutmut_", 1)[0]
        first = [item for item in killers.get(function, []) if function in reaches[item]]
        rest = (item for item in session.items if function in reaches[item] and item not in first)
        tests = first + sorted(rest, key=clean_cpu.__getitem__)
        if not tests:
            out.write(f"{name}\tno tests\t\t0\t0.0\n")
            continue
        set_mutant_under_test(name)
        verdict, by = "survived", ""
        start = time.process_time()
        for item in tests:
            signal.setitimer(signal.ITIMER_PROF, max(floor, 20 * clean_cpu[item]))
            signal.setitimer(signal.ITIMER_REAL, 600.0)  # one that waits forever uses no CPU
            try:
                passed = runner.passes(item)
                timed_out = not passed and runner.timed_out()
            except KeyboardInterrupt:
                raise
            except BaseException:  # the limit struck in pytest's own code
                passed, timed_out = False, True
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
                signal.setitimer(signal.ITIMER_PROF, 0)
            if not passed:
                verdict, by = ("timeout" if timed_out else "killed"), item.nodeid
                found = killers.setdefault(function, [])
                if item in found:
                    found.remove(item)
                found.insert(0, item)
                break
        out.write(f"{name}\t{verdict}\t{by}\t{len(tests)}\t{time.process_time() - start:.1f}\n")
        set_mutant_under_test("")
    out.close()
    return True
