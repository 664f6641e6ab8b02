"""scikit-fem's own objects: vertex sets from boundary names, facets and DOFs; region names of
mesh files in every format; states as scikit-fem DOF vectors."""

import meshio
import numpy as np
import pytest
import skfem
from skfem import Basis, ElementTetP1, ElementTetP2, ElementVector

import skfem_affine as sa


def bar():
    mesh = skfem.MeshTet.init_tensor(np.linspace(0, 1, 9), np.linspace(0, 0.2, 3), np.linspace(0, 0.2, 3))
    return mesh.with_boundaries({"left": lambda x: x[0] < 1e-9, "right": lambda x: x[0] > 1 - 1e-9})


def body(mesh, fixed=None, prescribed=None):
    return sa.ElasticBody(mesh, sa.NeoHookean(E=1e6, nu=0.3), fixed=fixed, prescribed=prescribed)


def test_fixed_takes_every_kind_of_vertex_set_and_they_agree():
    mesh = bar()
    left = mesh.nodes_satisfying(lambda x: x[0] < 1e-9)
    basis = Basis(mesh, ElementVector(ElementTetP1()))
    scalar = Basis(mesh, ElementTetP1())
    mask = np.zeros(mesh.p.shape[1], dtype=bool)
    mask[left] = True
    ways = {"indices": left, "mask": mask, "name": "left", "names": ["left"], "DofsView": basis.get_dofs("left"),
            "DofsView by test": basis.get_dofs(lambda x: x[0] < 1e-9), "scalar DofsView": scalar.get_dofs("left"),
            "facets": sa.vertices_of(mesh, facets=mesh.boundaries["left"]),
            "dofs": sa.vertices_of(mesh, dofs=basis.get_dofs("left").flatten()),
            "dofs view by keyword": sa.vertices_of(mesh, dofs=basis.get_dofs("left"))}
    for what, fixed in ways.items():
        assert np.array_equal(np.flatnonzero(body(mesh, fixed).fixed), left), what
    both = body(mesh, ["left", "right"]).fixed
    assert both.sum() == 2 * left.size


def test_dof_looking_and_partial_input_is_refused_naming_the_conversion():
    mesh = bar()
    n = mesh.p.shape[1]
    basis = Basis(mesh, ElementVector(ElementTetP1()))
    right_dofs = basis.get_dofs("right").flatten()  # indices up to 3n: cannot be vertices
    assert right_dofs.max() >= n
    with pytest.raises(ValueError, match=r"fixed vertex indices out of range.*DOF indices.*DofsView.*"
                                         r"vertices_of\(mesh, dofs=\.\.\.\)"):
        body(mesh, right_dofs)
    with pytest.raises(ValueError, match="only components.*whole vertices"):
        body(mesh, basis.get_dofs("left").keep("u^1"))
    with pytest.raises(ValueError, match="only some components"):
        sa.vertices_of(mesh, dofs=basis.get_dofs("left").keep("u^1").flatten())
    with pytest.raises(ValueError, match="DOFs beyond the vertices"):
        body(mesh, Basis(mesh, ElementVector(ElementTetP2())).get_dofs("left"))
    other = skfem.MeshTet.init_tensor(*[np.linspace(0, 1, 3)] * 3)
    with pytest.raises(ValueError, match="another mesh"):
        body(mesh, Basis(other, ElementVector(ElementTetP1())).get_dofs())
    with pytest.raises(ValueError, match=r"'top' is not a boundary of the mesh \(boundaries: \['left', 'right'\]\)"):
        body(mesh, "top")
    with pytest.raises(TypeError, match="exactly one"):
        sa.vertices_of(mesh, [0], facets=[0])
    with pytest.raises(ValueError, match="facets out of range"):
        sa.vertices_of(mesh, facets=[mesh.facets.shape[1]])


