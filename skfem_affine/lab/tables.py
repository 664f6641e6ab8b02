"""Tidy result tables (CSV, or Parquet with pyarrow): write, read, and merge rows under a lock.

Tables are written whole to a temporary file and renamed into place, so that a reader never
sees half a table. Several processes (e.g. two sweeps) may add rows to one table: each
:func:`merge_rows` holds an exclusive ``fcntl`` lock on ``<table>.lock`` while it reads the
table, adds its rows and writes it back, so that no writer's rows are lost. A damaged table
(a truncated row, bytes that are not UTF-8) raises :class:`FileFormatError` naming the file.
"""
import csv
import fcntl
import io
import os
from contextlib import contextmanager

from skfem_affine._extras import require


class FileFormatError(ValueError):
    """A results file (table, cached reference) that cannot be read: truncated, corrupt or not UTF-8."""


def _value(text):
    if text == "":
        return None
    try:
        number = float(text)
    except ValueError:
        return text
    return int(number) if number.is_integer() and "." not in text and "e" not in text.lower() else number


def write_table(rows, path):
    """Write a list of dicts as a tidy table: CSV, or Parquet (needs pyarrow) for a .parquet path."""
    path = os.fspath(path)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    columns = list(dict.fromkeys(k for r in rows for k in r))
    tmp = f"{path}.tmp{os.getpid()}"
    try:
        if path.endswith(".parquet"):
            pq = _pyarrow_parquet()
            pa = require("pyarrow", PARQUET, "parquet")
            pq.write_table(pa.Table.from_pylist([{c: r.get(c) for c in columns} for r in rows]), tmp)
        else:
            with open(tmp, "w", newline="", encoding="utf-8") as fh:
                writer = csv.DictWriter(fh, fieldnames=columns)
                writer.writeheader()
                for r in rows:
                    writer.writerow({c: "" if r.get(c) is None else r.get(c) for c in columns})
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


def read_table(path):
    """Rows (dicts) of a table written by :func:`write_table`.

    Raises :class:`FileFormatError` (naming the file) for a truncated or corrupt table.
    """
    path = os.fspath(path)
    if path.endswith(".parquet"):
        pq = _pyarrow_parquet()
        try:
            return pq.read_table(path).to_pylist()
        except (OSError, ValueError) as err:
            if isinstance(err, FileNotFoundError):
                raise
            raise FileFormatError(f"table {path} is not a readable Parquet file ({err})") from None
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            text = fh.read()
    except UnicodeDecodeError as err:
        raise FileFormatError(f"table {path} is not UTF-8 text (byte {err.start}: {err.reason}); "
                              f"is it a results table?") from None
    if text and not text.endswith("\n"):
        raise FileFormatError(f"table {path} is truncated (its last row is not complete); "
                              f"remove that row or the file")
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        header = next(reader, None)
        if header is None:
            return []
        rows = []
        for fields in reader:
            if len(fields) != len(header):
                raise FileFormatError(f"table {path}, line {reader.line_num}: {len(fields)} fields, the header has "
                                      f"{len(header)} (a truncated or corrupt row)")
            rows.append({k: _value(v) for k, v in zip(header, fields)})
    except csv.Error as err:
        raise FileFormatError(f"table {path} is not a readable CSV table ({err})") from None
    return rows


@contextmanager
def table_lock(path):
    """An exclusive lock on ``<path>.lock`` (``fcntl.flock``), held for the ``with`` block.

    It serialises writers of one table across processes and threads of one machine (and on
    network file systems that support ``flock``).
    """
    lock = os.fspath(path) + ".lock"
    os.makedirs(os.path.dirname(os.path.abspath(lock)), exist_ok=True)
    with open(lock, "a") as fh:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


def merge_rows(path, rows, key):
    """Add ``rows`` to the table at ``path`` under :func:`table_lock`; returns all its rows.

    A row replaces the table's row with the same ``key(row)``; rows of other writers that
    arrived in the meantime are kept.
    """
    path = os.fspath(path)
    with table_lock(path):
        old = read_table(path) if os.path.exists(path) else []
        new = {key(r): r for r in rows}
        merged = [r for r in old if key(r) not in new] + list(new.values())
        write_table(merged, path)
    return merged


#: What needs pyarrow, for the error that names its extra.
PARQUET = "a .parquet table (a .csv table needs nothing)"


def _pyarrow_parquet():
    return require("pyarrow.parquet", PARQUET, "parquet")
