"""Vertex sets from what a scikit-fem user has at hand: the one converter behind ``fixed=``,
``sa.Prescribed(vertices, ...)`` and ``sa.VertexForce(vertices, ...)``.

:func:`vertices_of` turns any of these into vertex indices of a mesh:

* vertex indices (a sequence, set or integer array), e.g. ``mesh.nodes_satisfying(...)``;
* a boolean mask with one entry per vertex;
* the name of a boundary of ``mesh.boundaries`` (a str), or a list of names: the vertices of
  its facets, e.g. ``fixed="left"`` after ``mesh.with_boundaries({"left": ...})``;
* a scikit-fem ``DofsView``, e.g. ``basis.get_dofs("left")`` or ``basis.get_dofs(lambda x: ...)``
  of a P1 basis on the mesh (``ElementVector(ElementTetP1())`` or ``ElementTetP1()``): the
  vertices whose DOFs it holds. It must hold every component of each vertex (a vertex set
  holds whole vertices): ``.keep("u^1")`` of a vector basis is refused;
* with keywords, ``vertices_of(mesh, facets=...)``: facet indices (into ``mesh.facets``, as
  ``mesh.boundaries`` values and ``mesh.facets_satisfying`` give them), and
  ``vertices_of(mesh, dofs=...)``: DOF indices of ``ElementVector(ElementTetP1())``, DOF =
  3 * vertex + component, every component of each vertex present.

**A plain integer array is always read as vertex indices.** Facet or DOF indices look the same
and cannot be told apart from it, so they are given by keyword (or as a ``DofsView``, which
knows its basis). An integer array that cannot be vertex indices (an index >= the number of
vertices) is refused with a message that names the conversion it may have needed.
"""
import numpy as np

__all__ = ["vertices_of"]


def _type_error(name, value):
    return TypeError(f"{name} must be vertex indices, a boolean mask, a boundary name of mesh.boundaries, "
                     f"or a scikit-fem DofsView (basis.get_dofs(...)); got {type(value).__name__}")


def _is_dofs_view(value):
    try:
        from skfem.assembly.dofs import DofsView
    except ImportError:  # pragma: no cover
        return False
    return isinstance(value, DofsView)


def _same_mesh(a, b):
    return a is b or (a.p.shape == b.p.shape and a.t.shape == b.t.shape
                      and np.array_equal(a.t, b.t) and np.array_equal(a.p, b.p))


def _from_dofs_view(view, mesh, n, name):
    dofs = view.obj
    if mesh is not None and not _same_mesh(dofs.topo, mesh):
        raise ValueError(f"{name}: the DofsView's basis is on another mesh (its {dofs.topo.p.shape[1]} vertices, "
                         f"{dofs.topo.t.shape[1]} elements) than the body's; build the basis on the body's mesh")
    if dofs.N != dofs.nodal_dofs.size:
        raise ValueError(f"{name}: the DofsView is of a basis with DOFs beyond the vertices "
                         f"({type(dofs.element).__name__}); give one of ElementVector(ElementTetP1()) or ElementTetP1()")
    if n is not None and dofs.nodal_dofs.shape[1] != n:
        raise ValueError(f"{name}: the DofsView's basis has {dofs.nodal_dofs.shape[1]} vertices, the body {n}")
    components = dofs.nodal_dofs.shape[0]
    if len(view.nodal) != components:
        raise ValueError(f"{name}: the DofsView holds only components {sorted(view.nodal)} of {components}; a vertex "
                         f"set holds whole vertices (all components): pass basis.get_dofs(...) without .keep(...)")
    return np.unique(np.asarray(view.nodal_ix, dtype=np.int64))


