"""What the never-slower fall-back compares: frames costed in CPU time (load from other processes
does not move its decisions), and frames it solves in full space costed as full space pays them."""
import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.reducers import budget
from skfem_affine.reducers.affine.clustered import frame_cost

from test_resting_contact import _stack


def test_a_frames_cost_is_its_cpu_time_when_the_record_has_it():
    reduced = {"kind": "reduced", "reduced": 0.5, "full": 0.0, "reduced_cpu": 0.2, "full_cpu": 0.0}
    judged, cost = frame_cost(reduced, {"wall": 1.5, "cpu": 0.3})
    assert cost == 0.3 and judged["reduced"] == 0.2 and judged["full"] == 0.0 and judged["kind"] == "reduced"
    assert reduced["reduced"] == 0.5  # the reducer's record is not changed
    assert frame_cost({"kind": "full"}, {"wall": 1.5, "cpu": 0.3}) == ({"kind": "full"}, 0.3)
    # without a CPU time (a record from elsewhere, or parts measured on the wall clock only): the wall time
    assert frame_cost(reduced, {"wall": 1.5}) == (reduced, 1.5)
    wall_only = {"kind": "shadow", "reduced": 0.5, "full": 0.4}
    assert frame_cost(wall_only, {"wall": 1.5, "cpu": 0.3}) == (wall_only, 1.5)


def _frames(rng, n=200):
    """A run's frames as the reducer reports them: (judged, CPU seconds). Full frames cost 1.0 s of work,
    reduced ones 0.85 s (reduction pays 15 %), 0.25 s of it the reducer's; a shadow frame, the
    reducer's 0.25 s, a full solve (0.3 s) and the rest of a full frame (0.7 s); the work scatters by 2 %."""
    frames = []
    for i in range(n):
        work = 1.0 + 0.02 * rng.standard_normal()
        if i % 10 == 0:
            frames.append(({"kind": "shadow", "reduced": 0.25 * work, "full": 0.3 * work, "ramp": False,
                            "settled": True, "dof_ratio": 0.05}, 1.25 * work))
        else:
            frames.append(({"kind": "reduced", "reduced": 0.25 * work, "full": 0.0, "ramp": False,
                            "settled": True, "dof_ratio": 0.05}, 0.85 * work))
    return frames


def _decisions(red, frames, loads, clock):
    """Feed ``frames`` to the reducer's fall-back (it plans each one); ``loads``: by what the wall time
    of each frame is stretched by load from elsewhere; ``clock``: "cpu" (records with both times) or
    "wall" (records with the wall time only). Returns what each frame was planned as."""
    red.pays = pays = budget.PaysOff(window=5, confirm=True, trial_frames=3)
    red.shadows = budget.ShadowClock(10)
    plans = []
    for (judged, cpu), load in zip(frames, loads):
        plan = pays.plan()
        plans.append(plan)
        if plan in ("full", "confirm"):
            judged, cpu = {"kind": plan}, cpu / 0.85 if judged["kind"] == "reduced" else cpu / 1.25  # a full frame
        elif plan in ("probe", "trial"):
            judged = dict(judged, kind=plan)
        parts = {"reduced_cpu": judged.get("reduced", 0.0), "full_cpu": judged.get("full", 0.0)}
        judged = dict(judged, **{k: load * v for k, v in judged.items() if k in ("reduced", "full")})
        rec = {"wall": load * cpu}
        if clock == "cpu":
            judged.update(parts)
            rec["cpu"] = cpu
        red._judged = judged
        red.end_frame(rec)
    return plans


def test_the_fall_back_decides_the_same_under_any_load():
    # a scene where reduction pays 15 %: judged on CPU time, the run stays reduced whether the machine
    # is quiet or other processes stretch each frame's wall time 1-3x; judged on the wall time, the
    # same load sends it to full space
    red = sa.Affinification()
    red.timer = None  # no time budget; the fall-back's controllers are set by _decisions
    rng = np.random.default_rng(1)
    frames = _frames(rng)
    quiet, loaded = np.ones(len(frames)), rng.uniform(1.0, 3.0, len(frames))
    calm = _decisions(red, frames, quiet, "cpu")
    assert set(calm) == {"reduced"}
    assert _decisions(red, frames, loaded, "cpu") == calm
    assert _decisions(red, frames, quiet, "wall") == calm
    assert "full" in _decisions(red, frames, loaded, "wall")  # the same load, judged on the wall clock


@pytest.mark.slow
def test_the_fall_back_judges_the_cpu_time_simulation_step_measures():
    red = sa.Affinification()
    sim = _stack(red, cells=1)
    seen = []
    judge = red._judge
    red._judge = lambda judged, cost: (seen.append(cost), judge(judged, cost))
    for _ in range(3):
        sim.step()
    assert all(r["cpu"] > 0 for r in sim.stats)
    assert seen == [r["cpu"] for r in sim.stats]


