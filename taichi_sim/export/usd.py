"""One USD stage holding a run: a ``UsdGeom.Mesh`` (or, without a surface, ``UsdGeom.Points``)
under ``/World`` whose ``points`` and ``extent`` have a time sample per frame.

Time codes are frame numbers: ``timeCodesPerSecond`` (and ``framesPerSecond``) is one over the
interval between saved frames, so a frame at t seconds sits at time code t * timeCodesPerSecond
(whole numbers for evenly spaced frames; a shortened last step or an adaptive run gives
fractional ones, which USD allows). Up axis Y and 1 metre per unit, as the simulation."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

if TYPE_CHECKING:
    from . import Frames

SUFFIXES = (".usda", ".usdc", ".usd")  # text, binary (crate), and crate under the plain suffix


def time_codes(times: np.ndarray) -> tuple[float, np.ndarray]:
    """``(timeCodesPerSecond, time code of each frame)`` for frame times ``times`` (s): one code
    per median frame interval, codes within 1e-6 of a whole number made whole (rounding in
    the stored times would otherwise leave 2.9999999997)."""
    times = np.asarray(times, np.float64)
    if len(times) < 2:
        return 24.0, np.zeros(len(times))  # one frame: no interval to go by; USD's own default
    per_second = float(f"{1.0 / float(np.median(np.diff(times))):.9g}")
    codes = (times - times[0]) * per_second
    whole = np.round(codes)
    return per_second, np.where(np.abs(codes - whole) < 1e-6, whole, codes)


def prim_name(name: str) -> str:
    """A valid USD prim name for a scene name (``cloth-sphere`` -> ``cloth_sphere``)."""
    from pxr import Tf

    return Tf.MakeValidIdentifier(name) or "run"


def write_stage(path: Path, frames: "Frames", on_frame: Callable[[], object] = lambda: None) -> None:
    """Write ``frames`` as a USD stage at ``path`` (its suffix picks text or crate)."""
    from pxr import Gf, Usd, UsdGeom, Vt

    per_second, codes = time_codes(frames.times)
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(per_second)
    stage.SetFramesPerSecond(per_second)
    stage.SetStartTimeCode(float(codes[0]))
    stage.SetEndTimeCode(float(codes[-1]))
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    where = f"/World/{prim_name(frames.name)}"
    if frames.triangles is not None and len(frames.triangles):
        geometry = UsdGeom.Mesh.Define(stage, where)
        triangles = np.ascontiguousarray(frames.triangles, np.int32)
        geometry.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(triangles), 3, np.int32)))
        geometry.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(triangles.ravel()))
        # a cloth is a sheet of triangles: no subdivision surface, seen from both sides
        geometry.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        geometry.CreateDoubleSidedAttr(True)
    else:
        geometry = UsdGeom.Points.Define(stage, where)
    points, extent = geometry.CreatePointsAttr(), geometry.CreateExtentAttr()
    for code, x in zip(codes, frames.positions):
        x32 = np.ascontiguousarray(x, np.float32)
        time = Usd.TimeCode(float(code))
        points.Set(Vt.Vec3fArray.FromNumpy(x32), time)
        extent.Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, x32.min(axis=0))), Gf.Vec3f(*map(float, x32.max(axis=0)))]),
                   time)
        on_frame()
    layer = stage.GetRootLayer()
    layer.documentation = f"taichi_sim run of {frames.name}: {len(codes)} frames, t = {frames.times[0]:g} to " \
                          f"{frames.times[-1]:g} s"
    if not layer.Export(str(path)):
        raise OSError(f"USD could not write {path}")
