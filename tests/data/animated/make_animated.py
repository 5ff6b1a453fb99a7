#!/usr/bin/env python3
"""Writes the animated glTF fixtures of tests/render.rs and src/render/scene/tests.

    python3 make_animated.py turning_boxes.gltf       # the animated file
    python3 make_animated.py turned_boxes.gltf 1.0    # the same boxes, still, posed as the
                                                      # animation poses them at 1.0 s

Two boxes: a base (2 x 1 x 2) on node "base", and a smaller box (1 x 1 x 1) on node "top",
a child of "base" standing 1.25 above it and turned 30 degrees about its own x axis. Clip
"turn" (2 s): "base" turns 0 -> 90 degrees about +y (LINEAR rotation) and rises 0 -> 0.5
(LINEAR translation); clip "hop" (1 s): "top" rises by 1 and falls back (CUBICSPLINE
translation, zero tangents). A perspective camera node looks at them from the front and
above. One file, its buffer embedded (base64); standard library only.
"""
import base64
import json
import math
import struct
import sys


def box(half):
    """24 vertices (4 per face, outward normals) and 36 indices of a box."""
    positions, normals, indices = [], [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            n = [0.0, 0.0, 0.0]
            n[axis] = sign
            u = [0.0, 0.0, 0.0]
            u[(axis + 1) % 3] = 1.0
            v = [n[1] * u[2] - n[2] * u[1], n[2] * u[0] - n[0] * u[2], n[0] * u[1] - n[1] * u[0]]
            base = len(positions)
            for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                positions.append([(n[i] + a * u[i] + b * v[i]) * half[i] for i in range(3)])
                normals.append(n)
            indices += [base, base + 1, base + 2, base, base + 2, base + 3]
    return positions, normals, indices


def quat_y(degrees):
    h = math.radians(degrees) / 2
    return [0.0, math.sin(h), 0.0, math.cos(h)]


def quat_x(degrees):
    h = math.radians(degrees) / 2
    return [math.sin(h), 0.0, 0.0, math.cos(h)]


def main():
    out = sys.argv[1]
    still_at = float(sys.argv[2]) if len(sys.argv) > 2 else None
    data = bytearray()
    accessors, views = [], []

    def add(values, kind, component=5126, fmt="f", target=None, minmax=False):
        while len(data) % 4:
            data.append(0)
        width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[kind]
        flat = [x for v in values for x in (v if isinstance(v, list) else [v])]
        view = {"buffer": 0, "byteOffset": len(data), "byteLength": struct.calcsize(fmt) * len(flat)}
        if target:
            view["target"] = target
        data.extend(struct.pack("<%d%s" % (len(flat), fmt), *flat))
        views.append(view)
        accessor = {"bufferView": len(views) - 1, "componentType": component,
                    "count": len(flat) // width, "type": kind}
        if minmax and kind == "SCALAR":
            accessor["min"], accessor["max"] = [min(values)], [max(values)]
        elif minmax:
            accessor["min"] = [min(v[i] for v in values) for i in range(width)]
            accessor["max"] = [max(v[i] for v in values) for i in range(width)]
        accessors.append(accessor)
        return len(accessors) - 1

    meshes = []
    for half in ((1.0, 0.5, 1.0), (0.5, 0.5, 0.5)):
        p, n, i = box(half)
        meshes.append({"primitives": [{
            "attributes": {"POSITION": add(p, "VEC3", target=34962, minmax=True),
                           "NORMAL": add(n, "VEC3", target=34962)},
            "indices": add(i, "SCALAR", 5123, "H", target=34963),
            "material": len(meshes)}]})

    # The clips' keys.
    turn_times = [0.0, 2.0]
    turn_rotations = [quat_y(0.0), quat_y(90.0)]
    turn_translations = [[0.0, 0.0, 0.0], [0.0, 0.5, 0.0]]
    hop_times = [0.0, 0.5, 1.0]
    top_rest = [0.0, 1.25, 0.0]
    hop = [[0.0, 0.0, 0.0], top_rest, [0.0, 0.0, 0.0],
           [0.0, 0.0, 0.0], [0.0, 2.25, 0.0], [0.0, 0.0, 0.0],
           [0.0, 0.0, 0.0], top_rest, [0.0, 0.0, 0.0]]

    base = {"name": "base", "mesh": 0, "children": [1]}
    top = {"name": "top", "mesh": 1, "translation": top_rest, "rotation": quat_x(30.0)}
    if still_at is None:
        animations = [
            {"name": "turn",
             "samplers": [{"input": add(turn_times, "SCALAR", minmax=True), "output": add(turn_rotations, "VEC4")},
                          {"input": add(turn_times, "SCALAR", minmax=True), "output": add(turn_translations, "VEC3")}],
             "channels": [{"sampler": 0, "target": {"node": 0, "path": "rotation"}},
                          {"sampler": 1, "target": {"node": 0, "path": "translation"}}]},
            {"name": "hop",
             "samplers": [{"input": add(hop_times, "SCALAR", minmax=True), "output": add(hop, "VEC3"),
                           "interpolation": "CUBICSPLINE"}],
             "channels": [{"sampler": 0, "target": {"node": 1, "path": "translation"}}]},
        ]
    else:
        # Clip "turn" at still_at (within its 2 s): slerp about one axis is linear in angle.
        u = min(max(still_at / 2.0, 0.0), 1.0)
        base["rotation"] = quat_y(90.0 * u)
        base["translation"] = [0.0, 0.5 * u, 0.0]
        animations = []

    gltf = {
        "asset": {"version": "2.0", "generator": "envlight tests/data/animated/make_animated.py"},
        "scene": 0,
        "scenes": [{"nodes": [0, 2]}],
        "nodes": [base, top,
                  {"name": "camera", "camera": 0, "translation": [0.0, 3.0, 7.0],
                   "rotation": quat_x(-20.0)}],
        "cameras": [{"type": "perspective", "perspective": {"yfov": 0.7, "znear": 0.1}}],
        "meshes": meshes,
        "materials": [
            {"name": "base", "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.3, 0.2, 1.0],
                                                      "metallicFactor": 0.0, "roughnessFactor": 0.5}},
            {"name": "top", "pbrMetallicRoughness": {"baseColorFactor": [0.2, 0.5, 0.8, 1.0],
                                                     "metallicFactor": 0.0, "roughnessFactor": 0.3}},
        ],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": len(data),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(bytes(data)).decode()}],
    }
    if animations:
        gltf["animations"] = animations
    with open(out, "w") as f:
        json.dump(gltf, f, separators=(",", ":"))


if __name__ == "__main__":
    main()
