"""Writes small Bonn PVF and BDI fixtures in this folder, independently of Meso's code,
with the values Bonn's reader returns for them.

Only Bonn's MATLAB btflib reads these two forms (btf_extractor reads DFMF and FMF).
This script writes each file field by field from btflib's reader (read_common_header.m,
read_ubo_pvf.m, read_ubo_bdi.m) and decodes it with numpy the way btflib's
`decode_abrdf` does (decode_pvf_abrdf.m, decode_bdi_abrdf.m, then the cosine divided out
where the file's cosine flag is set). `btflib_values.m`, run with GNU Octave and btflib
on its path, checks those values against btflib itself (docs/formats/ubo.md).

    python tests/reference/ubo/make_pvf_bdi_fixtures.py     (numpy only)

It writes, in tests/reference/ubo/:
  pvf_texels.btf   `!PVF06FCR`: per view, coefficients over (channel, light) and weights
                   over texels; half, f32 and f64 view slots; cosine flag set; no rotations
  pvf_lights.btf   `!PVF06FC`: per view, coefficients over (channel, texel) and weights
                   over lights; f32; meta-data version 2 with the cosine flag clear
  pvf_old.btf      `!PVF06FCR` in the old layout (magic number 301074, no meta data)
  bdi_full.btf     `!BDIF06R2!`, every texel stored, chunks of 1 scan line
  bdi_sparse.btf   `!BDIF06R2!`, only the texels of the mask stored, chunks of 2 lines
  expected_pvf_bdi.json  per file: values[light][view][y][x][rgb], btflib's (x, y),
                   y = 0 the file's first row
"""

import json
import os
import struct
import sys

import numpy as np

from bonn_header import meta_block, sampling

HERE = os.path.dirname(os.path.abspath(__file__))

LIGHTS = [(0.0, 0.0), (0.5, 1.0), (1.0, 4.0)]  # (theta, phi) radians
VIEWS = [(0.0, 0.0), (0.7, 2.0), (1.2, 5.5)]
NL, NV = len(LIGHTS), len(VIEWS)
W, H = 3, 2
DTYPE = {2: "<f2", 4: "<f4", 8: "<f8"}


def rotations(n):
    out = struct.pack("<I", n)
    for r in range(n):
        out += struct.pack("<9f", *np.eye(3).ravel() * (r + 1))
    return out


def stored(a, size):
    """The array as the file holds it, and its values as read back."""
    raw = np.ascontiguousarray(a, dtype=DTYPE[size])
    return raw.tobytes(), raw.astype(np.float64)


def light_cosines():
    return np.array([np.cos(t) for t, _ in LIGHTS])


def btflib_values(abrdf, cosine_flag):
    """abrdf[c, l, v, x, y] -> [l][v][y][x][c], the cosine divided out as btflib does."""
    out = np.transpose(abrdf, (1, 2, 4, 3, 0)).copy()
    if cosine_flag:
        out /= light_cosines()[:, None, None, None, None]
    return out.tolist()


def pvf(path, signature, header, slots, texel_weights):
    """slots: per view (scalar size, k). texel_weights: weights over texels (Cs over
    channel x light) or over lights (Cs over channel x texel)."""
    rng = np.random.default_rng(len(path))
    out = signature + header
    abrdf = np.zeros((3, NL, NV, W, H))
    for v, (size, k) in enumerate(slots):
        dim = 3 * NL if texel_weights else 3 * W * H
        nw = W * H if texel_weights else NL
        evs, _ = stored(np.linspace(2.0, 1.0, k), size)
        mb, m = stored(rng.uniform(0.1, 0.4, dim), size)
        cb, c = stored(rng.uniform(-0.2, 0.2, (dim, k)), size)
        wb, w = stored(rng.uniform(-0.5, 0.5, (nw, k)), size)
        out += struct.pack("<BIII", size, k, nw, dim) + evs + mb + cb + wb
        rec = c @ w.T + m[:, None]  # dim x nw
        if texel_weights:
            # rows c + 3 l, columns x + W y (btflib's sub2ind)
            abrdf[:, :, v, :, :] = rec.reshape(NL, 3, H, W).transpose(1, 0, 3, 2)
        else:
            # rows c + 3 (x + W y), columns l
            abrdf[:, :, v, :, :] = rec.reshape(H, W, 3, NL).transpose(2, 3, 1, 0)
    with open(path, "wb") as f:
        f.write(out)
    return abrdf


