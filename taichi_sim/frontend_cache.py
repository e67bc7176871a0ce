"""Remember two things Taichi's kernel frontend recomputes on every compile.

Taichi 1.7 turns a kernel's Python source into its IR on every compile: once per kernel and
template instance, again after every ``ti.init``, and once per call site for every ``ti.func``
it inlines. Two steps of that work depend on the source alone, yet are repeated each time:

- ``getsourcelines`` of each kernel and function (``inspect`` tokenises the whole definition),
- the source-position text attached to every IR statement (``get_pos_info``: a few lines of the
  source with a ``^^^`` marker under the node, wrapped by ``textwrap`` for error messages).

The second alone was 40 % of a compile's time in a profile of an ``implicit_euler`` cloth step.
:func:`install` wraps both in a dictionary keyed by what determines them (the function's code
object, by identity; the node's position in it), so every answer is the one Taichi would have
computed, also after a module is reloaded from an edited file, and a kernel compiled again (a
new scene, a new ``ts.init``, the next test) skips them. Entries last as long as the process,
one per code object and source position compiled. Nothing else of Taichi changes. It installs
only on the Taichi release it was written against (1.7) and only where the functions it wraps
exist; anywhere else it does nothing and compiles take their usual time.
"""
from __future__ import annotations

import taichi as ti

ORIGINALS: dict = {}
"""Taichi's own functions, by name, once :func:`install` has wrapped them (empty before; tests
compare the answers with them)."""


def installed() -> bool:
    """Whether :func:`install` wrapped Taichi's frontend in this process."""
    return bool(ORIGINALS)


def install() -> bool:
    """Wrap Taichi's source lookup and position text in caches (once per process); returns
    whether they are installed. Safe to call repeatedly."""
    if ORIGINALS:
        return True
    if tuple(ti.__version__[:2]) != (1, 7):
        return False
    try:
        from taichi.lang import kernel_impl
        from taichi.lang.ast import ast_transformer_utils, checkers
        context = ast_transformer_utils.ASTTransformerContext
        getsourcelines, get_pos_info = kernel_impl.getsourcelines, context.get_pos_info
        checkers.getsourcelines  # noqa: B018 - checkers reads it too: it must be there to wrap
    except (ImportError, AttributeError):
        return False
    source_lines = _remember_source_lines(getsourcelines)
    kernel_impl.getsourcelines = source_lines
    checkers.getsourcelines = source_lines
    context.get_pos_info = _remember_position_text(get_pos_info)
    ORIGINALS.update(getsourcelines=getsourcelines, get_pos_info=get_pos_info)
    return True


def _remember_source_lines(getsourcelines):
    """``getsourcelines(obj)`` answered once per code object: a function's source lines and
    first line number are those of its code (closures made by one factory share it). The key
    is the code object itself, by identity: equal code objects can come from different source
    (code equality ignores the file name, comments and local annotations, which Taichi reads
    from the source), and a reloaded module makes new ones. Each entry keeps its code object
    alive, so its id is not reused. Callers copy the list before changing it
    (``kernel_impl._get_tree_and_ctx``) or read one number (``checkers``)."""
    known: dict = {}

    def remembered(obj):
        code = getattr(obj, "__code__", None)
        if code is None:
            return getsourcelines(obj)
        entry = known.get(id(code))
        if entry is None or entry[0] is not code:
            entry = known[id(code)] = (code, getsourcelines(obj))
        return entry[1]

    return remembered


def _remember_position_text(get_pos_info):
    """``get_pos_info(context, node)`` answered once per source position: the text is built
    from the enclosing function's source (its file, lines, first line and indent: fixed by its
    code object, the key's first part, by identity as above), the function's name, the node's
    kind and the node's lines and columns."""
    known: dict = {}

    def remembered(context, node):
        function = context.func.func
        code = getattr(function, "__code__", None)
        if code is None:
            return get_pos_info(context, node)
        key = (id(code), function.__name__, type(node), node.lineno, node.col_offset,
               getattr(node, "end_lineno", None), getattr(node, "end_col_offset", None))
        entry = known.get(key)
        if entry is None or entry[0] is not code:
            entry = known[key] = (code, get_pos_info(context, node))
        return entry[1]

    return remembered
