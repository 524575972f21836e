"""`fieldcal` commands forked from one interpreter that has imported fieldcal once (test_docs).

A page of the guide runs some ten `fieldcal` commands; a fresh interpreter pays 0.6-0.8 s of
CPU importing numpy, scipy.optimize and fieldcal before each one does anything, most of a short
command's cost. Here a server imports them once, in the page's directory and environment, and
each command is a fork of it: still its own process (its own pid, file descriptors, exit status,
nothing it does reaches the next command), given the caller's arguments, environment, working
directory and standard streams (passed as descriptors, so a pipe, a redirection or a terminal is
exactly what the command would have had). The caller is `call` below, which a page's bash
runs in place of the venv's `fieldcal` script.

    python command_forks.py serve SOCKET                 # imports, says "ready", forks per request
    python -S command_forks.py call SOCKET FIELDCAL ARGS...   # what `fieldcal ARGS...` becomes
"""
from __future__ import annotations

import array
import contextlib
import gc
import json
import os
import shlex
import signal
import socket
import struct
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

# What every page's commands import anyway; matplotlib (certificates, Allan plots) is left to
# the command, which reads its settings from the environment it is given.
PRELOADED = ("numpy", "scipy.optimize", "yaml", "fieldcal.cli.main", "fieldcal.solvers.solve",
             "fieldcal.run.runner", "fieldcal.session.record")
STATUS = struct.Struct("!i")
READY = "ready"
NO_STATUS = 70  # the forked command died without saying its status (killed by a signal)


def _receive(connection: socket.socket) -> tuple[dict, list[int]]:
    """One request: its JSON (argv, environment, working directory) and the caller's three
    standard descriptors."""
    fds = array.array("i")
    data = b""
    try:
        while not data.endswith(b"\n"):
            chunk, ancillary, _, _ = connection.recvmsg(1 << 20, socket.CMSG_SPACE(3 * fds.itemsize))
            for level, kind, payload in ancillary:
                if level == socket.SOL_SOCKET and kind == socket.SCM_RIGHTS:
                    fds.frombytes(payload[: len(payload) - len(payload) % fds.itemsize])
            if not chunk:
                raise EOFError("the caller went away before its request was whole")
            data += chunk
        return json.loads(data), list(fds)
    except BaseException:
        for fd in fds:  # not left open in the server
            os.close(fd)
        raise


