"""Output through meshio: a ParaView time series (VTU per frame + a .pvd index)."""
import contextlib
import os
from io import StringIO
from xml.sax.saxutils import quoteattr

import meshio
import numpy as np

from skfem_affine._extras import EXTRA_OF, MissingExtra, message
from skfem_affine.checks import flag
from skfem_affine.files import replacing


def frame_mesh(sim, state, stresses=True):
    """A meshio.Mesh of all bodies at ``state`` with point velocity and cell data.

    With ``stresses`` it also holds the strains and stresses of :meth:`Simulation.stress`
    (:data:`skfem_affine.stress.FIELDS`) per element (cell data) and averaged at the
    vertices (point data), under the same names; tensors as 9 components, row-major.
    """
    sysm = sim.system
    cells = [("tetra", sysm.t.T.astype(np.int64))]
    clusters = state.clusters if state.clusters is not None else np.full(sysm.m, -1)
    cell_data = {"material": [sysm.material_index.astype(np.int32)],
                 "body": [sysm.body_of_element.astype(np.int32)],
                 "cluster": [np.asarray(clusters, dtype=np.int32)],
                 "affine": [(np.asarray(clusters) >= 0).astype(np.int8)]}
    point_data = {"velocity": state.v, "displacement": state.x - sysm.p0,
                  "fixed": sysm.fixed.astype(np.int8)}
    if stresses:
        st = sim.stress(state)
        cell_data.update({k: [v] for k, v in st.fields().items()})
        point_data.update(st.vertex.fields())
    return meshio.Mesh(state.x, cells, point_data=point_data, cell_data=cell_data)


class Series:
    """A ParaView time series of ``sim``'s states, written as you pass them in::

        series = Series("out/beam", sim)    # out/beam.pvd, out/beam_NNNNN.vtu
        series.write(sim.state)             # frame 0
        for state in sim.run(100):
            series.write(state)             # frames 1 ... 100

    Each state becomes ``<stem>_NNNNN.vtu`` (NNNNN = its frame) and ``<stem>.pvd``, the file
    ParaView opens, is rewritten after every state, so an interrupted run still opens. Writing
    the same frame again replaces it. Every file is written to a temporary file in the folder and
    renamed over its name (:mod:`skfem_affine.files`): a write that fails (a full disk, Ctrl-C)
    leaves the previous index readable, listing the frames written before, and no partial VTU;
    the failed frame is not in the index. Nothing is simulated here: the series holds exactly the
    states written. Each VTU holds point ``velocity``, ``displacement`` and ``fixed`` and cell
    ``cluster`` (body id, -1 elastic), ``affine`` (0/1), ``material`` and ``body``, and, unless
    ``stresses=False``, the strains and stresses of :meth:`Simulation.stress` per cell and
    averaged at the points: ``green_lagrange_strain``, ``first_piola_stress``,
    ``cauchy_stress`` (tensors, 9 components row-major), ``von_mises_stress``,
    ``principal_stress`` (3, largest first), all in Pa, and ``strain_energy_density`` (J/m^3).

    Parameters
    ----------
    path : str or os.PathLike
        ``folder/stem`` (a trailing ``.pvd`` is dropped); the folder is created.
    sim : Simulation
        The simulation the states belong to (its mesh, materials and fixed vertices).
    stresses : bool
        Write strains and stresses (default True; :mod:`skfem_affine.stress`).
    """

    def __init__(self, path, sim, stresses=True):
        if not hasattr(sim, "system"):
            raise TypeError(f"sim must be a skfem_affine.Simulation, got {type(sim).__name__}")
        path = os.fspath(path)
        if path.endswith(".pvd"):
            path = path[:-4]
        self.sim = sim
        self.stresses = flag(stresses, "stresses")
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
        mesh = frame_mesh(self.sim, state, self.stresses)
        with replacing(os.path.join(self.dir, name)) as tmp:
            meshio.write(tmp, mesh, file_format="vtu", binary=True)
        entries = dict(self.entries)
        entries[state.frame] = (state.time, name)
        with replacing(self.pvd) as tmp, open(tmp, "w") as fh:
            fh.write('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n<Collection>\n')
            for _, (t, n) in sorted(entries.items()):
                fh.write(f'<DataSet timestep="{t:.9g}" group="" part="0" file={quoteattr(n)}/>\n')
            fh.write("</Collection>\n</VTKFile>\n")
        self.entries = entries  # the frames the index on disk lists
        return name


