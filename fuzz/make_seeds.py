#!/usr/bin/env python3
"""Writes small seed inputs for the fuzz targets into corpus/<target>/ (run from fuzz/).

The seeds are valid inputs of each kind (the protocol's worked examples, tiny EXR and HDR files,
the project's test scenes, the example config), so that libFuzzer starts from the formats'
structure instead of from nothing. EXR seeds need the OpenEXR Python package (pip install
OpenEXR numpy); without it they are skipped."""
import json
import os
import shutil
import struct

ROOT = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(ROOT, "..", "tests", "data")


def put(target, name, data):
    folder = os.path.join(ROOT, "corpus", target)
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, name), "wb") as f:
        f.write(data)


def hexbytes(text):
    return bytes.fromhex(text.replace(" ", ""))


# Protocol: the worked examples of docs/protocol.md and their JSON forms.
frame = hexbytes(
    "40000000 454e564c 0100 0100 1100000000000000 000000000000e03f 00 01 0000 01000000"
    "03000000 00000000 0000803f 00000000 0000803f 0000003f 0000803e 0000803d"
)
subscribe = hexbytes("10000000 454e564c 0100 1000 40000000 00 00 0000")
goodbye = hexbytes("11000000 454e564c 0100 0300 0000 03000000 627965")
asg = hexbytes(
    "54000000 454e564c 0100 0100 1100000000000000 000000000000e03f 01 00 0000 01000000"
    "00000000 00000000 0000803f 00000000 0000803f 00000000 00000000 00000041 00000040"
    "00004040 00002040 00000040 0000403f"
)
wavelet = hexbytes(
    "48000000 454e564c 0100 0100 1100000000000000 000000000000e03f 02 00 0000 02000000"
    "01 02 00 00 04000000 00000000 00008040 00000040 0000803f 05000000 000000bf 0000803e 00000000"
)
put("protocol", "frame", bytes([7]) + frame)
put("protocol", "stream", bytes([13]) + frame + asg + wavelet + goodbye)
put("protocol", "subscribe", bytes([20]) + subscribe)
for i, text in enumerate([
    '{"seq":17,"time":0.5,"representation":"lights","stale":false,"lights":[{"id":3,"dir":[0.0,1.0,0.0],"rgb":[1.0,0.5,0.25],"solid_angle":0.0625}]}',
    '{"seq":17,"time":0.5,"representation":"asg","stale":false,"lobes":[{"id":0,"axis":[0.0,1.0,0.0],"tangent":[1.0,0.0,0.0],"lambda":8.0,"mu":2.0,"rgb":[3.0,2.5,2.0],"integral":0.75}]}',
    '{"seq":17,"time":0.5,"representation":"wavelet","stale":false,"basis":"haar","side":4,"levels":2,"coefficients":[[0,[4.0,2.0,1.0]],[5,[-0.5,0.25,0.0]]]}',
    '{"seq":17,"time":0.5,"representation":"sh","stale":false,"degree":1,"sh":[[1.0,0.9,0.8],[0.1,0.1,0.1],[0.0,0.0,0.0],[-0.05,0.0,0.02]]}',
    '{"subscribe": {"max_lights": 64, "representation": "lights", "format": "json"}}',
    '{"error":{"code":5,"message":"invalid JSON message"}}',
]):
    put("protocol", f"json{i}", text.encode())

# Config: the documented example.
with open(os.path.join(ROOT, "..", "config", "envlight.toml"), "rb") as f:
    put("config", "envlight.toml", f.read())

# Radiance HDR: a flat and a run-length encoded 8x4 image.
def rgbe(r, g, b):
    import math
    v = max(r, g, b)
    if v < 1e-32:
        return bytes(4)
    m, e = math.frexp(v)
    s = m * 256.0 / v
    return bytes([int(r * s), int(g * s), int(b * s), e + 128])


header = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4 +X 8\n"
pixels = [rgbe(0.1 * x, 0.2 * y, 1.0) for y in range(4) for x in range(8)]
put("hdr_image", "flat.hdr", header + b"".join(pixels))
rle = bytearray(header)
for y in range(4):
    row = pixels[y * 8:(y + 1) * 8]
    rle += bytes([2, 2, 0, 8])
    for c in range(4):
        rle += bytes([8]) + bytes(p[c] for p in row)
put("hdr_image", "rle.hdr", bytes(rle))

