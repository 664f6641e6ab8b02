"""Checkpoints: the state of a run in one versioned ``.npz`` file (``sim.save`` / ``sim.load_state``).

A checkpoint holds everything later frames depend on, so that a run resumed from it continues
bit-identically to an uninterrupted one: positions, velocities, frame, time and clusters, the
statistics so far, and the ``state_dict()`` of each component that carries state across frames
(the integrator's history, the reducer's clusters, seeds and random generator, the contact
warm starts, the solver's AMG hierarchy, the divergence monitor). It does not hold the bodies,
materials or settings: the user rebuilds the :class:`~skfem_affine.Simulation` with the same
arguments and calls ``sim.load_state(path)``. A file that does not match the simulation
(another mesh, bodies, materials, density, fixed or prescribed vertices, gravity, damping,
colliders, integrator, reducer or its settings, contact model or settings, time step), comes
from an incompatible format version or is damaged (:func:`check_like`) is refused with a
ValueError that says what differs or what is wrong.

The file is an uncompressed NumPy ``.npz`` (``np.load(path)`` reads it without pickle):

* ``__header__``: a JSON string: ``format`` (``"skfem-affine-checkpoint"``), ``version``
  (:data:`VERSION`), ``package`` (skfem_affine's version), what the simulation must match
  (``integrator``, ``reducer``, ``contact_model``, ``n_vertices``, ``n_elements``, ``dt``,
  ``mesh``: a SHA-256 of the rest positions and connectivity; :func:`setup_signature`,
  ``gravity``, ``damping``, ``mass``, ``colliders``, ``reducer_settings``, ``contact_settings``),
  ``values`` (the non-array entries
  of every state dict, e.g. ``"reducer.rng_state"``), ``stats`` (the per-frame records);
* one array per array entry of a state dict, named ``<component>.<key>`` (``state.x``,
  ``integrator.x_prev``, ``reducer.labels``, ``contact.previous_keys``, ...).

A component's state dict maps names to NumPy arrays or JSON values (None, numbers, strings,
lists, dicts). :class:`~skfem_affine.reducers.base.Reducer` builds its own from the attribute
names in ``_state_keys``, so a reducer adds saved state by listing it there.
"""
import hashlib
import json
from pathlib import Path

import numpy as np

from skfem_affine._json import jsonable
from skfem_affine.files import replacing

FORMAT = "skfem-affine-checkpoint"
VERSION = 2
COMPATIBLE = (2,)
#: What every header holds beside the signature (version 2 added the set-up to the signature).
REQUIRED = {"values": dict, "stats": list, "frame": int}


def mesh_hash(system):
    """SHA-256 (hex) of the rest positions and the connectivity of a system."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(system.p0, dtype=float).tobytes())
    h.update(np.ascontiguousarray(system.t, dtype=np.int64).tobytes())
    return h.hexdigest()


def digest(*arrays):
    """A short SHA-256 (16 hex digits) of arrays (their dtype, shape and bytes)."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


def setup_signature(system):
    """The bodies' set-up beyond the mesh: vertices per body, materials, density, fixed and
    prescribed vertices (short hashes; a file must match them to be loaded)."""
    bodies = system.bodies
    materials = [f"{type(m).__name__}" for b in bodies for m in b.materials]
    params = [np.asarray(getattr(m, k), float) for b in bodies for m in b.materials for k in ("E", "nu")]
    prescribed = [np.asarray(idx, np.int64) + o for b, o in zip(bodies, system.vertex_offsets) for idx in
                  b.prescribed_vertices]
    return {"bodies": [int(b.n_vertices) for b in bodies],
            "materials": digest(np.array(materials), *params, *[b.material_index for b in bodies]),
            "density": digest(system.density), "fixed": digest(system.fixed),
            "prescribed": digest(np.concatenate(prescribed) if prescribed else np.zeros(0, np.int64))}


def settings_of(obj):
    """The settings an object was built with, as JSON values: its public attributes (numbers,
    strings, lists; other objects by their repr, or their class name when that repr is the default)."""
    out = {}
    for key, value in sorted(vars(obj).items()):
        if key.startswith("_") or callable(value):
            continue
        try:
            out[key] = jsonable(value)
        except TypeError:
            default = type(value).__repr__ is object.__repr__
            out[key] = type(value).__name__ if default else repr(value)
    return out


