"""File formats: BVH (:mod:`.bvh`) and glTF 2.0 / GLB characters (:mod:`.gltf`)."""
from __future__ import annotations

from pathlib import Path

__all__ = ["read_character"]


def read_character(path):
    """The character (mesh and skin) a file holds, or None (a BVH)."""
    if Path(path).suffix.lower() not in (".glb", ".gltf"):
        return None
    from .gltf import read_gltf
    return read_gltf(path)
