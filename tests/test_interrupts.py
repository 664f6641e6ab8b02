"""Ctrl-C is transactional: a KeyboardInterrupt anywhere inside ``step``, ``run`` or ``load_state``
leaves the simulation (state, statistics, every component) as it was before the call, so that the
run continued after it equals, bit for bit, one that was never interrupted."""
import signal

import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.lab import scenes

SCENES = {  # a reducer with PGS contact, a reducer without, and an integrator with history
    "rigidification-pgs": lambda: scenes.drop(resolution=1, shape="box", height=0.002,
                                              reducer=sa.Rigidification(0.05, 0.1, warmup_frames=1)),
    "affinification": lambda: scenes.cantilever(resolution=1, E=1e5, reducer=sa.Affinification(0.05, 0.1)),
    "bdf2": lambda: scenes.cantilever(resolution=1, E=1e5, integrator="bdf2"),
}

# where a step is interrupted: (what holds the stage, its method), entered or just returned from
STAGES = {
    "integrator step": lambda sim: (sim.integrator, "step"),
    "reducer solve": lambda sim: (sim.integrator.reducer, "solve"),
    "contact detection": lambda sim: (sim.contact, "detect"),
    "contact solve": lambda sim: (sim.contact, "resolve"),
    "divergence checks": lambda sim: (sim.monitor, "check"),
    "monitor accept": lambda sim: (sim.monitor, "accept"),
    "reducer end_frame": lambda sim: (sim.integrator.reducer, "end_frame"),
    "stats recording": lambda sim: (sim.stats, "append"),  # returned from: the record is in, the state not yet
}
FRAMES, AT = 6, 4
CASES = [(scene, stage, after) for scene in SCENES for stage in STAGES for after in (False, True)
         if not (stage.startswith("contact") and scene != "rigidification-pgs")]


def _interrupt_once(monkeypatch, owner, name, after):
    """The next call of ``owner.name`` raises KeyboardInterrupt as it is entered, or as it returns."""
    real = getattr(owner, name)

    def interrupted(*args, **kwargs):
        monkeypatch.setattr(owner, name, real)
        if after:
            real(*args, **kwargs)
        raise KeyboardInterrupt

    monkeypatch.setattr(owner, name, interrupted)


def _fingerprint(sim):
    """Everything later frames depend on, as comparable values."""
    return {"state": (sim.state.x.tobytes(), sim.state.v.tobytes(), sim.state.frame, sim.state.time),
            "stats": len(sim.stats),
            **{name: repr(comp.state_dict()) for name, comp in sim._components().items()}}


_REFERENCE = {}


def _reference(scene):
    if scene not in _REFERENCE:
        _REFERENCE[scene] = [(s.x, s.v) for s in SCENES[scene]().run(FRAMES)]
    return _REFERENCE[scene]


@pytest.mark.parametrize("scene,stage,after", CASES)
def test_an_interrupt_at_any_stage_of_a_step_leaves_the_run_as_if_never_tried(scene, stage, after, monkeypatch):
    sim = SCENES[scene]()
    list(sim.run(AT - 1))
    before = _fingerprint(sim)
    _interrupt_once(monkeypatch, *STAGES[stage](sim), after)
    with pytest.raises(KeyboardInterrupt):
        sim.step()
    assert _fingerprint(sim) == before
    assert sim.state.frame == AT - 1 and len(sim.stats) == AT - 1
    got = [(s.x, s.v) for s in sim.run(FRAMES - AT + 1)]
    assert [r["frame"] for r in sim.stats] == list(range(1, FRAMES + 1))
    for (x, v), (xr, vr) in zip(got, _reference(scene)[AT - 1:]):
        assert np.array_equal(x, xr) and np.array_equal(v, vr)


def test_an_interrupt_inside_run_leaves_the_frames_before_it_and_the_run_continues(monkeypatch):
    sim = SCENES["affinification"]()
    done = []
    with pytest.raises(KeyboardInterrupt):
        for state in sim.run(FRAMES):
            done.append(state)
            if state.frame == AT - 1:
                _interrupt_once(monkeypatch, sim.integrator.reducer, "end_frame", after=False)
    assert sim.state.frame == AT - 1 == len(done) == len(sim.stats)
    got = [(s.x, s.v) for s in sim.run(FRAMES - AT + 1)]
    for (x, v), (xr, vr) in zip(got, _reference("affinification")[AT - 1:]):
        assert np.array_equal(x, xr) and np.array_equal(v, vr)


LOAD_STAGES = {  # (what holds the stage, its method) while a checkpoint is loaded
    "integrator": lambda sim: (sim.integrator, "load_state_dict"),
    "reducer": lambda sim: (sim.integrator.reducer, "load_state_dict"),
    "contact": lambda sim: (sim.contact, "load_state_dict"),
    "solver": lambda sim: (sim.solver, "load_state_dict"),
    "monitor": lambda sim: (sim.monitor, "load_state_dict"),
}
LOAD_CASES = [(scene, stage, after) for scene in ("rigidification-pgs", "bdf2") for stage in LOAD_STAGES
              for after in (False, True) if LOAD_STAGES[stage](SCENES[scene]())[0] is not None
              and hasattr(LOAD_STAGES[stage](SCENES[scene]())[0], "load_state_dict")]