def _from_dofs(dofs, n, name):
    d = _integers(dofs, f"{name} dofs")
    if d.size and (d.min() < 0 or (n is not None and d.max() >= 3 * n)):
        raise ValueError(f"{name} dofs out of range [0, {3 * n}) (3 per vertex): min {d.min()}, max {d.max()}")
    d = np.unique(d)
    vertices, counts = np.unique(d // 3, return_counts=True)
    if np.any(counts != 3):
        bad = vertices[counts != 3]
        raise ValueError(f"{name} dofs hold only some components of vertices {bad[:5].tolist()}: DOF = 3 * vertex + "
                         f"component of ElementVector(ElementTetP1()); a vertex set holds whole vertices")
    return vertices


def _from_facets(facets, mesh, name):
    f = _integers(facets, f"{name} facets")
    nf = mesh.facets.shape[1]
    if f.size and (f.min() < 0 or f.max() >= nf):
        raise ValueError(f"{name} facets out of range [0, {nf}) (the mesh's facets): min {f.min()}, max {f.max()}")
    return np.unique(mesh.facets[:, f])


def _from_names(names, mesh, name):
    boundaries = getattr(mesh, "boundaries", None) or {}
    out = []
    for key in names:
        if key not in boundaries:
            hint = f" (boundaries: {sorted(boundaries)})" if boundaries else \
                " (the mesh has no boundaries: name some with mesh.with_boundaries({name: test}))"
            raise ValueError(f"{name}: {key!r} is not a boundary of the mesh{hint}")
        out.append(np.asarray(boundaries[key], dtype=np.int64))
    return np.unique(mesh.facets[:, np.concatenate(out)])


def _integers(value, name):
    try:
        a = np.asarray(sorted(value) if isinstance(value, (set, frozenset)) else value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be an array of integers, got {type(value).__name__}") from None
    if a.size and (a.dtype == bool or not np.issubdtype(a.dtype, np.integer)):
        raise TypeError(f"{name} must hold integers, got {a.dtype} values")
    return a.ravel().astype(np.int64)


def is_name(selection):
    """Whether ``selection`` names boundaries (a str or a list of them), resolved with a mesh."""
    return isinstance(selection, str) or (isinstance(selection, (list, tuple)) and bool(selection)
                                          and all(isinstance(s, str) for s in selection))


def needs_mesh(selection):
    """Whether ``selection`` is resolved only with its mesh (boundary names, a DofsView)."""
    return is_name(selection) or _is_dofs_view(selection)


def vertices_of(mesh, selection=None, *, facets=None, dofs=None, n=None, name="vertices"):
    """Vertex indices (k,) of ``mesh`` from a selection (see the module docstring).

    Parameters
    ----------
    mesh : skfem.MeshTet or None
        The mesh the selection refers to. None (with ``n``) when only vertex indices or a
        mask can be given (e.g. the stacked vertices of several bodies).
    selection : indices, boolean mask, str, list of str or DofsView
        What to convert. Give exactly one of ``selection``, ``facets`` and ``dofs``.
    facets : integer array, keyword only
        Facet indices into ``mesh.facets``.
    dofs : integer array or DofsView, keyword only
        DOFs of ``ElementVector(ElementTetP1())`` (3 * vertex + component).
    n : int, optional
        The number of vertices (default: the mesh's; without a mesh nor n, indices and masks
        are not checked against it).
    name : str
        The argument's name in error messages.

    Returns
    -------
    numpy.ndarray of int64
        Indices as given for indices (order and repeats kept: callers decide about repeats),
        sorted and unique otherwise.

    Examples
    --------
    >>> import numpy as np, skfem
    >>> mesh = skfem.MeshTet.init_tensor(*[np.linspace(0, 1, 3)] * 3).with_boundaries(
    ...     {"left": lambda x: x[0] == 0})
    >>> basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementTetP1()))
    >>> vertices_of(mesh, "left").tolist()
    [0, 1, 2, 9, 10, 11, 18, 19, 20]
    >>> vertices_of(mesh, basis.get_dofs("left")).tolist() == vertices_of(mesh, dofs=basis.get_dofs("left").flatten()).tolist()
    True
    """
    given = [k for k, v in (("selection", selection), ("facets", facets), ("dofs", dofs)) if v is not None]
    if len(given) != 1:
        raise TypeError(f"{name}: give exactly one of selection, facets= and dofs=, got {given or 'none'}")
    if n is None and mesh is not None:
        n = mesh.p.shape[1]

    def need_mesh(what):
        if mesh is None:
            raise ValueError(f"{name}: {what} needs the body's mesh; give the vertex indices, or (for a force) "
                             f"sa.VertexForce(..., body=body)")

    if facets is not None:
        need_mesh("facet indices")
        return _from_facets(facets, mesh, name)
    if dofs is not None:
        if _is_dofs_view(dofs):
            return _from_dofs_view(dofs, mesh, n, name)
        return _from_dofs(dofs, n, name)
    if _is_dofs_view(selection):
        return _from_dofs_view(selection, mesh, n, name)
    if is_name(selection):
        need_mesh("a boundary name")
        return _from_names([selection] if isinstance(selection, str) else selection, mesh, name)
    if isinstance(selection, bytes) or callable(selection) or isinstance(selection, dict):
        raise _type_error(name, selection)
    if isinstance(selection, (list, tuple)) and any(isinstance(v, (bool, np.bool_)) for v in selection) \
            and not all(isinstance(v, (bool, np.bool_)) for v in selection):
        raise TypeError(f"{name} mixes booleans and integers; pass a boolean mask of length {n} or vertex indices")
    try:
        a = np.asarray(sorted(selection) if isinstance(selection, (set, frozenset)) else selection)
    except (TypeError, ValueError):
        raise _type_error(name, selection) from None
    if a.dtype == bool:
        if a.ndim != 1 or (n is not None and a.shape != (n,)):
            raise ValueError(f"boolean {name} mask must have length {n} (one entry per vertex), got shape {a.shape}")
        return np.flatnonzero(a)
    if a.size and not np.issubdtype(a.dtype, np.integer):
        if a.dtype.kind in "OUS":
            raise _type_error(name, selection)
        raise TypeError(f"{name} must hold vertex indices (integers) or a boolean mask, got {a.dtype} values")
    a = a.ravel().astype(np.int64)
    if n is not None and a.size == n and n > 2 and np.all((a == 0) | (a == 1)):
        raise ValueError(f"{name} has {n} entries, all 0 or 1: a mask or vertex indices? Pass a boolean mask "
                         f"(np.asarray({name}, dtype=bool)) or the indices (np.flatnonzero({name}))")
    if a.size and (a.min() < 0 or (n is not None and a.max() >= n)):
        hint = ""
        if a.min() >= 0 and n is not None:
            kinds = []
            if a.max() < 3 * n:
                kinds.append("DOF indices of ElementVector(ElementTetP1()) (3 * vertex + component): pass the "
                             "DofsView of basis.get_dofs(...) itself, or sa.vertices_of(mesh, dofs=...)")
            if mesh is not None and a.max() < mesh.facets.shape[1]:
                kinds.append("facet indices: sa.vertices_of(mesh, facets=...), or the boundary's name")
            if kinds:
                hint = "; they look like " + "; or ".join(kinds)
        if n is None:
            raise ValueError(f"{name}: vertex indices must be >= 0, got min {a.min()}")
        raise ValueError(f"{name} vertex indices out of range [0, {n}): min {a.min()}, max {a.max()}{hint}")
    return a


def vector_p1_dofs(basis, n, name="basis"):
    """``basis.nodal_dofs`` (3, n) of an ``ElementVector(ElementTetP1())`` basis on a mesh of n
    vertices: the DOF of component c of vertex v is ``nodal_dofs[c, v]`` (3 v + c in scikit-fem)."""
    dofs = getattr(basis, "dofs", None)
    nodal = getattr(dofs, "nodal_dofs", None)
    if nodal is None or not hasattr(basis, "mesh"):
        raise TypeError(f"{name} must be a scikit-fem Basis, e.g. skfem.Basis(mesh, ElementVector(ElementTetP1())), "
                        f"got {type(basis).__name__}")
    if nodal.shape[0] != 3 or basis.N != nodal.size:
        raise ValueError(f"{name} must be a basis of ElementVector(ElementTetP1()) (3 DOFs per vertex, none "
                         f"elsewhere), got {type(basis.elem).__name__} with {basis.N} DOFs")
    if nodal.shape[1] != n:
        raise ValueError(f"{name} is on a mesh of {nodal.shape[1]} vertices; the state has {n}")
    return nodal
