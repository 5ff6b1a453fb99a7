#!/usr/bin/env python3
"""Writes bending_arm.gltf, the skinned fixture of src/render/scene/tests/animated_files.rs.

    python3 make_skinned.py bending_arm.gltf

A square column 0.5 wide and 2 tall (y from 0 to 2), its four sides as quads between rings
of vertices at y = 0, 1 and 2, on node "arm" (skin 0; the node's own translation, (5, 0, 0),
is ignored, as glTF defines for skinned meshes). Joints: "shoulder" at the origin and its child
"elbow" at (0, 1, 0) (inverse bind matrices: the identity, and a translation by -1 in y).
Weights: the bottom ring follows the shoulder, the middle ring both halves, the top ring the
elbow. Clip "bend" (1 s): the elbow turns 0 -> 90 degrees about +z (LINEAR). Standard library
only; the buffer is embedded (base64).
"""
import base64
import json
import math
import struct
import sys


def main():
    out = sys.argv[1]
    data = bytearray()
    accessors, views = [], []

    def add(flat, kind, count, component=5126, fmt="f", minmax=None):
        while len(data) % 4:
            data.append(0)
        views.append({"buffer": 0, "byteOffset": len(data), "byteLength": struct.calcsize(fmt) * len(flat)})
        data.extend(struct.pack("<%d%s" % (len(flat), fmt), *flat))
        accessor = {"bufferView": len(views) - 1, "componentType": component, "count": count, "type": kind}
        if minmax:
            accessor["min"], accessor["max"] = minmax
        accessors.append(accessor)
        return len(accessors) - 1

    half = 0.25
    positions, normals, joints, weights, indices = [], [], [], [], []
    # Each side: a normal and the two corners (x, z) of its bottom edge, counter-clockwise
    # seen from outside.
    sides = [((0, 0, 1), (-half, half), (half, half)),
             ((1, 0, 0), (half, half), (half, -half)),
             ((0, 0, -1), (half, -half), (-half, -half)),
             ((-1, 0, 0), (-half, -half), (-half, half))]
    ring_weights = [((0, 0, 0, 0), (1.0, 0.0, 0.0, 0.0)),
                    ((0, 1, 0, 0), (0.5, 0.5, 0.0, 0.0)),
                    ((1, 0, 0, 0), (1.0, 0.0, 0.0, 0.0))]
    for normal, a, b in sides:
        base = len(positions)
        for ring in range(3):
            for x, z in (a, b):
                positions.append((x, float(ring), z))
                normals.append(normal)
                j, w = ring_weights[ring]
                joints.append(j)
                weights.append(w)
        for ring in range(2):
            k = base + 2 * ring
            indices += [k, k + 1, k + 3, k, k + 3, k + 2]
    flat = lambda rows: [c for r in rows for c in r]
    lo = [min(p[i] for p in positions) for i in range(3)]
    hi = [max(p[i] for p in positions) for i in range(3)]
    n = len(positions)
    attributes = {
        "POSITION": add(flat(positions), "VEC3", n, minmax=(lo, hi)),
        "NORMAL": add(flat(normals), "VEC3", n),
        "JOINTS_0": add(flat(joints), "VEC4", n, 5121, "B"),
        "WEIGHTS_0": add(flat(weights), "VEC4", n),
    }
    index_accessor = add(indices, "SCALAR", len(indices), 5123, "H")
    inverse_bind = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1,
                    1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, -1, 0, 1]
    ibm = add(inverse_bind, "MAT4", 2)
    h = math.radians(90) / 2
    times = add([0.0, 1.0], "SCALAR", 2, minmax=([0.0], [1.0]))
    turns = add([0, 0, 0, 1, 0, 0, math.sin(h), math.cos(h)], "VEC4", 2)
    gltf = {
        "asset": {"version": "2.0", "generator": "envlight tests/data/animated/make_skinned.py"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [
            {"name": "arm", "mesh": 0, "skin": 0, "translation": [5.0, 0.0, 0.0]},
            {"name": "shoulder", "children": [2]},
            {"name": "elbow", "translation": [0.0, 1.0, 0.0]},
        ],
        "skins": [{"joints": [1, 2], "inverseBindMatrices": ibm, "skeleton": 1}],
        "meshes": [{"primitives": [{"attributes": attributes, "indices": index_accessor, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.7, 0.7, 0.7, 1.0]}}],
        "animations": [{"name": "bend",
                        "samplers": [{"input": times, "output": turns}],
                        "channels": [{"sampler": 0, "target": {"node": 2, "path": "rotation"}}]}],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": len(data),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(bytes(data)).decode()}],
    }
    with open(out, "w") as f:
        json.dump(gltf, f, separators=(",", ":"))


if __name__ == "__main__":
    main()