try:
    import numpy as np
    import OpenEXR

    img = np.random.default_rng(1).random((4, 8, 3), dtype=np.float32) * 4
    for comp_name, comp in [("none", OpenEXR.NO_COMPRESSION), ("zip", OpenEXR.ZIP_COMPRESSION),
                            ("piz", OpenEXR.PIZ_COMPRESSION), ("rle", OpenEXR.RLE_COMPRESSION),
                            ("b44", OpenEXR.B44_COMPRESSION), ("pxr24", OpenEXR.PXR24_COMPRESSION)]:
        for dtype in (np.float32, np.float16):
            header = {"compression": comp, "type": OpenEXR.scanlineimage}
            path = os.path.join(ROOT, "seed.exr")
            with OpenEXR.File(header, {"RGB": img.astype(dtype)}) as f:
                f.write(path)
            with open(path, "rb") as f:
                put("hdr_image", f"{comp_name}_{np.dtype(dtype).name}.exr", f.read())
            os.remove(path)
    path = os.path.join(ROOT, "seed.exr")
    try:
        tiles = OpenEXR.TileDescription()
        tiles.xSize, tiles.ySize = 4, 4
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.tiledimage,
                  "tiles": tiles}
        with OpenEXR.File(header, {"RGB": img.astype(np.float16)}) as f:
            f.write(path)
        with open(path, "rb") as f:
            put("hdr_image", "tiled.exr", f.read())
        os.remove(path)
    except Exception as e:  # an older binding without tiled output
        print("tiled EXR seed skipped:", e)
except ImportError:
    print("OpenEXR not installed: EXR seeds skipped")

# Scenes: the test fixtures under 25 kB; the first byte picks the extension (0 glb, 1 gltf,
# 2 obj; 0x80 adds the ground).
for folder in ("animated", "compressed"):
    for name in sorted(os.listdir(os.path.join(DATA, folder))):
        path = os.path.join(DATA, folder, name)
        if os.path.getsize(path) > 25_000:
            continue
        kind = {".glb": 0, ".gltf": 1, ".obj": 2}.get(os.path.splitext(name)[1])
        if kind is None:
            continue
        with open(path, "rb") as f:
            put("scene", name, bytes([kind]) + f.read())
put("scene", "quad.obj", bytes([2]) + b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nvt 0 0\nf 1/1/1 2/1/1 3/1/1 4/1/1\n")

# Camera frames: format index, width, height, stride/4, flags, then the bytes.
for fmt in range(54):
    put("camera_frame", f"format{fmt}", bytes([fmt, 8, 4, 0, 0]) + bytes(range(256)) * 2)

# Response curves: a gamma-2.2 table of 256 entries (as calibrate-response writes, with its
# comment), a two-entry linear one and one with a flat toe and a steep shoulder.
lines = ["# envlight response curve: code red green blue"]
lines += [f"{i / 255:.6f} {(i / 255) ** 2.2:.6g} {(i / 255) ** 2.1:.6g} {(i / 255) ** 2.3:.6g}"
          for i in range(256)]
put("response_curve", "gamma.curve", ("\n".join(lines) + "\n").encode())
put("response_curve", "linear.curve", b"0 0 0 0\n1 1 1 1\n")
put("response_curve", "shoulder.curve", b"0 0 0 0\n0.5 0 0 0\n0.99 1e3 1e3 1e3\n1 3e38 1e300 1e30\n")

# Recordings: two bytes giving the length of session.json, session.json (as envlight record
# writes it, with variants of its settings), then frames.jsonl naming the target's three frames.
session = {
    "format": "envlight-recording", "version": 1, "source": "fuzz seed",
    "decompose": {"lights": 64, "working_width": 32, "placement": "centroid",
                  "filter_taps": [1.0, 6.0, 15.0, 20.0, 15.0, 6.0, 1.0],
                  "merge_spacing_fraction": None, "pdf_exponent": 0.75, "warp": "rows",
                  "concentrated_lloyd": False, "refine_concentrated": True,
                  "bright_history": "fold", "split_factor": None, "resample_threads": 1},
    "envlight": "0.1.0", "created_unix_s": 0,
}
fisheye = {"fisheye": {"model": "equidistant", "center": [8.0, 8.0], "radius": 8.0,
                       "fov_deg": 180.0, "rotation_deg": 0.0}}
index = "".join(json.dumps(line) + "\n" for line in [
    {"seq": 0, "time": 0.0, "file": "frames/000000.exr", "projection": "lat-long"},
    {"seq": 1, "time": 0.03, "file": "frames/000001.exr", "projection": "lat-long"},
    {"seq": 2, "time": 0.06, "file": "frames/000002.hdr", "projection": fisheye},
    {"seq": 3, "time": 0.09, "file": "frames/000002.hdr", "projection": "angular-map"},
])
variants = {
    "default": {},
    "merge_split": {"merge_spacing_fraction": 0.5, "split_factor": 4.0, "warp": "hierarchical"},
    "lloyd_blend": {"concentrated_lloyd": True, "bright_history": "blend", "placement": "sample-point",
                    "filter_taps": None, "pdf_exponent": 1.0},
}
for name, change in variants.items():
    s = json.loads(json.dumps(session))
    s["decompose"].update(change)
    text = json.dumps(s).encode()
    put("recording", name, struct.pack("<H", len(text)) + text + index.encode())
