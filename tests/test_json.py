"""One JSON conversion for checkpoints, stats records and the command line's ``--json``."""
import json
import math

import numpy as np
import pytest

from skfem_affine._json import jsonable


def test_numpy_scalars_and_containers_become_json():
    value = {1: (np.int64(2), np.float32(0.5)), "b": [np.bool_(True), None, "s"]}
    assert jsonable(value) == {"1": [2, 0.5], "b": [True, None, "s"]}
    assert type(jsonable(np.int64(2))) is int and type(jsonable(np.float64(0.5))) is float


def test_non_finite_floats_stay_floats_unless_strict_json_is_asked_for():
    assert math.isnan(jsonable(np.float64("nan"))) and jsonable(float("inf")) == float("inf")
    assert jsonable({"a": [np.float64("inf"), float("nan"), 1.0]}, finite=True) == {"a": [None, None, 1.0]}
    json.loads(json.dumps(jsonable([float("inf")], finite=True), allow_nan=False))


def test_other_values_are_refused():
    with pytest.raises(TypeError, match="ndarray"):
        jsonable({"a": np.zeros(2)})
    with pytest.raises(TypeError, match="object"):
        jsonable(object())
