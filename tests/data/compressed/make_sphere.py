#!/usr/bin/env python3
"""Writes sphere.glb: a UV sphere (24 segments, 12 rings) with positions, normals, texture
coordinates, vertex colours and 16-bit indices, textured with a 2x1 PNG: the uncompressed
source of the compressed fixtures (README.md beside it).

Usage: make_sphere.py [OUT.glb [SEGMENTS RINGS [NODES]]]; above 65,535 vertices the indices
are 32-bit (for timing the decoders on larger meshes). NODES > 1 draws the mesh from that many
nodes, each moved, turned and stretched differently (the source of the instancing fixture)."""
import json, math, struct, sys, zlib

SEGMENTS, RINGS = (int(sys.argv[2]), int(sys.argv[3])) if len(sys.argv) > 3 else (24, 12)
NODES = int(sys.argv[4]) if len(sys.argv) > 4 else 1


def turn(yaw, pitch):
    """The quaternion (x, y, z, w) of a turn by `yaw` about y after one by `pitch` about x."""
    y = (0.0, math.sin(yaw / 2), 0.0, math.cos(yaw / 2))
    x = (math.sin(pitch / 2), 0.0, 0.0, math.cos(pitch / 2))
    (x1, y1, z1, w1), (x2, y2, z2, w2) = y, x
    return [w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2]

def png_2x1():
    raw = b"\x00" + bytes([255, 0, 0, 255, 0, 0, 255, 255])
    def chunk(kind, data):
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))
    ihdr = struct.pack(">IIBBBBB", 2, 1, 8, 6, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")

pos, nrm, uv, col = [], [], [], []
for r in range(RINGS + 1):
    theta = math.pi * r / RINGS
    for s in range(SEGMENTS + 1):
        phi = 2 * math.pi * s / SEGMENTS
        n = (math.sin(theta) * math.cos(phi), math.cos(theta), math.sin(theta) * math.sin(phi))
        # An ellipsoid off the origin, so no two vertices but the seam's and the poles' share a place.
        pos.append((1.5 * n[0] + 0.25, 1.0 * n[1] + 1.0, 0.75 * n[2] - 0.5))
        nrm.append(n)
        uv.append((s / SEGMENTS, r / RINGS))
        col.append((s / SEGMENTS, r / RINGS, 0.5, 1.0))
idx = []
for r in range(RINGS):
    for s in range(SEGMENTS):
        a = r * (SEGMENTS + 1) + s
        b = a + SEGMENTS + 1
        if r != 0:
            idx += [a, a + 1, b]
        if r != RINGS - 1:
            idx += [a + 1, b + 1, b]

def pack(fmt, rows):
    return b"".join(struct.pack("<" + fmt, *row) for row in rows)

wide = len(pos) > 65535
chunks = [pack("3f", pos), pack("3f", nrm), pack("2f", uv), pack("4f", col),
          struct.pack("<%d%s" % (len(idx), "I" if wide else "H"), *idx)]
png = png_2x1()
chunks.append(png)
views, blob = [], b""
for c in chunks:
    views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(c)})
    blob += c + b"\x00" * (-len(c) % 4)
for v in views[:4]:
    v["target"] = 34962
views[4]["target"] = 34963
n = len(pos)
lo = [min(p[i] for p in pos) for i in range(3)]
hi = [max(p[i] for p in pos) for i in range(3)]
doc = {
    "asset": {"version": "2.0", "generator": "envlight tests/data/compressed/make_sphere.py"},
    "scene": 0, "scenes": [{"nodes": list(range(NODES))}],
    "nodes": [{"mesh": 0, "translation": [0.0, 0.5, 0.0]}] if NODES == 1 else [
        {"mesh": 0, "translation": [3.0 * i - 7.5, 0.2 * i, -1.0 * (i % 2)],
         "rotation": turn(0.7 * i, 0.3 * i), "scale": [1.0, 0.5 + 0.2 * i, 1.0]}
        for i in range(NODES)],
    "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2, "COLOR_0": 3},
                                 "indices": 4, "material": 0}]}],
    "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0.0, "roughnessFactor": 0.5}}],
    "textures": [{"source": 0, "sampler": 0}],
    "samplers": [{"wrapS": 33071, "wrapT": 33071}],
    "images": [{"bufferView": 5, "mimeType": "image/png"}],
    "accessors": [
        {"bufferView": 0, "componentType": 5126, "count": n, "type": "VEC3", "min": lo, "max": hi},
        {"bufferView": 1, "componentType": 5126, "count": n, "type": "VEC3"},
        {"bufferView": 2, "componentType": 5126, "count": n, "type": "VEC2"},
        {"bufferView": 3, "componentType": 5126, "count": n, "type": "VEC4"},
        {"bufferView": 4, "componentType": 5125 if wide else 5123, "count": len(idx), "type": "SCALAR"},
    ],
    "bufferViews": views,
    "buffers": [{"byteLength": len(blob)}],
}
js = json.dumps(doc, separators=(",", ":")).encode()
js += b" " * (-len(js) % 4)
glb = struct.pack("<III", 0x46546C67, 2, 12 + 8 + len(js) + 8 + len(blob))
glb += struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(blob), 0x004E4942) + blob
open(sys.argv[1] if len(sys.argv) > 1 else "sphere.glb", "wb").write(glb)
