"""benchmarks/detection_list.py: a few frames of the smallest pile, the list against a search from scratch."""


def test_the_list_and_the_search_from_scratch_are_timed_on_the_same_frames(benchmark_script):
    out = benchmark_script("detection_list").main(["--cells", "1", "--start", "2", "--end", "5"])
    assert out["contacts"] > 0 and out["list_ms"] > 0 and out["scratch_ms"] > 0
    assert 0 <= out["builds"] <= 3
