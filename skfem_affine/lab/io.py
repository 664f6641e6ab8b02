"""Output through meshio: a ParaView time series (VTU per frame + a .pvd index)."""
import os
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


class SeriesWriter:
    """Write frames as ``<stem>_NNNNN.vtu`` and keep ``<stem>.pvd`` up to date."""

    def __init__(self, path):
        path = os.fspath(path)
        if path.endswith(".pvd"):
            path = path[:-4]
        self.dir, self.stem = os.path.dirname(path) or ".", os.path.basename(path)
        os.makedirs(self.dir, exist_ok=True)
        self.entries = []

    @property
    def pvd(self):
        return os.path.join(self.dir, self.stem + ".pvd")

    def write(self, sim, state):
        name = f"{self.stem}_{state.frame:05d}.vtu"
        meshio.write(os.path.join(self.dir, name), frame_mesh(sim, state), binary=True)
        self.entries.append((state.time, name))
        with open(self.pvd, "w") as fh:
            fh.write('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n<Collection>\n')
            for t, n in self.entries:
                fh.write(f'<DataSet timestep="{t:.9g}" group="" part="0" file={quoteattr(n)}/>\n')
            fh.write("</Collection>\n</VTKFile>\n")
        return name


def write_series(path, sim, frames=None, every=1):
    """Run ``sim`` for ``frames`` and write the initial state and every ``every``-th state.

    Parameters
    ----------
    path : str or path-like
        Where to write: ``<path>.pvd`` and ``<stem>_NNNNN.vtu`` beside it (a trailing
        ``.pvd`` is optional); the folder is created.
    sim : Simulation
    frames : int, optional
        Frames to run (default ``sim.frames``, set by the scenes, else 100).
    every : int
        Keep every ``every``-th frame (and the last).

    Returns
    -------
    str
        The path of the .pvd file that ParaView opens as a time series.
    """
    frames = getattr(sim, "frames", 100) if frames is None else frames
    writer = SeriesWriter(path)
    writer.write(sim, sim.state)
    for state in sim.run(frames):
        if state.frame % every == 0 or state.frame == frames:
            writer.write(sim, state)
    return writer.pvd


def write_states(path, sim, states):
    """Write already computed states (e.g. ``runners.Run.states``) of ``sim`` as a ParaView series.

    Each VTU holds point ``velocity`` and ``displacement`` and cell data ``cluster``
    (body id, -1 elastic), ``affine`` (0/1) and ``material``; returns the .pvd path.
    """
    writer = SeriesWriter(path)
    for state in states:
        writer.write(sim, state)
    return writer.pvd


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
        If the file holds no tetrahedra.
    """
    import skfem
    m = meshio.read(path)
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
