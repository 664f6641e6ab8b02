"""A run's summary (``sim.stats.summary()``): a dict for programs that prints as a table for people.

>>> s = Summary({"frames": 100, "wall_s": 2.0, "frames_per_s": 50.0, "mean_dofs": 1234.5,
...              "assembly_s": 0.5, "solve_s": 1.25})
>>> s["frames_per_s"]
50.0
>>> print(s)
frames              100
wall time           2 s
frames per second   50
mean DOFs solved    1234
  assembly          0.5  s  (25 % of wall)
  solve             1.25 s  (62 % of wall)
"""

#: Significant digits of the numbers in the table (the dict keeps them all).
DIGITS = 4

#: Row labels of the keys that are not a phase's total (``<phase>_s``), in the table's order.
LABELS = {"frames": "frames", "wall_s": "wall time", "frames_per_s": "frames per second",
          "mean_dofs": "mean DOFs solved", "max_estimated_error": "largest estimated error",
          "max_estimated_error_m": "  the same in metres", "error_unit_m": "error unit"}

#: Units written after the number, by key.
UNITS = {"wall_s": "s", "max_estimated_error_m": "m", "error_unit_m": "m"}


def number(value):
    """``value`` with ``DIGITS`` significant digits; counts (integers, and mean DOFs) as integers."""
    if value is None:
        return "-"
    if isinstance(value, int):
        return str(value)
    return f"{value:.{DIGITS}g}"


class Summary(dict):
    """Frames, wall time, DOFs and per-phase totals of a run (``sim.stats.summary()``).

    A dict (``summary["wall_s"]``, ``json.dumps(summary)``) whose text is a two-column table:
    one row per entry, phase totals in seconds with their share of the wall time, at
    ``DIGITS`` significant digits.
    """

    def rows(self):
        """(label, text) of each entry, in the table's order: the run, its phases, the error budget."""
        wall = self.get("wall_s") or 0.0
        out = []
        for key in ("frames", "wall_s", "frames_per_s", "mean_dofs"):
            if key in self:
                value = int(self[key]) if key == "mean_dofs" else self[key]
                out.append((LABELS[key], _with_unit(number(value), UNITS.get(key))))
        phases = [(key[:-2], value) for key, value in self.items() if key.endswith("_s") and key not in LABELS]
        width = max((len(number(value)) for _, value in phases), default=0)
        for phase, value in phases:
            text = f"{number(value):<{width}} s"
            if wall > 0:
                text += f"  ({100 * value / wall:.0f} % of wall)"
            out.append((f"  {phase}", text))
        for key in ("max_estimated_error", "max_estimated_error_m", "error_unit_m"):
            if key in self:
                out.append((LABELS[key], _with_unit(number(self[key]), UNITS.get(key))))
        for key, value in self.items():  # anything else, as it is
            if key not in LABELS and not key.endswith("_s"):
                out.append((key, number(value) if isinstance(value, (int, float)) else str(value)))
        return out

    def __str__(self):
        rows = self.rows()
        width = max((len(label) for label, _ in rows), default=0) + 3
        return "\n".join(f"{label:<{width}}{text}".rstrip() for label, text in rows)

    __repr__ = __str__


def _with_unit(text, unit):
    return text if unit is None else f"{text} {unit}"