def test_prescribed_and_forces_take_boundary_names_and_dofs_views():
    mesh = bar()
    basis = Basis(mesh, ElementVector(ElementTetP1()))
    b = body(mesh, "left", prescribed=sa.Prescribed(basis.get_dofs("right"), lambda t, X: X))
    assert np.array_equal(b.prescribed_vertices[0], mesh.nodes_satisfying(lambda x: x[0] > 1 - 1e-9))
    sim = sa.Simulation(body(mesh, "left"), dt=0.01, forces=[sa.VertexForce("right", [0.0, 0.0, -1.0])])
    assert np.array_equal(sim.motion.forces[0][0], mesh.nodes_satisfying(lambda x: x[0] > 1 - 1e-9))
    # two bodies: a name is the named body's
    b1, b2 = body(mesh, "left"), body(mesh, "left")
    with pytest.raises(ValueError, match="needs the body's mesh.*body=body"):
        sa.Simulation([b1, b2], dt=0.01, forces=[sa.VertexForce("right", [0.0, 0.0, -1.0])])
    sim = sa.Simulation([b1, b2], dt=0.01, forces=[sa.VertexForce("right", [0.0, 0.0, -1.0], body=b2)])
    assert sim.motion.forces[0][0].min() >= b1.n_vertices


def test_state_to_and_from_scikit_fem_dofs_works_with_probes_and_interpolate():
    mesh = bar()
    basis = Basis(mesh, ElementVector(ElementTetP1()))
    sim = sa.Simulation(body(mesh, "left"), dt=0.01, gravity=(0, 0, -9.81))
    for _ in range(3):
        sim.step()
    s = sim.state
    u = s.dofs(basis)
    assert np.allclose(u[basis.nodal_dofs].T, s.x - mesh.p.T)
    assert np.allclose(sim.to_dofs(basis), u)
    assert np.allclose(s.dofs(basis, "velocity")[basis.nodal_dofs].T, s.v)
    # probes: at a vertex the vertex's displacement; mid-edge the mean of its two ends (P1)
    tip = mesh.nodes_satisfying(lambda x: x[0] > 1 - 1e-9)
    a, b = mesh.t[0, 0], mesh.t[1, 0]
    points = np.column_stack([mesh.p[:, tip], 0.5 * (mesh.p[:, a] + mesh.p[:, b])])
    probed = (basis.probes(points) @ u).reshape(3, -1)
    assert np.allclose(probed[:, :-1].T, s.x[tip] - mesh.p.T[tip])
    assert np.allclose(probed[:, -1], 0.5 * (s.x[a] + s.x[b]) - 0.5 * (mesh.p[:, a] + mesh.p[:, b]))
    # interpolate: the gradient of u is F - I, as the simulation's deformation gradients
    grad = basis.interpolate(u).grad  # (3, 3, m, q)
    F = sim.system.deformation_gradients(s.x)
    assert np.allclose(np.moveaxis(grad[:, :, :, 0], 2, 0), F - np.eye(3))
    back = sa.State.from_dofs(basis, u, s.dofs(basis, "velocity"), frame=s.frame, time=s.time)
    assert np.allclose(back.x, s.x) and np.allclose(back.v, s.v)
    with pytest.raises(ValueError, match="ElementVector\\(ElementTetP1\\(\\)\\)"):
        s.dofs(Basis(mesh, ElementTetP1()))
    with pytest.raises(ValueError, match="one of the simulation's bodies"):
        sim.to_dofs(Basis(skfem.MeshTet.init_tensor(*[np.linspace(0, 1, 3)] * 3), ElementVector(ElementTetP1())))


# ---------------------------------------------------------------- region names in mesh files

def two_region_cube():
    mesh = skfem.MeshTet.init_tensor(*[np.linspace(0, 1, 3)] * 3)
    labels = np.where(mesh.p[:, mesh.t].mean(axis=1)[0] < 0.5, 1, 2)
    return mesh, labels


