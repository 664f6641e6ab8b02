"""Input checks shared across the package: a bad value raises an error that names it.

Policy, the same for every public constructor:

* a number must be a real number: ``int``, ``float``, numpy integer or floating scalars,
  :class:`fractions.Fraction`, ... A ``str`` (``"0.3"``), a ``bool``, ``None``, a complex
  number or an array of several values is a :class:`TypeError`;
* a number outside its range, or NaN / inf where a finite value is needed, is a
  :class:`ValueError` that quotes the range;
* an integer option (a count, an iteration cap) takes an ``int`` or a float with an integral
  value (``3.0``); ``2.7`` is a :class:`ValueError`, never silently truncated to 2;
* a switch takes ``True``/``False`` (numpy booleans and the integers 0 and 1 too); a string
  such as ``"False"`` is a :class:`TypeError` (it would be truthy);
* every message starts with the argument's name as the user wrote it.

>>> real(0.3, "nu", low=-1.0, high=0.5, include_low=False, include_high=False)
0.3
>>> real("0.3", "nu")
Traceback (most recent call last):
...
TypeError: nu must be a real number, got '0.3' (str)
>>> integer(3.0, "iterations", low=1)
3
>>> integer(2.7, "iterations")
Traceback (most recent call last):
...
ValueError: iterations must be an integer, got 2.7
"""
import numbers
import operator

import numpy as np


def _show(value):
    """repr of a value with numpy scalars shown as Python numbers (``-1.0``, not ``np.float64(-1.0)``)."""
    return repr(value.item() if isinstance(value, np.generic) else value)


