"""Where commands write, checked before they start: one line naming the path and what is wrong,
instead of an OSError after a run of an hour (a file given as --out, an unwritable directory,
a name too long for the file system)."""
from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from pathlib import Path


def _existing_ancestor(path: Path) -> Path:
    for candidate in (path, *path.parents):
        if candidate.exists():
            return candidate
    return Path(".")


def _check_names(path: Path, flag: str) -> None:
    for part in path.parts:
        if len(os.fsencode(part)) > 255:  # NAME_MAX of every common Linux file system
            raise ValueError(f"{flag} {str(path)[:80]}...: a name in this path is longer than the "
                             "file system allows (255 bytes)")


def _probe(directory: Path, flag: str, path: Path) -> None:
    """Create and remove a temporary file in ``directory``: os.access cannot see a read-only
    file system, and as root it says yes to everything."""
    try:
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as exc:
        raise ValueError(f"{flag} {path}: cannot write in {directory} ({exc.strerror or exc})") from None


def output_directory(path: str | os.PathLike, flag: str) -> None:
    """A directory the command will create files (or sessions) in: it, or the nearest existing
    folder above it, must be a writable directory."""
    p = Path(path)
    _check_names(p, flag)
    if p.is_symlink():  # the user named a link: never followed, whatever it points at
        raise ValueError(f"{flag} {p}: is a symbolic link; fieldcal never writes through a link "
                         "(give the directory it points at, or another path)")
    if p.exists() and not p.is_dir():
        raise ValueError(f"{flag} {p}: is a file, not a directory (name a directory)")
    base = _existing_ancestor(p)
    if not base.is_dir():
        raise ValueError(f"{flag} {p}: {base} is a file, not a directory")
    _probe(base, flag, p)


def output_file(path: str | os.PathLike, flag: str) -> None:
    """A file the command will write: never inside a session, not a directory, in an existing
    writable directory."""
    from fieldcal.session.output import refuse_inside_session

    p = Path(path)
    _check_names(p, flag)
    refuse_inside_session(p, f"{flag}'s parameter file")
    if p.is_dir():
        raise ValueError(f"{flag} {p}: is a directory; name the file to write")
    parent = p.parent
    if not parent.exists():
        raise ValueError(f"{flag} {p}: the directory {parent} does not exist")
    if not parent.is_dir():
        raise ValueError(f"{flag} {p}: {parent} is a file, not a directory")
    _probe(parent, flag, p)
    from fieldcal.atomic import check_target
    check_target(p, force=True, option=flag)  # a link, a FIFO: refused before the work (--force: later)


def writable_session(directory: str | os.PathLike) -> None:
    """A session to be continued: its folder and files must take writes, checked before a
    resume re-runs anything."""
    d = Path(directory)
    if not d.is_dir():
        return  # the session reader names what is missing
    from fieldcal.atomic import open_append

    try:
        with tempfile.TemporaryFile(dir=d):
            pass
    except OSError as exc:  # named by the folder, not by the probe's hidden temp name
        raise ValueError(f"{d}: cannot resume: the folder cannot be written ({exc.strerror or exc}); "
                         "nothing was re-run") from None
    from fieldcal.atomic import check_appendable
    from fieldcal.session.capture import LOG, PARAMETERS, RAW_PREFIX, SAMPLES, TORN_SUFFIX

    appended = [LOG, SAMPLES, *(p.name for p in sorted(d.glob(f"{RAW_PREFIX}*")))]
    for name in appended:
        if (d / name).exists() or (d / name).is_symlink():
            try:
                with open_append(d / name):  # opened for appending (never through a link), nothing written
                    pass
            except (OSError, ValueError) as exc:
                raise ValueError(f"{d}: cannot resume: {exc}; nothing was re-run") from None
    # and what the resume writes at its end (the current parameter file) or when it cuts a torn
    # tail: refused now, not after the run (a link at parameters.yaml was refused only then)
    from fieldcal.session.lock import LOCK

    for name in (LOCK, PARAMETERS, *(n + TORN_SUFFIX for n in appended)):
        try:
            check_appendable(d / name)
        except ValueError as exc:
            raise ValueError(f"{d}: cannot resume: {exc}; nothing was re-run") from None


# Commands whose output can go to a file instead (--out): they check standard output themselves.
_OWN_STDOUT_CHECK = ("export", "apply")


def stdout_closed() -> bool:
    """Started with standard output closed (>&-): Python then has no sys.stdout and print() quietly
    drops everything."""
    return sys.stdout is None or getattr(sys.stdout, "closed", False) is True


