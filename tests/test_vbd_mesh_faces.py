"""The cloth's triangles against a collider mesh's sharp edges and vertices inside vertex block
descent (integrators/positional/vbd/mesh_faces.py): a cloth falling at 3 m/s onto a small mesh
box narrower than its spacing, lying between its vertices, so that no vertex comes near it; the
box held by the faces, judged each step by geometry written apart from the kernels. A cloth
with self-contact draped over a mesh box through the CLI, judged by `taichi-sim check`. And
which edges and vertices of a mesh are features at a cloth's scale."""
import numpy as np
import pytest
import trimesh
from test_object_faces import box_meets_cloth
from test_vbd_faces import BELOW, DT, SPEED, STEPS, fall, falling_cloth, upward_crossings
from test_vbd_mesh_contact import simulate_and_check

from taichi_sim.integrators.positional.vbd.mesh_faces import sharp_features

HALF = 0.006  # the box's half side (m): it passes between vertices 0.012 m away
SKIN = 0.002  # (m) with the 5 mm contact radius, nearer the box than the nearest vertex comes


def add_mesh_box(b, path):
    box = trimesh.creation.box(extents=(2 * HALF, 2 * HALF, 2 * HALF))
    b.add_mesh_collider(box.vertices, box.faces, path=path, skin=SKIN)


@pytest.mark.parametrize("serial", [None, False])
def test_a_mesh_box_narrower_than_the_spacing_holds_the_faces_that_fall_on_it(f64, serial):
    """serial=False: the kernels of large cloths and GPUs (a query kernel, one per colour)."""
    scene, tris = falling_cloth(add_mesh_box)
    centre, half = np.asarray(BELOW), np.full(3, HALF)

    def stays_out(x):
        assert not box_meets_cloth(x, tris, centre, half)

    x = fall(scene, stays_out, serial=serial)
    assert x[:, 1].min() < -0.2  # the cloth round it fell on past it
    assert upward_crossings(x, tris, BELOW) >= 1  # and over it


def test_with_object_faces_off_the_same_mesh_box_passes_between_the_vertices(f64):
    scene, tris = falling_cloth(add_mesh_box)
    x = fall(scene, lambda x: None, object_faces=False)
    assert x[:, 1].max() < -0.5  # the whole cloth fell past the box (held by nothing)
    assert upward_crossings(x, tris, BELOW) == 0


@pytest.mark.parametrize("faces", [True, False])
def test_a_cloth_draped_over_a_mesh_box_has_no_face_inside_it(tmp_path, capsys, faces):
    """A 12 x 12 cloth with self-contact falls 0.1 m onto a 0.3 m mesh box and drapes over its
    edges, every step saved and checked; without the faces in the solve (object_faces=0) the
    edges poke between its vertices (16.6 mm deep, in 12 of 21 frames saving every third step)."""
    box = str(tmp_path / "box.obj")
    trimesh.creation.box(extents=(0.3, 0.2, 0.3)).export(box)
    report = simulate_and_check(capsys, [
        "cloth", "--set", "pin=none", "--set", "nx=12", "--set", "ny=12", "--set", "height=0.3",
        "--set", "self_collision=1", "--set", f"collider_mesh={box}", "--t-end", "1",
        *([] if faces else ["--option", "object_faces=0"])], str(tmp_path / "drape.npz"))
    assert "no triangles intersect" in report
    assert "no vertex inside the collider mesh in any frame" in report
    assert ("no face reaches into the collider mesh in any frame" in report) == faces, report
    x = np.load(tmp_path / "drape.npz")["x_history"][-1]
    assert x[:, 1].max() > 0.1 and x[:, 1].min() < 0.0  # over the box's top (y = 0.1), its sides hanging


def test_a_box_has_its_twelve_edges_and_no_diagonal_for_features():
    box = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    v, t = np.asarray(box.vertices), np.asarray(box.faces)
    features = sharp_features(v[None], t, orientation=1, dip_length=0.02, skin=0.005)
    assert len(features) == 12 and (features[:, 0] != features[:, 1]).all()
    length = np.linalg.norm(v[features[:, 0]] - v[features[:, 1]], axis=1)
    assert np.allclose(length, 0.2)  # the sides, not the faces' diagonals (0.28 m)


def test_a_sphere_is_sharp_only_for_a_coarse_cloth_and_a_dent_never():
    """An icosphere's faces turn by at most 11.4 degrees across an edge: a cloth triangle of
    circumradius rho lying across one has it at most rho sin(5.7 degrees) above its plane, under
    half the 5 mm skin for rho = 1 cm, over it at some edges for 3 cm. Wound inside out (a dent:
    every edge concave, every vertex a pit) it has none; as a two-sided shell, the same as
    outside."""
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    v, t = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    assert len(sharp_features(v[None], t, 1, 0.01, 0.005)) == 0
    coarse = sharp_features(v[None], t, 1, 0.03, 0.005)
    assert 0 < len(coarse)
    assert len(sharp_features(v[None], t[:, ::-1], 1, 0.03, 0.005)) == 0  # every edge concave
    assert len(sharp_features(v[None], t[:, ::-1], 0, 0.03, 0.005)) == len(coarse)  # two-sided


def test_a_mesh_box_rising_into_a_resting_cloth_lifts_it_by_its_faces(f64):
    """The box rises at 3 m/s, 0.03 m a step, into a cloth at rest, its top between vertices.
    With sharp features near the cloth a piece lets the body move 0.8 bound_fraction of the
    distance a face keeps from them (skin and contact radius: 2.2 mm); at the vertices' pace
    alone (8.6 mm a piece, more than those 7 mm) its edges went through a face in the second
    step."""
    from taichi_sim.scene.colliders import SpherePath

    scene, tris = falling_cloth(lambda b, path: add_mesh_box(b, SpherePath(BELOW, velocity=(0.0, SPEED, 0.0))),
                                speed=0.0)
    half = np.full(3, HALF)

    def stays_out(x, k=[0]):
        k[0] += 1
        centre = np.add(BELOW, (0.0, SPEED * DT * k[0], 0.0))
        assert not box_meets_cloth(x, tris, centre, half)

    x = fall(scene, stays_out)
    top = BELOW[1] + SPEED * DT * STEPS
    assert x[:, 1].max() > top  # carried up on the box
    assert upward_crossings(x, tris, (BELOW[0], top, BELOW[2])) >= 1  # over it