@pytest.mark.parametrize("scene,stage,after", LOAD_CASES)
def test_an_interrupt_while_loading_a_checkpoint_leaves_the_simulation_as_it_was(scene, stage, after, tmp_path,
                                                                                 monkeypatch):
    saved = SCENES[scene]()
    list(saved.run(AT))
    saved.save(tmp_path / "run.npz")
    sim = SCENES[scene]()
    list(sim.run(2))
    before = _fingerprint(sim)
    _interrupt_once(monkeypatch, *LOAD_STAGES[stage](sim), after)
    with pytest.raises(KeyboardInterrupt):
        sim.load_state(tmp_path / "run.npz")
    assert _fingerprint(sim) == before
    got = [(s.x, s.v) for s in sim.run(FRAMES - 2)]
    for (x, v), (xr, vr) in zip(got, _reference(scene)[2:]):
        assert np.array_equal(x, xr) and np.array_equal(v, vr)
    sim = SCENES[scene]()  # and a load that is not interrupted still resumes exactly
    sim.load_state(tmp_path / "run.npz")
    got = [(s.x, s.v) for s in sim.run(FRAMES - AT)]
    for (x, v), (xr, vr) in zip(got, _reference(scene)[AT:]):
        assert np.array_equal(x, xr) and np.array_equal(v, vr)


def test_a_second_ctrl_c_while_a_step_is_rolled_back_waits_for_the_rollback(monkeypatch):
    sim = SCENES["bdf2"]()
    list(sim.run(AT - 1))
    before = _fingerprint(sim)
    _interrupt_once(monkeypatch, sim.monitor, "check", after=True)  # BDF2's history has moved on by then
    load = sim.integrator.load_state_dict

    def ctrl_c_again(state):  # the user presses Ctrl-C again as the history is being put back
        signal.raise_signal(signal.SIGINT)
        load(state)

    monkeypatch.setattr(sim.integrator, "load_state_dict", ctrl_c_again)
    with pytest.raises(KeyboardInterrupt):
        sim.step()
    monkeypatch.setattr(sim.integrator, "load_state_dict", load)
    assert _fingerprint(sim) == before
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def _interrupt_at_line(n, functions):
    """A trace function that raises KeyboardInterrupt at the n-th line run in the named functions of
    skfem_affine/simulation.py (Ctrl-C landing between any two of their lines), and the count of
    lines run so far."""
    from skfem_affine import simulation
    count = [0]

    def line(frame, event, arg):
        if event == "line":
            count[0] += 1
            if count[0] == n:
                raise KeyboardInterrupt
        return line

    def call(frame, event, arg):
        code = frame.f_code
        return line if code.co_filename == simulation.__file__ and code.co_name in functions else None

    return call, count


def _interrupted_at_every_line(call, functions):
    """Run ``call()`` interrupted at its first, second, ... line until it completes; after each
    interrupt yield whether it had completed before the interrupt landed."""
    import sys
    n = 1
    while True:
        trace, count = _interrupt_at_line(n, functions)
        sys.settrace(trace)
        try:
            call()
        except KeyboardInterrupt:
            yield
        finally:
            sys.settrace(None)
        if count[0] < n:  # it ran to its end without reaching the n-th line
            return
        n += 1


@pytest.mark.parametrize("scene", sorted(SCENES))
def test_an_interrupt_between_any_two_lines_of_a_step_is_before_or_after_it(scene):
    sim = SCENES[scene]()
    list(sim.run(AT - 1))
    before, reference = _fingerprint(sim), _reference(scene)
    lines = 0
    for _ in _interrupted_at_every_line(sim.step, {"step", "_advance", "_snapshot", "run"}):
        lines += 1
        if sim.state.frame == AT - 1:  # rolled back
            assert _fingerprint(sim) == before
        else:  # interrupted once the step had been taken on: the step is whole
            assert sim.state.frame == AT == len(sim.stats)
            assert np.array_equal(sim.state.x, reference[AT - 1][0])
            break
    assert lines > 20  # every line of the step was a place to interrupt it
    got = [(s.x, s.v) for s in sim.run(FRAMES - sim.state.frame)]
    for (x, v), (xr, vr) in zip(got, reference[FRAMES - len(got):]):
        assert np.array_equal(x, xr) and np.array_equal(v, vr)


def test_an_interrupt_between_any_two_lines_of_a_load_is_before_or_after_it(tmp_path):
    scene = "rigidification-pgs"
    saved = SCENES[scene]()
    list(saved.run(AT))
    saved.save(tmp_path / "run.npz")
    sim = SCENES[scene]()
    list(sim.run(2))
    before, reference = _fingerprint(sim), _reference(scene)
    for _ in _interrupted_at_every_line(lambda: sim.load_state(tmp_path / "run.npz"),
                                        {"load_state", "_loaded_state", "_load_component", "_snapshot"}):
        if sim.state.frame == 2:
            assert _fingerprint(sim) == before
        else:
            assert sim.state.frame == AT == len(sim.stats)
            break
    got = [(s.x, s.v) for s in sim.run(FRAMES - sim.state.frame)]
    for (x, v), (xr, vr) in zip(got, reference[FRAMES - len(got):]):
        assert np.array_equal(x, xr) and np.array_equal(v, vr)