def flush_stdout() -> None:
    """Flush standard output now, while a failure can still be said: an OSError naming "standard
    output" (a full disk, /dev/full), with what is left unwritten sent to /dev/null so that the
    interpreter's own flush at exit adds no second message."""
    if stdout_closed():
        return
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        raise
    except OSError as exc:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        raise OSError(exc.errno, exc.strerror, "standard output") from None


@contextlib.contextmanager
def _named_standard_output():
    """An OSError within names "standard output" (a broken pipe stays itself: the reader left)."""
    try:
        yield
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror, "standard output") from None


class _NamedStdout:
    """Standard output whose write errors name it: print() failing mid-command on a full disk
    otherwise raises an OSError with no file name, said as a bare "No space left on device"."""

    def __init__(self, stream) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        with _named_standard_output():
            return self._stream.write(text)

    def flush(self) -> None:
        with _named_standard_output():
            self._stream.flush()

    @property
    def buffer(self):  # the bytes beneath (apply writes its CSV there): its failures named too
        return _NamedStdout(self._stream.buffer)

    def __getattr__(self, name):
        return getattr(self._stream, name)


@contextlib.contextmanager
def stdout_named(command: str):
    """Within: a failed write to standard output is an OSError naming it (not for the terminal UI,
    which owns the terminal)."""
    if command == "tui" or stdout_closed():
        yield
        return
    stream = sys.stdout
    sys.stdout = _NamedStdout(stream)
    try:
        yield
    finally:
        if isinstance(sys.stdout, _NamedStdout):
            sys.stdout = stream


def write_stdout(text: str) -> None:
    """``text`` on standard output, flushed: a failure names standard output (see flush_stdout)."""
    try:
        sys.stdout.write(text)
    except BrokenPipeError:
        raise
    except OSError as exc:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        raise OSError(exc.errno, exc.strerror, "standard output") from None
    flush_stdout()


def check_paths(args) -> None:
    """The output paths of the parsed command line, before the command runs."""
    command = args.command
    if command not in _OWN_STDOUT_CHECK and stdout_closed():
        raise ValueError(f"{command}: standard output is closed (started with >&-?), so what it shows would "
                         "be lost: send it somewhere (> FILE, or > /dev/null to drop it)")
    # calibrate writes under --out only when it imports text files (a session is calibrated in place)
    imports = command == "calibrate" and not all(Path(r).is_dir() for r in args.recording)
    if command in ("run", "import") or imports or (
            command == "tui" and getattr(args, "go", False) and not getattr(args, "no_capture", False)):
        output_directory(args.out, "--out")
    if command in ("demo", "calibrate", "thermal") and getattr(args, "params", None):
        output_target(args.params, "--params", args, command_inputs(args, output="params"))
    if command == "replay" and args.out:
        output_target(args.out, "--out", args, command_inputs(args))
    if command == "resume":
        writable_session(args.session)
    if getattr(args, "registry", None) is not None:  # recorded at the end: refused before the run
        from fieldcal.registry.backends import check_location
        check_location(args.registry, require_tls=getattr(args, "registry_require_tls", False))
    if command == "allan" and args.plot_dir:
        output_directory(args.plot_dir, "--plot-dir")
    # files written whole (the rule of fieldcal.atomic), refused before the command's work
    if command == "plan":
        from fieldcal.planning.command import plan_inputs
        output_target(args.out, "--out", args, [*command_inputs(args), *plan_inputs(args)])
    if command in ("export", "certificate") and args.out:
        output_target(args.out, "--out", args, command_inputs(args))
    if command == "apply" and args.out and not Path(args.out).is_dir() and not (
            len(args.input or ()) > 1):  # one CSV (several go into a directory)
        output_target(args.out, "--out", args, command_inputs(args))
    elif command == "apply" and args.out and Path(args.out).is_dir():  # the folder the CSVs go into
        output_directory(args.out, "--out")


def command_inputs(args, output: str = "out") -> list[str]:
    """The files a command line names as inputs (every path option but its outputs)."""
    found = []
    for name, value in vars(args).items():
        if name in (output, "out", "plot_dir", "plot", "registry", "func", "command"):
            continue
        for item in value if isinstance(value, list) else [value]:
            if isinstance(item, (str, os.PathLike)) and os.path.isfile(item):
                found.append(os.fspath(item))
    return found


def output_target(path, flag: str, args, inputs) -> None:
    """A file written whole by the command: in an existing writable directory, never a link,
    never one of ``inputs``, never over a file without --force."""
    from fieldcal.atomic import check_target

    output_file(path, flag)
    check_target(path, force=getattr(args, "force", False), inputs=inputs, option=flag)


