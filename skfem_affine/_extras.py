"""The optional dependencies: each is imported where it is used, and a missing one is one line naming its extra.

The core (``pip install skfem-affine``) needs scikit-fem, numpy, scipy, meshio, pyamg, matplotlib,
numba and threadpoolctl. The rest come with the extras of ``pyproject.toml``:

* ``fast``: MKL Pardiso (pypardiso) and METIS (pymetis) for its nested-dissection orderings;
* ``ipc``: IPC contact from ipctk (``sa.IPC``, and so the Newton integrators with several bodies);
* ``subspace``: METIS (pymetis) for the subdomains of ``sa.AdaptiveSubspace``;
* ``lab``: dask, distributed and cloudpickle (``skfem-affine sweep``), tqdm (progress bars on a terminal;
  without it, the plain progress lines of a log) and h5py (XDMF meshes);
* ``parquet``: pyarrow, for sweep tables as Parquet (CSV needs nothing).

:func:`require` imports a module of an extra; :class:`Optional` stands for one at a module's import
line and imports it at its first attribute look-up, so that the module imports without it.
"""
import importlib

#: The optional packages and the extra that installs each (tests hide these to check the core).
EXTRA_OF = {"pypardiso": "fast", "ipctk": "ipc", "pymetis": "subspace", "dask": "lab", "distributed": "lab", "cloudpickle": "lab",
            "tqdm": "lab", "h5py": "lab", "pyarrow": "parquet"}


class MissingExtra(ModuleNotFoundError):
    """An optional package is not installed; the message names the feature and the extra to install."""


def message(feature, extra):
    """The one line that says ``feature`` needs ``extra`` and how to install it."""
    return f"{feature} needs the {extra!r} extra: pip install 'skfem-affine[{extra}]'"


def require(module, feature, extra):
    """``module`` imported, or :class:`MissingExtra` saying that ``feature`` needs ``extra``.

    Only a missing optional package (a key of :data:`EXTRA_OF`) becomes that error; any other
    failure to import is raised as it is.
    """
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as err:
        if (err.name or "").split(".")[0] not in EXTRA_OF:
            raise
        raise MissingExtra(message(feature, extra), name=err.name) from None


class Optional:
    """A module of an extra, imported at the first attribute look-up (see :func:`require`).

    ``ipctk = Optional("ipctk", "sa.IPC", "ipc")`` at a module's top lets the module import
    without ipctk; ``ipctk.CollisionMesh`` then imports it, or raises :class:`MissingExtra`.
    """

    def __init__(self, module, feature, extra):
        self._spec = (module, feature, extra)

    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(require(*self._spec), name)

    def __repr__(self):
        return f"<optional module {self._spec[0]!r} of the {self._spec[2]!r} extra>"
