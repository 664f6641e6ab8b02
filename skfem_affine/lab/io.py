"""Output through meshio: a ParaView time series (VTU per frame + a .pvd index)."""
import contextlib
import os
from io import StringIO
from xml.sax.saxutils import quoteattr

import meshio
import numpy as np


def frame_mesh(sim, state):
    """A meshio.Mesh of all bodies at ``state`` with point velocity and cell data."""
    sysm = sim.system
    cells = [("tetra", sysm.t.T.astype(np.int64))]
    clusters = state.clusters if state.clusters is not None else np.full(sysm.m, -1)
    cell_data = {"material": [sysm.material_index.astype(np.int32)],
                 "body": [sysm.body_of_element.astype(np.int32)],
                 "cluster": [np.asarray(clusters, dtype=np.int32)],
                 "affine": [(np.asarray(clusters) >= 0).astype(np.int8)]}
    point_data = {"velocity": state.v, "displacement": state.x - sysm.p0,
                  "fixed": sysm.fixed.astype(np.int8)}
    return meshio.Mesh(state.x, cells, point_data=point_data, cell_data=cell_data)


class Series:
    """A ParaView time series of ``sim``'s states, written as you pass them in::

        series = Series("out/beam", sim)    # out/beam.pvd, out/beam_NNNNN.vtu
        series.write(sim.state)             # frame 0
        for state in sim.run(100):
            series.write(state)             # frames 1 ... 100

    Each state becomes ``<stem>_NNNNN.vtu`` (NNNNN = its frame) and ``<stem>.pvd``, the file
    ParaView opens, is rewritten after every state, so an interrupted run still opens. Writing
    the same frame again replaces it. Nothing is simulated here: the series holds exactly the
    states written. Each VTU holds point ``velocity``, ``displacement`` and ``fixed`` and cell
    ``cluster`` (body id, -1 elastic), ``affine`` (0/1), ``material`` and ``body``.

    Parameters
    ----------
    path : str or os.PathLike
        ``folder/stem`` (a trailing ``.pvd`` is dropped); the folder is created.
    sim : Simulation
        The simulation the states belong to (its mesh, materials and fixed vertices).
    """

    def __init__(self, path, sim):
        if not hasattr(sim, "system"):
            raise TypeError(f"sim must be a skfem_affine.Simulation, got {type(sim).__name__}")
        path = os.fspath(path)
        if path.endswith(".pvd"):
            path = path[:-4]
        self.sim = sim
        self.dir, self.stem = os.path.dirname(path) or ".", os.path.basename(path)
        if not self.stem:
            raise ValueError(f"path must end in a file stem (e.g. 'out/beam'), got {path!r}")
        os.makedirs(self.dir, exist_ok=True)
        self.entries = {}

    @property
    def pvd(self):
        """The path of the ``.pvd`` index."""
        return os.path.join(self.dir, self.stem + ".pvd")

    def write(self, state):
        """Write one state (e.g. from ``sim.run``, or ``sim.state``); returns the VTU's file name."""
        x = getattr(state, "x", None)
        if x is None or not hasattr(state, "frame") or not hasattr(state, "v"):
            raise TypeError(f"state must be a skfem_affine.State, got {type(state).__name__}")
        if np.shape(x) != self.sim.state.x.shape:
            raise ValueError(f"state has positions of shape {np.shape(x)}, but the series' simulation has "
                             f"{self.sim.state.x.shape}: the state is not one of this simulation's")
        name = f"{self.stem}_{state.frame:05d}.vtu"
        meshio.write(os.path.join(self.dir, name), frame_mesh(self.sim, state), binary=True)
        self.entries[state.frame] = (state.time, name)
        with open(self.pvd, "w") as fh:
            fh.write('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n<Collection>\n')
            for _, (t, n) in sorted(self.entries.items()):
                fh.write(f'<DataSet timestep="{t:.9g}" group="" part="0" file={quoteattr(n)}/>\n')
            fh.write("</Collection>\n</VTKFile>\n")
        return name


def write_series(path, sim, *, states):
    """Write already computed ``states`` of ``sim`` as a ParaView series.

    Nothing is simulated: to record a run as it goes, pass each state to a :class:`Series`.

    Parameters
    ----------
    path : str or path-like
        Where to write: ``<path>.pvd`` and ``<stem>_NNNNN.vtu`` beside it (a trailing
        ``.pvd`` is optional); the folder is created.
    sim : Simulation
        The simulation the states belong to (its mesh and bodies).
    states : iterable of State
        The states to write, e.g. ``runners.Run.states`` or ``list(sim.run(60))``.

    Returns
    -------
    str
        The path of the ``.pvd`` file that ParaView opens as a time series.
    """
    series = Series(path, sim)
    for state in states:
        series.write(state)
    return series.pvd


def load_mesh(path):
    """Read a tetrahedral mesh file into a ``skfem.MeshTet``.

    Any format meshio reads (Gmsh ``.msh``, MEDIT ``.mesh``, VTK/VTU, ...). Only the
    tetrahedra are kept (other cells are ignored) and vertices no tetrahedron uses are
    dropped.

    Parameters
    ----------
    path : str or path-like
        The mesh file.

    Returns
    -------
    skfem.MeshTet
        With ``mesh.subdomains`` named ``"ref<label>"`` when the file labels its
        tetrahedra with more than one region (``medit:ref`` or ``gmsh:physical``), so
        that ``ElasticBody(mesh, material={"ref1": ..., "ref2": ...})`` assigns a
        material per region.

    Raises
    ------
    ValueError
        If meshio cannot read the file, or it holds no tetrahedra.
    FileNotFoundError
        If there is no such file.
    """
    import skfem
    m = _read(path)
    tets = [(i, c.data) for i, c in enumerate(m.cells) if c.type == "tetra"]
    if not tets:
        raise ValueError(f"{path} holds no tetrahedra (cell types: {[c.type for c in m.cells]})")
    t = np.concatenate([c for _, c in tets])
    labels = None
    for key in ("medit:ref", "gmsh:physical"):
        if key in m.cell_data:
            labels = np.concatenate([m.cell_data[key][i] for i, _ in tets])
            break
    used = np.unique(t)
    remap = np.full(m.points.shape[0], -1)
    remap[used] = np.arange(used.size)
    subdomains = None
    if labels is not None and np.unique(labels).size > 1:
        subdomains = {f"ref{int(v)}": np.flatnonzero(labels == v) for v in np.unique(labels)}
    return skfem.MeshTet(np.ascontiguousarray(m.points[used, :3].T), np.ascontiguousarray(remap[t].T),
                         _subdomains=subdomains)


def _read(path):
    """``meshio.read(path)``; a file meshio cannot read is a ValueError naming it, with meshio's reason.

    meshio prints its reasons and calls ``sys.exit(1)`` on a file of a known format it cannot
    parse, and raises its own ReadError on an unknown extension: both become one ValueError.
    """
    if not os.path.isfile(path):
        raise FileNotFoundError(f"mesh file {os.fspath(path)!r} does not exist")
    said = StringIO()
    try:
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            return meshio.read(path)
    except (Exception, SystemExit) as err:  # noqa: BLE001 (whatever a reader raises on a damaged file)
        reason = " ".join(said.getvalue().split()) or f"{type(err).__name__}: {err}"
        raise ValueError(f"mesh file {os.fspath(path)!r} cannot be read: {reason} (a tetrahedral mesh in a format "
                         f"meshio reads: .msh, .mesh, .vtu, .vtk, .xdmf, ...)") from None
