"""The scene-part protocol (taichi_sim.part): a new kind of part, defined here alone, is reset,
saved to the npz, drawn, summarised and guarded with no other file knowing of it."""
from dataclasses import dataclass

import numpy as np

import taichi_sim as ts
from taichi_sim import io
from taichi_sim.geometry.primitives import box
from taichi_sim.guard import injectable_energy, scene_facts
from taichi_sim.part import MovingSource, PartSpec, ScenePart, SolidMesh
from taichi_sim.render.drawer import DrawOptions, SceneDrawer
from taichi_sim.scene.builder import SceneBuilder
from taichi_sim.scene.visual import describe

LID_HALF = np.array([0.5, 0.01, 0.5])


class LidPart(ScenePart):
    """A horizontal lid at ``height - speed t`` (m) that nothing passes upwards: after each
    step a particle above it is put on it, its velocity no faster upwards than the lid's."""

    name = "lid"
    order = 15

    def __init__(self, height: float, speed: float):
        self.height0, self.speed, self.t, self.pushed = height, speed, 0.0, 0

    @classmethod
    def from_specs(cls, specs, context):
        return cls(specs[0].height, specs[0].speed)

    def height(self) -> float:
        return self.height0 - self.speed * self.t

    def __call__(self, state, t, h):
        self.t = t
        x, v = state.to_numpy()
        above = x[:, 1] > self.height()
        x[above, 1] = self.height()
        v[above, 1] = np.minimum(v[above, 1], -self.speed)
        self.pushed += int(above.sum())
        state.from_numpy(x, v)
        return False

    def reset(self):
        self.t = 0.0

    def features(self):
        return {"lid": 1}

    def arrays(self):
        return {"lid_height": np.float64(self.height())}

    def visuals(self):
        vertices, normals, triangles = box(LID_HALF)
        return [SolidMesh(vertices, normals, triangles, place=lambda: np.array([0.0, self.height() + 0.01, 0.0]),
                          reach=LID_HALF)]

    def energy_sources(self):
        return [MovingSource("moving lid", self.speed)]

    def summary(self):
        return f"lid: {self.pushed} pushes"


@dataclass(frozen=True)
class Lid(PartSpec):
    height: float
    speed: float
    part_class = LidPart


def lid_scene():
    b = SceneBuilder()
    b.add_particles([[0.0, 0.2, 0.0], [0.1, 0.2, 0.0]], 0.5, v=[[0.0, 1.0, 0.0], [0.0, 2.0, 0.0]])
    b.add_part(Lid(height=0.25, speed=0.1))
    return b.finalize(name="lid", params={}, default_dt=0.01, default_integrator="symplectic_euler")


def test_a_part_defined_in_a_test_is_stepped_reset_saved_drawn_and_guarded(f64, tmp_path):
    scene = lid_scene()
    (lid,) = scene.parts
    assert scene.part("lid") is lid and scene.features["lid"] == 1 and scene.post_step == [lid]

    integrator = ts.create_integrator("symplectic_euler", scene.system)
    result = ts.run(scene, integrator, dt=0.01, steps=20)
    assert result.status.value == "ok"
    x = scene.state.to_numpy()[0]
    assert np.isclose(lid.height(), 0.25 - 0.1 * 0.2) and np.all(x[:, 1] <= lid.height() + 1e-12)
    assert lid.pushed > 0 and lid.summary() == f"lid: {lid.pushed} pushes"

    # saved: its keys are in the run's npz
    path = io.save_npz(tmp_path / "lid.npz", io.run_arrays(scene, result, integrator=integrator, dt=0.01))
    assert np.isclose(float(np.load(path)["lid_height"]), lid.height())

    # guarded: the guard allows what a lid moving at 0.1 m/s may give the particles
    energy, speed = injectable_energy(scene, scene_facts(scene), 1.0)["moving lid"]
    assert np.isclose(speed, 0.2) and np.isclose(energy, 0.5 * 1.0 * 0.2**2)

    # drawn: its mesh where it is now, and framed where it starts
    visual = describe(scene)
    (solid,) = visual.solids
    drawer = SceneDrawer(visual)
    drawer.sync(scene.state.x)
    drawer.update(DrawOptions(), eye=(0.0, 1.0, 3.0))
    drawn = drawer.solid_vertices.to_numpy()
    assert np.allclose(drawn, box(LID_HALF)[0] + [0.0, lid.height() + 0.01, 0.0], atol=1e-6)
    assert visual.bounds[1][0] >= 0.5  # the lid's reach, wider than the particles

    # reset: back to t = 0 with the particles
    scene.reset()
    assert lid.height() == 0.25 and scene.arrays["lid_height"] == 0.25
