"""Writes the small Bonn-format BTF fixtures in this folder, independently of Meso's code,
and records what Bonn's reader (the `btf_extractor` Python package) returns for them.

Run from the repository root with a Python that has numpy, pillow and btf_extractor
(docs/formats/ubo.md says how to install it):

    python tests/reference/ubo/make_fixtures.py

It writes, in tests/reference/ubo/:
  dfmf_rgb.btf     DFMF `!DFMF08FCR`, colour model 0, cosine flag 1, half floats
  dfmf_logyuv.btf  DFMF, colour model 11 (log Y, U/Y, V/Y), cosine flag 0, f32
  fmf_drr.btf      FMF `!FMF12FCER`, header version 1 with dynamic-range reduction
  ubo2003.zip      UBO2003-style zip of 8x6 JPEGs (3 lights x 2 views) and a readme
  expected.json    btf_extractor's values for each file, RGB, row 0 the top row
and, when Meso's export of the test BTF exists (`meso_export.btf`, written by the
Rust test `ubo2014::tests::meso_export_matches_the_checked_in_file`), what
btf_extractor returns for it too.

The layout follows Bonn's btflib (read_meta_data.m, read_bidir_sampling.m,
read_ubo_dfmf.m, read_ubo_fmf.m), as docs/formats/ubo.md describes it.
"""

import io
import json
import os
import struct
import sys
import zipfile

import numpy as np
from PIL import Image

from bonn_header import meta_block, sampling

HERE = os.path.dirname(os.path.abspath(__file__))


def scalars(a, size):
    dtype = {2: "<f2", 4: "<f4", 8: "<f8"}[size]
    return np.ascontiguousarray(a, dtype=dtype).tobytes()


LIGHTS = [(0.0, 0.0), (0.5, 1.0), (1.0, 4.0)]  # (theta, phi) radians
VIEWS = [(0.0, 0.0), (0.7, 2.0), (1.2, 5.5)]
W, H = 3, 2


def dfmf(path, model, cosine_flag, size, planes):
    """planes: per channel (U [pairs x k], SxV [texels x k]); pairs light-fastest,
    texels row-major with file row 0 first."""
    out = b"!DFMF08FCR" + meta_block(4, cosine_flag) + sampling(LIGHTS, VIEWS)
    out += struct.pack("<II", W, H) + struct.pack("<I", 0)  # no rotations
    k_max = max(u.shape[1] for u, _ in planes)
    out += struct.pack("<Ii", k_max, model) + struct.pack("<3f", 0, 0, 0)
    out += struct.pack("<9f", 1, 0, 0, 0, 1, 0, 0, 0, 1)
    for u, sxv in planes:
        k = u.shape[1]
        out += struct.pack("<BIII", size, k, u.shape[0], sxv.shape[0])
        out += scalars(np.ones(k), size) + scalars(u, size) + scalars(sxv, size)
    with open(path, "wb") as f:
        f.write(out)


def fmf(path, size, u, sxv):
    out = b"!FMF12FCER" + meta_block(3, 1) + sampling(LIGHTS, VIEWS)
    out += struct.pack("<II", W, H) + struct.pack("<I", 0)
    out += struct.pack("<B", 1) + struct.pack("<I", 1)  # header version 1: DRR on
    k = u.shape[1]
    out += struct.pack("<I", k) + struct.pack("<B", size)
    out += struct.pack("<III", k, u.shape[0], sxv.shape[0])
    out += scalars(np.ones(k), size) + scalars(u, size) + scalars(sxv, size)
    with open(path, "wb") as f:
        f.write(out)


def ubo2014_values(path):
    from btf_extractor import Ubo2014

    btf = Ubo2014(path)
    nl = btf.angles_vs_index_dict and max(i for i, _ in btf.angles_vs_index_dict.values()) + 1
    nv = max(j for _, j in btf.angles_vs_index_dict.values()) + 1
    # [light][view][row][column][rgb]; btf_extractor returns BGR.
    return [
        [btf._angleindex_to_image_unsafe(l, v)[:, :, ::-1].astype(float).tolist() for v in range(nv)]
        for l in range(nl)
    ]


