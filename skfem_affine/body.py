"""ElasticBody: a tetrahedral scikit-fem mesh with materials, density, fixed vertices.

All validation of user input for a body lives here, so that bad input fails
early with a message that names the problem (and the element or vertex).
"""
import warnings

import numpy as np
import skfem

from skfem_affine.kinematics import shape_gradients, signed_volumes
from skfem_affine.checks import _describe, choice, real_array
from skfem_affine.materials import Material
from skfem_affine.vertex_sets import vertices_of

# a rest element whose volume is below this fraction of a regular tet with its longest edge
# is degenerate (its shape gradients would be meaningless)
_MIN_QUALITY = 1e-9

#: Poisson ratio from which linear tetrahedra with the volumetric energy on the elements lock visibly
LOCKING_NU = 0.45

VOLUMETRIC = ("element", "nodal")


class ElasticBody:
    """An elastic solid discretised by P1 tetrahedra.

    Parameters
    ----------
    mesh : skfem.MeshTet
        Linear (P1) tetrahedral mesh, any orientation of the elements. Refused (ValueError
        or TypeError naming ``mesh``): other element types, an empty mesh, non-finite
        coordinates, vertices used by no element (drop them first with
        ``mesh.remove_unused_nodes()``), repeated or duplicated elements, degenerate or
        folded rest elements (docs/reliability.md).
    material : Material, sequence of Material (one per element), or dict
        A dict maps subdomain names of ``mesh.subdomains`` to materials; every
        element must be covered exactly once. A single material may hold per-element
        ``E``/``nu`` arrays of length m.
    density : float or (m,) array
        Mass density (kg/m^3), > 0.
    fixed : vertex indices, boolean mask, boundary name(s) or scikit-fem DofsView, optional
        Vertices held in place (zero velocity, Dirichlet), e.g. ``mesh.nodes_satisfying(...)``,
        ``"left"`` (a name of ``mesh.boundaries``) or ``basis.get_dofs("left")`` of an
        ``ElementVector(ElementTetP1())`` basis. A plain integer array is read as vertex
        indices: facet or DOF index arrays go through ``sa.vertices_of(mesh, facets=...)`` /
        ``sa.vertices_of(mesh, dofs=...)`` (:mod:`skfem_affine.vertex_sets`). A mask must be
        boolean with one entry per vertex; an integer array of n zeros and ones is refused as
        ambiguous.
    velocity : (n, 3) or (3,) array, optional
        Initial velocity (default zero). Fixed and prescribed vertices get zero velocity.
    name : str, optional
    prescribed : Prescribed or list of Prescribed, optional
        Vertices whose positions follow a function of time (``sa.Prescribed(vertices, path)``,
        :mod:`skfem_affine.motion`): a moving clamp. They may not overlap ``fixed`` nor each
        other; they start at ``path(0, X)``.
    volumetric : {"element", "nodal"}
        Where the volumetric (lam) part of the energy is evaluated. ``"element"`` (default): in each
        element with its material, as scikit-fem's P1 elasticity; near-incompressible materials
        (``nu >= 0.45``) then lock, bending far too stiff, and the body warns
        (:class:`~skfem_affine.SimulationWarning`) when built. ``"nodal"``: on the volume ratio of
        each vertex's patch of elements (:mod:`skfem_affine.nodal_volume`), which does not lock;
        the elements keep the material's shear part. docs/materials.md compares the two. Not with
        ``prescribed`` vertices nor under ``sa.AdaptiveSubspace`` (ValueError).
    """

    def __init__(self, mesh, material, density=1000.0, fixed=None, velocity=None, name=None, prescribed=None,
                 volumetric="element"):
        self.volumetric = choice(volumetric, "volumetric", VOLUMETRIC)
        self.mesh = _check_mesh(mesh)
        if name is not None and not isinstance(name, str):
            raise TypeError(f"name must be a str or None, got {type(name).__name__}")
        self.name = name or "body"
        n, m = mesh.p.shape[1], mesh.t.shape[1]
        self.n_vertices, self.n_elements = n, m
        self.materials, self.material_index = _element_materials(material, mesh)
        if self.volumetric == "element":
            _warn_locking(self.materials, self.name)
        self.density = _positive_per_element(density, m, "density")
        self.fixed = _vertex_mask(fixed, mesh)
        self.prescribed, self.prescribed_vertices = _prescribed(prescribed, mesh, self.fixed)
        if self.prescribed and self.volumetric == "nodal":
            # the step's prescribed-velocity term takes H_fp from element blocks, which do not hold
            # the vertex couplings of the nodal volumetric energy
            raise ValueError('prescribed vertices are not supported with volumetric="nodal"; fix them '
                             '(fixed=...) or use volumetric="element"')
        self.velocity = _velocity(velocity, n)
        self.velocity[self.fixed] = 0.0
        for idx in self.prescribed_vertices:
            self.velocity[idx] = 0.0
        with np.errstate(all="ignore"):  # checked just below
            self.grads, self.volumes = shape_gradients(mesh)
        if not (np.all(np.isfinite(self.grads)) and np.all(self.volumes > 0)):
            raise ValueError("mesh coordinates are too large or too small for floating point: rest "
                             "volumes or shape gradients are not finite and positive; rescale the mesh "
                             "(e.g. to metres)")

    def __repr__(self):
        return (f"ElasticBody({self.name!r}, vertices={self.n_vertices}, elements={self.n_elements}, "
                f"materials={self.materials}, fixed={int(self.fixed.sum())}"
                + (f", prescribed={sum(i.size for i in self.prescribed_vertices)})" if self.prescribed else ")"))

    @property
    def size(self):
        """Diagonal of the rest bounding box (the length used to normalise errors)."""
        p = self.mesh.p
        return float(np.linalg.norm(p.max(axis=1) - p.min(axis=1)))