def write_msh41(path, p, t, labels, names):
    """A Gmsh 4.1 ASCII file, as Gmsh writes it: one volume entity per label with a named physical group."""
    tags = np.unique(labels)
    lo, hi = p.min(axis=0), p.max(axis=0)
    out = ["$MeshFormat", "4.1 0 8", "$EndMeshFormat", "$PhysicalNames", str(len(tags))]
    out += [f'3 {k} "{names[k]}"' for k in tags]
    out += ["$EndPhysicalNames", "$Entities", f"0 0 0 {len(tags)}"]
    out += [f"{k} {lo[0]} {lo[1]} {lo[2]} {hi[0]} {hi[1]} {hi[2]} 1 {k} 0" for k in tags]
    out += ["$EndEntities", "$Nodes", f"1 {len(p)} 1 {len(p)}", f"3 {tags[0]} 0 {len(p)}"]
    out += [str(i + 1) for i in range(len(p))] + [f"{x!r} {y!r} {z!r}" for x, y, z in p.tolist()]
    out += ["$EndNodes", "$Elements", f"{len(tags)} {len(t)} 1 {len(t)}"]
    for k in tags:
        idx = np.flatnonzero(labels == k)
        out.append(f"3 {k} 4 {idx.size}")
        out += [f"{e + 1} " + " ".join(str(v + 1) for v in t[e]) for e in idx]
    open(path, "w").write("\n".join(out + ["$EndElements"]) + "\n")


def write_xdmf(path, p, t, cell_fields):
    """An XDMF file with its data inline (XML), as meshio reads it."""
    flat = lambda a: " ".join(map(str, np.ravel(a).tolist()))
    attributes = "".join(f'<Attribute Name="{k}" AttributeType="Scalar" Center="Cell"><DataItem DataType="Int" '
                         f'Dimensions="{len(v)}" Format="XML" Precision="8">{flat(v)}</DataItem></Attribute>'
                         for k, v in cell_fields.items())
    open(path, "w").write(
        f'<?xml version="1.0"?><Xdmf Version="3.0"><Domain><Grid Name="mesh" GridType="Uniform">'
        f'<Geometry GeometryType="XYZ"><DataItem DataType="Float" Dimensions="{len(p)} 3" Format="XML" '
        f'Precision="8">{flat(p)}</DataItem></Geometry><Topology TopologyType="Tetrahedron" '
        f'NumberOfElements="{len(t)}"><DataItem DataType="Int" Dimensions="{len(t)} 4" Format="XML" '
        f'Precision="8">{flat(t)}</DataItem></Topology>{attributes}</Grid></Domain></Xdmf>')


def sizes(d):
    return {k: len(v) for k, v in (d or {}).items()}


