"""Kernels compiled without Taichi's CFG pass: the switch, and the stages that use it."""
import numpy as np
from helpers import cloth_builder
from taichi.lang import impl

import taichi_sim as ts
from taichi_sim import runtime
from taichi_sim.collide import SelfCollision
from taichi_sim.scene.colliders import SpherePath
from taichi_sim.scene.colliders.faces import FaceContact


def cfg_optimisation() -> bool:
    return impl.current_cfg().cfg_optimization


def test_the_switch_turns_the_pass_off_inside_nested_blocks_and_back_on_after(f64):
    assert cfg_optimisation()
    with runtime.without_cfg_optimisation():
        assert not cfg_optimisation()
        with runtime.without_cfg_optimisation():
            assert not cfg_optimisation()
        assert not cfg_optimisation()  # the inner block leaves the outer one's setting
    assert cfg_optimisation()
    try:
        with runtime.without_cfg_optimisation():
            raise KeyError("out of the block")
    except KeyError:
        pass
    assert cfg_optimisation()


def spy(monkeypatch, obj, name: str) -> list:
    """Record the CFG setting at each call of ``obj.name`` (a kernel: Taichi binds it to its
    object on each lookup, so the spy sits on the object, not its class)."""
    seen = []
    original = getattr(obj, name)

    def wrapper(*args):
        seen.append(cfg_optimisation())
        return original(*args)

    monkeypatch.setattr(obj, name, wrapper)
    return seen


def test_the_self_contact_stage_and_the_face_rounds_compile_without_the_pass(f64, monkeypatch):
    b = cloth_builder(n=4, size=0.3, height=0.12)
    b.add_box(SpherePath((0.0, 0.0, 0.0)), (0.1, 0.1, 0.1))
    b.set_gravity(9.8)
    b.enable_self_collision(0.005, 0.0, 2)
    scene = b.finalize(name="t", params={}, default_dt=1e-3, default_integrator="symplectic_euler")
    (stage,) = [e for e in scene.post_step if isinstance(e, SelfCollision)]
    (boxes,) = [e for e in scene.post_step if isinstance(e, FaceContact)]
    rounds, faces = spy(monkeypatch, stage, "_resolve"), spy(monkeypatch, boxes, "_face_round")
    assert ts.run(scene, "symplectic_euler", dt=1e-3, steps=3).status.value == "ok"
    assert rounds and faces and not any(rounds) and not any(faces)
    assert cfg_optimisation()  # and on again for whatever compiles next
    assert np.isfinite(scene.state.to_numpy()[0]).all()
