"""Component labelling against the BFS distance tables (an independent oracle)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from gateway.planning.connectivity import component_labels, is_connected, largest_component
from gateway.planning.distance import distance_table
from gateway.planning.grid import Grid


@settings(max_examples=60, deadline=None)
@given(arrays(np.bool_, st.tuples(st.integers(1, 7), st.integers(1, 7))))
def test_same_label_iff_reachable(free: np.ndarray) -> None:
    grid = Grid(free)
    labels = component_labels(grid)
    assert np.array_equal(labels > 0, free)
    cells = list(grid.free_cells())
    for a in cells[:6]:
        reach = distance_table(grid, a) >= 0
        for b in cells:
            assert (labels[a[1], a[0]] == labels[b[1], b[0]]) == bool(reach[grid.index(b)])
    if cells:
        biggest = largest_component(grid)
        assert int(biggest.sum()) == max(np.bincount(labels.ravel())[1:])
        assert is_connected(grid) == (int(labels.max()) == 1)
    else:
        assert not largest_component(grid).any() and not is_connected(grid)


def test_two_rooms() -> None:
    grid = Grid(np.array([[True, False, True, True]]))
    assert component_labels(grid).tolist() == [[1, 0, 2, 2]]
    assert largest_component(grid).tolist() == [[False, False, True, True]]
