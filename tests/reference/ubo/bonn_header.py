"""Bonn's common BTF header pieces (btflib's write_meta_data.m and
write_bidir_sampling.m), shared by the fixture scripts in this folder."""

import struct


def meta_block(version, cosine_flag, channels=("R", "G", "B")):
    body = struct.pack("<I", version)
    for text in (b"reference", b"", b""):
        body += text.ljust(80, b"\0")
    body += struct.pack("<f3f", 2.5, 1.0, 1.0, 1.0)
    if version > 1:
        body += struct.pack("<I", cosine_flag)
    if version > 2:
        xml = b"<measurement/>"
        body += struct.pack("<I", len(xml)) + xml
    if version > 3:
        body += struct.pack("<I", len(channels))
        for c in channels:
            body += struct.pack("<I", len(c)) + c.encode()
    return struct.pack("<I", 4 + len(body)) + body


def sampling(lights, views):
    out = struct.pack("<I", len(views))
    for v in views:
        out += struct.pack("<2f", *v) + struct.pack("<I", len(lights))
        for l in lights:
            out += struct.pack("<2f", *l)
    return out
