r"""Candidate subspace bases for :class:`~skfem_affine.AdaptiveSubspace` (adaptive-subspace paper, sec. 4.6).

A basis is a dense matrix U (3n x r) over all DOFs (rows of fixed DOFs are zero), split into
*blocks* of columns that the oracle queries as one unit (eq. 16-17), and a list of blocks that
start active. Three kinds:

* :class:`AffineModes`: per body, the 12 affine fields e_c (X - X_c, 1)^T (one block per body,
  active from the start; it holds the rigid motions).
* :class:`LinearModes`: the lowest ``n`` linear eigenmodes of the rest stiffness,
  K u = lambda M u on the free DOFs, by shift-invert Lanczos (``eigsh``). One block per mode;
  the rigid (zero-eigenvalue) modes, or the first mode if there are none, start active.
* :class:`SkinningEigenmodes` (Benchekroun et al. 2023): ``n`` scalar skinning weights per body,
  the lowest generalized eigenvectors of L w = lambda M w, where L is the rest elastic Hessian
  reduced to a scalar "Laplacian" (L_ij = trace of its 3 x 3 block ij / 3, exact for an
  operator L (x) I_3) and M the lumped mass; fixed vertices are Dirichlet (w = 0). Each weight
  w_k skins one affine handle: the 12 columns w_k(X) e_c (X - X_c, 1)^T form one block
  (12 n DOFs per body). The first weight of a free body is constant, so block 0 is the affine
  basis; it starts active.

Within a block the columns are orthonormalised (Euclidean, same span), so that the oracle's
projection (eq. 16) is the orthogonal projection onto the block. Bases are computed once per
mesh and material and cached on disk (``.npz``), keyed by a hash of the rest positions,
elements, fixed vertices, density and per-element material parameters, and of the code that
computes them (:func:`code_version`: the package version and this module's source), so that
a basis cached by other code is never reused.
"""
import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from skfem_affine.checks import flag, integer


@dataclass
class ModalBasis:
    """U (3n x r), its column blocks, and the blocks active at the start."""

    U: np.ndarray
    blocks: list
    initial: list
    name: str = "basis"
    eigenvalues: np.ndarray = field(default=None)

    @property
    def size(self):
        return self.U.shape[1]


_SOURCE = hashlib.sha1(Path(__file__).read_bytes()).hexdigest()


def code_version():
    """The package version and a hash of this module's source: part of every cache key."""
    import skfem_affine
    return f"{getattr(skfem_affine, '__version__', '?')}:{_SOURCE}"


def _start_vector(n):
    """A fixed Lanczos start vector: ARPACK's own random start changes from call to call within a
    process, which would make two bases of one mesh differ in the last bits."""
    return np.random.default_rng(0).uniform(0.5, 1.5, n)


def default_cache_dir():
    return Path(os.environ.get("SKFEM_AFFINE_CACHE", Path.home() / ".cache" / "skfem-affine" / "bases"))


class _Basis:
    """Common build-or-load logic; subclasses implement :meth:`compute`."""

    kind = "basis"

    def __init__(self, n=16, cache_dir=None, cache=True):
        self.n = integer(n, "n", low=1)
        self.cache = flag(cache, "cache")
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        self.last_cache_hit = False

    def __repr__(self):
        return f"{type(self).__name__}(n={self.n})"

    def key(self, system):
        """Hash of everything the basis depends on: mesh, fixed vertices, density, materials and the code."""
        h = hashlib.sha1()
        h.update(f"{self.kind}:{self.n}:{code_version()}".encode())
        for a in (system.p0, system.t, system.fixed, system.density, system.material_index):
            a = np.ascontiguousarray(a)
            h.update(str(a.dtype).encode() + str(a.shape).encode() + a.tobytes())
        for mat in system.material_list:
            h.update(repr(mat).encode())
        return h.hexdigest()

    def build(self, system):
        """The :class:`ModalBasis` of the system's bodies, from the disk cache if present."""
        path = None
        if self.cache:
            path = (self.cache_dir or default_cache_dir()) / f"{self.kind}-{self.key(system)}.npz"
            if path.exists():
                with np.load(path) as z:
                    off = z["offsets"]
                    blocks = [z["columns"][off[i]:off[i + 1]] for i in range(off.size - 1)]
                    self.last_cache_hit = True
                    ev = z["eigenvalues"] if "eigenvalues" in z.files else None
                    return ModalBasis(z["U"], blocks, list(z["initial"]), self.kind, ev)
        self.last_cache_hit = False
        basis = self.compute(system)
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            off = np.cumsum([0] + [b.size for b in basis.blocks])
            extra = {} if basis.eigenvalues is None else {"eigenvalues": basis.eigenvalues}
            tmp = path.with_suffix(".tmp.npz")
            np.savez(tmp, U=basis.U, columns=np.concatenate(basis.blocks), offsets=off,
                     initial=np.asarray(basis.initial, dtype=np.int64), **extra)
            os.replace(tmp, path)
        return basis


def _orthonormal_blocks(U, blocks, system):
    """Euclidean QR of each block (same span); rows of fixed DOFs stay exactly zero."""
    for cols in blocks:
        q, _ = np.linalg.qr(U[:, cols])
        U[:, cols] = q
    U[np.repeat(system.fixed, 3)] = 0.0
    return U