def test_frames_the_fall_back_solves_in_full_space_factorise_as_full_space_does():
    # with the contacts' unknowns last (their Schur complement gives the Delassus operator), not a
    # plain factorisation and a second one for the Delassus operator
    pytest.importorskip("pypardiso")
    full, red = _stack(None), sa.Affinification()
    fell_back = _stack(red)
    for sim in (full, fell_back):
        sim.contact.schur.min_size = 1  # the small stack touches fewer unknowns than a new analysis needs
    full.step()
    fell_back.step()
    red.pays.in_full, red.pays.wait = True, 10 ** 6  # from the second frame on: the fall-back
    for _ in range(8):
        full.step()
        fell_back.step()
    rest = fell_back.stats[1:]
    assert not any(r["reduced"] or r["shadow"] for r in rest)
    assert [r.get("frame_schur", 0) for r in rest] == [r.get("frame_schur", 0) for r in full.stats[1:]]
    assert all(r.get("frame_schur", 0) > 0 for r in rest)
    assert np.abs(fell_back.state.x - full.state.x).max() <= 1e-12


def _counted(judged, rec):
    """A frame's cost as counted work, whatever the clocks read: a full frame 1, a reduced one 0.2 plus
    0.8 per kept DOF fraction (contact on the bodies' DOFs included); a shadow frame or a probe, a
    reduced frame's own work (0.1) besides a full frame, of which 0.3 is the full solve."""
    if "reduced" not in judged:
        return judged, 1.0
    if judged["kind"] in ("shadow", "probe") or judged["full"]:
        return dict(judged, reduced=0.1, full=0.3), 1.1
    return dict(judged, reduced=0.1, full=0.0), 0.2 + 0.8 * judged["dof_ratio"]


def test_a_resting_stack_under_the_default_budget_goes_affine_where_reduction_pays(monkeypatch):
    # the default Affinification(), fall-back on, where a frame costs the DOFs it keeps (counted, not
    # timed): while the boxes settle, frames that keep most DOFs elastic do not pay and the run falls
    # back to full space; once they rest, a probe returns it to reduction, both boxes affine, within
    # its budget (measured: full space from frame 13, reduced from frame 34 on)
    from skfem_affine.reducers.affine import clustered
    monkeypatch.setattr(clustered, "frame_cost", _counted)
    full, sim = _stack(None), _stack(sa.Affinification())
    response, worst = 0.0, 0.0
    for _ in range(100):
        full.step()
        sim.step()
        response = max(response, np.abs(full.state.x - full.system.p0).max())
        worst = max(worst, np.linalg.norm(sim.state.x - full.state.x, axis=1).max())
    settling, rest = sim.stats[:50], sim.stats[50:]
    assert sum(not (r["reduced"] or r["shadow"]) for r in settling) >= 10  # the fall-back to full space
    reduced = [r for r in rest if r["reduced"]]
    assert len(reduced) >= 0.8 * len(rest), [(r["reduced"], r["shadow"]) for r in rest]
    assert min(r["reduced_fraction"] for r in reduced) >= 0.99 and all(r["n_clusters"] == 2 for r in reduced)
    assert worst <= 0.01 * response


def _failed_trial(red, speed):
    """``red``'s fall-back in full space, then a probe whose trial fails on its own error at ``speed``."""
    red.timer, red.settling_speed = None, 0.0
    red.shadows = budget.ShadowClock(10)
    red.pays = pays = budget.PaysOff(window=5, patience=3, confirm=True, probe_every=4)
    pays.in_full, pays.wait = True, 0
    for judged in ({"kind": "probe", "reduced": 0.2, "full": 0.2, "dof_ratio": 0.1},
                   {"kind": "trial", "reduced": 0.2, "full": 0.0, "dof_ratio": 0.1, "settled": False}):
        assert pays.plan() == judged["kind"]
        red._judged = dict(judged, ramp=False, speed=speed)
        red.end_frame({"wall": 0.5})
    assert pays.in_full and pays.wait == 8 and red.settling_speed == speed
    return pays


def test_after_a_probe_found_bodies_settling_the_next_comes_once_they_have_slowed_down():
    red = sa.Affinification()
    pays = _failed_trial(red, speed=0.2)
    for speed in (0.18, 0.15, 0.11):  # still settling: the doubled wait runs
        assert pays.plan() == "full"
        red._judged = {"kind": "full", "speed": speed}
        red.end_frame({"wall": 1.0})
    assert pays.plan() == "full"
    red._judged = {"kind": "full", "speed": 0.09}  # under half the speed at the failed trial
    red.end_frame({"wall": 1.0})
    assert pays.plan() == "probe"
    # the early probe fails on its error too: no series of early probes (speeds at rest keep halving)
    red._judged = {"kind": "probe", "reduced": 0.2, "full": 0.2, "dof_ratio": 0.1, "ramp": False,
                   "settled": False, "speed": 0.09}
    red.end_frame({"wall": 0.5})
    assert pays.in_full and red.settling_speed == 0.0
    plans = []
    for _ in range(4):
        plans.append(pays.plan())
        red._judged = {"kind": "full", "speed": 0.001}
        red.end_frame({"wall": 1.0})
    assert plans == ["full"] * 4 and pays.plan() == "probe"
    # bodies that keep moving: the whole doubled wait
    pays = _failed_trial(red, speed=0.2)
    plans = []
    for _ in range(9):
        plans.append(pays.plan())
        red._judged = {"kind": "full", "speed": 0.15}
        red.end_frame({"wall": 1.0})
    assert plans == ["full"] * 8 + ["probe"]
    # the speed is part of the controllers' state a checkpoint saves
    pays = _failed_trial(red, speed=0.2)
    assert red.controllers["thresholds"]["settling_speed"] == 0.2
