"""The frontend caches (taichi_sim/frontend_cache.py) give Taichi exactly the answers it would
have computed itself, on the package's own kernels compiled twice."""
import importlib
import sys

import pytest
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


def _write_module(folder, name, annotation, missing):
    (folder / f"{name}.py").write_text(
        "import taichi as ti\n\n\n@ti.kernel\ndef value() -> ti.f32:\n"
        f"    a: {annotation} = 0.7\n    return a\n\n\n@ti.kernel\ndef broken():\n    x = {missing}\n")


def test_kernels_with_equal_code_but_other_source_compile_their_own_source(tmp_path, monkeypatch):
    """Code objects compare equal when only a local annotation (which Taichi reads from the
    source) differs, and a reloaded module has new ones: neither may be given the source or
    the error text of another."""
    ts.init(precision="f32")
    # no bytecode: the edit below keeps the file's size, and a cached .pyc would hide it
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    _write_module(tmp_path, "fc_float", "ti.f32", "undefined_one")
    _write_module(tmp_path, "fc_int", "ti.i32", "undefined_one")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "fc_float", raising=False)
    monkeypatch.delitem(sys.modules, "fc_int", raising=False)
    as_float, as_int = importlib.import_module("fc_float"), importlib.import_module("fc_int")
    assert as_float.value._primal.func.__code__ == as_int.value._primal.func.__code__
    assert as_float.value() == pytest.approx(0.7) and as_int.value() == 0
    with pytest.raises(Exception, match="undefined_one"):
        as_float.broken()

    _write_module(tmp_path, "fc_float", "ti.i32", "undefined_two")  # edited, then reloaded
    importlib.reload(as_float)
    assert as_float.value() == 0
    with pytest.raises(Exception) as error:
        as_float.broken()
    assert "x = undefined_two" in str(error.value) and "undefined_one" not in str(error.value)
