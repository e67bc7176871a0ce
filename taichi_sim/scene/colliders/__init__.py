"""Object colliders: post-step events that keep particles out of spheres (moving, spinning),
capsules, boxes, a triangle mesh and a plane, with Coulomb friction (see each module for what is continuous)."""
from .mesh_collider import MeshObstacle
from .mesh_frames import load_mesh_file
from .path import SpherePath
from .plane import PlaneCollider
from .shapes import Box, BoxColliders, Capsule, CapsuleColliders
from .sphere import Sphere, SphereColliders

__all__ = ["Box", "BoxColliders", "Capsule", "CapsuleColliders", "MeshObstacle", "load_mesh_file", "PlaneCollider", "Sphere", "SphereColliders",
           "SpherePath"]
