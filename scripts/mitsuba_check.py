#!/usr/bin/env python3
"""Cross-checks envlight's light lists against an independent renderer, Mitsuba 3.

DESIGN.md says a light list can be checked in Mitsuba: the lat-long axes are Mitsuba 3's, a
light's `dir` points towards the light and its `rgb` is the irradiance it gives at normal
incidence (W/m^2), so a light is Mitsuba's `directional` emitter with `direction` = -dir and
`irradiance` = rgb, and a Lambertian surface with normal n sees E(n) = sum rgb max(0, n.dir).

For 128 normals n (a Fibonacci sphere) Mitsuba (scalar_rgb, its `direct` integrator) measures
the radiance of a white Lambertian unit sphere at the point with normal n (a `radiancemeter`
looking at exactly that point), which is E(n)/pi:
  - under the map, Mitsuba's `envmap` emitter, given the .hdr/.exr file as it is and given the
    map resampled onto Mitsuba's rows so that it sees envlight's pixels (`on_envlight_rows`:
    Mitsuba puts an H-row image's rows at theta = pi j / (H - 1), envlight at
    pi (j + 0.5) / H);
  - under the lights `envlight decompose` made of the same file, as `directional` emitters.
Each is the mean of --batches renders of --spp samples with different seeds (averaged in
double precision); the spread of the batches gives the Monte Carlo noise of the mean.

Columns (relative RMS over the normals, luminance): envlight's E(n) = sum rgb max(0, n.dir)
against Mitsuba's map, from the file and resampled (the light list's diffuse error as Mitsuba
sees the map; compare docs/quality.md's "diffuse" column, measured against envlight's own
reference); the noise of the resampled map's mean; Mitsuba's render of the lights against the
same sum (the directional emitters read as documented: about its own noise, in brackets); and
a control, the sum with every light's x negated (a handedness error) against the resampled
map, which must be far larger, or the check could not see a convention error.

    python3 -m venv /tmp/mi && /tmp/mi/bin/pip install mitsuba numpy
    cargo build --release
    /tmp/mi/bin/python scripts/mitsuba_check.py tests/data/*.hdr tests/data/*LatLong.exr --batches 32

Prints a Markdown table (docs/quality.md, "Cross-check with Mitsuba 3"), one row per map and
light count; about a minute per map at the defaults on one core (--batches 32: two).
"""
import argparse
import json
import subprocess
import sys

import mitsuba as mi
import numpy as np

mi.set_variant("scalar_rgb")


def fibonacci_normals(n):
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(phi), z, r * np.sin(phi)], axis=1)


def luminance(rgb):
    return 0.2126 * rgb[..., 0] + 0.7152 * rgb[..., 1] + 0.0722 * rgb[..., 2]


def irradiance(emitters, normals, spp, batches):
    """Mitsuba's E(n) (luminance) at each normal: mean and standard error over the batches."""
    scene = {
        "type": "scene",
        "integrator": {"type": "direct"},
        "sphere": {
            "type": "sphere",
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [1, 1, 1]}},
        },
    }
    scene.update(emitters)
    for k, n in enumerate(normals):
        scene[f"meter{k}"] = {
            "type": "radiancemeter",
            "origin": [float(3 * c) for c in n],
            "direction": [float(-c) for c in n],
            "film": {"type": "hdrfilm", "width": 1, "height": 1, "rfilter": {"type": "box"},
                     "pixel_format": "rgb"},
        }
    scene = mi.load_dict(scene)
    samples = np.zeros((len(normals), batches))
    for k in range(len(normals)):
        for b in range(batches):
            rgb = np.array(mi.render(scene, sensor=k, spp=spp, seed=1000 * b + 7), dtype=np.float64)
            samples[k, b] = np.pi * luminance(rgb.reshape(3))
    return samples.mean(axis=1), samples.std(axis=1, ddof=1) / np.sqrt(batches)


def light_sum(lights, normals, mirror=False):
    """envlight's own E(n) = sum rgb max(0, n.dir), luminance."""
    dirs = np.array([l["dir"] for l in lights], dtype=np.float64).reshape(-1, 3)
    lum = luminance(np.array([l["rgb"] for l in lights], dtype=np.float64).reshape(-1, 3))
    if mirror:
        dirs[:, 0] = -dirs[:, 0]
    return np.maximum(normals @ dirs.T, 0.0) @ lum