def _affine_columns(system, vertices, weight):
    """12 columns w(X) e_c (X - X_c, 1)^T over all DOFs for the given body vertices (eq. of affine skinning)."""
    X = system.p0[vertices]
    Xc = X.mean(axis=0)
    handle = np.column_stack([X - Xc, np.ones(len(vertices))]) * weight[:, None]  # (k, 4)
    cols = np.zeros((3 * system.n, 12))
    for c in range(3):
        cols[3 * vertices + c, 4 * c:4 * c + 4] = handle
    fixed_dofs = np.repeat(system.fixed, 3)
    cols[fixed_dofs] = 0.0
    return cols


def _body_vertices(system):
    o = system.vertex_offsets
    return [np.arange(o[i], o[i + 1]) for i in range(len(system.bodies))]


def _rest_stiffness(system):
    """Unprojected rest Hessian over all 3n DOFs (CSR)."""
    _, H = system.forces_and_stiffness(system.p0, project=False, full=True)
    return H


def _shift(K, M):
    """A small negative shift for shift-invert, so that singular K (free bodies) factorizes."""
    ratio = K.diagonal() / np.maximum(M.diagonal(), 1e-300)
    return -1e-6 * float(np.mean(ratio[ratio > 0])) if np.any(ratio > 0) else -1.0


class AffineModes(_Basis):
    """Per-body affine modes: 12 per body, all active from the start."""

    kind = "affine"

    def __init__(self, cache_dir=None, cache=False):
        super().__init__(12, cache_dir, cache)

    def __repr__(self):
        return "AffineModes()"

    def compute(self, system):
        cols, blocks = [], []
        for b, verts in enumerate(_body_vertices(system)):
            cols.append(_affine_columns(system, verts, np.ones(verts.size)))
            blocks.append(np.arange(12 * b, 12 * b + 12))
        U = _orthonormal_blocks(np.hstack(cols), blocks, system)
        return ModalBasis(U, blocks, list(range(len(blocks))), self.kind)


class LinearModes(_Basis):
    """The ``n`` lowest linear eigenmodes K u = lambda M u of the rest state (free DOFs), M-orthonormal."""

    kind = "linear"

    def compute(self, system):
        free = system.free
        K = _rest_stiffness(system)[free][:, free].tocsc()
        M = system.Mff.tocsc()
        k = min(self.n, free.size - 1)
        lam, V = spla.eigsh(K, k=k, M=M, sigma=_shift(K, M), which="LM", v0=_start_vector(K.shape[0]))
        order = np.argsort(lam)
        lam, V = lam[order], V[:, order]
        U = np.zeros((3 * system.n, k))
        U[free] = V
        rigid = np.flatnonzero(lam < 1e-8 * max(lam[-1], 1e-300))
        initial = list(rigid) if rigid.size else [0]
        return ModalBasis(U, [np.array([j]) for j in range(k)], initial, self.kind, lam)



class SkinningEigenmodes(_Basis):
    """Skinning Eigenmodes (Benchekroun et al. 2023): ``n`` weights per body, 12 DOFs each."""

    kind = "skinning"

    def weights(self, system):
        """Per body: (vertices, W (k, n) M-orthonormal weights, eigenvalues)."""
        H = _rest_stiffness(system)
        L = (H[0::3, 0::3] + H[1::3, 1::3] + H[2::3, 2::3]) / 3.0
        out = []
        for b, verts in enumerate(_body_vertices(system)):
            inner = verts[~system.fixed[verts]]
            if inner.size < 2:  # the eigenproblem of a weight needs 2 or more vertices
                raise ValueError(f"SkinningEigenmodes need 2 or more free vertices in every body; body {b} "
                                 f"({system.bodies[b].name!r}) has {inner.size} free "
                                 f"{'vertex' if inner.size == 1 else 'vertices'}. Use basis=sa.LinearModes() or "
                                 f"sa.AffineModes(), or no reducer")
            Lb = L[inner][:, inner].tocsc()
            Mb = sp.diags(system.lumped_mass[inner]).tocsc()
            k = min(self.n, inner.size - 1)
            lam, W = spla.eigsh(Lb, k=k, M=Mb, sigma=_shift(Lb, Mb), which="LM", v0=_start_vector(Lb.shape[0]))
            order = np.argsort(lam)
            lam, W = lam[order], W[:, order]
            W *= np.where(W.sum(axis=0) < 0, -1.0, 1.0)
            Wfull = np.zeros((verts.size, k))
            Wfull[~system.fixed[verts]] = W
            out.append((verts, Wfull, lam))
        return out

    def compute(self, system):
        cols, blocks, initial, lams = [], [], [], []
        for verts, W, lam in self.weights(system):
            initial.append(len(blocks))
            for j in range(W.shape[1]):
                blocks.append(np.arange(12 * len(blocks), 12 * len(blocks) + 12))
                cols.append(_affine_columns(system, verts, W[:, j]))
            lams.append(lam)
        U = _orthonormal_blocks(np.hstack(cols), blocks, system)
        return ModalBasis(U, blocks, initial, self.kind, np.concatenate(lams))