def test_region_names_survive_every_format_as_scikit_fem_names_them(tmp_path):
    mesh, labels = two_region_cube()
    p, t = mesh.p.T, mesh.t.T
    left = mesh.facets[:, mesh.facets_satisfying(lambda x: x[0] < 1e-9)].T
    names = {"left": np.array([1, 3]), "right": np.array([2, 3]), "clamp": np.array([3, 2])}
    files = {}
    meshio.write(tmp_path / "named22.msh", meshio.Mesh(
        p, [("triangle", left), ("tetra", t)], field_data=names,
        cell_data={"gmsh:physical": [np.full(len(left), 3), labels], "gmsh:geometrical": [np.ones(len(left), int), labels]}),
        file_format="gmsh22")
    files["named22.msh"] = ({"left": 24, "right": 24}, {"clamp": 8})
    write_msh41(tmp_path / "named41.msh", p, t, labels, {1: "left", 2: "right"})
    files["named41.msh"] = ({"left": 24, "right": 24}, {})
    meshio.write(tmp_path / "plain22.msh", meshio.Mesh(p, [("tetra", t)], cell_data={
        "gmsh:physical": [labels], "gmsh:geometrical": [labels]}), file_format="gmsh22")
    files["plain22.msh"] = ({"ref1": 24, "ref2": 24}, {})
    meshio.write(tmp_path / "c.mesh", meshio.Mesh(p, [("triangle", left), ("tetra", t)],
                                                  cell_data={"medit:ref": [np.full(len(left), 7), labels]}))
    files["c.mesh"] = ({"ref1": 24, "ref2": 24}, {"ref7": 8})
    for ext in ("vtu", "vtk"):
        meshio.write(tmp_path / f"d.{ext}", meshio.Mesh(p, [("tetra", t)], cell_data={"region": [labels]}))
        files[f"d.{ext}"] = ({"ref1": 24, "ref2": 24}, {})
    write_xdmf(tmp_path / "e.xdmf", p, t, {"region": labels})  # inline XML data
    files["e.xdmf"] = ({"ref1": 24, "ref2": 24}, {})
    meshio.write(tmp_path / "f.xdmf", meshio.Mesh(p, [("tetra", t)], cell_data={"region": [labels]}))  # HDF5 data
    files["f.xdmf"] = ({"ref1": 24, "ref2": 24}, {})
    named = mesh.with_subdomains({"soft": lambda x: x[0] < 0.5, "hard": lambda x: x[0] > 0.5}).with_boundaries(
        {"clamp": lambda x: x[0] < 1e-9})
    for ext in ("vtu", "msh", "vtk"):
        named.save(tmp_path / f"skfem.{ext}")
        files[f"skfem.{ext}"] = ({"soft": 24, "hard": 24}, {"clamp": 8})
    for name, (subdomains, boundaries) in files.items():
        loaded = sa.io.load_mesh(tmp_path / name)
        assert (sizes(loaded.subdomains), sizes(loaded.boundaries)) == (subdomains, boundaries), name
        assert np.allclose(loaded.p, mesh.p), name
        x = loaded.p[0, loaded.t].mean(axis=0)
        first, second = loaded.subdomains.values()  # label 1 (x < 0.5), then label 2
        assert np.all(x[first] < 0.5) and np.all(x[second] > 0.5), name
        for facets in (loaded.boundaries or {}).values():
            assert np.all(loaded.p[0, loaded.facets[:, facets]] == 0), name
        ref = skfem.MeshTet.load(tmp_path / name) if not name.endswith("xdmf") else None
        if ref is not None and ref.subdomains:  # where scikit-fem names them: the same names and sets
            assert {k: v.tolist() for k, v in loaded.subdomains.items()} == \
                {k: np.asarray(v).tolist() for k, v in ref.subdomains.items()}, name
            assert sizes(loaded.boundaries) == sizes(ref.boundaries), name
    # the names work as the materials and the fixed set of a body
    m = sa.io.load_mesh(tmp_path / "named22.msh")
    b = sa.ElasticBody(m, {"left": sa.NeoHookean(E=1e6, nu=0.3), "right": sa.StVK(E=1e5, nu=0.3)}, fixed="clamp")
    assert b.fixed.sum() == 9 and len(b.materials) == 2


def test_load_mesh_drops_unused_vertices_and_keeps_boundaries(tmp_path):
    mesh, labels = two_region_cube()
    p = np.vstack([mesh.p.T, [[5.0, 5.0, 5.0]]])  # a vertex no tetrahedron uses
    t = mesh.t.T
    left = mesh.facets[:, mesh.facets_satisfying(lambda x: x[0] < 1e-9)].T
    meshio.write(tmp_path / "a.mesh", meshio.Mesh(p, [("triangle", left), ("tetra", t)],
                                                  cell_data={"medit:ref": [np.full(len(left), 3), labels]}))
    m = sa.io.load_mesh(tmp_path / "a.mesh")
    assert m.p.shape[1] == mesh.p.shape[1]
    assert np.array_equal(np.unique(m.facets[:, m.boundaries["ref3"]]), mesh.nodes_satisfying(lambda x: x[0] < 1e-9))
    with pytest.raises(ValueError, match="regions='label' is not a cell field"):
        sa.io.load_mesh(tmp_path / "a.mesh", regions="label")
