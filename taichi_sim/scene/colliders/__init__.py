"""Object colliders: post-step events that keep particles out of spheres (moving, spinning),
capsules, boxes and a plane, with Coulomb friction (see each module for what is continuous)."""
from .path import SpherePath
from .plane import PlaneCollider
from .shapes import Box, BoxColliders, Capsule, CapsuleColliders
from .sphere import Sphere, SphereColliders

__all__ = ["Box", "BoxColliders", "Capsule", "CapsuleColliders", "PlaneCollider", "Sphere", "SphereColliders",
           "SpherePath"]
