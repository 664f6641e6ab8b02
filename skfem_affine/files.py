"""Files written whole or not at all: a temporary file in the target's folder, renamed over it.

A reader (ParaView, ``np.load``, a resumed run) sees either the previous file or the new one,
never a part of one: the rename (``os.replace``) is atomic within a folder, and a write that
raises, Ctrl-C included, deletes its temporary file and leaves the target untouched.
"""
import contextlib
import os
from pathlib import Path


@contextlib.contextmanager
def replacing(path):
    """The path of a temporary file beside ``path`` for the block to write; renamed over ``path``
    when the block ends, deleted when it raises."""
    path = Path(path)
    tmp = path.with_name(f"{path.name}.tmp{os.getpid()}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
