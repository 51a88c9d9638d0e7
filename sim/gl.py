"""Import pyrender with the OSMesa platform, in one place.

PYOPENGL_PLATFORM must be set before anything imports OpenGL (NOTES.md).
pyrender 0.1.45 still uses ``np.infty`` (removed in NumPy 2) in ``Mesh.bounds``;
the alias below keeps those code paths working.
"""

from __future__ import annotations

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")

import numpy as np  # noqa: E402

if not hasattr(np, "infty"):
    np.infty = np.inf  # pyrender 0.1.45 uses np.infty, removed in NumPy 2

import pyrender  # noqa: E402

__all__ = ["pyrender"]
