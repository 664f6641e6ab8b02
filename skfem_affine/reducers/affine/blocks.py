"""A reduced frame of several scene bodies factorised body by body.

The frame's matrix does not couple the scene's bodies (contact couples them later, through the
Delassus operator), so it is block diagonal, one block per body. Factorised whole, any cluster that
forms or dissolves changes the whole pattern and costs a new symbolic analysis of all of it
(docs/affinification.md, "A frame that reduces little"); factorised per body (:class:`BodyBlocks`),
each block keeps its own analysis while its clusters stay, and only the bodies whose clusters changed
are analysed again. The blocks are taken from the frame's upper triangle in the full space's
numbering (:class:`~skfem_affine.reducers.affine.numbering.FullNumbering`), each with its part of the
frame's elimination order.

Given the unknowns the frame's contacts touch and contact's
:class:`~skfem_affine.contact.schur.SchurInverse`, a body whose block it accepts is factorised with its
touched unknowns last, in the mode that also solves (as a full-space frame of several bodies,
:mod:`skfem_affine.contact.blocks`): the same factorisation then leaves the body's Schur complement
S_b on them, and the Delassus operator takes ``(A_r^-1)_{T_b T_b} = S_b^-1`` from it instead of
solving one column per touched unknown. A block whose pattern the body's plain handle has not
analysed is taken at any number of touched unknowns: its plain factorisation would analyse anew too.

The unknowns of a body's reduced vertices stay in the numbering, idle: their rows hold the diagonal
alone. A block's Pardiso handle takes only its coupled unknowns (and its touched ones); the idle
ones are solved by their diagonal, so that a box reduced to its 12 affine unknowns is factorised
at that size, not at its vertices' count.
"""
import numpy as np
import scipy.sparse as sp

from skfem_affine.solvers import Pardiso, SolverError, coupled_unknowns


def unknown_labels(bodies, numbering, width):
    """The scene body of each unknown of a renumbered frame: a free DOF's own body for the free DOFs'
    unknowns, a reduced body's scene body for its ``width`` columns."""
    nf = bodies.size
    out = np.empty(numbering.size, dtype=np.int64)
    out[:nf] = bodies
    first = numbering.body_rows  # one free DOF of each reduced body
    out[nf:] = np.repeat(bodies[first], width)
    return out


