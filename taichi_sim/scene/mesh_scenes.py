"""The ``mesh`` scene: a triangle mesh file as cloth (docs/meshes.md)."""
from typing import Any

from .builder import SceneBuilder
from .garment import skirt_mesh
from .mesh_cloth import MESH_CLOTH_PARAMS, add_mesh_cloth, finish_mesh_cloth, mesh_size
from .mesh_import import ClothMesh, load_mesh
from .params import Param
from .preset import ScenePreset
from .scene import Scene

MESH_FILE_PARAMS: tuple[Param, ...] = (
    Param("file", "", "path", "the mesh file (OBJ, PLY, STL, OFF, glTF or GLB); empty: the toolkit's "
          "own skirt (scene garment, without the body)"),
    Param("scale", 1.0, "", "file units to metres (0.01 for a file in cm)", minimum=0.0, exclusive=True),
    Param("up", "y", "", "the file's up axis: y, or z (rotated to y-up)", choices=("y", "z")),
    Param("weld", 1e-6, "m", "vertices closer than this merge (they were split along UV seams or "
          "normal creases)", minimum=0.0),
)


def scene_mesh(p: dict[str, Any]) -> ClothMesh:
    """The mesh of the ``mesh`` scene: ``file`` as loaded, or the built-in skirt."""
    if not p["file"]:
        return skirt_mesh()
    return load_mesh(p["file"], weld=p["weld"], scale=p["scale"], up=p["up"])


def build_mesh(preset: ScenePreset, p: dict[str, Any], seed: int) -> Scene:
    b = SceneBuilder()
    add_mesh_cloth(b, p, seed, scene_mesh(p), default_thickness=preset.param("thickness").default)
    return finish_mesh_cloth(preset, b, p, seed)


MESH = ScenePreset(
    "mesh", "any triangle mesh file as cloth (--set file=shirt.obj pin=top:0.02): stretch springs on "
    "its edges, bending springs across them, mass from its area; the cloth extras apply",
    MESH_FILE_PARAMS + MESH_CLOTH_PARAMS, build_mesh, default_dt=1 / 60,
    default_integrator="xpbd", size=lambda p: mesh_size(scene_mesh(p), p["bending"], p["material"]),
    size_params=("file",))
