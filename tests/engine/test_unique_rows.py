"""geometry.unique_rows: numpy's unique over integer rows, to the element, in the same order."""

from __future__ import annotations

import numpy as np
import pytest

from ovrad_addon.geometry import unique_rows


def _as_tuple(x):
    return x if isinstance(x, tuple) else (x,)


@pytest.mark.parametrize("dtype", [np.int64, np.int32, np.int8])
@pytest.mark.parametrize("shape", [(2000, 3), (7, 2), (1, 4), (0, 3), (500, 6)])
def test_unique_rows_is_numpys_unique_over_rows(dtype, shape):
    rng = np.random.default_rng(shape[0] + shape[1])
    rows = rng.integers(-40, 40, shape).astype(dtype)
    for index in (False, True):
        for inverse in (False, True):
            for counts in (False, True):
                want = _as_tuple(
                    np.unique(rows, axis=0, return_index=index, return_inverse=inverse, return_counts=counts)
                )
                got = _as_tuple(unique_rows(rows, index, inverse, counts))
                assert len(got) == len(want)
                np.testing.assert_array_equal(got[0], want[0])
                for g, w in zip(got[1:], want[1:], strict=True):
                    np.testing.assert_array_equal(g, np.ravel(w))


def test_rows_too_wide_for_one_key_fall_back_to_numpy():
    rows = np.array([[0, 0, 0], [2**40, 2**40, 1], [5, 3, 2**40], [5, 3, 2**40]])
    uniq, inverse, counts = unique_rows(rows, return_inverse=True, return_counts=True)
    want = np.unique(rows, axis=0, return_inverse=True, return_counts=True)
    np.testing.assert_array_equal(uniq, want[0])
    np.testing.assert_array_equal(inverse, np.ravel(want[1]))
    np.testing.assert_array_equal(counts, want[2])
    assert len(uniq) == 3