def write_series(path, sim, *, states, stresses=True):
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
    stresses : bool
        Write strains and stresses per cell and at the points (default True; see :class:`Series`).

    Returns
    -------
    str
        The path of the ``.pvd`` file that ParaView opens as a time series.
    """
    series = Series(path, sim, stresses)
    for state in states:
        series.write(state)
    return series.pvd


# integer cell data read as region labels when scikit-fem names no subdomains, in this order
REGION_KEYS = ("medit:ref", "gmsh:physical", "CellEntityIds", "region", "regions", "subdomain", "subdomains")


def load_mesh(path, regions=None):
    """Read a tetrahedral mesh file into a ``skfem.MeshTet``, its region labels kept.

    Any format meshio reads (Gmsh ``.msh``, MEDIT ``.mesh``, VTK/VTU, XDMF, ...). Only the
    tetrahedra are kept (other cells are ignored) and vertices no tetrahedron uses are
    dropped.

    Regions become ``mesh.subdomains`` (element sets) and labelled boundary triangles
    ``mesh.boundaries`` (facet sets, usable as ``fixed="name"``):

    * named as ``skfem.MeshTet.load`` names them wherever it does: Gmsh physical names,
      meshio cell sets (e.g. XDMF), and the regions scikit-fem itself saved (``mesh.save``);
    * otherwise from integer labels in the cell data (``medit:ref``, ``gmsh:physical``,
      ``CellEntityIds``, ``region``, ... in this order, or the field ``regions`` names), one
      set per label value, named ``"ref<label>"``; a single label makes a single region.

    Parameters
    ----------
    path : str or path-like
        The mesh file.
    regions : str, optional
        The integer cell-data field holding the labels, when it is none of the above.

    Returns
    -------
    skfem.MeshTet
        E.g. ``ElasticBody(mesh, material={"ref1": ..., "ref2": ...})`` assigns a material
        per region.

    Raises
    ------
    ValueError
        If meshio cannot read the file, it holds no tetrahedra, or ``regions`` names no integer
        cell data.
    FileNotFoundError
        If there is no such file.
    ImportError
        If meshio needs a package for the format that is missing (``h5py`` for XDMF, a dependency).
    """
    import skfem
    m = _read(path)
    tets = [(i, c.data) for i, c in enumerate(m.cells) if c.type == "tetra"]
    if not tets:
        raise ValueError(f"{path} holds no tetrahedra (cell types: {[c.type for c in m.cells]})")
    t = np.concatenate([c for _, c in tets]).T
    p = np.ascontiguousarray(m.points[:, :3].T, dtype=float)
    full = skfem.MeshTet(p, np.ascontiguousarray(t), validate=False)
    subdomains, boundaries = _skfem_regions(m)
    if regions is not None and regions not in m.cell_data:
        raise ValueError(f"regions={regions!r} is not a cell field of {path} (fields: {sorted(m.cell_data)})")
    keys = (regions,) if regions is not None else REGION_KEYS
    key = next((k for k in keys if k in m.cell_data), None)
    if key is not None:
        if not subdomains:
            labels = np.concatenate([np.asarray(m.cell_data[key][i]).ravel() for i, _ in tets])
            subdomains = _label_sets(labels, f"{key} of the tetrahedra")
        if not boundaries:
            boundaries = _labelled_facets(full, m, key)
    mesh = skfem.MeshTet(p, np.ascontiguousarray(t), _boundaries=boundaries or None, _subdomains=subdomains or None)
    if np.unique(t).size < p.shape[1]:
        mesh = mesh.remove_unused_nodes()  # keeps the vertex order: facets keep their indices
    return mesh


def _skfem_regions(m):
    """(subdomains, boundaries) as ``skfem.MeshTet.load`` names them, empty where it names none."""
    import logging
    from skfem.io.meshio import from_meshio
    log = logging.getLogger("skfem.io.meshio")
    level = log.level
    log.setLevel(logging.ERROR)  # its notes on files without names
    try:
        mesh = from_meshio(m, force_meshio_type="tetra")
    except Exception:  # a file scikit-fem cannot parse for names: integer labels below
        return {}, {}
    finally:
        log.setLevel(level)
    named = lambda d: {k: np.asarray(v) for k, v in (d or {}).items() if isinstance(k, str) and not k.startswith("gmsh:")}
    return named(mesh.subdomains), named(mesh.boundaries)


def _label_sets(labels, what):
    if labels.size and not np.issubdtype(labels.dtype, np.integer):
        if not np.all(labels == np.round(labels)):
            raise ValueError(f"{what}: region labels must be integers")
        labels = labels.astype(np.int64)
    return {f"ref{int(v)}": np.flatnonzero(labels == v).astype(np.int32) for v in np.unique(labels)}


def _labelled_facets(mesh, m, key):
    """Boundaries from the labels of the file's triangles that are facets of the mesh."""
    tri = [(np.sort(c.data, axis=1), np.asarray(m.cell_data[key][i]).ravel()) for i, c in enumerate(m.cells)
           if c.type == "triangle"]
    if not tri:
        return {}
    faces = np.concatenate([a for a, _ in tri])
    labels = np.concatenate([b for _, b in tri])
    n = mesh.p.shape[1]
    code = lambda f: (f[:, 0].astype(np.int64) * n + f[:, 1]) * n + f[:, 2]
    facets = np.sort(mesh.facets, axis=0).T
    order = np.argsort(code(facets))
    keys = code(facets)[order]
    pos = np.searchsorted(keys, code(faces))
    found = (pos < keys.size) & (keys[np.minimum(pos, keys.size - 1)] == code(faces))
    index = order[pos[found]]
    return {name: index[sel] for name, sel in _label_sets(labels[found], f"{key} of the triangles").items()}


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
    except ModuleNotFoundError as err:  # a reader's package missing (h5py for XDMF, of the 'lab' extra)
        if err.name in EXTRA_OF:
            raise MissingExtra(message(f"reading {path}", EXTRA_OF[err.name]), name=err.name) from None
        raise ImportError(f"reading {path} needs the package {err.name} (pip install {err.name})") from err
    except (Exception, SystemExit) as err:  # noqa: BLE001 (whatever a reader raises on a damaged file)
        reason = " ".join(said.getvalue().split()) or f"{type(err).__name__}: {err}"
        raise ValueError(f"mesh file {os.fspath(path)!r} cannot be read: {reason} (a tetrahedral mesh in a format "
                         f"meshio reads: .msh, .mesh, .vtu, .vtk, .xdmf, ...)") from None