def directional(lights):
    total = sum(luminance(np.array(l["rgb"])) for l in lights)
    emitters = {}
    for i, light in enumerate(lights):
        emitters[f"light{i}"] = {
            "type": "directional",
            "direction": [-c for c in light["dir"]],
            "irradiance": {"type": "rgb", "value": light["rgb"]},
            # Mitsuba picks one emitter per sample with probability proportional to this
            # weight: by luminance, so the bright ones are not left to chance.
            "sampling_weight": float(max(luminance(np.array(light["rgb"])) / total, 1e-6))
            if total > 0
            else 1.0,
        }
    return emitters


def on_envlight_rows(path, rows_per_pixel=4, columns_per_pixel=2):
    """The map as a Mitsuba bitmap whose samples sit where envlight's pixels are.

    Mitsuba's `envmap` reads an H-row image as samples on rows at theta = pi j / (H - 1), the
    first at the zenith and the last at the nadir, bilinearly interpolated; envlight (DESIGN.md)
    reads row j as the band theta in [pi j / H, pi (j + 1) / H] of constant radiance, centred at
    pi (j + 0.5) / H. Columns agree (centres at u = (i + 0.5) / W in both). This resamples the
    piecewise-constant map onto rows_per_pixel * H + 1 Mitsuba rows and columns_per_pixel * W
    columns, so that each band keeps its radiance over its own solid angle."""
    image = np.array(mi.Bitmap(path).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32,
                                             srgb_gamma=False), dtype=np.float32)
    height = image.shape[0]
    # Mitsuba row k sits at theta = pi k / (rows_per_pixel * height): inside band
    # k // rows_per_pixel, or on the boundary of two bands (k a multiple of rows_per_pixel),
    # where it takes their mean so that the interpolation is symmetric about the boundary.
    k = np.arange(rows_per_pixel * height + 1)
    above = np.clip((k - 1) // rows_per_pixel, 0, height - 1)
    below = np.clip(k // rows_per_pixel, 0, height - 1)
    rows = 0.5 * (image[above] + image[below])
    source_col = np.arange(columns_per_pixel * image.shape[1]) // columns_per_pixel
    return mi.Bitmap(np.ascontiguousarray(rows[:, source_col], dtype=np.float32))


def rel_rms(a, b):
    return float(np.sqrt(np.sum((a - b) ** 2) / np.sum(b**2)))


def main():
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("maps", nargs="+", help="lat-long .hdr or .exr files")
    parser.add_argument("--lights", default="64,256", help="light counts, comma-separated")
    parser.add_argument("--normals", type=int, default=128, help="normals (Fibonacci sphere)")
    parser.add_argument("--spp", type=int, default=4096, help="samples per render")
    parser.add_argument("--batches", type=int, default=16, help="renders averaged per normal")
    parser.add_argument("--envlight", default="target/release/envlight", help="the envlight binary")
    args = parser.parse_args()
    counts = [int(n) for n in args.lights.split(",")]
    normals = fibonacci_normals(args.normals)

    print("| map | N | envlight vs Mitsuba, map file | envlight vs Mitsuba, map on envlight's rows "
          "| noise | Mitsuba's lights vs envlight [noise] | mirrored vs Mitsuba, envlight's rows |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for path in args.maps:
        as_file, _ = irradiance(
            {"env": {"type": "envmap", "filename": path}}, normals, args.spp, args.batches)
        reference, reference_se = irradiance(
            {"env": {"type": "envmap", "bitmap": on_envlight_rows(path)}}, normals, args.spp,
            args.batches)
        noise = float(np.sqrt(np.sum(reference_se**2) / np.sum(reference**2)))
        name = path.rsplit("/", 1)[-1].rsplit(".", 1)[0]
        for n in counts:
            out = subprocess.run([args.envlight, "decompose", path, "--lights", str(n)],
                                 check=True, capture_output=True, text=True)
            lights = json.loads(out.stdout.splitlines()[0])["lights"]
            ours = light_sum(lights, normals)
            rendered, rendered_se = irradiance(directional(lights), normals, args.spp, args.batches)
            rendered_noise = float(np.sqrt(np.sum(rendered_se**2) / np.sum(ours**2)))
            mirrored = light_sum(lights, normals, mirror=True)
            print(f"| {name} | {n} | {rel_rms(ours, as_file):.4f} | {rel_rms(ours, reference):.4f} "
                  f"| {noise:.4f} | {rel_rms(rendered, ours):.4f} [{rendered_noise:.4f}] | "
                  f"{rel_rms(mirrored, reference):.4f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
