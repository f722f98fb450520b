"""Connected components of a grid's free cells (4-connected)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy import ndimage

_FOUR_CONNECTED = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], dtype=bool)


def component_labels(free: npt.NDArray[np.bool_]) -> npt.NDArray[np.int32]:
    """Label each free cell with its 4-connected component (1, 2, ...); obstacles get 0.

    ``free`` is indexed ``[y, x]`` like :attr:`Grid.free`.
    """
    labels, _ = ndimage.label(np.asarray(free, dtype=bool), structure=_FOUR_CONNECTED)
    return np.asarray(labels, dtype=np.int32)


def largest_component(free: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """The mask of the largest 4-connected component of ``free`` (all False if none is free)."""
    labels = component_labels(free)
    sizes = np.bincount(labels.ravel())
    if sizes.size <= 1:
        return np.zeros_like(labels, dtype=bool)
    sizes[0] = 0
    return np.asarray(labels == int(np.argmax(sizes)), dtype=bool)


def is_connected(free: npt.NDArray[np.bool_]) -> bool:
    """True if the free cells form one 4-connected component (and there is at least one)."""
    labels = component_labels(free)
    return int(labels.max()) == 1
