"""Result tables: CSV and Parquet, merged by concurrent writers under a lock, damaged files named."""
import os
import subprocess
import sys

import numpy as np
import pytest

from skfem_affine.lab import runners, tables
from skfem_affine.lab.runs import Reference

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_tables_csv_and_parquet(tmp_path):
    rows = [{"a": 1, "b": 0.5, "s": "ok", "n": None}, {"a": 2, "b": 1e-3, "s": "diverged", "n": 3.0},
            {"a": 3, "b": 2.0, "s": "error", "n": None, "message": "two\nlines, \"quoted\""}]
    for name in ("t.csv", "t.parquet"):
        path = runners.write_table(rows, str(tmp_path / name))
        back = runners.read_table(path)
        assert back[0]["a"] == 1 and back[1]["b"] == pytest.approx(1e-3) and back[1]["s"] == "diverged"
        assert back[0]["n"] is None and back[1]["n"] == 3.0
        assert back[2]["message"] == "two\nlines, \"quoted\"" and back[0]["message"] is None
    assert sorted(os.listdir(tmp_path)) == ["t.csv", "t.parquet"]  # no temporary file left behind


def test_merge_rows_replaces_by_key_and_keeps_the_others(tmp_path):
    path = str(tmp_path / "t.csv")
    tables.merge_rows(path, [{"k": 1, "v": "a"}, {"k": 2, "v": "b"}], key=lambda r: r["k"])
    rows = tables.merge_rows(path, [{"k": 2, "v": "c", "extra": 1.5}], key=lambda r: r["k"])
    assert sorted((r["k"], r["v"]) for r in rows) == [(1, "a"), (2, "c")]
    assert {r["k"]: r["extra"] for r in tables.read_table(path)} == {1: None, 2: 1.5}


WRITER = """
import sys
from skfem_affine.lab import tables
path, who, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
for i in range(n):
    tables.merge_rows(path, [{"writer": who, "i": i, "payload": "x" * 200}], key=lambda r: (r["writer"], r["i"]))
"""


@pytest.mark.parametrize("name", ["t.csv", "t.parquet"])
def test_two_concurrent_writers_lose_no_row(tmp_path, name):
    path = str(tmp_path / name)
    n = 25
    env = {**os.environ, "PYTHONPATH": ROOT}
    procs = [subprocess.Popen([sys.executable, "-c", WRITER, path, who, str(n)], env=env) for who in "ab"]
    for p in procs:
        assert p.wait(timeout=300) == 0
    rows = tables.read_table(path)
    assert sorted((r["writer"], r["i"]) for r in rows) == sorted((w, i) for w in "ab" for i in range(n))


def test_a_truncated_table_names_the_file(tmp_path):
    path = tmp_path / "sweep.csv"
    runners.write_table([{"a": 1, "b": 2.5, "s": "ok"}, {"a": 2, "b": 3.5, "s": "ok"}], str(path))
    whole = path.read_bytes()
    path.write_bytes(whole[:-6])  # the last row cut short
    with pytest.raises(tables.FileFormatError, match="sweep.csv.*truncated"):
        runners.read_table(str(path))
    path.write_bytes(whole.replace(b"2,3.5,ok", b"2,3.5"))  # a row with a field missing, well ended
    with pytest.raises(tables.FileFormatError, match=r"sweep.csv, line 3: 2 fields, the header has 3"):
        runners.read_table(str(path))
    path.write_bytes(whole[:-10] + b"\xff\xfe\n")
    with pytest.raises(tables.FileFormatError, match="sweep.csv is not UTF-8"):
        runners.read_table(str(path))
    bad = tmp_path / "sweep.parquet"
    runners.write_table([{"a": 1}], str(bad))
    bad.write_bytes(bad.read_bytes()[:20])
    with pytest.raises(tables.FileFormatError, match="sweep.parquet"):
        runners.read_table(str(bad))


def test_reference_is_written_atomically_and_a_truncated_one_is_named(tmp_path):
    ref = Reference(np.zeros((3, 4, 3)), np.zeros(3), np.ones(2), np.full(2, 12.0), 1.0)
    path = str(tmp_path / "reference.npz")
    ref.save(path)
    assert os.listdir(tmp_path) == ["reference.npz"]
    back = Reference.load(path)
    assert back.frames == 2 and back.size == 1.0 and np.array_equal(back.dofs, ref.dofs)
    with open(path, "rb") as fh:
        whole = fh.read()
    with open(path, "wb") as fh:
        fh.write(whole[: len(whole) // 2])
    with pytest.raises(tables.FileFormatError, match="reference .*reference.npz.*truncated or corrupt"):
        Reference.load(path)
    with pytest.raises(FileNotFoundError):
        Reference.load(str(tmp_path / "missing.npz"))
