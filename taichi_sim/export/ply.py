"""Stanford PLY frames, binary little-endian: float vertex coordinates and, with a surface, a
``face`` element of 3-index lists.

Our own writer rather than trimesh's: the header and the face block are the same in every
frame of a run, so they are packed once and each frame writes its positions as one block."""
from __future__ import annotations

from typing import BinaryIO, Callable

import numpy as np

_FACE = np.dtype([("count", "u1"), ("ids", "<i4", (3,))])


def frame_writer(triangles: np.ndarray | None, name: str) -> Callable[[BinaryIO, np.ndarray, float], None]:
    """A writer of one frame: ``write(file, positions (n, 3) in m, t in s)``. Without
    ``triangles`` the file holds the vertices alone (a point cloud)."""
    faces = b""
    if triangles is not None and len(triangles):
        table = np.empty(len(triangles), _FACE)
        table["count"] = 3
        table["ids"] = triangles
        faces = table.tobytes()
    face_count = 0 if not faces else len(triangles)

    def write(f: BinaryIO, positions: np.ndarray, t: float) -> None:
        header = ["ply", "format binary_little_endian 1.0", f"comment taichi_sim {name}, t = {float(t)!r} s",
                  f"element vertex {len(positions)}", "property float x", "property float y",
                  "property float z"]
        if face_count:
            header += [f"element face {face_count}", "property list uchar int vertex_indices"]
        f.write(("\n".join(header + ["end_header"]) + "\n").encode("ascii"))
        f.write(np.ascontiguousarray(positions, "<f4").tobytes())
        f.write(faces)

    return write
