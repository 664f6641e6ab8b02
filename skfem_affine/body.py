"""ElasticBody: a tetrahedral scikit-fem mesh with materials, density, fixed vertices.

All validation of user input for a body lives here, so that bad input fails
early with a message that names the problem (and the element or vertex).
"""
import numpy as np
import skfem

from skfem_affine.kinematics import shape_gradients, signed_volumes
from skfem_affine.materials import Material


class ElasticBody:
    """An elastic solid discretised by P1 tetrahedra.

    Parameters
    ----------
    mesh : skfem.MeshTet
        Linear tetrahedral mesh (any orientation of the elements).
    material : Material, sequence of Material (one per element), or dict
        A dict maps subdomain names of ``mesh.subdomains`` to materials; every
        element must be covered exactly once.
    density : float or (m,) array
        Mass density (kg/m^3), > 0.
    fixed : array of vertex indices or boolean mask, optional
        Vertices held in place (zero velocity, Dirichlet), e.g. from
        ``mesh.nodes_satisfying``.
    velocity : (n, 3) or (3,) array, optional
        Initial velocity (default zero). Fixed vertices get zero velocity.
    name : str, optional
    """

    def __init__(self, mesh, material, density=1000.0, fixed=None, velocity=None, name=None):
        self.mesh = _check_mesh(mesh)
        self.name = name or "body"
        n, m = mesh.p.shape[1], mesh.t.shape[1]
        self.n_vertices, self.n_elements = n, m
        self.materials, self.material_index = _element_materials(material, mesh)
        self.density = _positive_per_element(density, m, "density")
        self.fixed = _vertex_mask(fixed, n)
        self.velocity = _velocity(velocity, n)
        self.velocity[self.fixed] = 0.0
        self.grads, self.volumes = shape_gradients(mesh)

    def __repr__(self):
        return (f"ElasticBody({self.name!r}, vertices={self.n_vertices}, elements={self.n_elements}, "
                f"materials={self.materials}, fixed={int(self.fixed.sum())})")

    @property
    def size(self):
        """Diagonal of the rest bounding box (the length used to normalise errors)."""
        p = self.mesh.p
        return float(np.linalg.norm(p.max(axis=1) - p.min(axis=1)))


def _check_mesh(mesh):
    if not isinstance(mesh, skfem.Mesh):
        raise TypeError(f"mesh must be a skfem.MeshTet, got {type(mesh).__name__}")
    if not isinstance(mesh, skfem.MeshTet1) or mesh.t.shape[0] != 4:
        raise TypeError(f"mesh must be a linear tetrahedral skfem.MeshTet, got {type(mesh).__name__}")
    p, t = mesh.p, mesh.t
    if p.shape[0] != 3:
        raise ValueError(f"mesh points must be 3D, got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        bad = np.flatnonzero(~np.all(np.isfinite(p), axis=0))
        raise ValueError(f"mesh has non-finite (NaN/inf) coordinates at vertices {bad[:5].tolist()}")
    if t.min() < 0 or t.max() >= p.shape[1]:
        raise ValueError("mesh elements reference vertices out of range")
    vol = signed_volumes(p, t)
    edges = p.T[t[[0, 0, 0, 1, 1, 2]]] - p.T[t[[1, 2, 3, 2, 3, 3]]]
    longest = np.linalg.norm(edges, axis=-1).max(axis=0)
    # volume relative to a regular tet with the same longest edge (1 for regular)
    quality = np.abs(vol) * 6.0 * np.sqrt(2.0) / np.maximum(longest, 1e-300) ** 3
    bad = np.flatnonzero(quality < 1e-9)
    if bad.size:
        raise ValueError(f"degenerate (zero-volume) rest elements {bad[:5].tolist()}"
                         f"{' ...' if bad.size > 5 else ''} (relative volume {quality[bad[0]]:.1e})")
    _check_folds(mesh, vol)
    return mesh


def _check_folds(mesh, vol):
    """Raise if an element is inverted relative to its face neighbour (the mesh folds)."""
    f2t = mesh.f2t
    inner = f2t[1] >= 0
    if not np.any(inner):
        return
    e0, e1 = f2t[0, inner], f2t[1, inner]
    facets = mesh.facets[:, inner]
    p, t = mesh.p.T, mesh.t

    def side(e):
        # the vertex of e opposite the shared facet
        te = t[:, e]
        opp = te[np.argmax(~np.any(te[:, None, :] == facets[None], axis=1), axis=0), np.arange(e.size)]
        a, b, c = p[facets[0]], p[facets[1]], p[facets[2]]
        return np.einsum("ij,ij->i", np.cross(b - a, c - a), p[opp] - a)

    same = np.sign(side(e0)) == np.sign(side(e1))
    if np.any(same):
        k = np.flatnonzero(same)[0]
        raise ValueError(f"inverted rest element: elements {int(e0[k])} and {int(e1[k])} lie on the "
                         f"same side of their shared face ({int(same.sum())} such faces)")


def _element_materials(material, mesh):
    """Return (unique materials, per-element index into them)."""
    m = mesh.t.shape[1]
    if isinstance(material, Material):
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
    raise TypeError(f"material must be a Material, a sequence of them or a dict, got {type(material).__name__}")


def _check_material(mat):
    if not isinstance(mat, Material):
        raise TypeError(f"expected a Material (StVK, Corotational, NeoHookean), got {type(mat).__name__}")
    if mat.E.ndim or mat.nu.ndim:
        raise ValueError("per-element materials must have scalar E and nu")


def _positive_per_element(value, m, what):
    a = np.asarray(value, dtype=float)
    if a.ndim == 0:
        a = np.full(m, float(a))
    if a.shape != (m,):
        raise ValueError(f"{what} must be a scalar or an array of length {m}, got shape {a.shape}")
    if not np.all(np.isfinite(a)) or np.any(a <= 0):
        bad = np.flatnonzero(~(np.isfinite(a) & (a > 0)))
        raise ValueError(f"{what} must be finite and > 0, got {a[bad[0]]:g} (element {bad[0]})")
    return a


def _vertex_mask(fixed, n):
    mask = np.zeros(n, dtype=bool)
    if fixed is None:
        return mask
    f = np.asarray(fixed)
    if f.dtype == bool:
        if f.shape != (n,):
            raise ValueError(f"boolean fixed mask must have length {n}, got {f.shape}")
        return f.copy()
    if f.size and not np.issubdtype(f.dtype, np.integer):
        raise TypeError(f"fixed must hold vertex indices (integers) or a boolean mask, got {f.dtype}")
    f = f.ravel().astype(np.int64)
    if f.size and (f.min() < 0 or f.max() >= n):
        raise ValueError(f"fixed vertex indices out of range [0, {n}): min {f.min()}, max {f.max()}")
    mask[f] = True
    return mask


def _velocity(velocity, n):
    if velocity is None:
        return np.zeros((n, 3))
    v = np.array(velocity, dtype=float)
    if v.shape == (3,):
        v = np.tile(v, (n, 1))
    if v.shape != (n, 3):
        raise ValueError(f"velocity must have shape ({n}, 3) or (3,), got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError("initial velocity has non-finite values")
    return v
