"""Collision meshes kept on disk between commands: making them loads trimesh, about a second of
every trial's start; reading them back takes a millisecond.

Each mesh is one ``.npz`` file (its vertices and faces) named by a digest of everything it depends on
(the shape's kind, size and scale, a mesh file's bytes, trimesh's version and :data:`CACHE_VERSION`), under
``$XDG_CACHE_HOME/needle-hil-bench/shapes`` (``~/.cache`` when unset). A file that cannot be read
is made again; a folder that cannot be written leaves the shape uncached, never the command failed.
"""

from __future__ import annotations

import hashlib
import os
from importlib import metadata
from pathlib import Path
from typing import Callable

import numpy as np

__all__ = ["CACHE_VERSION", "cache_dir", "cached_mesh", "mesh_key"]

#: Part of every key: raise it when the way a shape becomes triangles changes.
CACHE_VERSION = 1


def cache_dir() -> Path:
    """Where the shapes are kept."""
    root = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(root) / "needle-hil-bench" / "shapes"


def _trimesh_version() -> str:
    try:
        return metadata.version("trimesh")
    except metadata.PackageNotFoundError:
        return "none"


def mesh_key(kind: str, size: tuple, scale: tuple = (1.0, 1.0, 1.0), mesh_file: Path | None = None) -> str:
    """The digest naming a mesh's file: ``kind`` and ``size`` say what is made (a primitive, the
    gantry's torus), ``mesh_file`` the file a mesh is read from."""
    h = hashlib.sha256()
    h.update(repr((CACHE_VERSION, _trimesh_version(), kind, tuple(float(s) for s in size),
                   tuple(float(s) for s in scale))).encode())
    if mesh_file is not None:
        h.update(Path(mesh_file).read_bytes())
    return h.hexdigest()


Mesh = tuple[np.ndarray, np.ndarray]


def _readable(path: Path) -> Mesh | None:
    try:
        with np.load(path, allow_pickle=False) as kept:
            vertices, faces = kept["vertices"], kept["faces"]
    except (OSError, ValueError, EOFError, KeyError):
        return None
    if (vertices.ndim != 2 or vertices.shape[1:] != (3,) or vertices.dtype != np.float64
            or faces.ndim != 2 or faces.shape[1:] != (3,) or faces.dtype.kind not in "iu"
            or (faces.size and (faces.min() < 0 or faces.max() >= len(vertices)))):
        return None
    return vertices, faces


def cached_mesh(key: str, make: Callable[[], Mesh]) -> Mesh:
    """The mesh (vertices, faces) kept under ``key``, or ``make()``'s, kept for the next command."""
    path = cache_dir() / f"{key}.npz"
    kept = _readable(path)
    if kept is not None:
        return kept
    vertices, faces = make()
    vertices, faces = np.asarray(vertices, dtype=float), np.asarray(faces, dtype=np.int64)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(f".{path.stem}.{os.getpid()}.npz")
        with open(partial, "wb") as f:
            np.savez(f, vertices=vertices, faces=faces)
        os.replace(partial, path)  # whole or not at all, whoever else writes it meanwhile
    except OSError:
        pass
    return vertices, faces
