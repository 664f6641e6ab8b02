"""benchmarks/detection_list.py: a few frames of the smallest pile, the list against a search from scratch."""
import importlib.util
import os
import sys

HERE = os.path.join(os.path.dirname(__file__), "..", "benchmarks")


def test_the_list_and_the_search_from_scratch_are_timed_on_the_same_frames():
    sys.path.insert(0, HERE)
    try:
        spec = importlib.util.spec_from_file_location("detection_list", os.path.join(HERE, "detection_list.py"))
        bench = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(bench)
        out = bench.main(["--cells", "1", "--start", "2", "--end", "5"])
    finally:
        sys.path.remove(HERE)
    assert out["contacts"] > 0 and out["list_ms"] > 0 and out["scratch_ms"] > 0
    assert 0 <= out["builds"] <= 3
