"""The guide is true: README.md and every page under docs/ is checked here.

How a page's commands are run (the harness):

- Every fenced block opened by a line "```sh" (indented in a list item too) is a command block; its
  first line may be "# not run: REASON" (a real serial port, a PostgreSQL URL, a long
  benchmark), and then it is not run, but a marker without a reason fails. Other shell tags
  (bash, shell, console) are refused, so no command can hide from the harness; output goes in
  "```text" blocks, which are not run.
- A page's runnable blocks run in order in ONE bash process (`set -eo pipefail`), as a reader
  types them into one terminal: the page's `. .venv/bin/activate` holds for the blocks after it,
  and nothing else puts `fieldcal` on PATH (the test's own venv is taken off it), so a page that
  forgets to activate fails. A failing command names its page, block and line.
- The working directory is a fresh temporary directory per page, laid out like the checkout for
  what pages name: `.venv` is a symbolic link to the environment running the tests (the
  checkout's .venv under `make test`, so the commands run the code under test), and `configs/`, `procedures/`, `benchmarks/`, `tests/data/real/` and `tests/faults/` are
  copies, so a command that writes beside its input cannot touch the checkout. `$XDG_DATA_HOME`
  and `$XDG_CONFIG_HOME` point into it (the unit registry, the TUI's last setup).
- Each `fieldcal` command of a page is forked from one interpreter that imported fieldcal, numpy
  and scipy once for all the pages a test process runs (tests/command_forks.py): still a process
  of its own with the caller's arguments, environment, directory and streams, without the
  0.4-0.5 s of imports each fresh one pays; a command still running when its page ends is ended
  then. Only the venv under test's `fieldcal` goes that way; not on PATH is still "command not
  found".
- Not run, still checked: in every block, run or not, each `fieldcal COMMAND` names a command
  the parser has and each `--option` after it is one of that command's.

Also: every repository path a page names (`fieldcal/...`, `drivers/...`, `configs/...`) exists,
README.md keeps to 150 lines and its links resolve, and the site builds with mkdocs --strict.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
from command_forks import CommandServer

ROOT = Path(__file__).resolve().parent.parent
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])
PAGE_IDS = [str(p.relative_to(ROOT)) for p in PAGES]
COPIED = ("configs", "procedures", "benchmarks", "tests/data/real", "tests/faults")
NOT_RUN = re.compile(r"#\s*not run\b:?(.*)", re.IGNORECASE)
OTHER_SHELL_TAGS = ("bash", "shell", "console", "zsh", "shell-session")
README_MAX_LINES = 150


@dataclass(frozen=True)
class Block:
    page: Path
    line: int  # of the first command line, 1-based
    text: str

    @property
    def not_run_reason(self) -> str | None:
        """The reason after "# not run:", "" for a marker without one, None when it runs."""
        first = self.text.splitlines()[0].strip() if self.text.strip() else ""
        marker = NOT_RUN.fullmatch(first)
        return None if marker is None else marker[1].strip()

    def where(self) -> str:
        name = self.page.relative_to(ROOT) if self.page.is_relative_to(ROOT) else self.page.name
        return f"{name}:{self.line}"


def fenced_blocks(page: Path) -> list[tuple[str, int, str]]:
    """(info string, first line number, text) of every fenced block opened at a line's start."""
    blocks, lines = [], page.read_text(encoding="utf-8").splitlines()
    i = 0
    while i < len(lines):
        opening = re.match(r"( *)(`{3,}|~{3,})\s*([^\s`]*)", lines[i])  # indented in a list item too
        if not opening:
            i += 1
            continue
        indent, fence, tag, start = len(opening[1]), opening[2], opening[3].lower(), i + 1
        i += 1
        while i < len(lines) and not lines[i].lstrip().startswith(fence):
            i += 1
        blocks.append((tag, start + 1, "\n".join(line[indent:] for line in lines[start:i])))
        i += 1
    return blocks


