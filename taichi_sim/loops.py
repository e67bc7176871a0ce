"""Serial loops that LLVM can vectorise: each memory tree's base address looked up once.

Taichi groups the fields allocated between two kernel launches into one memory tree and finds
a field's data through the runtime's table of tree roots, at each access. In a loop that
stores to any field, LLVM cannot prove that the stores leave that table alone, so it reads the
root again on every iteration, and a loop with such a read in it is not vectorised. Taichi's
own common-subexpression pass replaces the lookups inside a loop with one made before it, in
the same serial task, when there is one: :func:`anchor` makes one, as a store of a field's
first element to itself (nothing changes, and in a serial task no other thread can be
writing it). A loop whose every tree is anchored keeps its base addresses in registers and
vectorises where its body allows (measured on a 16 384-particle stage combination, 2 vCPUs:
about 40 us scalar, 20 us anchored).

Use (CPU, serial):

    ti.loop_config(serialize=True)
    for _ in range(1):           # one serial task: the anchors and the loop
        anchor(a.x)
        anchor(b.x)
        for i in range(n):
            b.x[i] = 2 * a.x[i]

Parallel loops (a GPU, or a CPU loop worth its threads) gain nothing from it: their body is
compiled as a function called per iteration, which LLVM does not vectorise.
"""

import taichi as ti


@ti.func
def anchor(field: ti.template()):
    """Store ``field``'s first element to itself (see the module docstring); call it in the
    serial task of the loop it serves, before the loop."""
    if ti.static(len(field.shape) == 0):
        field[None] = field[None]
    elif ti.static(len(field.shape) == 1):
        field[0] = field[0]
    elif ti.static(len(field.shape) == 2):
        field[0, 0] = field[0, 0]
    else:
        ti.static_assert(len(field.shape) == 3, "anchor: fields of up to three dimensions")
        field[0, 0, 0] = field[0, 0, 0]
