"""Write the skirt of the `garment` scene as an OBJ (one `g` group per panel), e.g.

    python examples/garments/make_skirt.py examples/garments/skirt.obj --rows 50

then drape it from a file: taichi-sim simulate mesh --set file=examples/garments/skirt.obj
--set pin=top:0.005 ...
"""
import argparse

from taichi_sim.scene.garment import SKIRT_DEFAULTS, skirt_mesh, write_obj


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="write the garment scene's skirt as an OBJ")
    parser.add_argument("out", help="the OBJ file to write")
    for name, default in SKIRT_DEFAULTS.items():
        parser.add_argument(f"--{name.replace('_', '-')}", type=type(default), default=default,
                            help=f"default {default}")
    args = parser.parse_args(argv)
    mesh = skirt_mesh(**{name: getattr(args, name) for name in SKIRT_DEFAULTS})
    write_obj(mesh, args.out)
    print(f"{args.out}: {mesh.vertex_count} vertices, {len(mesh.triangles)} triangles")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
