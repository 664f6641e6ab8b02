"""Write ``api/toplevel.inc``: a table of the names ``skfem_affine`` exports, linked to their modules.

Generated at every build from ``skfem_affine.__all__``, so that the table follows the package.
"""
import inspect
import os


def _write(app):
    import skfem_affine

    rows = []
    for name in skfem_affine.__all__:
        obj = getattr(skfem_affine, name)
        if inspect.ismodule(obj):
            target, role = obj.__name__, "mod"
        else:
            target, role = f"{obj.__module__}.{obj.__qualname__}", "class" if inspect.isclass(obj) else "func"
        doc = inspect.getdoc(obj) or ""
        summary = doc.strip().split("\n\n")[0].replace("\n", " ").strip() if doc else ""
        rows.append((f"``sa.{name}``", f":{role}:`{target}`", summary))
    out = os.path.join(app.srcdir, "api", "toplevel.inc")
    os.makedirs(os.path.dirname(out), exist_ok=True)
    lines = [".. list-table::", "   :header-rows: 1", "   :widths: 18 37 45", "",
             "   * - name", "     - defined in", "     - summary"]
    for a, b, c in rows:
        lines += [f"   * - {a}", f"     - {b}", f"     - {c}"]
    text = "\n".join(lines) + "\n"
    if not os.path.exists(out) or open(out).read() != text:
        with open(out, "w") as fh:
            fh.write(text)


def setup(app):
    app.connect("builder-inited", _write)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
