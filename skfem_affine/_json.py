"""JSON values of the package's numbers and containers: checkpoints, ``sim.stats`` records, ``--json`` output."""
import math

import numpy as np


def jsonable(value, finite=False):
    """A JSON-serialisable copy of a non-array value: numpy scalars become Python numbers, tuples
    lists and dict keys strings. ``finite=True`` writes NaN and infinities as None (strict JSON,
    for other programs); by default they stay floats (Python's ``json`` reads them back).

    Raises a TypeError for anything else (an array, an object).
    """
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, dict):
        return {str(k): jsonable(v, finite) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v, finite) for v in value]
    if isinstance(value, float) and finite and not math.isfinite(value):
        return None
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(f"JSON values are numbers, strings, lists or dicts, got {type(value).__name__}")