def _describe(value):
    text = _show(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{text} ({type(value).__name__})"


def _is_bool(value):
    return isinstance(value, (bool, np.bool_))


def _scalar(value):
    """A 0-d numpy array as its scalar; anything else unchanged."""
    if isinstance(value, np.ndarray) and value.ndim == 0:
        return value[()]
    return value


def _interval(low, high, include_low, include_high):
    lo = "-inf" if low is None else f"{low:g}"
    hi = "inf" if high is None else f"{high:g}"
    return f"{'[' if include_low and low is not None else '('}{lo}, {hi}{']' if include_high and high is not None else ')'}"


def _in_range(x, low, high, include_low, include_high):
    """Elementwise: x within the bounds (NaN is never within)."""
    ok = np.ones(np.shape(x), dtype=bool) & ~np.isnan(x)
    if low is not None:
        ok &= (x >= low) if include_low else (x > low)
    if high is not None:
        ok &= (x <= high) if include_high else (x < high)
    return ok


def real(value, name, low=None, high=None, include_low=True, include_high=True, finite=True):
    """``value`` as a Python float, checked to be a real number within the given range.

    Parameters
    ----------
    value : object
        What the user passed.
    name : str
        The argument's name, used in the error message.
    low, high : float, optional
        Bounds of the accepted interval (None: unbounded).
    include_low, include_high : bool
        Whether each bound itself is accepted (default closed interval).
    finite : bool
        Refuse NaN and +-inf (default).

    Returns
    -------
    float

    Raises
    ------
    TypeError
        ``value`` is not a real number (str, bool, None, complex, an array of several values).
    ValueError
        ``value`` is NaN/inf (when ``finite``) or outside the interval.

    Examples
    --------
    >>> real(2, "radius", low=0.0, include_low=False)
    2.0
    >>> real(0.0, "radius", low=0.0, include_low=False)
    Traceback (most recent call last):
    ...
    ValueError: radius must lie in (0, inf), got 0.0
    """
    value = _scalar(value)
    if _is_bool(value) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number, got {_describe(value)}")
    try:
        number = float(value)
    except OverflowError:
        raise ValueError(f"{name} must be finite, got {_describe(value)}") from None
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a real number, got {_describe(value)}") from None
    if np.isnan(number) or (finite and np.isinf(number)):
        raise ValueError(f"{name} must be finite, got {_show(value)}")
    if not _in_range(number, low, high, include_low, include_high):
        raise ValueError(f"{name} must lie in {_interval(low, high, include_low, include_high)}, got {_show(value)}")
    return number


def positive(value, name):
    """``value`` as a float, finite and > 0 (:func:`real` with ``low=0`` excluded).

    >>> positive(1e-3, "dt")
    0.001
    """
    return real(value, name, low=0.0, include_low=False)


def nonnegative(value, name):
    """``value`` as a float, finite and >= 0 (:func:`real` with ``low=0``).

    >>> nonnegative(0, "friction")
    0.0
    """
    return real(value, name, low=0.0)


def integer(value, name, low=None, high=None):
    """``value`` as a Python int within ``[low, high]``.

    An ``int`` or numpy integer is taken as is; a real number with an integral value
    (``3.0``) is accepted; ``2.7`` raises rather than being truncated.

    Parameters
    ----------
    value : object
    name : str
        The argument's name, used in the error message.
    low, high : int, optional
        Inclusive bounds (None: unbounded).

    Returns
    -------
    int

    Raises
    ------
    TypeError
        ``value`` is not a number (str, bool, None, ...).
    ValueError
        ``value`` is not integral, not finite, or out of range.

    Examples
    --------
    >>> integer(np.int32(5), "n", low=1)
    5
    >>> integer(0, "n", low=1)
    Traceback (most recent call last):
    ...
    ValueError: n must be an integer >= 1, got 0
    """
    value = _scalar(value)
    if _is_bool(value) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be an integer, got {_describe(value)}")
    try:
        number = operator.index(value)
    except TypeError:
        x = float(value)
        if not np.isfinite(x) or x != np.floor(x):
            raise ValueError(f"{name} must be an integer, got {_show(value)}") from None
        number = int(x)
    if (low is not None and number < low) or (high is not None and number > high):
        if high is None:
            bound = f">= {low}"
        elif low is None:
            bound = f"<= {high}"
        else:
            bound = f"in [{low}, {high}]"
        raise ValueError(f"{name} must be an integer {bound}, got {_show(value)}")
    return int(number)


def flag(value, name):
    """``value`` as a bool: ``True``/``False``, numpy booleans, or the integers 0 and 1.

    A string (``"False"`` is truthy), None or any other number raises a TypeError.

    >>> flag(np.True_, "warm_start")
    True
    >>> flag("no", "warm_start")
    Traceback (most recent call last):
    ...
    TypeError: warm_start must be True or False, got 'no' (str)
    """
    value = _scalar(value)
    if _is_bool(value):
        return bool(value)
    if isinstance(value, numbers.Integral) and int(value) in (0, 1):
        return bool(value)
    raise TypeError(f"{name} must be True or False, got {_describe(value)}")


def choice(value, name, options):
    """``value`` if it is one of ``options`` (compared with ``==``, types must match).

    >>> choice("lumped", "mass", ("lumped", "consistent"))
    'lumped'
    >>> choice("heavy", "mass", ("lumped", "consistent"))
    Traceback (most recent call last):
    ...
    ValueError: mass must be one of 'lumped', 'consistent'; got 'heavy'
    """
    for option in options:
        if type(value) is type(option) and value == option:
            return value
        if option is None and value is None:
            return value
    listed = ", ".join(repr(o) for o in options)
    got = repr(value) if isinstance(value, str) else _describe(value)
    raise ValueError(f"{name} must be one of {listed}; got {got}")


def real_array(value, name, shape=None, low=None, high=None, include_low=True, include_high=True,
               finite=True):
    """``value`` as a float numpy array of real numbers, with an optional shape and range.

    Strings, booleans, None and complex numbers inside are refused (``np.asarray(..., float)``
    would turn ``"1.5"`` into 1.5 and ``True`` into 1.0).

    Parameters
    ----------
    value : array_like
    name : str
        The argument's name, used in the error message.
    shape : tuple, optional
        Required shape; an entry ``None`` matches any length.
    low, high, include_low, include_high, finite
        As in :func:`real`, for every entry.

    Returns
    -------
    numpy.ndarray
        A new float64 array (the caller may modify it).

    Examples
    --------
    >>> real_array([0, 0, 1], "normal", shape=(3,))
    array([0., 0., 1.])
    >>> real_array(["0", "0", "1"], "normal", shape=(3,))
    Traceback (most recent call last):
    ...
    TypeError: normal must be a real number or an array of real numbers, got ['0', '0', '1'] (list)
    """
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError):  # ragged nested sequences
        raise TypeError(f"{name} must be an array of real numbers, got {_describe(value)}") from None
    if raw.dtype.kind == "O":
        flat = raw.ravel()
        if not all(isinstance(v, numbers.Real) and not _is_bool(v) for v in flat):
            raise TypeError(f"{name} must be a real number or an array of real numbers, got {_describe(value)}")
    elif raw.dtype.kind not in "iuf" or (not isinstance(value, np.ndarray) and _holds_bool(value)):
        # (a bool among numbers is converted to 0/1 by np.asarray: found in the sequence itself)
        raise TypeError(f"{name} must be a real number or an array of real numbers, got {_describe(value)}")
    a = np.array(raw, dtype=float)
    if shape is not None and (a.ndim != len(shape) or any(s is not None and s != k for s, k in zip(shape, a.shape))):
        want = "(" + ", ".join("k" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
        raise ValueError(f"{name} must have shape {want}, got shape {a.shape}")
    bad = np.isnan(a) | (np.isinf(a) if finite else False)
    if np.any(bad):
        if a.ndim == 0:
            raise ValueError(f"{name} must be finite, got {float(a)!r}")
        raise ValueError(f"{name} must be finite, got {int(bad.sum())} non-finite (NaN/inf) entries "
                         f"(first at index {_first_index(bad)})")
    if low is not None or high is not None:
        out = ~_in_range(a, low, high, include_low, include_high)
        if np.any(out):
            where = f" at index {_first_index(out)}" if a.ndim else ""
            raise ValueError(f"{name} must lie in {_interval(low, high, include_low, include_high)}, "
                             f"got {_show(a[out].ravel()[0])}{where}")
    return a


def _holds_bool(value):
    """Whether a (nested) sequence holds a bool (``[0, 0, True]``, ``[1e5, np.True_]``)."""
    if isinstance(value, (list, tuple)):
        return any(_holds_bool(v) for v in value)
    return _is_bool(value) or (isinstance(value, np.ndarray) and value.dtype.kind == "b")


def _first_index(mask):
    idx = np.argwhere(mask)[0]
    return int(idx[0]) if idx.size == 1 else tuple(int(i) for i in idx)