def bdi(path, cosine_flag, lines, mask):
    """mask[x, y]; btflib reads it as width x height, the byte for (x, y) at y + H x."""
    rng = np.random.default_rng(len(path) + 7)
    out = b"!BDIF06R2!" + meta_block(4, cosine_flag) + sampling(LIGHTS, VIEWS)
    compression = 0 if mask.all() else 2
    out += struct.pack("<III", W, H, lines) + struct.pack("<B", compression)
    out += mask.astype(np.uint8).tobytes()  # C order of [x, y]: y fastest
    # btflib's read_ubo_bdi reads 3 floats per rotation instead of 9, so a file with
    # rotations is misread there: the fixtures carry a rotation count of 0.
    out += rotations(0)
    # Stored texels in btflib's logical order: x fastest, then y.
    order = [(x, y) for y in range(H) for x in range(W) if compression == 0 or mask[x, y]]
    abrdf = np.zeros((3, NL, NV, W, H))
    per_chunk = W * lines
    for start in range(0, len(order), per_chunk):
        texels = order[start : start + per_chunk]
        halves = np.zeros((len(texels), NV, NL, 3), dtype="<f2")
        for i, (x, y) in enumerate(texels):
            halves[i] = rng.uniform(0.05, 0.9, (NV, NL, 3))
            # file order per texel: channel fastest, then light, then view
            abrdf[:, :, :, x, y] = halves[i].astype(np.float64).transpose(2, 1, 0)
        chunk = halves.tobytes()
        out += struct.pack("<I", len(chunk)) + chunk
    with open(path, "wb") as f:
        f.write(out)
    return abrdf


def main():
    common = lambda version, cosine, sig_r: (
        # btflib's read_common_header calls an undefined `read_matrix` when a file has
        # rotations, so the PVF fixtures carry a rotation count of 0.
        meta_block(version, cosine) + sampling(LIGHTS, VIEWS) + struct.pack("<II", W, H) + (rotations(0) if sig_r else b"")
    )
    expected = {}
    a = pvf(
        os.path.join(HERE, "pvf_texels.btf"),
        b"!PVF06FCR",
        common(4, 1, True) + struct.pack("<II", 3, NV),
        [(2, 2), (4, 3), (8, 1)],
        True,
    )
    expected["pvf_texels.btf"] = btflib_values(a, True)
    a = pvf(
        os.path.join(HERE, "pvf_lights.btf"),
        b"!PVF06FC",
        common(2, 0, False) + struct.pack("<II", 2, NV),
        [(4, 2), (4, 2), (4, 1)],
        False,
    )
    expected["pvf_lights.btf"] = btflib_values(a, False)
    old = struct.pack("<iIIII", 301074, 2, W, H, NV) + sampling(LIGHTS, VIEWS)
    a = pvf(os.path.join(HERE, "pvf_old.btf"), b"!PVF06FCR", old, [(2, 2)] * NV, True)
    expected["pvf_old.btf"] = btflib_values(a, False)
    a = bdi(os.path.join(HERE, "bdi_full.btf"), 1, 1, np.ones((W, H), bool))
    expected["bdi_full.btf"] = btflib_values(a, True)
    mask = np.array([[1, 0], [1, 1], [0, 1]], bool)  # [x, y]
    a = bdi(os.path.join(HERE, "bdi_sparse.btf"), 0, 2, mask)
    expected["bdi_sparse.btf"] = btflib_values(a, False)
    expected["reader"] = f"numpy {np.__version__} transcription of btflib's decoders"
    with open(os.path.join(HERE, "expected_pvf_bdi.json"), "w") as f:
        json.dump(expected, f)
    print("wrote PVF and BDI fixtures and expected_pvf_bdi.json", file=sys.stderr)


if __name__ == "__main__":
    main()
