"""benchmarks/detection_frames.py: detection alone on a few frames of the smallest pile."""
import pytest


def test_detection_is_timed_on_the_frames_of_a_run(benchmark_script):
    out = benchmark_script("detection_frames").main(["--cells", "1", "--start", "2", "--end", "5", "--repeat", "2"])
    assert out["frames"] == 3 and out["contacts"] > 0 and out["cpu_ms"] > 0 and out["builds"] >= 1


def test_window_and_meshes_are_checked(benchmark_script):
    bench = benchmark_script("detection_frames")
    with pytest.raises(ValueError, match="--start"):
        bench.main(["--start", "5", "--end", "5"])
    with pytest.raises(ValueError, match="MESH_DIR"):
        bench.main(["--scene", "pills", "--start", "0", "--end", "1"])