def _become_the_command(request: dict, fds: list[int], connection: socket.socket) -> None:
    """In the fork: take the caller's streams, directory and environment, run `fieldcal`, send
    the exit status, and end as the console script's process would."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    for target, fd in enumerate(fds):
        os.dup2(fd, target)
        os.close(fd)
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    # Streams as a new interpreter opens them: stdout line-buffered on a terminal only.
    sys.stdin = open(0, "r", closefd=False)
    sys.stdout = open(1, "w", buffering=1 if os.isatty(1) else -1, closefd=False)
    sys.stderr = open(2, "w", buffering=1, errors="backslashreplace", closefd=False)
    sys.argv = request["argv"]
    sys.path[0] = os.path.dirname(sys.argv[0])  # as the console script starts: its own folder, not tests/
    status = 1
    try:
        from fieldcal.cli.main import run
        status = run()
    except SystemExit as exc:
        status = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        if exc.code is not None and not isinstance(exc.code, int):
            print(exc.code, file=sys.stderr)
    except BaseException:
        import traceback
        traceback.print_exc()
    finally:
        import atexit
        import threading
        code = status & 0xFF if isinstance(status, int) else 1
        threading._shutdown()  # non-daemon threads joined, as at an interpreter's exit
        atexit._run_exitfuncs()
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(OSError, ValueError):
                stream.flush()
        with contextlib.suppress(OSError):  # the caller may be gone
            connection.sendall(STATUS.pack(code))
        os._exit(code)


def serve(path: str) -> None:
    for name in PRELOADED:
        __import__(name)
    # The imports' objects out of the collector's sight: a collection in a fork would otherwise
    # write to every one of them and so copy all the server's memory, in every fork.
    gc.freeze()
    signal.signal(signal.SIGTERM, _stop)
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(path)
    listener.listen(16)
    print(READY, flush=True)  # what the starter waits for: imports done, socket listening
    forks: set[int] = set()
    try:
        while True:
            connection, _ = listener.accept()
            _reap(forks, os.WNOHANG)
            try:
                request, fds = _receive(connection)
            except (EOFError, ValueError, OSError):
                connection.close()
                continue
            pid = os.fork()
            if pid == 0:
                try:
                    listener.close()
                    _become_the_command(request, fds, connection)
                finally:  # never back into this loop (nor its finally, which kills the forks)
                    os._exit(NO_STATUS)
            forks.add(pid)
            for fd in fds:
                os.close(fd)
            connection.close()
    finally:
        # Every fork waited for, so their CPU time is the server's children's, and so the
        # test's: a measurement of the suite sees what the commands cost. One still running
        # (the page's bash was stopped by its timeout) is ended first.
        for pid in forks:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        _reap(forks, 0)


def _stop(signum, frame):
    raise SystemExit(0)


def _reap(forks: set[int], options: int) -> None:
    for pid in list(forks):
        with contextlib.suppress(ChildProcessError):
            if os.waitpid(pid, options)[0] == 0:
                continue  # still running
        forks.discard(pid)


def call(path: str, argv: list[str]) -> int:
    """`fieldcal ARGV` through the server: its exit status, after it has ended. A caller with a
    standard descriptor closed (`>&-`) runs the real script instead: the socket opened here would
    take that descriptor's number and be sent as the command's stream."""
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            os.execv(argv[0], argv)
    connection = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    connection.connect(path)
    request = json.dumps({"argv": argv, "env": dict(os.environ), "cwd": os.getcwd()}).encode() + b"\n"
    connection.sendmsg([request], [(socket.SOL_SOCKET, socket.SCM_RIGHTS, array.array("i", [0, 1, 2]))])
    answer = b""
    while len(answer) < STATUS.size:
        chunk = connection.recv(STATUS.size - len(answer))
        if not chunk:
            return NO_STATUS
        answer += chunk
    return STATUS.unpack(answer)[0]


@contextlib.contextmanager
def forked_fieldcal(directory: Path, env: dict[str, str]) -> Iterator[str]:
    """A server started in DIRECTORY with ENV, for as long as the block runs: yields the bash
    function that makes `fieldcal` its fork when `fieldcal` is the venv under test's (any other,
    or none, as ever: not on PATH is still status 127)."""
    with tempfile.TemporaryDirectory(prefix="fc-forks-") as where:  # short: a socket path is <= 107 bytes
        path = os.path.join(where, "socket")
        # One BLAS thread in the server: OpenBLAS's pool of threads, carried into a fork, spins
        # (a plan took 72 s of CPU forked, 7 s as its own process). One thread is also what the
        # fieldcal command itself sets before numpy loads (fieldcal/__init__.py), so the forks
        # compute as the script does.
        server = subprocess.Popen([sys.executable, __file__, "serve", path], cwd=directory,
                                  env={**env, "OPENBLAS_NUM_THREADS": "1"},
                                  stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, text=True)
        try:
            said = server.stdout.readline().strip()
            assert said == READY, f"the fork server did not start (said {said!r}, status {server.poll()})"
            script = shlex.quote(str(Path(sys.prefix) / "bin" / "fieldcal"))
            call = " ".join(shlex.quote(word) for word in [sys.executable, "-S", __file__, "call", path])
            yield (f"fieldcal() {{\n"
                   f"  local real; real=$(type -P fieldcal) || {{ echo 'bash: fieldcal: command not found' >&2; return 127; }}\n"
                   f"  if [[ $real -ef {script} ]]; then {call} \"$real\" \"$@\"; else \"$real\" \"$@\"; fi\n"
                   f"}}")
        finally:
            server.terminate()  # it waits for its forks, then ends
            server.wait(timeout=60)
            server.stdout.close()


if __name__ == "__main__":
    if sys.argv[1] == "serve":
        serve(sys.argv[2])
    else:
        sys.exit(call(sys.argv[2], sys.argv[3:]))
