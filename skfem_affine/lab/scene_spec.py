"""A scene to measure, by name or file: :class:`SceneSpec` (picklable, hashable, keyed by content).

A scene is the name of a factory in :data:`skfem_affine.lab.scenes.SCENES`, or the path of a
Python file defining ``scene(**kwargs)`` that returns a :class:`~skfem_affine.Simulation` and
accepts ``reducer=``, plus keyword overrides.
"""
import hashlib
import inspect
import json
import os
import runpy
from dataclasses import dataclass

from skfem_affine.checks import integer
from skfem_affine.lab import scenes


def load_scene_file(path):
    """The ``scene`` function of a user's Python file (it must return a Simulation and accept ``reducer=``)."""
    if not os.path.isfile(path):
        raise ValueError(f"scene file {path!r} does not exist")
    try:
        namespace = runpy.run_path(path, run_name="skfem_affine_scene")
    except SyntaxError as err:  # also a file that is not UTF-8 text
        raise ValueError(f"scene file {path}, line {err.lineno}: SyntaxError: {err.msg} (not a readable Python file)") from None
    factory = namespace.get("scene")
    if not callable(factory):
        raise ValueError(f"{path} must define a function scene(**kwargs) returning a skfem_affine.Simulation "
                         f"(it receives reducer=... and the scene's keyword overrides)")
    return factory


@dataclass(frozen=True)
class SceneSpec:
    """A scene by name (``scenes.SCENES``) or file path, with keyword overrides (picklable, hashable)."""

    name: str
    kwargs: tuple = ()

    @classmethod
    def make(cls, name, **kwargs):
        if not (name in scenes.SCENES or str(name).endswith(".py")):
            raise ValueError(f"unknown scene {name!r}; built-in scenes: {', '.join(scenes.SCENES)} "
                             f"(or give the path of a .py file defining scene(**kwargs))")
        name = os.path.abspath(name) if str(name).endswith(".py") else name
        return cls(name, tuple(sorted((k, v) for k, v in kwargs.items() if v is not None)))

    @property
    def label(self):
        return os.path.splitext(os.path.basename(self.name))[0]

    @property
    def is_file(self):
        return self.name not in scenes.SCENES

    def factory(self):
        return scenes.SCENES[self.name] if not self.is_file else load_scene_file(self.name)

    def build(self, reducer=None):
        """The scene's Simulation, running ``reducer`` (None: full space). Built-in scenes solve with
        the reducers' direct solver unless ``solver`` is given, so that every method is timed with
        the same solver (the reference too).

        A run is reported under the method whose reducer it was given, so a scene whose simulation
        runs another reducer, or none, than the one passed (a file's ``scene(reducer=None, ...)``
        that never hands it to ``sa.Simulation``) is refused with a ValueError rather than measured
        under a name that is not what ran."""
        kwargs = dict(self.kwargs)
        if not self.is_file:
            kwargs.setdefault("solver", "direct")
        sim = self.factory()(reducer=reducer, **kwargs)
        if not all(hasattr(sim, key) for key in ("stats", "run", "reducer")):
            raise TypeError(f"scene {self.name!r} returned {type(sim).__name__}, not a Simulation")
        if sim.reducer is not reducer:
            given = "reducer=None (full space)" if reducer is None else f"reducer={type(reducer).__name__}(...)"
            ran = "in full space" if sim.reducer is None else f"under its own {type(sim.reducer).__name__}"
            raise ValueError(f"scene {self.label!r} was given {given} but its simulation runs {ran}: a scene must "
                             f"pass its reducer on, sa.Simulation(..., reducer=reducer), for its runs to be "
                             f"measured and reported as the method asked for")
        return sim

    def with_kwargs(self, **kwargs):
        return SceneSpec.make(self.name, **{**dict(self.kwargs), **kwargs})

    def source_digest(self):
        """SHA-1 of what defines the scene: the file's bytes, or a built-in factory's source."""
        if self.is_file:
            try:
                with open(self.name, "rb") as fh:
                    data = fh.read()
            except OSError as err:
                raise ValueError(f"scene file {self.name!r} cannot be read: {err.strerror}") from None
        else:
            factory = scenes.SCENES[self.name]
            try:
                data = inspect.getsource(factory).encode()
            except (OSError, TypeError):  # no source at hand (e.g. a compiled install): its bytecode
                code = getattr(factory, "__code__", None)
                data = code.co_code if code is not None else repr(factory).encode()
        return hashlib.sha1(data).hexdigest()

    def key(self):
        """A short identifier of the scene's contents and overrides, for caches of runs.

        A file scene is keyed by its bytes, not its path, so that editing the file gives
        a new key (old sweep cells and references are not reused) and moving it does not.
        """
        kind = "file" if self.is_file else self.name
        text = json.dumps([kind, self.source_digest(), [[k, repr(v)] for k, v in self.kwargs]])
        return "s" + hashlib.sha1(text.encode()).hexdigest()[:12]


def default_frames(sim, frames=None):
    """``frames`` if given, else the scene's own ``sim.frames`` (100 when it has none)."""
    return integer(frames if frames is not None else getattr(sim, "frames", 100), "frames", low=0)
