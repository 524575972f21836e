"""Write mutmut's copy of the project under mutants/ with every mutant of [tool.mutmut]'s modules.

Uses mutmut's own generation (the same mutants, names and `.meta` files as `mutmut run`), not its
runner: run.py runs them in one pytest process per module. Files mutmut mutated before and that
have not changed since are left as they are (mutmut compares modification times); the test and
data folders (`also_copy`) are copied afresh, so new tests are seen.
"""
from __future__ import annotations

import contextlib
import io
import os

# mutmut 3.8's internals (pinned in the Makefile): they moved between 3.x releases.
from mutmut.__main__ import create_mutants
from mutmut.mutation.trampoline import set_mutant_under_test
from mutmut.utils.file_utils import copy_also_copy_files, copy_src_dir


def generate(processes: int = 2) -> None:
    set_mutant_under_test("mutant_generation")  # what `mutmut run` sets while it writes mutants
    os.makedirs("mutants", exist_ok=True)
    with contextlib.redirect_stdout(io.StringIO()):  # mutmut names every file it copies (forked workers too)
        copy_src_dir()
        copy_also_copy_files()
        stats = create_mutants(processes)
    print(f"mutants: {stats.mutated} files mutated afresh, {stats.unmodified} unchanged, "
          f"{stats.ignored} copied as they are")


if __name__ == "__main__":
    generate()
