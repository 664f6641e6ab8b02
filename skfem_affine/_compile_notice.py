"""One line on stderr when the package's numba kernels are compiled (a cold on-disk cache).

The kernels are compiled on first use and cached on disk (``cache=True``), so a first run
spends tens of seconds compiling before the first frame, and later runs load the cache. So
that a first run is not mistaken for a hang or for the package's speed, the first compilation
of one of the package's cached kernels in a process prints :data:`MESSAGE` once.

It listens to numba's ``"numba:compile"`` event, which numba fires only when it compiles a
function, not when it loads one from the cache. That is exactly "the cache is cold", whatever
the reason (first run, a new numba or Python, a changed source file, an unwritable cache
folder), with no guess at numba's cache file names. Importing this module installs the listener.
"""
import sys
import threading

MESSAGE = ("skfem-affine: compiling the numba kernels this run uses, once (they are cached on disk; "
           "`python -m skfem_affine compile` compiles all of them at once) ...")

_PACKAGE = __name__.split(".")[0]


def _is_package_kernel(dispatcher):
    """Whether ``dispatcher`` is a disk-cached numba function of this package."""
    module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
    if module != _PACKAGE and not module.startswith(_PACKAGE + "."):
        return False
    cache = getattr(dispatcher, "_cache", None)
    return cache is None or type(cache).__name__ != "NullCache"  # cache=False: compiled every run, say nothing


def _make_listener():
    from numba.core import event

    class CompileNotice(event.Listener):
        """Prints :data:`MESSAGE` on the first compilation of a package kernel, then stays quiet."""

        def __init__(self, stream=None):
            self.stream = stream
            self.said = False
            self._lock = threading.Lock()

        def on_start(self, ev):
            if self.said or not _is_package_kernel((ev.data or {}).get("dispatcher")):
                return
            with self._lock:
                if self.said:
                    return
                self.said = True
            stream = self.stream or sys.stderr
            print(MESSAGE, file=stream, flush=True)

        def on_end(self, ev):
            pass

    return CompileNotice


def install():
    """Register the listener with numba (once per process); returns it, or None without numba's event API."""
    global _listener
    if _listener is not None:
        return _listener
    try:
        from numba.core import event
        listener = _make_listener()()
        event.register("numba:compile", listener)
    except (ImportError, AttributeError):  # an old numba without the event API: no notice, nothing breaks
        return None
    _listener = listener
    return listener


_listener = None
install()
