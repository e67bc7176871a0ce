"""Object colliders: post-step events that keep particles out of spheres (moving, spinning),
capsules, boxes, a triangle mesh and a plane, with Coulomb friction (see each module for what is
continuous). Each analytic kind is one module that registers itself (:mod:`.shape`); importing
this package registers the built-in ones."""
from .box import Box, BoxColliders
from .capsule import Capsule, CapsuleColliders
from .mesh_collider import MeshObstacle
from .mesh_frames import load_mesh_file
from .path import SpherePath
from .plane import GroundPlane, PlaneCollider
from .shape import Shape, face_depths, faces_inside, inside_objects, object_depths, register_shape, shapes
from .sphere import Sphere, SphereColliders
from .translating import TranslatingShapes

__all__ = ["Box", "BoxColliders", "Capsule", "CapsuleColliders", "GroundPlane", "MeshObstacle", "load_mesh_file", "PlaneCollider",
           "Shape", "Sphere", "SphereColliders", "SpherePath", "TranslatingShapes", "face_depths", "faces_inside",
           "inside_objects", "object_depths", "register_shape", "shapes"]
