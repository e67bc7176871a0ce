"""The ``export`` command, and ``simulate --export``: a run's frames for other tools
(:mod:`taichi_sim.export`)."""
from __future__ import annotations

from ..errors import ConfigError


def export_request(args):
    """The export format of ``simulate --export``, its path checked before any work (or None)."""
    if args.export is None and args.export_format is None:
        return None
    from ..export import FORMATS, check_export_path, export_format

    if args.export is not None and args.export_format is None and any(
            str(args.export).endswith(suffix) for suffix in FORMATS["usd"].suffixes):
        args.export_format = "usd"  # the file's suffix says it
    if args.export is None or args.export_format is None:
        raise ConfigError("--export PATH and --export-format obj|ply|usd go together; give both "
                          "(a PATH ending in .usda, .usdc or .usd needs no format)")
    if not args.save_every:
        raise ConfigError("--export writes the frames that --save-every K keeps; give --save-every")

    fmt = export_format(args.export_format)
    check_export_path(args.export, fmt)
    return fmt


def export_frames(fmt, arrays, args) -> str:
    """Write the run's frames as ``fmt`` to ``args.export``; the summary line."""
    from ..export import export, frames_of

    frames = frames_of(arrays, "the run")
    path = export(frames, fmt, args.export, progress=None if not args.quiet else False)
    return f"{frames.name}: {len(frames.times)} frames as {fmt.name} -> {path}"


def cmd_export(args) -> int:
    """A saved run's frames as OBJ or PLY files in a folder, or one USD file."""
    from ..export import check_export_path, export, export_format, load_frames

    fmt = export_format(args.format)
    check_export_path(args.out, fmt)
    frames = load_frames(args.npz)
    path = export(frames, fmt, args.out, progress=None if not args.quiet else False)
    if not args.quiet:
        surface = f"{len(frames.triangles)} triangles" if frames.triangles is not None else "points only"
        print(f"{frames.name}: {len(frames.times)} frames of {frames.positions.shape[1]} vertices ({surface}), "
              f"t = {frames.times[0]:.6g} to {frames.times[-1]:.6g} s, as {fmt.name} -> {path}")
    return 0
