"""The Python API given a method that is not a string (an array, a number): a ConfigError naming
the methods, never numpy's "truth value of an array is ambiguous"."""

from __future__ import annotations

import numpy as np
import pytest

import hsio
from hsio.errors import ConfigError


@pytest.mark.parametrize("method", [np.array([1.0, np.nan]), np.array(["alpha_os", "mixed"]), 3, None])
def test_a_method_that_is_not_a_string_is_named(method):
    structure = hsio.load_structure("structure_I")
    with pytest.raises(ConfigError, match="method must be one of alpha_os"):
        hsio.run_numerical(structure, hsio.synthetic_record(duration_s=1.0), method)
    with pytest.raises(ConfigError, match="method must be one of alpha_os"):
        hsio.make_integrator(structure, method)
