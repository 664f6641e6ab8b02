"""benchmarks/contact_phases.py: a few frames of the smallest pile, with the contact functions profiled."""


def test_profile_lists_the_contact_functions_of_one_method(benchmark_script):
    bench = benchmark_script("contact_phases")
    means, table = bench.main(["--scene", "pile", "--cells", "1", "--start", "3", "--end", "5",
                               "--profile", "affinification"])
    assert set(means) == set(bench.METHODS) and means["affinification"]["n_contacts"] > 0
    assert "| pgs.py:detect |" in table and "| geometry.py:find |" in table and "| pgs.py:resolve |" in table
    # one detection and one resolve per profiled frame
    assert "| pgs.py:detect | 1.0 |" in table and "| pgs.py:resolve | 1.0 |" in table
