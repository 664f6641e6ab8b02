"""Progress of a long run on stderr: a tqdm bar on a terminal, plain lines in a log (:func:`bar`).

A run whose stderr goes to a file or a pipe (``skfem-affine run ... 2> log``, a batch job)
gets a line when it starts, then one every :data:`LOG_SECONDS` seconds, and one when it ends::

    cantilever full, affinification: frame 1/370, 2.1 s
    cantilever full, affinification: frame 52/370, 32.3 s, about 185 s left
"""
import sys
import time

#: Seconds between two progress lines in a log.
LOG_SECONDS = 30.0


def bar(total, desc, enabled, unit="frame"):
    """A progress counter: ``update(n)`` and ``close()``.

    A tqdm bar when ``enabled`` and stderr is a terminal (and tqdm, of the ``lab`` extra, is
    installed), :class:`LogProgress` lines when ``enabled`` otherwise, else an object that ignores updates.
    """
    if not enabled:
        return NoProgress()
    if _is_terminal(sys.stderr):
        try:
            from tqdm import tqdm
        except ModuleNotFoundError:  # tqdm comes with the 'lab' extra: without it, the log's lines
            return LogProgress(total, desc, unit)
        return tqdm(total=total, desc=desc, unit=unit, leave=False)
    return LogProgress(total, desc, unit)


class NoProgress:
    """Ignores updates."""

    def update(self, n=1):
        pass

    def close(self):
        pass


class LogProgress:
    """Progress as lines on stderr: at the first update, every :data:`LOG_SECONDS` s, and at the end.

    Parameters
    ----------
    total : int
        Units of work (frames, cells).
    desc : str
        What runs, the start of each line.
    unit : str
        The unit's name, e.g. ``"frame"``.
    seconds : float, optional
        Seconds between lines (default :data:`LOG_SECONDS`).
    stream : file, optional
        Where the lines go (default ``sys.stderr`` at the time of each line).
    """

    def __init__(self, total, desc, unit="frame", seconds=None, stream=None):
        self.total, self.desc, self.unit = int(total), desc, unit
        self.seconds = LOG_SECONDS if seconds is None else float(seconds)
        self.stream = stream
        self.n = 0
        self.start = time.perf_counter()
        self.said = None  # (count, time) of the last line

    def update(self, n=1):
        self.n += n
        now = time.perf_counter()
        if self.said is None or self.n >= self.total or now - self.said[1] >= self.seconds:
            self._say(now)

    def close(self):
        if self.said is None or self.said[0] != self.n:
            self._say(time.perf_counter())

    def _say(self, now):
        elapsed = now - self.start
        text = f"{self.desc}: {self.unit} {self.n}/{self.total}, {elapsed:.1f} s"
        if 0 < self.n < self.total:
            text += f", about {elapsed * (self.total - self.n) / self.n:.0f} s left"
        print(text, file=self.stream or sys.stderr, flush=True)
        self.said = (self.n, now)


def _is_terminal(stream):
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # no stream, or a closed one
        return False
