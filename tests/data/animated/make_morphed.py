#!/usr/bin/env python3
"""Writes the morph-target fixtures of src/render/scene/tests/animated_files.rs and tests/render.rs.

    python3 make_morphed.py morphing_tent.gltf           # the animated file
    python3 make_morphed.py morphed_tent.gltf 1.5        # no morph targets: clip "rise" at 1.5 s baked

A 2 x 2 sheet of 5 x 5 vertices in the xz plane (y = 0, normals +y), drawn twice by one mesh
with two morph targets:
  target 0 "peak": lifts the centre vertex by 1 (a sparse accessor: one displacement; no normal
    displacements);
  target 1 "tilt": lifts every vertex by 0.5 x (a ramp), its normals displaced towards the ramp's
    normal (-0.5, 1, 0) / |.|.
Node "animated" (at the origin) has the mesh's weights [0, 0]; node "posed" (at x = 3) its own
weights [0.5, 1.0]. Clip "rise" (2 s, LINEAR) weighs the animated node's targets [0, 0] -> [1, 0]
at 1 s -> [1, 1] at 2 s; clip "blink" (1 s, STEP) holds [0, 0] and then [1, 0] from 0.5 s.
With a time argument the file has no morph targets and no animation: the vertices of both nodes
are written where the weights put them (the animated node's as clip "rise" at that time),
normals normalised. Standard library only; the buffer is embedded (base64).
"""
import base64
import json
import math
import struct
import sys

GRID = 5
CENTRE = (GRID * GRID) // 2
RAMP_NORMAL = (-0.5 / math.sqrt(1.25), 1.0 / math.sqrt(1.25), 0.0)


def sheet():
    """The base positions, normals and indices (counter-clockwise from +y)."""
    positions, normals, indices = [], [], []
    for k in range(GRID):
        for i in range(GRID):
            positions.append((-1.0 + 2.0 * i / (GRID - 1), 0.0, -1.0 + 2.0 * k / (GRID - 1)))
            normals.append((0.0, 1.0, 0.0))
    for k in range(GRID - 1):
        for i in range(GRID - 1):
            a = k * GRID + i
            b, c, d = a + 1, a + GRID, a + GRID + 1
            indices += [a, c, b, b, c, d]
    return positions, normals, indices


def targets(positions):
    """Per target: position and normal displacements (None: not given)."""
    peak = [(0.0, 1.0 if v == CENTRE else 0.0, 0.0) for v in range(len(positions))]
    tilt = [(0.0, 0.5 * p[0], 0.0) for p in positions]
    tilt_normals = [(RAMP_NORMAL[0], RAMP_NORMAL[1] - 1.0, 0.0)] * len(positions)
    return [(peak, None), (tilt, tilt_normals)]


def rise(t):
    """Clip "rise"'s weights at t seconds."""
    t = min(max(t, 0.0), 2.0)
    return [min(t, 1.0), max(t - 1.0, 0.0)]


def morphed(positions, normals, weights):
    out_p, out_n = [], []
    for v, (p, n) in enumerate(zip(positions, normals)):
        p, n = list(p), list(n)
        for w, (dp, dn) in zip(weights, targets(positions)):
            p = [a + w * b for a, b in zip(p, dp[v])]
            if dn:
                n = [a + w * b for a, b in zip(n, dn[v])]
        length = math.sqrt(sum(c * c for c in n))
        out_p.append(tuple(p))
        out_n.append(tuple(c / length for c in n))
    return out_p, out_n