def _warn_locking(materials, name):
    """Warn once, naming the stiffening, when linear tetrahedra will lock (nu >= LOCKING_NU)."""
    from skfem_affine.monitor import SimulationWarning
    nu = max(float(np.max(m.nu)) for m in materials)
    if nu >= LOCKING_NU:
        ratio = 2.0 * nu / (1.0 - 2.0 * nu)  # lam / mu
        warnings.warn(f"body {name!r}: nu = {nu:g} (lam / mu = {ratio:.3g}) locks linear tetrahedra with "
                      f"the volumetric energy on the elements: bending and other volume-keeping motions "
                      f"come out too stiff, deflections too small by a factor that grows with lam / mu "
                      f"(docs/materials.md, 'Near-incompressible materials'); pass "
                      f"volumetric=\"nodal\" to ElasticBody for a locking-free treatment",
                      SimulationWarning, stacklevel=3)


def _check_mesh(mesh):
    """Refuse meshes the simulator cannot run: wrong kind, empty, non-finite, unused vertices,
    out-of-range or repeated elements, degenerate or folded rest elements."""
    if not isinstance(mesh, skfem.Mesh):
        raise TypeError(f"mesh must be a skfem.MeshTet, got {type(mesh).__name__}")
    if isinstance(mesh, skfem.MeshTet1) and getattr(mesh, "elem", skfem.ElementTetP1) is not skfem.ElementTetP1:
        raise TypeError(f"mesh must be a linear (P1) tetrahedral skfem.MeshTet, got the higher-order "
                        f"{type(mesh).__name__}; keep its vertices with "
                        f"skfem.MeshTet(mesh.p[:, :mesh.nvertices], mesh.t)")
    if not isinstance(mesh, skfem.MeshTet1) or mesh.t.ndim != 2 or mesh.t.shape[0] != 4:
        raise TypeError(f"mesh must be a linear tetrahedral skfem.MeshTet, got {type(mesh).__name__}")
    p, t = mesh.p, mesh.t
    if p.ndim != 2 or p.shape[0] != 3:
        raise ValueError(f"mesh points must be 3D, got shape {p.shape}")
    if p.shape[1] == 0 or t.shape[1] == 0:
        raise ValueError(f"mesh is empty ({p.shape[1]} vertices, {t.shape[1]} elements); "
                         f"an ElasticBody needs at least one tetrahedron")
    if not np.all(np.isfinite(p)):
        bad = np.flatnonzero(~np.all(np.isfinite(p), axis=0))
        raise ValueError(f"mesh has non-finite (NaN/inf) coordinates at vertices {_some(bad)}")
    if t.min() < 0 or t.max() >= p.shape[1]:
        bad = np.flatnonzero(np.any((t < 0) | (t >= p.shape[1]), axis=0))
        raise ValueError(f"mesh elements {_some(bad)} reference vertices out of range [0, {p.shape[1]})")
    used = np.zeros(p.shape[1], dtype=bool)
    used[t.ravel()] = True
    if not np.all(used):
        bad = np.flatnonzero(~used)
        raise ValueError(f"mesh has {bad.size} vertices used by no element: {_some(bad)}; they would make "
                         f"the system singular. Drop them with mesh = mesh.remove_unused_nodes() "
                         f"(renumbers the vertices: compute fixed vertices afterwards)")
    sorted_t = np.sort(t, axis=0)
    if np.any(sorted_t[1:] == sorted_t[:-1]):
        bad = np.flatnonzero(np.any(sorted_t[1:] == sorted_t[:-1], axis=0))
        raise ValueError(f"mesh has degenerate rest elements {_some(bad)}: an element uses the same vertex twice")
    order = np.lexsort(sorted_t[::-1])
    same = np.all(sorted_t[:, order[1:]] == sorted_t[:, order[:-1]], axis=0)
    if np.any(same):
        k = np.flatnonzero(same)[0]
        raise ValueError(f"mesh has duplicated elements (same four vertices): elements "
                         f"{sorted([int(order[k]), int(order[k + 1])])} ({int(same.sum())} such pairs)")
    # quality on coordinates scaled to a unit bounding box: independent of the unit of length,
    # no overflow or underflow for very large or very small meshes
    extent = np.ptp(p, axis=1).max()
    if not extent > 0:
        raise ValueError("mesh is degenerate: all its vertices coincide")
    q = (p - p.min(axis=1, keepdims=True)) / extent
    vol = signed_volumes(q, t)
    edges = q.T[t[[0, 0, 0, 1, 1, 2]]] - q.T[t[[1, 2, 3, 2, 3, 3]]]
    longest = np.linalg.norm(edges, axis=-1).max(axis=0)
    # volume relative to a regular tet with the same longest edge (1 for regular); NaN-proof:
    # coincident vertices (longest = 0) or any non-finite value count as degenerate
    with np.errstate(divide="ignore", invalid="ignore"):
        quality = np.abs(vol) * 6.0 * np.sqrt(2.0) / longest ** 3
    good = np.isfinite(quality) & (longest > 0) & (quality >= _MIN_QUALITY)
    if not np.all(good):
        bad = np.flatnonzero(~good)
        qb = quality[bad[0]]
        raise ValueError(f"mesh has degenerate (zero-volume) rest elements {_some(bad)} "
                         f"(relative volume {qb if np.isfinite(qb) else 0.0:.1e}, below {_MIN_QUALITY:g})")
    _check_folds(mesh, q)
    return mesh


