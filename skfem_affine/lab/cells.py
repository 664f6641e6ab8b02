"""Run a sweep cell in a child process that may crash or hang: :func:`call`.

A cell runs a whole simulation. A crash in native code (segfault), the kernel's out-of-memory
killer or an endless loop in one cell must stop neither its Dask worker nor the sweep. So each
worker thread keeps one child Python process (the same interpreter and ``sys.path``) and sends
it one cell at a time over a socket; the child runs it and sends the result back. If the child
dies, :class:`CellCrashed` says how (signal or exit code); if no answer comes within the
timeout, the child is killed and :class:`CellTimedOut` is raised. The next cell starts a new
child. A child started once serves many cells, so that loading the interpreter, the package
and its compiled kernels is paid once per worker, not once per cell.

A child is a new interpreter (``subprocess``), not a fork: forking a process that already
runs OpenMP or BLAS threads is unsafe, and Dask's worker processes may not have
``multiprocessing`` children.
"""
import os
import pickle
import signal
import socket
import subprocess
import sys
import threading
import time
from multiprocessing.connection import Connection

from skfem_affine._extras import Optional

cloudpickle = Optional("cloudpickle", "skfem-affine sweep's cells", "lab")


class CellCrashed(RuntimeError):
    """The cell's process died (a signal such as SIGSEGV or SIGKILL, or an exit code)."""


class CellTimedOut(RuntimeError):
    """The cell gave no result within its time limit; its process was killed."""


_HINTS = {signal.SIGKILL: "out of memory, or killed by a user", signal.SIGSEGV: "a crash in native code",
          signal.SIGABRT: "aborted by native code", signal.SIGBUS: "a crash in native code"}


def describe_exit(code):
    """Words for a child's return code (negative: the signal that ended it)."""
    if code is None:
        return "the cell's process is still running"
    if code < 0:
        sig = signal.Signals(-code)
        hint = _HINTS.get(sig)
        return f"the cell's process was ended by signal {-code} ({sig.name}" + (f": {hint})" if hint else ")")
    return f"the cell's process exited with code {code}"


#: Seconds a new child may take to start (import the package) before it counts as crashed.
START_TIMEOUT = 600.0


class CellProcess:
    """One child Python process that runs ``fn(*args)`` on request (see the module's docstring).

    The constructor returns once the child has imported the package, so that a call's
    timeout does not include the start.
    """

    def __init__(self):
        ours, theirs = socket.socketpair()
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(os.path.abspath(p) if p else os.getcwd() for p in sys.path)
        code = f"from skfem_affine.lab.cells import serve; serve({theirs.fileno()}, {os.getpid()})"
        # the child's stdout goes to stderr: with --json, stdout carries one JSON object only
        self.proc = subprocess.Popen([sys.executable, "-c", code], pass_fds=(theirs.fileno(),), env=env,
                                     stdin=subprocess.DEVNULL, stdout=sys.__stderr__.fileno()
                                     if _has_fileno(sys.__stderr__) else subprocess.DEVNULL)
        theirs.close()
        self.conn = Connection(ours.detach())
        self.busy = False
        try:
            ready = self.conn.poll(START_TIMEOUT) and self.conn.recv_bytes() == b"ready"
        except (EOFError, OSError):
            ready = False
        if not ready:
            self.close()
            raise CellCrashed(f"the cell's process did not start ({describe_exit(self.proc.returncode)})")

    def call(self, fn, args=(), timeout=None):
        """``fn(*args)`` in the child; its result, or :class:`CellCrashed` / :class:`CellTimedOut`.

        An exception raised by ``fn`` comes back as a RuntimeError naming it.
        """
        self.busy = True
        try:
            return self._call(fn, args, timeout)
        finally:
            self.busy = False

    def _call(self, fn, args, timeout):
        try:
            self.conn.send_bytes(cloudpickle.dumps((fn, tuple(args))))
            ready = self.conn.poll(timeout)
        except OSError:
            ready = True  # the child is gone: recv_bytes says so
        if not ready:
            self.close()
            raise CellTimedOut(f"no result after {timeout:g} s; the cell's process was killed")
        try:
            ok, value = pickle.loads(self.conn.recv_bytes())
        except (EOFError, OSError):
            try:
                code = self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                code = None
            self.close()
            raise CellCrashed(describe_exit(code)) from None
        if not ok:
            raise RuntimeError(value)
        return value

    def alive(self):
        return self.proc.poll() is None

    def close(self):
        """End the child (at once: it may be stuck) and reap it."""
        try:
            self.conn.close()
        except OSError:
            pass
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()


_PROCESSES = {}
_LOCK = threading.Lock()


def call(fn, args=(), timeout=None):
    """``fn(*args)`` in this thread's child process (started on first use, replaced after a crash)."""
    key = (os.getpid(), threading.get_ident())
    with _LOCK:
        proc = _PROCESSES.get(key)
        if proc is not None and proc.alive():
            proc.busy = True  # not idle from now: close_idle leaves it alone
        else:
            proc = None
    if proc is None:
        proc = CellProcess()
        proc.busy = True
        with _LOCK:
            _PROCESSES[key] = proc
    try:
        return proc.call(fn, args, timeout)
    except (CellCrashed, CellTimedOut):
        with _LOCK:
            if _PROCESSES.get(key) is proc:
                del _PROCESSES[key]
        raise


def close_idle():
    """End the child processes of this process that run no cell (a sweep calls it on its workers
    when done; a child busy with another sweep's cell is left to it)."""
    with _LOCK:
        idle = {key: proc for key, proc in _PROCESSES.items() if not proc.busy}
        for key in idle:
            del _PROCESSES[key]
    for proc in idle.values():
        proc.close()


def _has_fileno(stream):
    try:
        stream.fileno()
        return True
    except (AttributeError, OSError, ValueError):
        return False


def serve(fd, parent):
    """The child's loop: receive ``(fn, args)``, send back ``(True, result)`` or ``(False, error)``.

    It ends when the parent closes the socket, or when the parent process is gone (a
    watchdog thread checks, so that a child stuck in a cell does not outlive its sweep).
    """
    def watchdog():
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(3)

    threading.Thread(target=watchdog, daemon=True).start()
    # Ctrl-C (sent to the whole process group) is the sweep's to handle: it ends this child
    # by closing the socket, or the watchdog does once the parent is gone
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    conn = Connection(fd)
    conn.send_bytes(b"ready")
    while True:
        try:
            fn, args = pickle.loads(conn.recv_bytes())
        except EOFError:
            return
        try:
            out = (True, fn(*args))
        except BaseException as err:  # sent back as words: the exception itself may not unpickle
            out = (False, f"{type(err).__name__}: {err}")
        conn.send_bytes(pickle.dumps(out))
