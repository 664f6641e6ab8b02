"""benchmarks/contact_phases.py: a few frames of the smallest pile, profiled, and with both full-space routes."""


def test_profile_lists_the_contact_functions_of_one_method(benchmark_script):
    bench = benchmark_script("contact_phases")
    means, table = bench.main(["--scene", "pile", "--cells", "1", "--start", "3", "--end", "5",
                               "--profile", "affinification"])
    assert set(means) == set(bench.METHODS) and means["affinification"]["n_contacts"] > 0
    assert "| pgs.py:detect |" in table and "| geometry.py:find |" in table and "| pgs.py:resolve |" in table
    # one detection and one resolve per profiled frame
    assert "| pgs.py:detect | 1.0 |" in table and "| pgs.py:resolve | 1.0 |" in table


def test_frame_schur_steps_two_full_space_runs_in_turn(benchmark_script):
    bench = benchmark_script("contact_phases")
    means, _ = bench.main(["--scene", "pile", "--cells", "1", "--start", "3", "--end", "5", "--frame-schur"])
    assert list(means) == list(bench.FRAME_METHODS)
    own, framed = (means[m] for m in bench.FRAME_METHODS)
    assert own["n_contacts"] == framed["n_contacts"] > 0 and own["frame_schur"] == 0


def test_frame_schur_of_a_reducer_steps_two_runs_of_it_in_turn(benchmark_script):
    bench = benchmark_script("contact_phases")
    means, _ = bench.main(["--scene", "pile", "--cells", "1", "--start", "3", "--end", "5",
                           "--frame-schur", "affinification"])
    assert list(means) == ["affinification, own handle", "affinification, frame's Schur"]
    own, framed = means.values()
    assert own["n_contacts"] == framed["n_contacts"] > 0 and own["frame_schur"] == 0


def test_blocks_steps_two_full_space_runs_from_a_checkpoint(benchmark_script, tmp_path):
    bench = benchmark_script("contact_phases")
    from budget import pile  # the benchmark's folder is on the path once the script is loaded
    sim = pile(1)
    list(sim.run(3))
    sim.save(tmp_path / "pile.npz")
    means, _ = bench.main(["--scene", "pile", "--cells", "1", "--start", "4", "--end", "6", "--blocks",
                           "--resume", str(tmp_path / "pile.npz")])
    assert list(means) == list(bench.BLOCK_METHODS)
    plain, by_body = (means[m] for m in bench.BLOCK_METHODS)
    assert plain["n_contacts"] == by_body["n_contacts"] > 0 and plain["frame_schur"] == 0


def test_frame_schur_runs_the_stacked_beams_of_the_lab_scenes(benchmark_script):
    bench = benchmark_script("contact_phases")
    means, _ = bench.main(["--scene", "stacked_beams", "--cells", "1", "--start", "1", "--end", "3", "--frame-schur"])
    own, framed = (means[m] for m in bench.FRAME_METHODS)
    assert own["n_contacts"] == framed["n_contacts"] > 0 and own["dofs"] == framed["dofs"] == 216


def test_resume_takes_a_checkpoint_saved_without_the_schur_complements_state(benchmark_script, tmp_path):
    import pytest
    bench = benchmark_script("contact_phases")
    from budget import pile
    sim = pile(1)
    list(sim.run(3))
    sim.contact.schur.state_dict = dict  # as a run saved before that state was
    sim.save(tmp_path / "old.npz")
    with pytest.raises(ValueError, match="schur"):
        pile(1).load_state(tmp_path / "old.npz")
    resumed = pile(1)
    bench.load_state(resumed, tmp_path / "old.npz")
    assert resumed.state.frame == 3 and resumed.contact.schur._resume == {}