def _some(indices, k=5):
    """The first ``k`` indices as a list, with ' ...' when there are more."""
    return f"{np.asarray(indices)[:k].tolist()}{' ...' if len(indices) > k else ''}"


def _check_folds(mesh, q):
    """Raise if an element is inverted relative to its face neighbour (the mesh folds).

    ``q`` are the mesh points scaled to a unit box (see :func:`_check_mesh`)."""
    f2t = mesh.f2t
    inner = f2t[1] >= 0
    if not np.any(inner):
        return
    e0, e1 = f2t[0, inner], f2t[1, inner]
    facets = mesh.facets[:, inner]
    p, t = q.T, mesh.t

    def side(e):
        # the vertex of e opposite the shared facet
        te = t[:, e]
        opp = te[np.argmax(~np.any(te[:, None, :] == facets[None], axis=1), axis=0), np.arange(e.size)]
        a, b, c = p[facets[0]], p[facets[1]], p[facets[2]]
        return np.einsum("ij,ij->i", np.cross(b - a, c - a), p[opp] - a)

    same = np.sign(side(e0)) == np.sign(side(e1))
    if np.any(same):
        k = np.flatnonzero(same)[0]
        raise ValueError(f"mesh folds: inverted rest element: elements {int(e0[k])} and {int(e1[k])} lie on the "
                         f"same side of their shared face ({int(same.sum())} such faces)")


def _element_materials(material, mesh):
    """Return (unique materials, per-element index into them)."""
    m = mesh.t.shape[1]
    if isinstance(material, Material):
        for what in ("E", "nu"):
            a = getattr(material, what)
            if a.ndim and a.shape != (m,):
                raise ValueError(f"material {what} has one value per element: it must have length {m} "
                                 f"(the mesh's elements), got length {a.shape[0]}")
        return [material], np.zeros(m, dtype=np.int64)
    if isinstance(material, dict):
        subs = mesh.subdomains or {}
        index = np.full(m, -1, dtype=np.int64)
        mats = []
        for key, mat in material.items():
            if key not in subs:
                raise ValueError(f"material dict key {key!r} is not a subdomain of the mesh "
                                 f"(subdomains: {sorted(subs)})")
            _check_material(mat)
            idx = np.asarray(subs[key])
            if np.any(index[idx] >= 0):
                raise ValueError(f"subdomain {key!r} overlaps another subdomain")
            index[idx] = len(mats)
            mats.append(mat)
        if np.any(index < 0):
            raise ValueError(f"{int((index < 0).sum())} elements are in no subdomain of the material dict")
        return mats, index
    if isinstance(material, (list, tuple, np.ndarray)):
        seq = list(material)
        if len(seq) != m:
            raise ValueError(f"material array has length {len(seq)}, but the mesh has {m} elements")
        mats, index = [], np.empty(m, dtype=np.int64)
        ids = {}
        for e, mat in enumerate(seq):
            key = id(mat)
            if key not in ids:
                _check_material(mat)
                ids[key] = len(mats)
                mats.append(mat)
            index[e] = ids[key]
        return mats, index
    if isinstance(material, type):
        _check_material(material)
    raise TypeError(f"material must be a Material, a sequence of them or a dict, got {type(material).__name__}")


