"""`fieldcal` commands forked from one interpreter that has imported fieldcal once (test_docs).

A page of the guide runs some ten `fieldcal` commands; a fresh interpreter pays 0.4-0.5 s of
CPU importing numpy, scipy.optimize and fieldcal before each one does anything, most of a short
command's cost. Here a server imports them once and each command is a fork of it: still its own
process (its own pid, file descriptors, exit status, nothing it does reaches the next command),
given the caller's arguments, environment, working directory and standard streams (passed as
descriptors, so a pipe, a redirection or a terminal is exactly what the command would have had).
The caller is `call` below, which a page's bash runs in place of the venv's `fieldcal` script.

One server serves every page a test process runs (test_docs's session fixture): importing reads
neither the working directory nor the environment a page sets up (its XDG folders), which a fork
takes from its request before it runs anything, so a server started elsewhere forks the command
a page's own would have. After each page, `end_forks` ends any command of it still running.

    python command_forks.py serve SOCKET                 # imports, says "ready", forks per request
    python -S command_forks.py call SOCKET FIELDCAL ARGS...   # what `fieldcal ARGS...` becomes
"""
from __future__ import annotations

# Only what `call` needs at the top: it starts a fresh interpreter for every command of a page
# (socket, json and the server's modules cost it 25 ms of CPU, each time); the server imports
# the rest in the functions that use them.
import os
import sys

# What the pages' commands import anyway, in a fork of every command otherwise: the numerical
# stack, the commands' own modules, the registry's sqlite3, pyserial. matplotlib (certificates,
# Allan plots) is left to the command: its configuration folder comes from the environment it
# is given (XDG_CONFIG_HOME, a page's own) when it is imported.
PRELOADED = ("numpy", "scipy.optimize", "yaml", "sqlite3", "serial", "fieldcal.cli.main",
             "fieldcal.cli.sessions", "fieldcal.cli.production", "fieldcal.cli.calibrate",
             "fieldcal.solvers.solve", "fieldcal.run.runner", "fieldcal.run.replay",
             "fieldcal.session.record", "fieldcal.registry", "fieldcal.paramfile", "fieldcal.report")
READY = "ready"
NO_STATUS = 70  # the forked command died without saying its status (killed by a signal)
LENGTH_BYTES = STATUS_BYTES = 4  # a request's length before it, a status after the command: big-endian
END_FORKS = "end-forks"  # the request that ends the commands still running (a page is over)
# and is answered with the CPU its commands took, in ms: a measurement of the suite (per-test
# CPU from getrusage) counts a shared server's forks only when the server ends, not per page.


def _receive(connection) -> tuple[dict, list[int]]:
    """One request: its dictionary (argv, environment, working directory; or END_FORKS) and the
    caller's three standard descriptors."""
    import array
    import marshal
    import socket

    fds = array.array("i")
    data = b""
    try:
        while len(data) < LENGTH_BYTES or len(data) < LENGTH_BYTES + int.from_bytes(data[:LENGTH_BYTES], "big"):
            chunk, ancillary, _, _ = connection.recvmsg(1 << 20, socket.CMSG_SPACE(3 * fds.itemsize))
            for level, kind, payload in ancillary:
                if level == socket.SOL_SOCKET and kind == socket.SCM_RIGHTS:
                    fds.frombytes(payload[: len(payload) - len(payload) % fds.itemsize])
            if not chunk:
                raise EOFError("the caller went away before its request was whole")
            data += chunk
        return marshal.loads(data[LENGTH_BYTES:]), list(fds)
    except BaseException:
        for fd in fds:  # not left open in the server
            os.close(fd)
        raise


def _become_the_command(request: dict, fds: list[int], connection) -> None:
    """In the fork: take the caller's streams, directory and environment, run `fieldcal`, send
    the exit status, and end as the console script's process would."""
    import signal

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
        import contextlib
        import threading
        code = status & 0xFF if isinstance(status, int) else 1
        threading._shutdown()  # non-daemon threads joined, as at an interpreter's exit
        atexit._run_exitfuncs()
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(OSError, ValueError):
                stream.flush()
        with contextlib.suppress(OSError):  # the caller may be gone
            connection.sendall(code.to_bytes(STATUS_BYTES, "big", signed=True))
        os._exit(code)


def serve(path: str) -> None:
    import gc
    import signal
    import socket

    for name in PRELOADED:
        try:
            __import__(name)
        except ModuleNotFoundError as exc:  # a module moved or renamed: the forks import what they use
            if exc.name != name:
                raise
    # The imports' objects out of the collector's sight: a collection in a fork would otherwise
    # write to every one of them and so copy all the server's memory, in every fork.
    gc.freeze()
    signal.signal(signal.SIGTERM, _stop)
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(path)
    listener.listen(16)
    print(READY, flush=True)  # what the starter waits for: imports done, socket listening
    forks: set[int] = set()
    spent = [0.0]  # CPU seconds of the forks waited for since the last END_FORKS
    try:
        while True:
            connection, _ = listener.accept()
            _reap(forks, os.WNOHANG, spent)
            try:
                request, fds = _receive(connection)
            except (EOFError, ValueError, OSError):
                connection.close()
                continue
            if request == END_FORKS:
                for fd in fds:
                    os.close(fd)
                _end(forks, spent)
                connection.sendall(round(spent[0] * 1000).to_bytes(STATUS_BYTES, "big", signed=True))
                spent[0] = 0.0
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
        # Every fork waited for, so their CPU time is the server's children's, and so that of
        # the process that started it, once it has waited for the server.
        _end(forks, [0.0])