def sh_blocks(page: Path) -> list[Block]:
    return [Block(page, line, text) for tag, line, text in fenced_blocks(page) if tag == "sh"]


# --------------------------------------------------------------------------------------------
# The blocks' form, and the commands they name (fast: nothing is run)

@pytest.mark.parametrize("page", PAGES, ids=PAGE_IDS)
def test_command_blocks_are_sh_and_a_skipped_one_says_why(page):
    wrong_tags = [f"{page.relative_to(ROOT)}:{line} is ```{tag}" for tag, line, _ in fenced_blocks(page)
                  if tag in OTHER_SHELL_TAGS]
    assert not wrong_tags, f"command blocks are ```sh (run by this test) or ```text (output): {wrong_tags}"
    no_reason = [b.where() for b in sh_blocks(page) if b.not_run_reason == ""]
    assert not no_reason, f"'# not run:' needs a reason after the colon: {no_reason}"


@pytest.mark.parametrize("page", PAGES, ids=PAGE_IDS)
def test_commands_are_written_one_way(page):
    """Bare `fieldcal ...` after `. .venv/bin/activate`, never `.venv/bin/fieldcal` or
    `python -m fieldcal`; and a page that runs fieldcal activates the venv before."""
    activated = False
    problems = []
    for block in sh_blocks(page):
        for number, line in enumerate(block.text.splitlines(), block.line):
            code = line.split("#", 1)[0]
            if re.search(r"\.venv/bin/(?!activate\b)", code) or re.search(r"python3? -m fieldcal", code):
                problems.append(f"{page.relative_to(ROOT)}:{number}: {line.strip()}")
            if re.search(r"(^|\s)(\.|source) \.venv/bin/activate\b", code):
                activated = True
            if block.not_run_reason is None and re.search(r"(^|[\s;&|(])fieldcal\s", code) and not activated:
                problems.append(f"{page.relative_to(ROOT)}:{number}: fieldcal before `. .venv/bin/activate`")
    assert not problems, problems


def _reference_generator():
    """docs/gen_commands_reference.py, the MkDocs hook that writes the commands page."""
    spec = importlib.util.spec_from_file_location("gen_commands_reference", ROOT / "docs" / "gen_commands_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _command_parsers() -> dict[tuple[str, ...], argparse.ArgumentParser]:
    """Every command's parser by its words: ('calibrate',), ('sim', 'serve'), ..."""
    return _reference_generator().command_parsers()


def _fieldcal_invocations(text: str):
    """(line offset, words after `fieldcal`) for each fieldcal command of a block; a trailing
    backslash continues a line, a `#` starts a comment, `|`, `;`, `&&` end a command."""
    joined, offsets, pending = [], [], ""
    for offset, line in enumerate(text.splitlines()):
        if not pending:
            offsets.append(offset)
        pending += line[:-1] + " " if line.endswith("\\") else line
        if not line.endswith("\\"):
            joined.append(pending)
            pending = ""
    for offset, line in zip(offsets, joined):
        try:
            words = shlex.split(line, comments=True)
        except ValueError:
            continue
        command: list[str] | None = None
        for word in words + [";"]:
            if word in ("|", ";", "&&", "||", "&") or word.endswith(";"):
                if command is not None:
                    yield offset, command
                command = None
            elif command is not None:
                command.append(word)
            elif word == "fieldcal":
                command = []


@pytest.mark.parametrize("page", PAGES, ids=PAGE_IDS)
def test_every_fieldcal_command_and_option_a_page_names_exists(page):
    parsers = _command_parsers()
    problems = []
    for block in sh_blocks(page):
        for offset, words in _fieldcal_invocations(block.text):
            where = f"{page.relative_to(ROOT)}:{block.line + offset}"
            key: tuple[str, ...] = ()
            for word in words:
                if word.startswith("-") or (*key, word) not in parsers:
                    break
                key = (*key, word)
            if not words or words[0].startswith("-"):
                continue  # `fieldcal --version`, `fieldcal --help`
            if not key:
                problems.append(f"{where}: no command {words[0]!r}")
                continue
            options = set(parsers[key]._option_string_actions)
            unknown = [w.split("=")[0] for w in words if w.startswith("--") and w.split("=")[0] not in options]
            if unknown:
                problems.append(f"{where}: fieldcal {' '.join(key)} has no {', '.join(unknown)}")
    assert not problems, problems


# Repository paths a page may name: these top-level folders; a placeholder (SERIAL, ...), a glob
# or an ellipsis is not a path.
REPO_PATH = re.compile(r"(?<![\w./-])((?:fieldcal|drivers|benchmarks|tests|configs|procedures|docs)/[\w./-]*)")


@pytest.mark.parametrize("page", PAGES, ids=PAGE_IDS)
def test_every_repository_path_a_page_names_exists(page):
    missing = []
    for number, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1):
        for found in REPO_PATH.finditer(line):
            path = found[1].rstrip(".,:;")
            if "..." in path or path.endswith("-"):
                continue
            if not (ROOT / path).exists():
                missing.append(f"{page.relative_to(ROOT)}:{number}: {path}")
    assert not missing, f"paths named that do not exist in the checkout: {missing}"