class BodyBlocks:
    """The frame's system factorised per scene body, one Pardiso handle each (module docstring).

    ``factorize(U, labels, order)`` takes the upper triangle U (CSR, rows sorted), the body of each
    unknown and the elimination order; ``solve(b)`` solves each block (a block whose rows of b are zero
    has x = 0 there, unsolved: the Delassus operator's columns of one body). Bodies' handles are kept
    from frame to frame by body; with ``touched`` and ``schur``, :attr:`complements` holds
    ``(keep, [S_b])`` of the blocks factorised with their touched unknowns last (``keep``: their
    unknowns, each block's sorted, block after block), or None. Idle unknowns (coupled to no other,
    :func:`~skfem_affine.solvers.coupled_unknowns`) are left out of the blocks and solved by their diagonal.
    """

    name = "pardiso-blocks"
    iterative = False
    last_iterations = 1
    accepts_upper = True

    def __init__(self):
        self.handles = {}
        self.blocks = []  # (handle, the body's coupled unknowns) of the last factorisation
        self.idle = np.zeros(0, dtype=np.int64)  # the unknowns solved by their diagonal
        self.idle_diagonal = np.zeros(0)
        self.analyses = 0  # blocks analysed anew by the last factorisation
        self.complements = None

    def factorize(self, U, labels, order, touched=None, schur=None):
        """Factorise each body's block of U; ``touched`` (sorted unknowns) and ``schur``
        (:class:`~skfem_affine.contact.schur.SchurInverse`): with its touched unknowns last where the
        Schur inverse accepts (its key for body b: ``(0, b)``)."""
        U = sp.csr_matrix(U)
        labels = np.asarray(labels, dtype=np.int64)
        mine = np.zeros(labels.size, dtype=bool)
        if touched is not None and schur is not None:
            mine[np.asarray(touched, dtype=np.int64)] = True
        idle = ~coupled_unknowns(U.indptr, U.indices) & ~mine  # a diagonal entry alone, not touched
        self.idle = np.flatnonzero(idle)
        self.idle_diagonal = U.diagonal()[self.idle]
        if np.any(~(self.idle_diagonal > 0.0)):
            raise SolverError("the frame's matrix is not positive definite: an unknown that couples to no other "
                              "has a diagonal entry <= 0")
        labels = np.where(idle, -1, labels)  # an idle unknown belongs to no block
        n_bodies = int(labels.max()) + 1 if labels.size else 0
        local = np.empty(labels.size, dtype=np.int64)
        rank = np.argsort(labels, kind="stable")
        cuts = np.searchsorted(labels[rank], np.arange(n_bodies + 1))  # labels -1 (idle) sort first
        for b in range(n_bodies):
            local[rank[cuts[b]:cuts[b + 1]]] = np.arange(cuts[b + 1] - cuts[b])
        order = np.asarray(order, dtype=np.int64)
        by_body = labels[order]
        self.blocks, self.analyses, keep, parts = [], 0, [], []
        for b in range(n_bodies):
            idx = rank[cuts[b]:cuts[b + 1]]  # increasing: local numbers keep the unknowns' order
            if not idx.size:
                continue
            rows = U[idx]  # the body's rows: their columns are its own coupled unknowns, in the same order
            block = sp.csr_matrix((rows.data, local[rows.indices].astype(np.int32), rows.indptr),
                                  shape=(idx.size, idx.size))
            handle = self.handles.get(b)
            if handle is None:  # a body's handle, made once (not a new MKL solver per body per frame)
                handle = self.handles[b] = Pardiso()
            known = handle.analysed_for(block, upper=True)
            Tb = np.flatnonzero(mine[idx])
            before = schur.analyses if Tb.size else 0
            out = schur.complement_block(block, Tb, (0, b), floor=known) if Tb.size else None
            if out is not None:
                handle, kept, S = out
                self.analyses += schur.analyses - before
                keep.append(idx[kept])
                parts.append(S)
            else:
                self.analyses += not known
                handle.factorize(block, upper=True, order=local[order[by_body == b]])
            self.blocks.append((handle, idx))
        self.complements = (np.concatenate(keep), parts) if parts else None

    def state_dict(self):
        """Each body's handle's ordering history (:meth:`~skfem_affine.solvers.Pardiso.state_dict`):
        whether a block's pattern is known decides whether its touched unknowns go last at any
        number, and the ordering how its factorisation rounds."""
        out = {"bodies": np.array(sorted(self.handles), dtype=np.int64)}
        for b in sorted(self.handles):
            out.update({f"{b}.{k}": v for k, v in self.handles[b].state_dict().items()})
        return out

    def load_state_dict(self, state):
        bodies = np.asarray(state["bodies"], dtype=np.int64).reshape(-1)
        if bodies.size and (bodies.min() < 0 or np.any(np.diff(bodies) <= 0)):
            raise ValueError(f"blocks bodies must be sorted distinct body indices, got {bodies.tolist()}")
        self.handles, self.blocks, self.complements = {}, [], None
        for b in bodies.tolist():
            handle = self.handles[b] = Pardiso()
            handle.load_state_dict({k[len(f"{b}."):]: v for k, v in state.items() if k.startswith(f"{b}.")})

    def solve(self, b):
        b = np.asarray(b, dtype=float)
        x = np.zeros_like(b)
        x[self.idle] = b[self.idle] / self.idle_diagonal.reshape((-1,) + (1,) * (b.ndim - 1))
        for handle, idx in self.blocks:
            rhs = b[idx]
            if np.any(rhs):
                x[idx] = handle.solve(rhs)
        return x
