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


def test_the_methods_resume_from_their_own_checkpoints_beside_a_plain_blocks_run(benchmark_script, tmp_path):
    """``--resume`` with ``{method}``: each method from its checkpoint (one written before the Schur inverse
    saved ``schur_seen``, loaded with it empty), ``--methods`` a subset, ``--plain-blocks`` a second run of
    affinification with ``SchurInverse.blocks`` off."""
    import numpy as np
    import pytest
    bench = benchmark_script("contact_phases")
    from budget import pile
    import skfem_affine as sa
    for name, reducer in (("full", None), ("affinification", sa.Affinification(tau_a=1e-4, tau_e=2e-4))):
        sim = pile(1, reducer) if reducer is not None else pile(1)
        list(sim.run(3))
        sim.save(tmp_path / f"{name}-3.npz")
    with np.load(tmp_path / "full-3.npz") as data:  # as an older run wrote it
        older = {k: data[k] for k in data.files if k != "contact.schur_seen"}
    np.savez(tmp_path / "full-3.npz", **older)
    with pytest.raises(ValueError, match="schur_seen is missing"):
        pile(1).load_state(tmp_path / "full-3.npz")
    means, _ = bench.main(["--scene", "pile", "--cells", "1", "--start", "3", "--end", "5", "--methods", "full",
                           "affinification", "--plain-blocks", "affinification",
                           "--resume", str(tmp_path / "{method}-3.npz")])
    assert list(means) == ["full", "affinification", "affinification, plain blocks"]
    assert all(m["n_contacts"] > 0 and m["wall"] > m["other"] > 0 for m in means.values())
    with pytest.raises(ValueError, match="{method}"):
        bench.main(["--scene", "pile", "--cells", "1", "--start", "3", "--end", "5",
                    "--resume", str(tmp_path / "full-3.npz")])


def test_frame_schur_runs_the_stacked_beams_of_the_lab_scenes(benchmark_script):
    bench = benchmark_script("contact_phases")
    means, _ = bench.main(["--scene", "stacked_beams", "--cells", "1", "--start", "1", "--end", "3", "--frame-schur"])
    own, framed = (means[m] for m in bench.FRAME_METHODS)
    assert own["n_contacts"] == framed["n_contacts"] > 0 and own["dofs"] == framed["dofs"] == 216


def test_contact_cpu_times_the_contact_parts_of_runs_stepped_in_turn(benchmark_script):
    bench = benchmark_script("contact_cpu")
    runs = bench.main(["--cells", "1", "--start", "3", "--end", "5", "--dense", "160,0"])
    assert len(runs) == 2
    for ms, frame in runs:
        assert {"detect", "resolve", "find", "Resolvent.delassus", "PGS sweeps"} <= set(ms)
        assert 0 < ms["detect"] + ms["resolve"] < frame and ms["Resolvent.delassus"] < ms["resolve"]
