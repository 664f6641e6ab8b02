"""Runners that measure the speed/accuracy trade: ``compare``, ``sweep`` (on Dask) and ``scaling``.

The public face of the lab's runners, one import for scripts and the command line::

    from skfem_affine import runners
    spec = runners.SceneSpec.make("cantilever", resolution=4)
    reference, runs = runners.compare(spec, frames=100)

A *scene* is a :class:`SceneSpec` (:mod:`~skfem_affine.lab.scene_spec`); a *method* is a
:class:`Method` (:mod:`~skfem_affine.lab.methods`), a name and a reducer factory. The work is
done by :mod:`~skfem_affine.lab.runs` (:func:`run`, :func:`reference_run`, :func:`interleaved`,
:func:`compare`), :mod:`~skfem_affine.lab.sweep`, :mod:`~skfem_affine.lab.scaling` and
:mod:`~skfem_affine.lab.tables`.
"""
from skfem_affine.lab.methods import COMPARED, METHODS, Method, get_method, register
from skfem_affine.lab.runs import TIMING, Reference, Run, compare, interleaved, reference_run, run, warm_up
from skfem_affine.lab.scaling import PAPER_TABLE1_BEAM, PAPER_TABLE2, paper_speedup, scaling
from skfem_affine.integrators.problem import PHASES
from skfem_affine.lab.scene_spec import SceneSpec, default_frames, load_scene_file
from skfem_affine.lab.sweep import cell_key, connect, sweep, sweep_cell, sweep_taus
from skfem_affine.lab.tables import FileFormatError, merge_rows, read_table, write_table

__all__ = ["COMPARED", "METHODS", "Method", "get_method", "register", "TIMING", "Reference", "Run", "compare",
           "interleaved", "reference_run", "run", "warm_up", "scaling", "paper_speedup", "PAPER_TABLE2",
           "PAPER_TABLE1_BEAM", "PHASES", "SceneSpec", "default_frames",
           "load_scene_file", "cell_key", "connect", "sweep", "sweep_cell", "sweep_taus", "FileFormatError",
           "merge_rows", "read_table", "write_table"]
