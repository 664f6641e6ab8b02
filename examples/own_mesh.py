r"""Your own mesh, with a material per region
==========================================

A simulation starts from a tetrahedral mesh. Any file that `meshio
<https://github.com/nschloe/meshio>`_ reads and that holds tetrahedra will do:
Gmsh ``.msh``, MEDIT ``.mesh`` (the format of the affinification paper's beams),
VTK/VTU, ... :func:`skfem_affine.lab.io.load_mesh` (``sa.io.load_mesh``) reads it
into a scikit-fem ``MeshTet``. Region labels (``gmsh:physical`` in a Gmsh file,
``medit:ref`` in a MEDIT file) become ``mesh.subdomains`` named ``"ref<label>"``,
and :class:`~skfem_affine.ElasticBody` accepts a dict that maps those names to
materials, one per region.

To stay self-contained, this tutorial first *writes* such a file: a 4 m bar whose
half near the wall is labelled 1 and whose outer half is labelled 2. A mesher such
as Gmsh writes the same kind of file from a CAD model.
"""
import os
import tempfile

import meshio
import numpy as np
import skfem

import skfem_affine as sa

# %%
# Write a mesh file with two labelled regions
# -------------------------------------------
# Any tetrahedral mesh works; here scikit-fem builds a box and meshio writes it as
# Gmsh 2.2 with the region label of each tetrahedron in ``gmsh:physical``.
box = skfem.MeshTet.init_tensor(np.linspace(0, 4, 13), np.linspace(0, 1, 4), np.linspace(0, 1, 4))
centroid_x = box.p[0, box.t].mean(axis=0)
labels = np.where(centroid_x < 2.0, 1, 2)
folder = tempfile.mkdtemp()
path = os.path.join(folder, "bar.msh")
meshio.write(path, meshio.Mesh(box.p.T, [("tetra", box.t.T)],
                               cell_data={"gmsh:physical": [labels], "gmsh:geometrical": [labels]}),
             file_format="gmsh22", binary=False)

# %%
# Load it
# -------
# ``load_mesh`` keeps only the vertices that tetrahedra use, and turns the labels
# into subdomains.
mesh = sa.io.load_mesh(path)
regions = {name: len(elements) for name, elements in mesh.subdomains.items()}
print(f"{mesh.t.shape[1]} tetrahedra, {mesh.p.shape[1]} vertices, regions {regions}")

# %%
# One material per region
# -----------------------
# The half at the wall is fifty times stiffer than the outer half. A dict must
# cover every element exactly once; a list with one material per element works too.
# The density may also vary per element (an array of length ``m``).
stiff, soft = sa.NeoHookean(E=1e9, nu=0.35), sa.NeoHookean(E=2e7, nu=0.35)   # a stiff plastic, a stiff rubber
clamped = mesh.nodes_satisfying(lambda p: p[0] < 1e-9)


def tip_height(material, frames=100):
    """Release the bar clamped at x = 0; return the simulation and the tip's height per frame."""
    body = sa.ElasticBody(mesh, material=material, density=1000.0, fixed=clamped)
    sim = sa.Simulation(body, dt=0.01, gravity=(0.0, 0.0, -9.81), damping=sa.Rayleigh(alpha=0.0, beta=0.01))
    tip = mesh.nodes_satisfying(lambda p: p[0] > 4 - 1e-9)
    return sim, np.array([s.x[tip, 2].mean() - 0.5 for s in sim.run(frames)])


two_materials, height_two_materials = tip_height({"ref1": stiff, "ref2": soft})
all_soft, height_soft = tip_height(soft)
sag_two_materials, sag_soft = height_two_materials.min(), height_soft.min()
print(f"lowest tip: {sag_two_materials:.3f} m with a stiff root, {sag_soft:.3f} m all rubber (of a 4 m bar)")

# %%
# The per-element material index is stored with the system
# (``sim.system.material_index``), and the ParaView output (``sa.io.Series``)
# writes it as the cell field ``material``.
if __name__ == "__main__":
    import matplotlib.pyplot as plt

    t = 0.01 * np.arange(1, height_soft.size + 1)
    fig, ax = plt.subplots(figsize=(7, 3.2))
    ax.plot(t, height_two_materials, label="stiff root (ref1, E = 1 GPa), rubber tip (ref2, E = 20 MPa)")
    ax.plot(t, height_soft, label="all rubber (E = 20 MPa)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("tip height (m)")
    ax.set_title("The bar from the file, clamped at x = 0")
    ax.legend(fontsize=8)
    fig.tight_layout()