def _check_material(mat):
    if isinstance(mat, type):
        raise TypeError(f"material must be a Material instance such as sa.NeoHookean(E=1e5, nu=0.3), "
                        f"got the class {mat.__name__}")
    if not isinstance(mat, Material):
        raise TypeError(f"material must be a Material (StVK, Corotational, NeoHookean), got {type(mat).__name__}")
    if mat.E.ndim or mat.nu.ndim:
        raise ValueError("material: a list or dict of materials needs scalar E and nu in each (per-element arrays go in one material)")


def _positive_per_element(value, m, what):
    a = real_array(value, what)
    if a.ndim == 0:
        a = np.full(m, float(a))
    if a.shape != (m,):
        raise ValueError(f"{what} must be a scalar or an array of length {m} (one value per element), "
                         f"got shape {a.shape}")
    if np.any(a <= 0):
        bad = np.flatnonzero(a <= 0)
        raise ValueError(f"{what} must be > 0, got {a[bad[0]]:g} (element {bad[0]})")
    return a


def _vertex_mask(fixed, mesh):
    """Boolean (n,) mask of the fixed vertices from any selection :func:`~skfem_affine.vertex_sets.vertices_of` takes."""
    mask = np.zeros(mesh.p.shape[1], dtype=bool)
    if fixed is not None:
        mask[vertices_of(mesh, fixed, name="fixed")] = True
    return mask


def _prescribed(prescribed, mesh, fixed):
    """The list of :class:`~skfem_affine.motion.Prescribed` and their checked vertex indices."""
    from skfem_affine.motion import Prescribed
    if prescribed is None:
        return [], []
    items = [prescribed] if isinstance(prescribed, Prescribed) else prescribed
    if not isinstance(items, (list, tuple)) or not all(isinstance(p, Prescribed) for p in items):
        raise TypeError(f"prescribed must be a sa.Prescribed(vertices, path) or a list of them, "
                        f"got {type(prescribed).__name__}")
    taken = fixed.copy()
    indices = []
    for p in items:
        idx = p.bind(mesh.p.T, mesh)
        if np.any(taken[idx]):
            raise ValueError(f"prescribed vertices {_some(idx[taken[idx]])} are also fixed or prescribed by "
                             f"another sa.Prescribed; a vertex has one boundary condition")
        taken[idx] = True
        indices.append(idx)
    return list(items), indices


def _velocity(velocity, n):
    if velocity is None:
        return np.zeros((n, 3))
    v = real_array(velocity, "velocity")
    if v.shape == (3,):
        v = np.tile(v, (n, 1))
    if v.shape != (n, 3):
        raise ValueError(f"velocity must have shape ({n}, 3) or (3,), got {v.shape}")
    return v


def check_bodies(bodies):
    """A non-empty list of :class:`~skfem_affine.ElasticBody` from one body or a sequence of them.

    Raises
    ------
    TypeError
        ``bodies`` is None, a mesh, a class, or holds something that is not an ElasticBody;
        the message says which entry and how to make a body.
    ValueError
        ``bodies`` is an empty sequence, or lists one body twice.

    Examples
    --------
    >>> check_bodies(None)
    Traceback (most recent call last):
    ...
    TypeError: bodies must be an ElasticBody or a non-empty list of them, got None (NoneType)
    """
    hint = "make one with sa.ElasticBody(mesh, material)"
    if isinstance(bodies, ElasticBody):
        return [bodies]
    if bodies is None or isinstance(bodies, (str, bytes, type, dict)) or not hasattr(bodies, "__iter__") \
            or _looks_like_mesh(bodies):
        extra = f"; {hint}" if bodies is not None and _looks_like_mesh(bodies) else ""
        raise TypeError(f"bodies must be an ElasticBody or a non-empty list of them, got {_describe(bodies)}{extra}")
    out = list(bodies)
    if not out:
        raise ValueError("bodies must hold at least one ElasticBody, got an empty sequence")
    for i, b in enumerate(out):
        if not isinstance(b, ElasticBody):
            what = f"the class {b.__name__}" if isinstance(b, type) else type(b).__name__
            raise TypeError(f"bodies[{i}] must be an ElasticBody, got {what}"
                            f"{'; ' + hint if _looks_like_mesh(b) or isinstance(b, type) else ''}")
    first = {}
    for i, b in enumerate(out):
        if id(b) in first:  # two coincident copies of one body would overlap everywhere
            raise ValueError(f"bodies[{first[id(b)]}] and bodies[{i}] are the same ElasticBody; make one body per "
                             f"object in the scene (a second sa.ElasticBody(...) of a moved mesh)")
        first[id(b)] = i
    return out


def _looks_like_mesh(obj):
    return hasattr(obj, "p") and hasattr(obj, "t")