def test_readme_is_short_and_its_links_resolve():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= README_MAX_LINES
    broken = [target for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
              if "://" not in target and not (ROOT / target).exists()]
    assert not broken, f"README.md links to files that do not exist: {broken}"


def test_readme_reaches_a_calibrated_real_recording_in_three_commands_after_set_up():
    """The issue's promise: after `make demo` and `make test`, at most 3 commands to a calibrated
    bundled recording (and the command that does it is one the page's test runs)."""
    commands = []
    for block in runnable(ROOT / "README.md"):
        joined = block.text.replace("\\\n", " ")
        commands += [line.split("#", 1)[0].strip() for line in joined.splitlines() if line.split("#", 1)[0].strip()]
    first = next(i for i, c in enumerate(commands) if c.startswith("fieldcal calibrate tests/data/real/"))
    assert first + 1 <= 3, commands[:first + 1]


# --------------------------------------------------------------------------------------------
# Running the blocks

def _page_directory(tmp_path: Path) -> Path:
    work = tmp_path / "page"
    work.mkdir()
    (work / ".venv").symlink_to(Path(sys.prefix), target_is_directory=True)  # the venv under test
    for name in COPIED:
        shutil.copytree(ROOT / name, work / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    return work


def _environment(tmp_path: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("VIRTUAL_ENV", "FIELDCAL_OPERATOR"))}
    venv_bin = str(Path(sys.prefix) / "bin")
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep)
                                  if p and Path(p).resolve() != Path(venv_bin).resolve()
                                  and Path(p).resolve() != (ROOT / ".venv" / "bin").resolve())
    for name in ("XDG_DATA_HOME", "XDG_CONFIG_HOME"):
        env[name] = str(tmp_path / name.lower())
    return env


def _script(blocks: list[Block], prelude: str = "") -> str:
    parts = ["set -eo pipefail", prelude]
    for block in blocks:
        parts.append(f"echo '>>> {block.where()}' >&2")
        parts.append(block.text)
    return "\n".join(parts) + "\n"


def runnable(page: Path) -> list[Block]:
    return [b for b in sh_blocks(page) if b.not_run_reason is None]


@pytest.fixture(scope="session")
def command_server(tmp_path_factory):
    """The fork server of every page this test process runs: its imports (0.4-0.5 s of CPU) paid
    once, not once per page. Started in a directory of its own, with an environment like the
    pages' (not their XDG folders): a fork takes its page's directory and environment before it
    runs anything."""
    with CommandServer(tmp_path_factory.mktemp("forks"), _environment(tmp_path_factory.getbasetemp())) as server:
        yield server