def flatten(components):
    """Arrays (name -> ndarray) and JSON values (name -> value) of ``{component: state_dict}``."""
    arrays, values = {}, {}
    for comp, state in components.items():
        for key, val in state.items():
            name = f"{comp}.{key}"
            if isinstance(val, np.ndarray):
                arrays[name] = val
            else:
                values[name] = jsonable(val)
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
    with replacing(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, __header__=np.array(text), **arrays)
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
    if not isinstance(header, dict):
        raise ValueError(f"{path} is not a skfem-affine checkpoint (its header is a {type(header).__name__}, "
                         f"not a JSON object)")
    if header.get("format") != FORMAT:
        raise ValueError(f"{path} is not a skfem-affine checkpoint (format {header.get('format')!r})")
    if header.get("version") not in COMPATIBLE:
        raise ValueError(f"{path} has checkpoint format version {header.get('version')!r} (written by skfem-affine "
                         f"{header.get('package')}); this skfem-affine reads versions {list(COMPATIBLE)}")
    for key, kind in REQUIRED.items():
        if not isinstance(header.get(key), kind) or isinstance(header.get(key), bool):
            raise ValueError(f"checkpoint {path} is damaged: header entry {key!r} must be a {kind.__name__}, "
                             f"got {header.get(key)!r:.60}")
    for name, a in arrays.items():  # every array of a run's state holds finite numbers
        if a.dtype.kind not in "biuf":
            raise ValueError(f"checkpoint {path} is damaged: array {name!r} holds {a.dtype} values, not numbers")
        if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
            raise ValueError(f"checkpoint {path} is damaged: array {name!r} holds non-finite values")
    return header, arrays


def _kind(value):
    if value is None:
        return "None"
    if isinstance(value, (bool, np.bool_)):
        return "bool"
    if isinstance(value, (int, float, np.number)):
        return "number"
    if isinstance(value, np.ndarray):
        return "array"
    return type(value).__name__


def check_like(name, loaded, reference):
    """ValueError naming the first entry of a loaded state dict that is missing or not of the kind
    the component's own state has (a string where a number was, a list where a dict was, ...).

    ``None`` in the reference (a value not set yet) accepts anything; an empty list or dict in the
    reference accepts any entries but strings.
    """
    if isinstance(reference, dict):
        if not isinstance(loaded, dict):
            raise ValueError(f"{name} must be a dict of entries, got {_kind(loaded)}")
        for key, ref in reference.items():
            if key not in loaded:
                raise ValueError(f"{name}.{key} is missing")
            check_like(f"{name}.{key}", loaded[key], ref)
        return
    if reference is None:
        return
    if _kind(loaded) != _kind(reference):
        raise ValueError(f"{name} must be a {_kind(reference)}, got {_kind(loaded)} {loaded!r:.40}")
    if isinstance(reference, list):
        for i, item in enumerate(loaded):
            if reference:
                check_like(f"{name}[{i}]", item, reference[min(i, len(reference) - 1)])
            elif isinstance(item, str) or (isinstance(item, list) and any(isinstance(v, str) for v in item)):
                raise ValueError(f"{name}[{i}] must hold numbers, got {item!r:.40}")
    elif isinstance(reference, np.ndarray) and (loaded.dtype.kind == "f") != (reference.dtype.kind == "f"):
        raise ValueError(f"{name} must hold {reference.dtype} values, got {loaded.dtype}")


def check_matches(path, header, expected):
    """ValueError listing every entry of ``expected`` that the file's header does not match."""
    diff = []
    for k, v in expected.items():
        got = header.get(k)
        if got == v:
            continue
        if isinstance(got, dict) and isinstance(v, dict):  # settings: the entries that differ
            keys = sorted(key for key in set(got) | set(v) if got.get(key) != v.get(key))
            diff.append(f"{k}: " + ", ".join(f"{key} file {got.get(key)!r}, simulation {v.get(key)!r}" for key in keys))
        else:
            diff.append(f"{k}: file {got!r}, simulation {v!r}")
    if diff:
        raise ValueError(f"checkpoint {path} does not match this simulation (rebuild it with the arguments of the "
                         f"saved run): " + "; ".join(diff))
