"""The upper-triangle form of a symmetric matrix, shared by the wire, the envelope and the session files."""

import numpy as np
import pytest

from seesys.core.upper_triangle import symmetric_3x3, symmetric_from_upper, upper_triangle


def test_a_stack_of_symmetric_matrices_survives_its_upper_triangles_row_by_row():
    a = np.random.default_rng(1).normal(size=(4, 6, 6))
    symmetric = a + a.transpose(0, 2, 1)
    rows = upper_triangle(symmetric)
    assert rows.shape == (4, 21) and rows[0, :6].tolist() == symmetric[0, 0].tolist()  # row 0 first
    assert np.array_equal(symmetric_from_upper(rows), symmetric)
    assert symmetric_from_upper(np.arange(6.0)).tolist() == [[0, 1, 2], [1, 3, 4], [2, 4, 5]]


def test_values_that_are_no_triangle_are_refused():
    with pytest.raises(ValueError, match="5 values are no square matrix's upper triangle"):
        symmetric_from_upper(np.zeros(5))


def test_a_three_by_three_from_six_values_is_the_general_matrix_to_the_last_bit():
    rng = np.random.default_rng(3)
    values = np.concatenate([rng.normal(size=(50, 6)) * 10.0 ** rng.uniform(-12, 3, (50, 1)), [[0.0, -0.0] * 3]])
    for row in values:
        built = symmetric_3x3(*row.tolist())
        assert built.dtype == np.float64 and built.shape == (3, 3)
        assert built.tobytes() == symmetric_from_upper(row).tobytes()
    assert symmetric_3x3(0, 1, 2, 3, 4, 5).tolist() == [[0, 1, 2], [1, 3, 4], [2, 4, 5]]
