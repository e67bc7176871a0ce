"""The frontend caches (taichi_sim/frontend_cache.py) give Taichi exactly the answers it would
have computed itself, on the package's own kernels compiled twice."""
from taichi.lang.ast import ast_transformer_utils

import taichi_sim as ts
from taichi_sim import frontend_cache


def test_every_cached_answer_is_the_one_taichi_computes(monkeypatch):
    ts.init(precision="f32")
    assert frontend_cache.installed()
    context = ast_transformer_utils.ASTTransformerContext
    cached = context.get_pos_info
    original = frontend_cache.ORIGINALS["get_pos_info"]
    checked, wrong = [0], []

    def compare(ctx, node):
        answer = cached(ctx, node)
        checked[0] += 1
        if answer != original(ctx, node):
            wrong.append(answer)
        return answer

    monkeypatch.setattr(context, "get_pos_info", compare)
    for _ in range(2):  # the second compile answers from the caches
        ts.init(precision="f32")
        scene = ts.build_scene("cloth", {"nx": 6, "ny": 6, "self_collision": True}, seed=1)
        ts.run(scene, "implicit_euler", dt=1e-3, t_end=2e-3)
    assert checked[0] > 1000 and not wrong, wrong[:1]


def test_source_lines_are_taichis_for_every_kernel():
    ts.init(precision="f32")
    scene = ts.build_scene("cloth", {"nx": 6, "ny": 6}, seed=1)
    ts.run(scene, "vbd", dt=1e-3, t_end=2e-3)
    from taichi.lang import kernel_impl
    original = frontend_cache.ORIGINALS["getsourcelines"]
    functions = [f for f in _taichi_functions() if getattr(f, "__code__", None) is not None]
    assert len(functions) > 20
    for function in functions:
        assert kernel_impl.getsourcelines(function) == original(function)


def _taichi_functions():
    """The Python functions behind the package's kernels and ti.funcs."""
    import gc

    from taichi.lang.kernel_impl import Func, Kernel
    return [obj.func for obj in gc.get_objects()
            if isinstance(obj, (Kernel, Func)) and obj.func.__module__.startswith("taichi_sim")]
