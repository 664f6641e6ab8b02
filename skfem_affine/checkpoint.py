"""Checkpoints: the state of a run in one versioned ``.npz`` file (``sim.save`` / ``sim.load_state``).

A checkpoint holds everything later frames depend on, so that a run resumed from it continues
bit-identically to an uninterrupted one: positions, velocities, frame, time and clusters, the
statistics so far, and the ``state_dict()`` of each component that carries state across frames
(the integrator's history, the reducer's clusters, seeds and random generator, the contact
warm starts, the solver's AMG hierarchy, the divergence monitor). It does not hold the bodies,
materials or settings: the user rebuilds the :class:`~skfem_affine.Simulation` with the same
arguments and calls ``sim.load_state(path)``. A file that does not match the simulation
(another mesh, integrator, reducer, contact model or time step) or comes from an incompatible
format version is refused with a ValueError that says what differs.

The file is an uncompressed NumPy ``.npz`` (``np.load(path)`` reads it without pickle):

* ``__header__``: a JSON string: ``format`` (``"skfem-affine-checkpoint"``), ``version``
  (:data:`VERSION`), ``package`` (skfem_affine's version), what the simulation must match
  (``integrator``, ``reducer``, ``contact_model``, ``n_vertices``, ``n_elements``, ``dt``,
  ``mesh``: a SHA-256 of the rest positions and connectivity), ``values`` (the non-array entries
  of every state dict, e.g. ``"reducer.rng_state"``), ``stats`` (the per-frame records);
* one array per array entry of a state dict, named ``<component>.<key>`` (``state.x``,
  ``integrator.x_prev``, ``reducer.labels``, ``contact.previous_keys``, ...).

A component's state dict maps names to NumPy arrays or JSON values (None, numbers, strings,
lists, dicts). :class:`~skfem_affine.reducers.base.Reducer` builds its own from the attribute
names in ``_state_keys``, so a reducer adds saved state by listing it there.
"""
import hashlib
import json
import os
from pathlib import Path

import numpy as np

FORMAT = "skfem-affine-checkpoint"
VERSION = 1
COMPATIBLE = (1,)


def mesh_hash(system):
    """SHA-256 (hex) of the rest positions and the connectivity of a system."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(system.p0, dtype=float).tobytes())
    h.update(np.ascontiguousarray(system.t, dtype=np.int64).tobytes())
    return h.hexdigest()


def _jsonable(value):
    """A JSON-serialisable copy of a non-array value (numpy scalars become Python numbers)."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(f"checkpoint values must be arrays, numbers, strings, lists or dicts, got {type(value).__name__}")


def flatten(components):
    """Arrays (name -> ndarray) and JSON values (name -> value) of ``{component: state_dict}``."""
    arrays, values = {}, {}
    for comp, state in components.items():
        for key, val in state.items():
            name = f"{comp}.{key}"
            if isinstance(val, np.ndarray):
                arrays[name] = val
            else:
                values[name] = _jsonable(val)
    return arrays, values


def unflatten(arrays, values, component):
    """The state dict of ``component`` back from the flat arrays and values."""
    prefix = component + "."
    out = {k[len(prefix):]: v for k, v in values.items() if k.startswith(prefix)}
    out.update({k[len(prefix):]: v for k, v in arrays.items() if k.startswith(prefix)})
    return out


def write(path, header, components):
    """Write a checkpoint atomically (a temporary file renamed over ``path``)."""
    path = Path(path)
    arrays, values = flatten(components)
    header = dict(header, format=FORMAT, version=VERSION, values=values)
    text = json.dumps(header, allow_nan=True)
    tmp = path.with_name(path.name + f".tmp{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            np.savez(f, __header__=np.array(text), **arrays)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def read(path):
    """``(header, arrays)`` of a checkpoint; ValueError naming the file when it is not one
    or comes from an incompatible format version."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except Exception as err:  # not a zip, truncated, or a pickled array
        raise ValueError(f"{path} is not a readable skfem-affine checkpoint ({type(err).__name__}: {err})") from None
    try:
        header = json.loads(str(arrays.pop("__header__")))
    except (KeyError, ValueError):
        raise ValueError(f"{path} is not a skfem-affine checkpoint (no valid __header__)") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise ValueError(f"{path} is not a skfem-affine checkpoint (format {header.get('format')!r})")
    if header.get("version") not in COMPATIBLE:
        raise ValueError(f"{path} has checkpoint format version {header.get('version')!r} (written by skfem-affine "
                         f"{header.get('package')}); this skfem-affine reads versions {list(COMPATIBLE)}")
    return header, arrays


def check_matches(path, header, expected):
    """ValueError listing every entry of ``expected`` that the file's header does not match."""
    diff = [f"{k}: file {header.get(k)!r}, simulation {v!r}" for k, v in expected.items() if header.get(k) != v]
    if diff:
        raise ValueError(f"checkpoint {path} does not match this simulation (rebuild it with the arguments of the "
                         f"saved run): " + "; ".join(diff))
