"""Environment lighting against an independent renderer (Mitsuba 3, `direct` integrator).

Renders a Lambertian bunny on a Lambertian floor under materials/env/env_sky.exr turned
about +y, with `meso render` and with Mitsuba 3, and prints each image's mean, their
relative difference and the relative RMSE (also between two Meso seeds, the noise
floor). Not part of the test suite (it needs Mitsuba):

    python3 -m venv venv && venv/bin/pip install mitsuba numpy openexr
    cargo build --release -p meso-cli
    venv/bin/python tests/reference/mitsuba_env/cross_check.py [--mode biscale]
        [--mesh OBJ] [--no-floor] [ROT_DEG ...]

`--mode` picks Meso's render mode (spmm by default); `--mesh` replaces the low-res
bunny with another OBJ placed the same way (for example the full-resolution Stanford
bunny); `--no-floor` leaves the object alone under the sky.

Conventions, probed on Mitsuba 3.9 with a map whose pixels encode their coordinates:
Mitsuba's envmap reads u = atan2(x, -z) / 2 pi, which is Meso's u minus 1/4, so the
map's columns are rolled by a quarter before Mitsuba gets it; its `rotate` about +y
turns the map the same way as Meso's `rotate_y_deg`; row 0 is the zenith in both.
Mitsuba filters the map bilinearly, Meso reads the nearest pixel.
"""
import os
import subprocess
import sys

import mitsuba as mi
import numpy as np
import OpenEXR

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.normpath(os.path.join(HERE, "../../.."))
MESO = os.path.join(ROOT, "target/release/meso")
SIZE, SPP = 128, 1024


def read_exr(path):
    ch = OpenEXR.File(path).channels()
    if "RGB" in ch:
        return np.array(ch["RGB"].pixels, dtype=np.float64)
    return np.stack([np.array(ch[c].pixels, dtype=np.float64) for c in "RGB"], -1)


LOWRES = os.path.join(ROOT, "tests/scenes/meshes/bunny_lowres.obj")


def render_meso(rot, seed, out, mode="spmm", mesh=LOWRES, floor=True):
    text = open(os.path.join(HERE, "scene.toml.in")).read()
    text = text.replace("ROT", str(rot)).replace("seed = 11", f"seed = {seed}")
    text = text.replace('"../../../tests/scenes/meshes/bunny_lowres.obj"', f'"{mesh}"')
    if not floor:
        start = text.index("[[quad]]")
        text = text[:start] + text[text.index("[environment]"):]
    scene = os.path.join(HERE, f"_scene_{rot}_{seed}.toml")
    with open(scene, "w") as f:
        f.write(text)
    subprocess.run([MESO, "render", scene, "-o", out, "--frames", str(SPP), "--mode", mode],
                   check=True, stdout=subprocess.DEVNULL)
    os.remove(scene)
    return read_exr(out)


def render_mitsuba(rot, out, mesh=LOWRES, floor=True):
    mi.set_variant("scalar_rgb")
    src = np.array(mi.Bitmap(os.path.join(ROOT, "materials/env/env_sky.exr")).convert(
        mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, False))
    rolled = np.roll(src, -src.shape[1] // 4, axis=1)
    T = mi.ScalarTransform4f
    diffuse = lambda rgb: {"type": "diffuse", "reflectance": {"type": "rgb", "value": rgb}}
    shapes = {
        "bunny": {"type": "obj", "filename": mesh,
                  "to_world": T().rotate([0, 1, 0], 150), "bsdf": diffuse([0.7, 0.7, 0.7])},
    }
    if floor:
        shapes["floor"] = {"type": "rectangle",
                           "to_world": T().rotate([1, 0, 0], -90).scale([2, 2, 1]),
                           "bsdf": diffuse([0.4, 0.5, 0.3])}
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 1},
        "sensor": {
            "type": "perspective", "fov": 35, "fov_axis": "y",
            "to_world": T().look_at(origin=[0.4, 0.8, 2.6], target=[0, 0.3, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": SIZE, "height": SIZE,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            "sampler": {"type": "independent", "sample_count": SPP},
        },
        "env": {"type": "envmap", "bitmap": mi.Bitmap(rolled),
                "to_world": T().rotate([0, 1, 0], rot)},
        **shapes,
    })
    mi.Bitmap(mi.render(scene)).write(out)
    return read_exr(out)


def rel_rmse(a, b):
    return np.sqrt(((a - b) ** 2).mean()) / b.mean()


if __name__ == "__main__":
    import argparse
    ap = argparse.ArgumentParser()
    ap.add_argument("--mode", default="spmm")
    ap.add_argument("--mesh", default=LOWRES)
    ap.add_argument("--no-floor", action="store_true")
    ap.add_argument("rot", nargs="*", type=float)
    a = ap.parse_args()
    mesh, floor = os.path.abspath(a.mesh), not a.no_floor
    out = os.path.join(HERE, "_out")
    os.makedirs(out, exist_ok=True)
    tag = f"{a.mode}_{os.path.basename(mesh)}_{'floor' if floor else 'alone'}"
    for rot in a.rot or [40.0, -110.0]:
        m = render_meso(rot, 11, os.path.join(out, f"meso_{tag}_{rot}.exr"), a.mode, mesh, floor)
        m2 = render_meso(rot, 12, os.path.join(out, f"meso_seed12_{tag}_{rot}.exr"), a.mode,
                         mesh, floor)
        r = render_mitsuba(rot, os.path.join(out, f"mitsuba_{tag}_{rot}.exr"), mesh, floor)
        print(f"{tag} rotate_y_deg {rot}: mean Meso {m.mean():.5f}, Mitsuba {r.mean():.5f} "
              f"({(m.mean() - r.mean()) / r.mean():+.2%}); relative RMSE {rel_rmse(m, r):.2%} "
              f"(Meso seed 11 vs 12: {rel_rmse(m, m2):.2%})")