@pytest.mark.parametrize("page", PAGES, ids=PAGE_IDS)
def test_every_command_block_of_a_page_runs(page, tmp_path, request):
    blocks = runnable(page)
    if not blocks:
        return  # every block says why it is not run (checked above)
    work = _page_directory(tmp_path)
    env = _environment(tmp_path)
    commands = sum(1 for block in blocks for _ in _fieldcal_invocations(block.text))
    server = request.getfixturevalue("command_server") if commands else None
    try:
        done = subprocess.run(["bash", "-c", _script(blocks, server.prelude() if server else "")], cwd=work, env=env,
                              capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=540)
    finally:
        if server:  # the commands' CPU, which the test process's own (getrusage) no longer holds
            request.node.user_properties.append(("commands_cpu_s", server.end_forks()))
    if done.returncode != 0:
        started = re.findall(r"^>>> (\S+)$", done.stderr, re.MULTILINE)
        pytest.fail(f"{page.relative_to(ROOT)}: the block at {started[-1] if started else '?'} "
                    f"exited {done.returncode}\n--- stdout (end)\n{done.stdout[-3000:]}\n"
                    f"--- stderr (end)\n{done.stderr[-3000:]}")


def test_a_failing_block_fails_the_page_and_a_forgotten_activation_too(tmp_path):
    """The harness itself: a command that fails stops the page; fieldcal is not on PATH unless
    the page activates the venv."""
    work = _page_directory(tmp_path)
    env = _environment(tmp_path)
    fake = tmp_path / "x.md"
    fake.write_text("```sh\nfalse\necho after\n```\n")
    done = subprocess.run(["bash", "-c", _script(runnable(fake))], cwd=work, env=env, capture_output=True, text=True)
    assert done.returncode != 0 and "after" not in done.stdout
    fake.write_text("```sh\nfieldcal --version\n```\n")
    assert subprocess.run(["bash", "-c", _script(runnable(fake))], cwd=work, env=env,
                          capture_output=True, text=True).returncode == 127
    fake.write_text("```sh\n. .venv/bin/activate\n```\n\n```sh\nfieldcal --version\n```\n")
    done = subprocess.run(["bash", "-c", _script(runnable(fake))], cwd=work, env=env, capture_output=True, text=True)
    assert done.returncode == 0 and done.stdout.startswith("fieldcal ")


def test_a_forked_fieldcal_says_and_exits_as_the_script_does(tmp_path, command_server):
    """The harness's forks (tests/command_forks.py) against the venv's own `fieldcal` script: the
    same output through a pipe, the same exit statuses and messages, and still "command not
    found" before the page activates the venv."""
    work = _page_directory(tmp_path)
    env = _environment(tmp_path)
    page = tmp_path / "x.md"
    page.write_text("```sh\n. .venv/bin/activate\nfieldcal --version | tr a-z A-Z\n"
                    "fieldcal units || echo \"units: $?\"\n"
                    "fieldcal check no-such.yaml 2>&1 || echo \"check: $?\"\n"
                    "fieldcal no-such-command 2>&1 | tail -1 || echo \"usage: $?\"\n```\n")

    def run(script: str):
        return subprocess.run(["bash", "-c", script], cwd=work, env=env, capture_output=True, text=True,
                              stdin=subprocess.DEVNULL)

    script = run(_script(runnable(page)))
    prelude = command_server.prelude()
    forked = run(_script(runnable(page), prelude))
    not_activated = run(prelude + "\nfieldcal --version\n")
    # and the forks did run the commands: with another socket than the server's, the same page fails
    unserved = run(_script(runnable(page), command_server.prelude(str(tmp_path / "no-server"))))
    assert (forked.returncode, forked.stdout) == (script.returncode, script.stdout) == (0, script.stdout)
    assert script.stdout.startswith("FIELDCAL ") and "units: 2\n" in script.stdout and "check: 2\n" in script.stdout, \
        script.stdout
    assert not_activated.returncode == 127 and "command not found" in not_activated.stderr
    assert unserved.returncode != 0 and not unserved.stdout