def main():
    rng = np.random.default_rng(2014)
    pairs, texels = len(LIGHTS) * len(VIEWS), W * H
    expected = {}

    # RGB, cosine flag set, half floats, 2 components per channel.
    planes = [(rng.uniform(0.1, 0.6, (pairs, 2)), rng.uniform(0.2, 0.9, (texels, 2))) for _ in range(3)]
    dfmf(os.path.join(HERE, "dfmf_rgb.btf"), 0, 1, 2, planes)

    # Log-YUV (model 11), cosine flag clear, f32, 3 / 2 / 1 components: Y in about
    # [0.2, 0.6] and |U|, |V| < 0.1 Y, so RGB stays inside btf_extractor's [0, 1] clamp.
    y_u = np.column_stack([np.log(rng.uniform(0.2, 0.6, pairs)), rng.uniform(-0.1, 0.1, (pairs, 2))])
    y_s = np.column_stack([np.ones(texels), rng.uniform(-0.5, 0.5, (texels, 2))])
    planes = [
        (y_u, y_s),
        (rng.uniform(-0.1, 0.1, (pairs, 2)), rng.uniform(0, 0.5, (texels, 2))),
        (rng.uniform(-0.1, 0.1, (pairs, 1)), rng.uniform(0, 0.5, (texels, 1))),
    ]
    dfmf(os.path.join(HERE, "dfmf_logyuv.btf"), 11, 0, 4, planes)

    # FMF with dynamic-range reduction: rows are (channel fastest, then light, view).
    target = rng.uniform(0.05, 0.8, (3 * pairs, texels))
    logs = np.log(target + 1e-5)
    uu, s, vt = np.linalg.svd(logs, full_matrices=False)
    k = 3
    fmf(os.path.join(HERE, "fmf_drr.btf"), 2, uu[:, :k], (vt[:k].T * s[:k]))

    for name in ("dfmf_rgb.btf", "dfmf_logyuv.btf", "fmf_drr.btf"):
        expected[name] = ubo2014_values(os.path.join(HERE, name))

    # UBO2003: 3 lights x 2 views of 8x6 JPEGs, in a folder, with a readme beside them.
    lights = [(0, 0), (15, 0), (15, 60)]
    views = [(0, 0), (30, 90)]
    zpath = os.path.join(HERE, "ubo2003.zip")
    with zipfile.ZipFile(zpath, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("tiny/readme.txt", "UBO2003-style fixture\n")
        for li, (tl, pl) in enumerate(lights):
            for vi, (tv, pv) in enumerate(views):
                yy, xx = np.mgrid[0:6, 0:8]
                img = np.stack(
                    [40 + 20 * xx + 10 * li, 60 + 25 * yy + 30 * vi, 90 + 5 * (xx + yy)], axis=-1
                ).clip(0, 255).astype(np.uint8)
                buf = io.BytesIO()
                Image.fromarray(img).save(buf, format="JPEG", quality=95)
                z.writestr(f"tiny/tl{tl:03} pl{pl:03} tv{tv:03} pv{pv:03}.jpg", buf.getvalue())
    from btf_extractor import Ubo2003

    btf = Ubo2003(zpath)
    expected["ubo2003.zip"] = {
        "lights": lights,
        "views": views,
        # [light][view][row][column][rgb], 8-bit codes.
        "codes": [
            [btf.angles_to_image(tl, pl, tv, pv)[:, :, ::-1].astype(int).tolist() for (tv, pv) in views]
            for (tl, pl) in lights
        ],
    }

    export = os.path.join(HERE, "meso_export.btf")
    if os.path.exists(export):
        expected["meso_export.btf"] = ubo2014_values(export)
    import btf_extractor

    expected["reader"] = f"btf_extractor {getattr(btf_extractor, '__version__', '1.7.0')}, numpy {np.__version__}"
    with open(os.path.join(HERE, "expected.json"), "w") as f:
        json.dump(expected, f)
    print("wrote fixtures and expected.json", file=sys.stderr)


if __name__ == "__main__":
    main()
