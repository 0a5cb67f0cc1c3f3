"""Attitude arithmetic on NumPy arrays (the CasADi model has its own symbolic forms in `uam_fdm.vehicle.model`).

Quaternions are unit [w, x, y, z], body FLU -> world ENU.
"""
from __future__ import annotations

import numpy as np


def rotation_matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices body -> world (K, 3, 3) of unit quaternions (K, 4) [w, x, y, z]."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
                     np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
                     np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1)], axis=1)


def rotation_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix body -> world (3, 3) of a unit quaternion (4,) [w, x, y, z]."""
    return rotation_matrices(np.asarray(q, float)[None])[0]