def main():
    out = sys.argv[1]
    baked_at = float(sys.argv[2]) if len(sys.argv) > 2 else None
    data = bytearray()
    accessors, views = [], []

    def view(raw):
        while len(data) % 4:
            data.append(0)
        views.append({"buffer": 0, "byteOffset": len(data), "byteLength": len(raw)})
        data.extend(raw)
        return len(views) - 1

    def add(flat, kind, count, component=5126, fmt="f", minmax=None):
        accessor = {"bufferView": view(struct.pack("<%d%s" % (len(flat), fmt), *flat)),
                    "componentType": component, "count": count, "type": kind}
        if minmax:
            accessor["min"], accessor["max"] = minmax
        accessors.append(accessor)
        return len(accessors) - 1

    def add_sparse(count, index, value):
        """A VEC3 float accessor of `count` zeros but one `value` at `index` (no buffer view)."""
        accessors.append({
            "componentType": 5126, "count": count, "type": "VEC3",
            "min": [min(0.0, c) for c in value], "max": [max(0.0, c) for c in value],
            "sparse": {"count": 1,
                       "indices": {"bufferView": view(struct.pack("<H", index)), "componentType": 5123},
                       "values": {"bufferView": view(struct.pack("<3f", *value))}},
        })
        return len(accessors) - 1

    flat = lambda rows: [c for r in rows for c in r]
    bounds = lambda rows: ([min(r[i] for r in rows) for i in range(3)],
                           [max(r[i] for r in rows) for i in range(3)])
    positions, normals, indices = sheet()
    n = len(positions)
    material = {"pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.6, 0.4, 1.0], "roughnessFactor": 0.6},
                "doubleSided": True}
    nodes = [{"name": "animated"}, {"name": "posed", "translation": [3.0, 0.0, 0.0]}]
    gltf = {
        "asset": {"version": "2.0", "generator": "envlight tests/data/animated/make_morphed.py"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": nodes,
        "materials": [material],
    }
    index_accessor = add(indices, "SCALAR", len(indices), 5123, "H")
    if baked_at is None:
        attributes = {"POSITION": add(flat(positions), "VEC3", n, minmax=bounds(positions)),
                      "NORMAL": add(flat(normals), "VEC3", n)}
        (peak, _), (tilt, tilt_normals) = targets(positions)
        morph = [{"POSITION": add_sparse(n, CENTRE, peak[CENTRE])},
                 {"POSITION": add(flat(tilt), "VEC3", n, minmax=bounds(tilt)),
                  "NORMAL": add(flat(tilt_normals), "VEC3", n)}]
        gltf["meshes"] = [{"name": "tent", "weights": [0.0, 0.0],
                           "extras": {"targetNames": ["peak", "tilt"]},
                           "primitives": [{"attributes": attributes, "indices": index_accessor,
                                           "material": 0, "targets": morph}]}]
        nodes[0]["mesh"] = 0
        nodes[1]["mesh"] = 0
        nodes[1]["weights"] = [0.5, 1.0]
        rise_times = add([0.0, 1.0, 2.0], "SCALAR", 3, minmax=([0.0], [2.0]))
        rise_weights = add([0.0, 0.0, 1.0, 0.0, 1.0, 1.0], "SCALAR", 6)
        blink_times = add([0.0, 0.5, 1.0], "SCALAR", 3, minmax=([0.0], [1.0]))
        blink_weights = add([0.0, 0.0, 1.0, 0.0, 1.0, 0.0], "SCALAR", 6)
        gltf["animations"] = [
            {"name": "rise", "samplers": [{"input": rise_times, "output": rise_weights}],
             "channels": [{"sampler": 0, "target": {"node": 0, "path": "weights"}}]},
            {"name": "blink",
             "samplers": [{"input": blink_times, "output": blink_weights, "interpolation": "STEP"}],
             "channels": [{"sampler": 0, "target": {"node": 0, "path": "weights"}}]},
        ]
    else:
        meshes = []
        for weights in (rise(baked_at), [0.5, 1.0]):
            p, nn = morphed(positions, normals, weights)
            attributes = {"POSITION": add(flat(p), "VEC3", n, minmax=bounds(p)),
                          "NORMAL": add(flat(nn), "VEC3", n)}
            meshes.append({"primitives": [{"attributes": attributes, "indices": index_accessor,
                                           "material": 0}]})
        gltf["meshes"] = meshes
        nodes[0]["mesh"] = 0
        nodes[1]["mesh"] = 1
    gltf["accessors"] = accessors
    gltf["bufferViews"] = views
    gltf["buffers"] = [{"byteLength": len(data),
                        "uri": "data:application/octet-stream;base64," + base64.b64encode(bytes(data)).decode()}]
    with open(out, "w") as f:
        json.dump(gltf, f, separators=(",", ":"))


if __name__ == "__main__":
    main()
