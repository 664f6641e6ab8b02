"""Link the package's names the way a reader writes them.

- A Python reference that Sphinx cannot resolve as written (``Simulation``, ``sa.Simulation``,
  ``Simulation.step``, ``lab.io.load_mesh``) is looked up among the package's documented
  objects: ``sa.`` stands for ``skfem_affine.``, a name exported by ``skfem_affine`` resolves to
  the object it exports, otherwise a unique documented object whose dotted name ends with the
  reference is taken. A reference that names none of the package's objects (``numpy.ndarray``
  when the NumPy inventory is not reachable, ``float``) is shown as code without a link; one that
  looks like ours but matches no object, or several, stays a warning (nitpicky mode).
- Inline code in the prose (Markdown `` `Simulation` ``, reST ````sa.Simulation````) that names
  one of the package's documented classes, functions or methods becomes a link to its page.
"""
import importlib
import importlib.util
import re

from docutils import nodes
from sphinx import addnodes
from sphinx.util.nodes import make_refnode

PACKAGE = "skfem_affine"
LINKED = {"class", "function", "exception", "method", "property", "module"}
NAME = re.compile(r"^~?[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*(\(\))?$")


def _objects(env):
    return env.get_domain("py").objects


def _exported(target):
    """The canonical name of ``skfem_affine.<target>`` when the package exports it, else None."""
    head, _, rest = target.partition(".")
    try:
        obj = getattr(importlib.import_module(PACKAGE), head)
        for part in filter(None, rest.split(".")):
            obj = getattr(obj, part)
    except (AttributeError, ImportError):
        return None
    if hasattr(obj, "__module__") and hasattr(obj, "__qualname__") and str(obj.__module__).startswith(PACKAGE):
        return f"{obj.__module__}.{obj.__qualname__}"
    if getattr(obj, "__name__", "").startswith(PACKAGE):  # a module
        return obj.__name__
    return None


ROLE_KINDS = {"func": {"function", "method"}, "meth": {"method", "function"}, "class": {"class", "exception"},
              "exc": {"exception", "class"}, "mod": {"module"}, "data": {"data", "attribute"},
              "attr": {"attribute", "property", "data"}}


def lookup(env, target, kinds=None, context=None):
    """The documented object's full name for ``target`` (see the module docstring), or None.

    Returns ``(name, ambiguous)``: ``ambiguous`` is True when the target names the package's
    objects but not exactly one. Among several, those under the module ``context`` win.
    """
    objects = _objects(env)
    target = target.lstrip("~").removesuffix("()")
    if target.startswith("sa."):
        target = target[3:]
    elif target.startswith(PACKAGE + "."):
        target = target[len(PACKAGE) + 1:]
    elif target == PACKAGE:
        return (PACKAGE, False) if PACKAGE in objects else (None, False)
    ok = (lambda n: objects[n].objtype in kinds) if kinds else (lambda n: True)
    full = f"{PACKAGE}.{target}"
    if full in objects and ok(full):
        return full, False
    canonical = _exported(target)
    if canonical in objects and ok(canonical):
        return canonical, False
    matches = [n for n in objects if n.startswith(PACKAGE) and n.endswith("." + target) and ok(n)]
    if len(matches) > 1 and context:
        near = [n for n in matches if n.startswith(context + ".")]
        matches = near or matches
    if len(matches) == 1:
        return matches[0], False
    return None, bool(matches)


def _inherited(env, target, module, cls):
    """``Base.target`` documented on a base class of ``module.cls`` (a docstring inherited from it)."""
    if not (module and cls) or "." in target:
        return None
    try:
        obj = importlib.import_module(module)
        for part in cls.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError):
        return None
    objects = _objects(env)
    for base in getattr(obj, "__mro__", ()):
        name = f"{base.__module__}.{base.__qualname__}.{target}"
        if name in objects:
            return name
    return None


def _missing_reference(app, env, node, contnode):
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"]
    if "._" in target or target.startswith("_"):
        return contnode  # a private name: code, not documented
    head = target.split(".")[0]
    if head not in (PACKAGE, "sa") and "." in target and importlib.util.find_spec(head) is not None:
        return contnode  # numpy.ndarray, skfem.MeshTet, ... when their inventory is not reachable
    kinds = ROLE_KINDS.get(node.get("reftype"))
    context = node.get("py:module")
    name = _inherited(env, target, context, node.get("py:class"))
    ambiguous = False
    if name is None and node.get("reftype") == "func":
        name, ambiguous = lookup(env, target, {"function"}, context)
    if name is None:
        name, ambiguous = lookup(env, target, kinds, context)
    if name is None and kinds and not ambiguous:
        name, ambiguous = lookup(env, target, None, context)
    if name is not None:
        entry = _objects(env)[name]
        return make_refnode(app.builder, node["refdoc"], entry.docname, entry.node_id, contnode, name)
    last, last_ambiguous = lookup(env, target.rsplit(".", 1)[-1])
    if ambiguous or target.startswith((PACKAGE, "sa.")) or last is not None or last_ambiguous:
        return None  # one of ours that does not resolve: nitpicky warns, naming it
    return contnode  # a foreign name without an inventory (float, ndarray): code, no link, no warning


def _link_literals(app, doctree, docname):
    env = app.env
    for lit in list(doctree.findall(nodes.literal)):
        text = lit.astext()
        if not NAME.match(text) or isinstance(lit.parent, (nodes.reference, addnodes.pending_xref)):
            continue
        if any(isinstance(a, (addnodes.desc_signature, nodes.literal_block)) for a in _ancestors(lit)):
            continue
        dotted = "." in text.removeprefix("sa.").removeprefix("~")
        kinds = LINKED if dotted else {"class", "function", "exception"}
        name, _ = lookup(env, text, kinds)
        if name is None:
            continue
        entry = _objects(env)[name]
        if entry.docname == docname and _inside_own_description(lit, entry.node_id):
            continue
        ref = make_refnode(app.builder, docname, entry.docname, entry.node_id, lit.deepcopy(), name)
        lit.replace_self(ref)


def _ancestors(node):
    node = node.parent
    while node is not None:
        yield node
        node = node.parent


def _inside_own_description(node, node_id):
    for a in _ancestors(node):
        if isinstance(a, addnodes.desc):
            return any(node_id in sig.get("ids", ()) for sig in a.findall(addnodes.desc_signature))
    return False


def setup(app):
    app.connect("missing-reference", _missing_reference, priority=900)  # after intersphinx
    app.connect("doctree-resolved", _link_literals)
    return {"parallel_read_safe": True, "parallel_write_safe": True}


def empty_inventory():
    """Path of an empty Sphinx inventory (written once to the temporary folder): the offline fallback
    of every intersphinx project."""
    import os
    import tempfile
    import zlib
    path = os.path.join(tempfile.gettempdir(), "skfem_affine_docs_empty_objects.inv")
    data = (b"# Sphinx inventory version 2\n# Project: offline\n# Version: \n"
            b"# The remainder of this file is compressed using zlib.\n" + zlib.compress(b""))
    if not os.path.exists(path) or open(path, "rb").read() != data:
        with open(path, "wb") as fh:
            fh.write(data)
    return path