def test_one_server_forks_each_page_s_command_in_that_page_s_directory_and_environment(tmp_path, command_server):
    """The server every page shares was started elsewhere: each fork still works where its page
    is (a relative path) and reads the page's own environment (its XDG folders); and the CPU its
    commands took is counted once, when the page is over."""
    command_server.end_forks()  # the commands of the tests before this one
    said = {}
    for name in ("first", "second"):
        page = tmp_path / name
        page.mkdir()
        work = _page_directory(page)
        (work / "here.sqlite").write_text("not a registry" if name == "first" else "")
        script = (f"{command_server.prelude()}\n. .venv/bin/activate\n"
                  "fieldcal units 2>&1 || true\nfieldcal units --registry here.sqlite 2>&1 || true\n")
        said[name] = subprocess.run(["bash", "-c", script], cwd=work, env=_environment(page), capture_output=True,
                                    text=True, stdin=subprocess.DEVNULL).stdout
    for name in ("first", "second"):
        assert f"registry {tmp_path / name / 'xdg_data_home'}/fieldcal/registry.sqlite: no such registry" in said[name]
    assert "registry here.sqlite: file is not a database" in said["first"]
    assert "registry here.sqlite: file is not a database" not in said["second"], said["second"]
    assert command_server.end_forks() > 0  # the four commands' CPU
    assert command_server.end_forks() == 0  # none since


def test_a_marker_without_a_reason_is_caught_and_one_with_a_reason_skips(tmp_path):
    page = tmp_path / "x.md"
    page.write_text("```sh\n# not run:\nfieldcal tui\n```\n\n```sh\n# not run: a real serial port\n"
                    "fieldcal monitor --config vn100\n```\n\n```text\nnot a command\n```\n"
                    "- a list item:\n\n    ```sh\n    fieldcal units\n    ```\n")
    first, second, in_a_list = sh_blocks(page)
    assert first.not_run_reason == "" and second.not_run_reason == "a real serial port"
    assert runnable(page) == [in_a_list] and in_a_list.text == "fieldcal units"


def test_the_option_check_sees_a_stale_option(tmp_path):
    parsers = _command_parsers()
    assert ("sim", "serve") in parsers and ("calibrate",) in parsers
    invocations = list(_fieldcal_invocations("fieldcal calibrate a.txt \\\n  --map imu_tk --no-such-option | head\n"
                                             "x=1; fieldcal units --registry r.sqlite  # a comment --nope\n"))
    assert invocations == [(0, ["calibrate", "a.txt", "--map", "imu_tk", "--no-such-option"]),
                           (2, ["units", "--registry", "r.sqlite"])]
    assert "--no-such-option" not in parsers[("calibrate",)]._option_string_actions


# --------------------------------------------------------------------------------------------
# The generated reference and the site

def test_the_commands_reference_holds_each_command_s_own_help():
    """The page is made from the parsers: each command's `--help`, as the installed command
    prints it (the real process, whose calibrate and import parsers are built alone), is in it."""
    generator = _reference_generator()
    page = generator.commands_page()
    env = {**os.environ, "COLUMNS": "100"}
    for words in [("calibrate",), ("import",), ("run",), ("sim", "serve")]:
        assert f"## fieldcal {' '.join(words)}\n" in page
        shown = subprocess.run([str(Path(sys.prefix) / "bin" / "fieldcal"), *words, "--help"], env=env,
                               capture_output=True, text=True, check=True).stdout
        assert shown.strip() and shown.strip() in page, words
    headings = set(re.findall(r"^## fieldcal (.+)$", page, re.MULTILINE))
    assert headings == {" ".join(words) for words in generator.command_parsers()}


def test_the_site_builds_strictly(tmp_path):
    """`make docs`: mkdocs --strict fails on a broken link, a page left out of the nav, a
    missing nav page or any other warning."""
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=ROOT, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"}, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-4000:]
    assert (tmp_path / "site" / "reference" / "commands" / "index.html").is_file()
    assert "WARNING" not in done.stderr
