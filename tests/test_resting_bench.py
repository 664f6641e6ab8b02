"""benchmarks/resting_bowl.py and resting_slab_pgs.py run and print their tables (a few frames)."""


def test_resting_bowl_prints_the_phases_of_each_method_and_setting(benchmark_script, capsys):
    benchmark_script("resting_bowl").main(["--settle", "1", "--frames", "2"])
    out = capsys.readouterr().out
    header = next(line for line in out.splitlines() if line.startswith("| phase |"))
    assert header.count("|") == 6 and "full, default threads" in header and "affinification, one thread" in header
    for phase in ("detection", "elastic frame", "Delassus", "grouping", "PGS", "correction", "checks", "other",
                  "frame"):
        row = next(line for line in out.splitlines() if line.startswith(f"| {phase} |"))
        assert all(float(cell) >= 0.0 or phase == "other" for cell in row.strip("|").split("|")[1:])
    assert "default threads / one thread CPU time" in out


def test_resting_slab_pgs_times_the_grouping_inside_the_solve(benchmark_script, capsys):
    benchmark_script("resting_slab_pgs").main(["--cells", "3", "--frames", "4", "--repeat", "1"])
    out = capsys.readouterr().out
    assert "16 contacts" in out and "of it grouping" in out
