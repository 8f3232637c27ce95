"""Voxel rendering draws exactly the faces not hidden by a filled neighbour."""

import numpy as np
import pytest

from nbvdata.render import exposed_faces


@pytest.mark.parametrize("block, faces", [((1, 1, 1), 6), ((2, 1, 1), 10), ((3, 3, 3), 54)])
def test_exposed_faces_of_a_block(block, faces):
    filled = np.zeros((6, 6, 6), dtype=bool)
    filled[1:1 + block[0], 2:2 + block[1], 0:block[2]] = True
    colors = np.ones((6, 6, 6, 4))
    quads, face_colors = exposed_faces(filled, colors)
    assert quads.shape == (faces, 4, 3) and face_colors.shape == (faces, 4)
    edges = np.linalg.norm(np.diff(quads, axis=1, append=quads[:, :1]), axis=2)
    assert np.allclose(edges, 1.0)  # unit squares
    low, high = quads.reshape(-1, 3).min(axis=0), quads.reshape(-1, 3).max(axis=0)
    assert np.array_equal(low, [1, 2, 0]) and np.array_equal(high - low, block)  # on the block's hull
