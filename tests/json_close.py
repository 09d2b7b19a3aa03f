"""Comparing JSON documents of numbers (truth files, ``CycleResult.to_json``) within a stated tolerance."""

import numpy as np
from numpy.testing import assert_allclose


def assert_json_close(actual, expected, rtol: float, atol: float = 0.0, where: str = "") -> None:
    """Same keys and strings; numbers (and lists of numbers) equal within rtol/atol, NaN equal to NaN."""
    if isinstance(expected, dict):
        assert actual.keys() == expected.keys(), where
        for k in expected:
            assert_json_close(actual[k], expected[k], rtol, atol, f"{where}.{k}")
    elif isinstance(expected, list | tuple) and expected and isinstance(expected[0], dict | list | tuple | str):
        assert len(actual) == len(expected), where
        for i, (a, b) in enumerate(zip(actual, expected)):
            assert_json_close(a, b, rtol, atol, f"{where}[{i}]")
    elif isinstance(expected, float | int | list | tuple) and not isinstance(expected, bool):
        assert_allclose(np.asarray(actual, dtype=float), np.asarray(expected, dtype=float), rtol=rtol, atol=atol,
                        equal_nan=True, err_msg=where)
    else:
        assert actual == expected, where