def _stop(signum, frame):
    raise SystemExit(0)


def _end(forks: set[int], spent: list[float]) -> None:
    """Each fork still running ended (a page's bash stopped by its timeout, a command left in
    the background), and every one waited for."""
    import contextlib
    import signal

    for pid in forks:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    _reap(forks, 0, spent)


def _reap(forks: set[int], options: int, spent: list[float]) -> None:
    """The forks that have ended waited for, and their CPU (their own children's included, as
    the kernel counts a process waited for) added to SPENT[0]."""
    import contextlib

    for pid in list(forks):
        with contextlib.suppress(ChildProcessError):
            done, _, usage = os.wait4(pid, options)
            if done == 0:
                continue  # still running
            spent[0] += usage.ru_utime + usage.ru_stime
        forks.discard(pid)


def _ask(path: str, request, descriptors: tuple[int, ...] = ()) -> int:
    """Send REQUEST (with DESCRIPTORS) to the server at PATH: the status it answers, once it
    answers (a command's, after it has ended), NO_STATUS if it goes away first. Only modules a
    fresh interpreter has loaded or are built in: `call` runs for every command of a page."""
    import _socket
    import marshal

    connection = _socket.socket(_socket.AF_UNIX, _socket.SOCK_STREAM)
    connection.connect(path)
    payload = marshal.dumps(request)
    message = len(payload).to_bytes(LENGTH_BYTES, "big") + payload
    rights = [(_socket.SOL_SOCKET, _socket.SCM_RIGHTS, b"".join(fd.to_bytes(4, sys.byteorder) for fd in descriptors))]
    sent = connection.sendmsg([message], rights if descriptors else [])  # a C int is 4 bytes here
    if sent < len(message):  # (not an empty send: the server may have answered and closed by now)
        connection.sendall(message[sent:])
    answer = b""
    while len(answer) < STATUS_BYTES:
        chunk = connection.recv(STATUS_BYTES - len(answer))
        if not chunk:
            return NO_STATUS
        answer += chunk
    return int.from_bytes(answer, "big", signed=True)


def call(path: str, argv: list[str]) -> int:
    """`fieldcal ARGV` through the server: its exit status, after it has ended. A caller with a
    standard descriptor closed (`>&-`) runs the real script instead: the socket opened here would
    take that descriptor's number and be sent as the command's stream."""
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            os.execv(argv[0], argv)
    return _ask(path, {"argv": argv, "env": dict(os.environ), "cwd": os.getcwd()}, (0, 1, 2))


class CommandServer:
    """A server started in DIRECTORY with ENV until `close` (or the end of a with block):
    `prelude()` is the bash function that makes `fieldcal` its fork when `fieldcal` is the venv
    under test's (any other, or none, as ever: not on PATH is still status 127)."""

    def __init__(self, directory, env: dict[str, str]):
        import subprocess
        import tempfile

        self._where = tempfile.TemporaryDirectory(prefix="fc-forks-")  # short: a socket path is <= 107 bytes
        self.socket_path = os.path.join(self._where.name, "socket")
        # One BLAS thread in the server: OpenBLAS's pool of threads, carried into a fork, spins
        # (a plan took 72 s of CPU forked, 7 s as its own process). One thread is also what the
        # fieldcal command itself sets before numpy loads (fieldcal/__init__.py), so the forks
        # compute as the script does.
        self._server = subprocess.Popen([sys.executable, __file__, "serve", self.socket_path], cwd=directory,
                                        env={**env, "OPENBLAS_NUM_THREADS": "1"},
                                        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, text=True)
        said = self._server.stdout.readline().strip()
        if said != READY:
            self.close()
            raise AssertionError(f"the fork server did not start (said {said!r}, status {self._server.poll()})")

    def prelude(self, socket_path: str | None = None) -> str:
        """The bash function; SOCKET_PATH: another socket than this server's (a check's)."""
        import shlex

        script = shlex.quote(os.path.join(sys.prefix, "bin", "fieldcal"))
        call = " ".join(shlex.quote(word) for word in
                        [sys.executable, "-S", __file__, "call", socket_path or self.socket_path])
        return (f"fieldcal() {{\n"
                f"  local real; real=$(type -P fieldcal) || {{ echo 'bash: fieldcal: command not found' >&2; return 127; }}\n"
                f"  if [[ $real -ef {script} ]]; then {call} \"$real\" \"$@\"; else \"$real\" \"$@\"; fi\n"
                f"}}")

    def end_forks(self) -> float:
        """End the commands still running (a page is over) and wait for them: the CPU seconds of
        the commands forked since the last call."""
        milliseconds = _ask(self.socket_path, END_FORKS)
        assert milliseconds >= 0, f"the fork server did not end its forks (status {milliseconds})"
        return milliseconds / 1000

    def close(self) -> None:
        self._server.terminate()  # it ends its forks, waits for them, then ends
        self._server.wait(timeout=60)
        self._server.stdout.close()
        self._where.cleanup()

    def __enter__(self) -> CommandServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


if __name__ == "__main__":
    if sys.argv[1] == "serve":
        serve(sys.argv[2])
    else:
        sys.exit(call(sys.argv[2], sys.argv[3:]))
