"""``aobake.vectors``' replacements for np.unique on integers (numpy 2 hashes them, which is
slow when most values are distinct): the same values, in the same order, as np.unique."""

import numpy as np
import pytest

from aobake.vectors import distinct, unique_ints


@pytest.mark.parametrize("size", [0, 1, 2, 17, 5000])
def test_unique_ints_is_np_unique(size):
    rng = np.random.default_rng(size)
    for dtype in (np.int64, np.int32, np.uint32):
        values = rng.integers(0 if dtype == np.uint32 else -50, 60, size).astype(dtype)
        got, want = unique_ints(values), np.unique(values)
        np.testing.assert_array_equal(got, want)
        assert got.dtype == want.dtype


def test_unique_ints_takes_any_shape_and_leaves_its_input():
    values = np.array([[3, 1], [3, 2]])
    np.testing.assert_array_equal(unique_ints(values), [1, 2, 3])
    np.testing.assert_array_equal(values, [[3, 1], [3, 2]])


@pytest.mark.parametrize("size", [0, 1, 300])
def test_distinct_is_np_unique_of_bounded_indices(size):
    index = np.random.default_rng(size).integers(0, 40, (size, 3))
    np.testing.assert_array_equal(distinct(index, 40), np.unique(index))
