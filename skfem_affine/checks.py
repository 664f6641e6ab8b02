"""Input checks shared across the package: a bad number raises an error that names it."""
import numpy as np


def positive(value, name):
    """``value`` as a float, finite and > 0; else TypeError (not a number) or ValueError naming ``name``."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(number) or number <= 0:
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    return number
