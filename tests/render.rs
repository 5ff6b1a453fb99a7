//! GPU tests of the renderer, on whatever adapter wgpu finds (lavapipe on CI). A missing adapter
//! FAILS these tests with the install hint: they never skip silently.
//!
//! Golden images live in tests/data/golden/; `ENVLIGHT_BLESS=1 cargo test --release --test
//! render` rewrites them. A failing comparison writes the actual and difference images to
//! `$CARGO_TARGET_DIR/golden-failures/` (default `target/golden-failures/`).

// Per-channel loops over rgb triples read better than zipped iterators.
#![allow(clippy::needless_range_loop)]

use envlight::light::Light;
use envlight::render::scene::{AlphaMode, Camera, Ground, Material, Scene, TextureImage};
use envlight::render::{
    light_prefix, output, Image, RenderSettings, Renderer, ShadowRaster, CULLING_TOLERANCE,
};
use glam::Vec3;
use std::f32::consts::PI;
use std::path::{Path, PathBuf};

/// Both ways of drawing the shadow maps: the tests of shadows run on each.
const RASTERS: [ShadowRaster; 2] = [ShadowRaster::Pipeline, ShadowRaster::Compute];

fn renderer(scene: Scene, settings: RenderSettings) -> Renderer {
    Renderer::new(scene, settings).unwrap_or_else(|e| {
        panic!(
            "GPU tests need a graphics adapter; on a machine without a GPU install Mesa's \
             lavapipe (apt-get install mesa-vulkan-drivers libvulkan1): {e}"
        )
    })
}

fn light(id: u32, dir: Vec3, rgb: [f32; 3], solid_angle: f32) -> Light {
    Light {
        id,
        dir: dir.normalize().to_array(),
        rgb,
        solid_angle,
    }
}

/// A deterministic sky-like light set: `n` lights on a Fibonacci sphere, brighter towards a
/// sun direction and above the horizon, each covering 4π/n, plus a small bright sun.
fn sky_lights(n: usize) -> Vec<Light> {
    let sun = Vec3::new(0.5, 0.7, 0.4).normalize();
    let golden = PI * (3.0 - 5f32.sqrt());
    let mut v: Vec<Light> = (1..n)
        .map(|i| {
            let y = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let r = (1.0 - y * y).sqrt();
            let phi = golden * i as f32;
            let d = Vec3::new(r * phi.cos(), y, r * phi.sin());
            let sky = if d.y > 0.0 { 1.0 + 3.0 * d.y } else { 0.3 };
            let w = 4.0 * PI / n as f32;
            let glow = 1.0 + 20.0 * d.dot(sun).max(0.0).powi(8);
            light(
                i as u32,
                d,
                [
                    0.6 * sky * glow * w * 20.0,
                    0.8 * sky * glow * w * 20.0,
                    sky * glow * w * 20.0,
                ],
                w,
            )
        })
        .collect();
    v.insert(0, light(0, sun, [400.0, 380.0, 340.0], 6.8e-5));
    v
}

fn lum(p: [f32; 4]) -> f32 {
    0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]
}

fn failure_dir() -> PathBuf {
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target"));
    let dir = target.join("golden-failures");
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Panics with the first failures, after writing the image to the failure folder.
fn fail_with_image(name: &str, img: &Image, failures: &[String]) {
    if failures.is_empty() {
        return;
    }
    let path = failure_dir().join(format!("{name}.actual.exr"));
    output::write_exr(&path, img).unwrap();
    panic!(
        "{} pixel values off (image written to {}):\n{}",
        failures.len(),
        path.display(),
        failures[..failures.len().min(10)].join("\n")
    );
}

/// Ray-sphere intersection: the nearest t > 0.
fn hit_sphere(o: Vec3, d: Vec3, c: Vec3, r: f32) -> Option<f32> {
    let oc = o - c;
    let b = oc.dot(d);
    let disc = b * b - (oc.length_squared() - r * r);
    if disc < 0.0 {
        return None;
    }
    let t = -b - disc.sqrt();
    (t > 0.0).then_some(t)
}

/// The pixels of a `size`×`size` render that see the unit sphere at the origin from `eye`, away
/// from its silhouette (n·v ≥ 0.3): (x, y, the exact normal, the unit direction to the eye).
fn sphere_pixels(r: &Renderer, eye: Vec3, size: u32) -> Vec<(u32, u32, Vec3, Vec3)> {
    let mut pixels = Vec::new();
    for y in 0..size {
        for x in 0..size {
            let d = r.pixel_ray(x as f32, y as f32);
            let Some(t) = hit_sphere(eye, d, Vec3::ZERO, 1.0) else {
                continue;
            };
            let n = (eye + d * t).normalize();
            if n.dot(-d) >= 0.3 {
                pixels.push((x, y, n, -d));
            }
        }
    }
    pixels
}

#[test]
fn diffuse_sphere_matches_the_analytic_reference_within_one_percent() {
    let albedo = [0.8, 0.6, 0.4];
    let camera = Camera::perspective(Vec3::new(0.0, 0.5, 4.0), Vec3::ZERO, 35f32.to_radians());
    let scene = Scene::sphere(
        Vec3::ZERO,
        1.0,
        160,
        Material::lambertian(albedo),
        None,
        camera,
    );
    let lights = vec![
        light(0, Vec3::new(0.3, 1.0, 0.5), [300.0, 280.0, 250.0], 1e-4),
        light(1, Vec3::new(-1.0, 0.2, 0.4), [60.0, 80.0, 120.0], 0.02),
        light(2, Vec3::new(0.8, -0.3, 0.6), [40.0, 30.0, 20.0], 0.05),
        light(3, Vec3::new(0.0, 0.1, -1.0), [100.0, 100.0, 100.0], 0.01),
        light(4, Vec3::new(-0.2, 0.9, 0.9), [25.0, 50.0, 25.0], 0.1),
    ];
    let mut r = renderer(
        scene,
        RenderSettings {
            width: 96,
            height: 96,
            shadow_resolution: 512,
            ..Default::default()
        },
    );
    let (img, stats) = r.render(&lights).unwrap();
    assert_eq!(stats.lights, 5);
    let mut failures = Vec::new();
    let mut checked = 0;
    let mut worst = 0.0f32;
    for (x, y, n, _) in sphere_pixels(&r, camera.eye, 96) {
        let mut e = [0.0f32; 3];
        for l in &lights {
            let cos = n.dot(Vec3::from_array(l.dir)).max(0.0);
            for c in 0..3 {
                e[c] += l.rgb[c] * cos;
            }
        }
        let px = img.pixel(x, y);
        for c in 0..3 {
            let want = albedo[c] / PI * e[c];
            let rel = (px[c] - want).abs() / want.max(1e-3);
            worst = worst.max(rel);
            if rel > 0.01 {
                failures.push(format!(
                    "pixel ({x},{y}) channel {c}: GPU {} vs CPU {want} ({:.3}% off)",
                    px[c],
                    rel * 100.0
                ));
            }
        }
        checked += 1;
    }
    fail_with_image("diffuse_sphere", &img, &failures);
    assert!(checked > 2500, "only {checked} pixels checked");
    eprintln!(
        "diffuse sphere: {checked} pixels, worst relative error {:.4}%",
        worst * 100.0
    );
}

#[test]
fn ground_behind_the_occluder_lacks_exactly_that_lights_contribution() {
    for raster in RASTERS {
        ground_behind_the_occluder(raster);
    }
}

fn ground_behind_the_occluder(raster: ShadowRaster) {
    let albedo = 0.5;
    let center = Vec3::new(0.0, 0.9, 0.0);
    let radius = 0.5;
    let camera = Camera::perspective(
        Vec3::new(0.0, 4.5, 4.0),
        Vec3::new(0.0, 0.0, 0.3),
        45f32.to_radians(),
    );
    let scene = Scene::sphere(
        center,
        radius,
        64,
        Material::default(),
        Some(Ground {
            height: 0.0,
            half_size: 4.0,
            material: Material::lambertian([albedo; 3]),
        }),
        camera,
    );
    let lights = vec![
        light(0, Vec3::new(0.9, 1.0, 0.3), [300.0, 280.0, 260.0], 1e-5),
        light(1, Vec3::new(-0.8, 1.0, -0.2), [200.0, 210.0, 220.0], 1e-5),
        light(2, Vec3::new(0.2, 1.0, -0.8), [150.0, 150.0, 160.0], 1e-5),
    ];
    let (w, h) = (128, 96);
    let mut r = renderer(
        scene,
        RenderSettings {
            width: w,
            height: h,
            shadow_resolution: 1024,
            shadow_raster: raster,
            ..Default::default()
        },
    );
    let (img, stats) = r.render(&lights).unwrap();
    assert_eq!(stats.shadow_maps, 3);
    let mut failures = Vec::new();
    let mut shadowed = [0usize; 3];
    let mut lit_checked = 0;
    for y in 0..h {
        for x in 0..w {
            let d = r.pixel_ray(x as f32, y as f32);
            if d.y >= -1e-3 {
                continue;
            }
            let t = -camera.eye.y / d.y;
            let p = camera.eye + d * t;
            if p.x.abs() > 3.5 || p.z.abs() > 3.5 {
                continue;
            }
            // The sphere hides this ground point from the camera (with a margin).
            let to_c = center - camera.eye;
            let along = to_c.dot(d);
            if along > 0.0 && (to_c - d * along).length() < radius * 1.2 {
                continue;
            }
            let mut expected = [0.0f32; 3];
            let mut ambiguous = false;
            let mut in_shadow = [false; 3];
            for (i, l) in lights.iter().enumerate() {
                let ld = Vec3::from_array(l.dir);
                let pc = center - p;
                let s = pc.dot(ld);
                let miss = (pc - ld * s).length();
                if s > 0.0 && miss < radius * 0.9 {
                    in_shadow[i] = true;
                } else if s > 0.0 && miss < radius * 1.1 {
                    ambiguous = true;
                } else {
                    for c in 0..3 {
                        expected[c] += albedo / PI * l.rgb[c] * ld.y;
                    }
                }
            }
            if ambiguous {
                continue;
            }
            let px = img.pixel(x, y);
            for c in 0..3 {
                let rel = (px[c] - expected[c]).abs() / expected[c].max(1e-3);
                if rel > 0.01 {
                    failures.push(format!(
                        "{raster:?}: ground pixel ({x},{y}) shadowed by {in_shadow:?}: channel \
                         {c} GPU {} vs {} ({:.2}% off)",
                        px[c],
                        expected[c],
                        rel * 100.0
                    ));
                }
            }
            for i in 0..3 {
                shadowed[i] += usize::from(in_shadow[i]);
            }
            lit_checked += usize::from(!in_shadow.iter().any(|&s| s));
        }
    }
    fail_with_image(
        &format!("ground_shadows_{}", raster.name()),
        &img,
        &failures,
    );
    for (i, n) in shadowed.iter().enumerate() {
        assert!(
            *n >= 20,
            "only {n} pixels in light {i}'s shadow were checked"
        );
    }
    assert!(lit_checked > 1000, "{lit_checked}");
}

/// Differences between two renders, relative to the mean of the reference's opaque pixels:
/// (mean absolute, 99.9th percentile, maximum).
fn relative_differences(reference: &Image, other: &Image) -> (f32, f32, f32) {
    let opaque: Vec<usize> = (0..reference.rgba.len() / 4)
        .filter(|&i| reference.rgba[4 * i + 3] > 0.0)
        .collect();
    let mean: f32 = opaque
        .iter()
        .map(|&i| reference.rgba[4 * i..4 * i + 3].iter().sum::<f32>() / 3.0)
        .sum::<f32>()
        / opaque.len() as f32;
    let mut diffs: Vec<f32> = opaque
        .iter()
        .flat_map(|&i| (0..4).map(move |c| 4 * i + c))
        .map(|k| {
            let scale = if k % 4 == 3 { 1.0 } else { mean };
            (reference.rgba[k] - other.rgba[k]).abs() / scale
        })
        .collect();
    diffs.sort_by(f32::total_cmp);
    let avg = diffs.iter().sum::<f32>() / diffs.len() as f32;
    let p999 = diffs[(diffs.len() as f64 * 0.999) as usize];
    (avg, p999, *diffs.last().unwrap())
}

/// A budget's prefix of the light set lights the scene as brightly as every light (its lights
/// carry the dropped ones' power): the mean luminance of an unshadowed render of 32 of 256
/// lights is within 10% of the full render's (a plain truncation of 64 lights to 16 rendered
/// a uniform sky at 0.22 of full, as measured through `envlight render --budget-ms`).
#[test]
fn a_budget_prefix_keeps_the_scene_as_bright() {
    let lights = sky_lights(256);
    let mut r = renderer(
        Scene::default_scene(),
        RenderSettings {
            width: 96,
            height: 64,
            shadows: false,
            ..Default::default()
        },
    );
    let mean = |img: &Image| -> f64 {
        let px: Vec<f64> = (img.rgba.chunks_exact(4))
            .map(|p| f64::from(lum([p[0], p[1], p[2], p[3]])))
            .collect();
        px.iter().sum::<f64>() / px.len() as f64
    };
    let (full, _) = r.render(&lights).unwrap();
    for count in [32, 128] {
        let (prefix, _) = r.render(&light_prefix(&lights, count)).unwrap();
        let ratio = mean(&prefix) / mean(&full);
        eprintln!("{count} of 256 lights: mean luminance {ratio:.4} of the full render's");
        assert!((0.9..=1.1).contains(&ratio), "{count} lights: {ratio}");
    }
}

#[test]
fn culling_on_and_off_agree_within_the_stated_tolerance() {
    let lights = sky_lights(64);
    let mut r = renderer(
        Scene::default_scene(),
        RenderSettings {
            width: 128,
            height: 80,
            shadow_resolution: 256,
            culling: false,
            ..Default::default()
        },
    );
    let (full, _) = r.render(&lights).unwrap();
    r.set_culling(true);
    let (culled, _) = r.render(&lights).unwrap();
    let (mean, p999, max) = relative_differences(&full, &culled);
    eprintln!("culling on vs off: mean {mean:.5}, 99.9th percentile {p999:.5}, max {max:.5}");
    let (tol_mean, tol_p999) = CULLING_TOLERANCE;
    assert!(mean <= tol_mean, "mean difference {mean} > {tol_mean}");
    assert!(p999 <= tol_p999, "99.9th percentile {p999} > {tol_p999}");
    // Nearly every pixel is identical: only off-lobe penumbrae differ.
    let same = full
        .rgba
        .iter()
        .zip(&culled.rgba)
        .filter(|(a, b)| (*a - *b).abs() <= 1e-4 * a.abs().max(1.0))
        .count();
    assert!(
        same as f64 > 0.9 * full.rgba.len() as f64,
        "{same} of {}",
        full.rgba.len()
    );
}

#[test]
fn merged_light_spread_softens_its_shadow() {
    let camera = Camera::perspective(Vec3::new(0.0, 5.0, 0.01), Vec3::ZERO, 40f32.to_radians());
    let scene = || {
        Scene::sphere(
            Vec3::new(0.0, 0.8, 0.0),
            0.4,
            48,
            Material::default(),
            Some(Ground {
                height: 0.0,
                half_size: 4.0,
                material: Material::lambertian([0.5; 3]),
            }),
            camera,
        )
    };
    let settings = RenderSettings {
        width: 96,
        height: 96,
        shadow_resolution: 512,
        shadow_catcher: true,
        ..Default::default()
    };
    let mut r = renderer(scene(), settings);
    let penumbra = |r: &mut Renderer, omega: f32| {
        let l = [light(0, Vec3::new(0.3, 1.0, 0.2), [100.0; 3], omega)];
        let (img, _) = r.render(&l).unwrap();
        let ground: Vec<f32> = (0..img.rgba.len() / 4)
            .filter(|&i| img.rgba[4 * i..4 * i + 3] == [0.0; 3])
            .map(|i| img.rgba[4 * i + 3])
            .collect();
        let soft = ground.iter().filter(|a| **a > 0.05 && **a < 0.95).count();
        let dark = ground.iter().filter(|a| **a >= 0.95).count();
        (soft, dark)
    };
    let (hard_soft, hard_dark) = penumbra(&mut r, 1e-5);
    let (merged_soft, _) = penumbra(&mut r, 0.05);
    assert!(
        hard_dark > 100,
        "the sharp shadow has an umbra: {hard_dark}"
    );
    assert!(
        merged_soft > 2 * hard_soft.max(1),
        "penumbra pixels: point light {hard_soft}, merged light {merged_soft}"
    );
}

/// Shading is a sum over lights, each with the shadow map it was given: in a set of 20 lights
/// the wide light X (half a steradian: a PCF kernel 0.12 of its map wide) gets layer 17. X's
/// contribution — the image of all 20 lights minus the image without X — must equal the image
/// of X alone (layer 0 of a one-layer array), to float rounding: a light reading another's
/// layer, or a pass writing the wrong one, breaks it.
#[test]
fn each_light_reads_its_own_shadow_layer() {
    for raster in RASTERS {
        each_light_reads_its_own_map(raster);
    }
}

fn each_light_reads_its_own_map(raster: ShadowRaster) {
    let camera = Camera::perspective(
        Vec3::new(0.0, 5.0, 3.0),
        Vec3::new(0.0, 0.3, 0.0),
        50f32.to_radians(),
    );
    let scene = || {
        Scene::sphere(
            Vec3::new(0.0, 0.8, 0.0),
            0.5,
            32,
            Material::default(),
            Some(Ground {
                height: 0.0,
                half_size: 4.0,
                material: Material::lambertian([0.5; 3]),
            }),
            camera,
        )
    };
    let settings = RenderSettings {
        width: 96,
        height: 72,
        shadow_resolution: 512,
        shadow_raster: raster,
        ..Default::default()
    };
    let wide = 17;
    let lights: Vec<Light> = (0..20u32)
        .map(|i| {
            let a = i as f32 * 2.4;
            let dir = Vec3::new(a.cos(), 1.2 + 0.05 * i as f32, a.sin());
            if i == wide {
                light(i, Vec3::new(0.4, 1.0, 0.5), [60.0, 55.0, 50.0], 0.5)
            } else {
                light(i, dir, [10.0, 11.0, 12.0], 1e-4)
            }
        })
        .collect();
    let without: Vec<Light> = lights.iter().filter(|l| l.id != wide).cloned().collect();
    let alone = vec![lights[wide as usize]];
    let mut r = renderer(scene(), settings);
    let (all_img, stats) = r.render(&lights).unwrap();
    assert_eq!(stats.shadow_maps, 20, "every light needs a map");
    let (without_img, _) = r.render(&without).unwrap();
    let mut r_alone = renderer(scene(), settings);
    let (alone_img, _) = r_alone.render(&alone).unwrap();
    // X's shadow is in the image: rendered without shadows, X alone lights more pixels.
    let mut r_unshadowed = renderer(
        scene(),
        RenderSettings {
            shadows: false,
            ..settings
        },
    );
    let (unshadowed_img, _) = r_unshadowed.render(&alone).unwrap();
    let peak = alone_img.rgba.iter().fold(0.0f32, |m, v| m.max(*v));
    let mut failures = Vec::new();
    let mut shadowed = 0;
    for i in 0..alone_img.rgba.len() / 4 {
        if alone_img.rgba[4 * i + 3] == 0.0 {
            continue;
        }
        shadowed += usize::from(alone_img.rgba[4 * i + 1] < 0.8 * unshadowed_img.rgba[4 * i + 1]);
        for c in 0..3 {
            let k = 4 * i + c;
            let contribution = all_img.rgba[k] - without_img.rgba[k];
            let tolerance = 1e-3 * peak + 1e-5 * all_img.rgba[k];
            if (contribution - alone_img.rgba[k]).abs() > tolerance {
                failures.push(format!(
                    "pixel {i} channel {c}: X adds {contribution} among 20 lights, {} alone",
                    alone_img.rgba[k]
                ));
            }
        }
    }
    fail_with_image(
        &format!("own_shadow_layer_{}", raster.name()),
        &all_img,
        &failures,
    );
    assert!(
        peak > 0.0 && shadowed > 25,
        "{raster:?}: pixels X lights at under 80% of its unshadowed value: {shadowed}"
    );
}

/// A 96×64 renderer of the built-in scene whose ground is a shadow catcher.
fn default_scene_catcher() -> Renderer {
    renderer(
        Scene::default_scene(),
        RenderSettings {
            width: 96,
            height: 64,
            shadow_resolution: 256,
            shadow_catcher: true,
            ..Default::default()
        },
    )
}

#[test]
fn shadow_catcher_output_composites_over_a_camera_image() {
    let mut r = default_scene_catcher();
    let (mut img, _) = r
        .render(&[light(0, Vec3::new(0.2, 1.0, 0.3), [500.0; 3], 1e-4)])
        .unwrap();
    // Ground pixels: zero colour and alpha = shadow fraction; the objects are opaque; the ground
    // far from the objects is transparent.
    let (mut shadow, mut clear, mut opaque) = (0, 0, 0);
    for p in img.rgba.chunks_exact(4) {
        if p[3] >= 0.999 && lum([p[0], p[1], p[2], p[3]]) > 0.0 {
            opaque += 1;
        } else if p[..3] == [0.0; 3] && p[3] > 0.5 {
            shadow += 1;
        } else if p[3] < 0.01 {
            clear += 1;
        }
    }
    assert!(
        opaque > 300 && shadow > 50 && clear > 1000,
        "{opaque} {shadow} {clear}"
    );
    // Compositing over a grey camera image darkens it exactly by the shadow's alpha.
    let before = img.clone();
    output::composite_background(&mut img, |_, _| [1.0, 1.0, 1.0]);
    for (a, b) in before.rgba.chunks_exact(4).zip(img.rgba.chunks_exact(4)) {
        let want = a[0] + (1.0 - a[3].clamp(0.0, 1.0));
        assert!(
            (b[0] - want).abs() <= 1e-5 * want.abs().max(1.0),
            "{a:?} → {b:?}"
        );
        assert_eq!(b[3], 1.0);
    }
}

#[test]
fn lights_that_reach_no_visible_surface_render_no_map() {
    // Seen from straight above, only the ground and the sphere's upper half are visible.
    let camera = Camera::perspective(Vec3::new(0.0, 6.0, 0.01), Vec3::ZERO, 0.7);
    let scene = Scene::sphere(
        Vec3::new(0.0, 0.5, 0.0),
        0.5,
        32,
        Material::default(),
        Some(Ground {
            height: 0.0,
            half_size: 4.0,
            material: Material::default(),
        }),
        camera,
    );
    let settings = RenderSettings {
        width: 32,
        height: 32,
        shadow_resolution: 64,
        ..Default::default()
    };
    let mut r = renderer(scene, settings);
    let (_, stats) = r
        .render(&[
            light(0, Vec3::new(0.0, -1.0, 0.0), [10.0; 3], 0.01),
            light(1, Vec3::new(0.0, 1.0, 0.0), [10.0; 3], 0.01),
            light(2, Vec3::new(f32::NAN, 1.0, 0.0), [10.0; 3], 0.01),
        ])
        .unwrap();
    assert_eq!(stats.lights, 2, "the NaN light is dropped");
    assert_eq!(
        stats.shadow_maps, 1,
        "only the light from above needs a map"
    );
    assert!(stats.frame_ms() > 0.0);
}

/// Compares an image with its golden PNG (tone-mapped, fixed exposure). Tolerance: every 8-bit
/// channel within 6 levels on ≥ 99.5% of pixels, and a mean absolute difference ≤ 0.5 levels.
fn check_golden(name: &str, img: &Image, exposure: f32) {
    let actual = output::to_rgba8(img, exposure);
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/golden")
        .join(format!("{name}.png"));
    let save = |p: &std::path::Path, bytes: &[u8]| {
        image::save_buffer_with_format(
            p,
            bytes,
            img.width,
            img.height,
            image::ExtendedColorType::Rgba8,
            image::ImageFormat::Png,
        )
        .unwrap()
    };
    if std::env::var_os("ENVLIGHT_BLESS").is_some() {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        save(&path, &actual);
        eprintln!("blessed {}", path.display());
        return;
    }
    let golden = image::open(&path)
        .unwrap_or_else(|e| {
            panic!(
                "golden image {} missing or unreadable ({e}); run with ENVLIGHT_BLESS=1 to create it",
                path.display()
            )
        })
        .to_rgba8();
    assert_eq!((golden.width(), golden.height()), (img.width, img.height));
    let diff: Vec<u8> = actual
        .iter()
        .zip(golden.as_raw())
        .map(|(a, b)| a.abs_diff(*b))
        .collect();
    let mean = diff.iter().map(|&d| f64::from(d)).sum::<f64>() / diff.len() as f64;
    let bad_pixels = diff
        .chunks_exact(4)
        .filter(|p| p.iter().any(|&d| d > 6))
        .count();
    let frac_bad = bad_pixels as f64 / (img.width * img.height) as f64;
    if mean > 0.5 || frac_bad > 0.005 {
        let dir = failure_dir();
        let actual_path = dir.join(format!("{name}.actual.png"));
        let diff_path = dir.join(format!("{name}.diff.png"));
        save(&actual_path, &actual);
        // Differences amplified ×16, opaque.
        let amplified: Vec<u8> = diff
            .chunks_exact(4)
            .flat_map(|p| {
                [
                    p[0].saturating_mul(16),
                    p[1].saturating_mul(16),
                    p[2].saturating_mul(16),
                    255,
                ]
            })
            .collect();
        save(&diff_path, &amplified);
        panic!(
            "{name}: differs from {} (mean {mean:.3} levels, {:.2}% of pixels off by > 6); \
             wrote {} and {}",
            path.display(),
            frac_bad * 100.0,
            actual_path.display(),
            diff_path.display()
        );
    }
}

/// The default scene at 128×80 under 24 sky lights against golden image `name`, with both
/// ways of drawing the shadow maps: the goldens were drawn with render passes, and the compute
/// rasteriser's images must match them within the same tolerance.
fn check_golden_default_scene(name: &str, shadow_catcher: bool) {
    for raster in RASTERS {
        let mut r = renderer(
            Scene::default_scene(),
            RenderSettings {
                width: 128,
                height: 80,
                shadow_resolution: 256,
                shadow_catcher,
                shadow_raster: raster,
                ..Default::default()
            },
        );
        let (img, _) = r.render(&sky_lights(24)).unwrap();
        check_golden(name, &img, 0.003);
    }
}

#[test]
fn golden_default_scene() {
    check_golden_default_scene("default_scene", false);
}

#[test]
fn golden_mixed_reality() {
    check_golden_default_scene("mixed_reality", true);
}

/// Compute-rasterised shadow maps against the render passes' on the default scene under 64 sky
/// lights: the same texel centres and bias, so only penumbra texels (and the comparison's
/// filter weights: the sampler's fixed point against f32) differ. Bound: mean ≤ 5·10⁻⁵ and
/// 99.9th percentile ≤ 5·10⁻³ of the mean opaque value (measured on lavapipe: 2·10⁻⁶ and
/// 6.0·10⁻⁴; the shadows themselves change the image by 0.039 on average).
#[test]
fn compute_shadow_maps_match_the_render_passes() {
    // Both compute kernels are in play: the box's faces are large triangles, the spheres' small.
    let (ids, small) = envlight::render::shadow_raster::split_by_size(&Scene::default_scene(), 200);
    assert!(
        small > 0 && (small as usize) < ids.len(),
        "{small} of {}",
        ids.len()
    );
    let lights = sky_lights(64);
    let render = |raster, shadows| {
        let mut r = renderer(
            Scene::default_scene(),
            RenderSettings {
                width: 128,
                height: 80,
                // Not a power of two, not a multiple of 64.
                shadow_resolution: 200,
                shadows,
                shadow_raster: raster,
                ..Default::default()
            },
        );
        r.render(&lights).unwrap().0
    };
    let passes = render(ShadowRaster::Pipeline, true);
    let compute = render(ShadowRaster::Compute, true);
    let unshadowed = render(ShadowRaster::Pipeline, false);
    let (mean, p999, max) = relative_differences(&passes, &compute);
    eprintln!(
        "compute vs render-pass maps: mean {mean:.6}, 99.9th percentile {p999:.5}, max {max:.5}"
    );
    // What the shadows themselves change, so the bound above means something.
    let (shadow_mean, ..) = relative_differences(&passes, &unshadowed);
    eprintln!("shadows on vs off: mean {shadow_mean:.5}");
    assert!(
        shadow_mean > 0.02,
        "the scene barely has shadows: {shadow_mean}"
    );
    assert!(mean <= 5e-5, "mean difference {mean} > 5e-5");
    assert!(p999 <= 5e-3, "99.9th percentile {p999} > 5e-3");
}

/// The automatic exposure is fixed from the first frame with lit pixels: a first frame
/// without lights (black) used to fix it at 1, and every later frame came out nearly white.
/// Frame 1's PNG is the same with and without a black frame before it.
#[test]
fn cli_exposure_comes_from_the_first_lit_frame() {
    let dir = tempfile::tempdir().unwrap();
    let frame = |seq: u64, n: usize| {
        let lights: Vec<Light> = sky_lights(8).into_iter().take(n).collect();
        serde_json::json!({"seq": seq, "time": 0.0, "lights": lights}).to_string()
    };
    let render = |name: &str, text: String| {
        let lights = dir.path().join(format!("{name}.jsonl"));
        std::fs::write(&lights, text).unwrap();
        let out = dir.path().join(name);
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
            .args(["render", "--size", "48x32", "--no-shadows", "--lights"])
            .arg(&lights)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read(out.join("frame_00001.png")).unwrap()
    };
    let after_black = render("after_black", format!("{}\n{}\n", frame(0, 0), frame(1, 8)));
    let alone = render("alone", format!("{}\n", frame(1, 8)));
    assert!(
        after_black == alone,
        "frame 1 is exposed differently after a black frame"
    );
}

#[test]
fn cli_renders_png_and_exr_per_frame() {
    let dir = tempfile::tempdir().unwrap();
    let lights = dir.path().join("lights.jsonl");
    let frame = |seq: u64| {
        serde_json::json!({"seq": seq, "time": 0.0, "lights": sky_lights(8)}).to_string()
    };
    std::fs::write(&lights, format!("{}\n{}\n", frame(0), frame(1))).unwrap();
    let out = dir.path().join("out");
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
        .args([
            "render",
            "--size",
            "48x32",
            "--shadow-res",
            "64",
            "--lights",
        ])
        .arg(&lights)
        .arg("--out")
        .arg(&out)
        // As under a service: no session. Mesa's device-selection layer then made libwayland
        // print "error: XDG_RUNTIME_DIR is invalid …" on a successful render.
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("NODEVICE_SELECT")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&status.stderr);
    assert!(status.status.success(), "{stderr}");
    assert!(!stderr.contains("error"), "{stderr}");
    for f in [
        "frame_00000.png",
        "frame_00000.exr",
        "frame_00001.png",
        "frame_00001.exr",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let png = image::open(out.join("frame_00001.png")).unwrap();
    assert_eq!((png.width(), png.height()), (48, 32));
    let stats = std::fs::read_to_string(out.join("stats.jsonl")).unwrap();
    assert_eq!(stats.lines().count(), 2);
    for line in stats.lines() {
        // The CPU's share of the frame is part of its wall time.
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        let (encode, cpu) = (v["encode_ms"].as_f64(), v["cpu_ms"].as_f64());
        assert!(
            matches!((encode, cpu), (Some(e), Some(c)) if e > 0.0 && e <= c),
            "{line}"
        );
    }
    // Supersampled: the same image size; a factor past 4 is a usage error.
    let supersampled = dir.path().join("supersampled");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
        .args([
            "render",
            "--size",
            "48x32",
            "--supersample",
            "2",
            "--lights",
        ])
        .arg(&lights)
        .arg("--out")
        .arg(&supersampled)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let png = image::open(supersampled.join("frame_00001.png")).unwrap();
    assert_eq!((png.width(), png.height()), (48, 32));
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
        .args(["render", "--supersample", "5", "--out"])
        .arg(dir.path().join("never"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("--supersample"), "{stderr}");

    // A bad scene file is an error that names it, not a panic.
    let bad = dir.path().join("bad.glb");
    std::fs::write(&bad, b"glTF garbage").unwrap();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
        .args(["render", "--out"])
        .arg(&out)
        .arg("--scene")
        .arg(&bad)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("bad.glb"));
}

/// `envlight render` with a budget: a frame's light count follows the budget, not the first
/// frame's count (a first frame of one light held every later frame at one); and an output
/// that would overwrite the light list read is refused.
#[test]
fn cli_budget_follows_each_frame_and_inputs_are_not_overwritten() {
    let dir = tempfile::tempdir().unwrap();
    let lights = dir.path().join("lights.jsonl");
    let frame = |seq: u64, n: usize| {
        serde_json::json!({"seq": seq, "time": 0.0, "lights": sky_lights(n)}).to_string()
    };
    let text: Vec<String> = [1, 40, 40, 40, 40, 40, 40, 40]
        .iter()
        .enumerate()
        .map(|(seq, &n)| frame(seq as u64, n))
        .collect();
    std::fs::write(&lights, text.join("\n") + "\n").unwrap();
    let out = dir.path().join("out");
    let run = |out: &std::path::Path| {
        std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
            .args(["render", "--size", "16x12", "--shadow-res", "16"])
            .args(["--budget-ms", "100000", "--lights"])
            .arg(&lights)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap()
    };
    let o = run(&out);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stats = std::fs::read_to_string(out.join("stats.jsonl")).unwrap();
    let counts: Vec<u64> = stats
        .lines()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["lights"]
                .as_u64()
                .unwrap()
        })
        .collect();
    // Far under budget the count doubles each frame (the controller's largest step) until it
    // holds every light of the frame.
    assert_eq!(counts, [1, 2, 4, 8, 16, 32, 40, 40], "{stats}");
    // The output folder holding the light list as stats.jsonl: refused, the list kept.
    std::fs::copy(&lights, out.join("stats.jsonl")).unwrap();
    let before = std::fs::read(out.join("stats.jsonl")).unwrap();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
        .args([
            "render",
            "--size",
            "16x12",
            "--shadow-res",
            "16",
            "--lights",
        ])
        .arg(out.join("stats.jsonl"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("is the input file"));
    assert_eq!(std::fs::read(out.join("stats.jsonl")).unwrap(), before);
}

/// Lobes for the ASG tests: a sharp sun-like lobe, a wide sky, an anisotropic streak, a lobe
/// from behind the sphere.
fn test_lobes() -> Vec<envlight::asg::Asg> {
    use envlight::asg::Asg;
    use glam::DVec3;
    vec![
        Asg::new(
            DVec3::new(0.3, 1.0, 0.5),
            DVec3::X,
            200.0,
            60.0,
            [50.0, 45.0, 40.0],
        ),
        Asg::new(DVec3::Y, DVec3::Z, 1.5, 1.5, [2.0, 3.0, 4.0]),
        Asg::new(
            DVec3::new(-1.0, 0.2, 0.4),
            DVec3::Y,
            30.0,
            3.0,
            [6.0, 4.0, 2.0],
        ),
        Asg::new(
            DVec3::new(0.5, -0.3, 1.0),
            DVec3::X,
            5.0,
            10.0,
            [3.0, 3.0, 3.0],
        ),
    ]
    .into_iter()
    .map(|a| a.expect("valid lobe"))
    .collect()
}

/// The camera of [`reference_sphere`].
fn reference_sphere_camera() -> Camera {
    Camera::perspective(Vec3::new(0.0, 0.5, 4.0), Vec3::ZERO, 35f32.to_radians())
}

/// A renderer of the unit sphere of `material`, finely tessellated, seen by `camera` at 96×96
/// without shadows, for comparisons with a CPU closed form per pixel. 320 segments: the warped
/// GGX lobe is narrow across the plane of incidence at grazing views, and the sheen rises
/// steeply there, where a coarser sphere's interpolated normals alone move a pixel by 1–2%.
fn reference_sphere(material: Material, camera: Camera) -> Renderer {
    let scene = Scene::sphere(Vec3::ZERO, 1.0, 320, material, None, camera);
    renderer(
        scene,
        RenderSettings {
            width: 96,
            height: 96,
            shadows: false,
            ..Default::default()
        },
    )
}

/// The GGX α (floored as the shading floors it), the specular reflectance f0 and the diffuse
/// albedo of an untextured metallic-roughness `material`, as the CPU references take them.
fn reference_brdf(material: &Material) -> (f64, [f64; 3], [f64; 3]) {
    let alpha = f64::from(material.roughness * material.roughness).max(0.002);
    let f0: [f64; 3] = if material.metallic > 0.0 {
        material.base_color.map(f64::from)
    } else {
        [0.16 * f64::from(material.specular).powi(2); 3]
    };
    let albedo = material
        .base_color
        .map(|c| f64::from(c) * f64::from(1.0 - material.metallic));
    (alpha, f0, albedo)
}

/// Renders one sphere of `material` under [`test_lobes`] with ASG lighting and compares every
/// pixel away from the silhouette with the CPU closed form (`Asg::irradiance` for the diffuse
/// part, `Asg::ggx_specular` for the specular one). Returns the worst error relative to the
/// CPU value (pixels above 5% of the image's brightest) and the worst error relative to the
/// brightest CPU value (all pixels), after asserting both are within `tolerance`.
fn asg_sphere_against_cpu(name: &str, material: Material, tolerance: (f32, f32)) -> (f32, f32) {
    let camera = reference_sphere_camera();
    let lobes = test_lobes();
    // The closed form has no shadows (`asg_lobes_cast_soft_shadows` tests them).
    let mut r = reference_sphere(material, camera);
    let (img, stats) = r.render_asg(&lobes).unwrap();
    assert_eq!(stats.lights, lobes.len());
    assert_eq!(stats.shadow_maps, 0);
    let (alpha, f0, albedo) = reference_brdf(&material);
    let mut pixels = Vec::new();
    for (x, y, n, v) in sphere_pixels(&r, camera.eye, 96) {
        let (n64, v64) = (n.as_dvec3(), v.as_dvec3());
        let mut want = [0.0f64; 3];
        for lobe in &lobes {
            let e = lobe.irradiance(n64);
            let s = lobe.ggx_specular(n64, v64, alpha, 1.0);
            for c in 0..3 {
                want[c] += albedo[c] / std::f64::consts::PI * e[c] + f0[c] * s[c];
            }
        }
        pixels.push((x, y, want.map(|w| w as f32), img.pixel(x, y)));
    }
    check_against_cpu(name, &img, &pixels, tolerance)
}

/// Compares the rendered `img` at `pixels` (x, y, CPU value, GPU value) and returns the worst
/// error relative to the CPU value (pixels above 5% of the brightest CPU value) and the worst
/// relative to that brightest value (all pixels), after asserting both are within `tolerance`.
fn check_against_cpu(
    name: &str,
    img: &Image,
    pixels: &[(u32, u32, [f32; 3], [f32; 4])],
    tolerance: (f32, f32),
) -> (f32, f32) {
    assert!(pixels.len() > 2500, "only {} pixels checked", pixels.len());
    let peak = pixels.iter().flat_map(|p| p.2).fold(0.0f32, f32::max);
    let (mut worst_rel, mut worst_abs) = (0.0f32, 0.0f32);
    let mut failures = Vec::new();
    for (x, y, want, got) in pixels {
        for c in 0..3 {
            let abs = (got[c] - want[c]).abs() / peak;
            worst_abs = worst_abs.max(abs);
            let bright = want[c] > 0.05 * peak;
            let rel = (got[c] - want[c]).abs() / want[c].max(1e-12);
            if bright {
                worst_rel = worst_rel.max(rel);
            }
            if abs > tolerance.1 || (bright && rel > tolerance.0) {
                failures.push(format!(
                    "pixel ({x},{y}) channel {c}: GPU {} vs CPU {} ({:.3}% off, {:.3}% of peak)",
                    got[c],
                    want[c],
                    rel * 100.0,
                    abs * 100.0
                ));
            }
        }
    }
    fail_with_image(name, img, &failures);
    eprintln!(
        "{name}: {} pixels, worst {:.3}% of the CPU value (bright pixels), {:.3}% of the peak",
        pixels.len(),
        worst_rel * 100.0,
        worst_abs * 100.0
    );
    (worst_rel, worst_abs)
}

#[test]
fn asg_lit_spheres_match_the_cpu_closed_form() {
    // Stated tolerances (docs/rendering.md): 2% of the CPU value on pixels above 5% of the
    // peak, 1% of the peak everywhere (f32 shading, and the tessellated sphere's interpolated
    // normals against the exact ones the CPU uses).
    let tolerance = (0.02, 0.01);
    asg_sphere_against_cpu(
        "asg_diffuse_sphere",
        Material::lambertian([0.8, 0.6, 0.4]),
        tolerance,
    );
    asg_sphere_against_cpu(
        "asg_glossy_metal_sphere",
        Material {
            base_color: [0.95, 0.9, 0.8],
            roughness: 0.5,
            metallic: 1.0,
            specular: 0.5,
            ..Default::default()
        },
        tolerance,
    );
    asg_sphere_against_cpu(
        "asg_plastic_sphere",
        Material {
            base_color: [0.2, 0.5, 0.8],
            roughness: 0.7,
            metallic: 0.0,
            specular: 0.5,
            ..Default::default()
        },
        tolerance,
    );
}

/// An environment as SH coefficients of `degree`: three lights of different colours and a
/// uniform sky of radiance 0.5 (L_00 = 0.5 √(4π)).
fn test_sh(degree: usize) -> envlight::sh::ShCoefficients {
    use envlight::sh::ShCoefficients;
    let light = |dir: [f32; 3], rgb: [f32; 3]| {
        let d = Vec3::from_array(dir).normalize();
        Light {
            id: 0,
            dir: d.to_array(),
            rgb,
            solid_angle: 0.0,
        }
    };
    let lights = [
        light([0.3, 1.0, 0.5], [6.0, 5.0, 4.0]),
        light([-1.0, 0.2, 0.4], [1.0, 2.0, 3.0]),
        light([0.5, -0.3, 1.0], [2.0, 1.0, 0.5]),
    ];
    let mut rgb = ShCoefficients::from_lights(&lights, degree).rgb().to_vec();
    let sky = 0.5 * (4.0 * std::f64::consts::PI).sqrt();
    for c in 0..3 {
        rgb[0][c] += sky;
    }
    ShCoefficients::from_rgb(rgb).unwrap()
}

/// Renders one sphere of `material` under [`test_sh`] of `degree` with SH lighting and
/// compares every pixel away from the silhouette with the CPU reference
/// (`render::sh::shade_reference`).
fn sh_sphere_against_cpu(
    name: &str,
    material: Material,
    degree: usize,
    tolerance: (f32, f32),
) -> (f32, f32) {
    let camera = reference_sphere_camera();
    let sh = test_sh(degree);
    let mut r = reference_sphere(material, camera);
    let (img, stats) = r.render_sh(&sh).unwrap();
    assert_eq!(stats.lights, (degree + 1) * (degree + 1));
    assert_eq!(stats.shadow_maps, 0);
    let (alpha, f0, albedo) = reference_brdf(&material);
    let pixels: Vec<_> = sphere_pixels(&r, camera.eye, 96)
        .into_iter()
        .map(|(x, y, n, v)| {
            let want = envlight::render::sh::shade_reference(
                &sh,
                n.as_dvec3(),
                v.as_dvec3(),
                albedo,
                f0,
                alpha,
            );
            (x, y, want.map(|w| w as f32), img.pixel(x, y))
        })
        .collect();
    check_against_cpu(name, &img, &pixels, tolerance)
}

#[test]
fn sh_lit_spheres_match_the_cpu_reference() {
    // The ASG spheres' tolerances: 2% of the CPU value on pixels above 5% of the peak, 1% of
    // the peak everywhere.
    let tolerance = (0.02, 0.01);
    for degree in [2, 8] {
        sh_sphere_against_cpu(
            &format!("sh{degree}_diffuse_sphere"),
            Material::lambertian([0.8, 0.6, 0.4]),
            degree,
            tolerance,
        );
        sh_sphere_against_cpu(
            &format!("sh{degree}_glossy_metal_sphere"),
            Material {
                base_color: [0.95, 0.9, 0.8],
                roughness: 0.5,
                metallic: 1.0,
                specular: 0.5,
                ..Default::default()
            },
            degree,
            tolerance,
        );
        sh_sphere_against_cpu(
            &format!("sh{degree}_smooth_plastic_sphere"),
            Material {
                base_color: [0.2, 0.5, 0.8],
                roughness: 0.15,
                metallic: 0.0,
                specular: 0.5,
                ..Default::default()
            },
            degree,
            tolerance,
        );
    }
}

#[test]
fn cli_renders_with_asg_lighting() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
        .args([
            "render",
            "--lighting",
            "asg",
            "--lobes",
            "4",
            "--fit-height",
            "8",
            "--frames",
            "2",
            "--size",
            "48x32",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stats = std::fs::read_to_string(out.join("stats.jsonl")).unwrap();
    assert_eq!(stats.lines().count(), 2);
    for line in stats.lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        assert_eq!(v["lights"], 4, "{line}");
        // A shadow map per lobe that reaches a visible surface.
        let maps = v["shadow_maps"].as_u64().unwrap();
        assert!((1..=4).contains(&maps), "{line}");
    }
    let png = image::open(out.join("frame_00001.png")).unwrap();
    assert_eq!((png.width(), png.height()), (48, 32));
    // ASG lighting fits frames: it cannot take a light list, and bad fit options are named.
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
        .args([
            "render",
            "--lighting",
            "asg",
            "--lights",
            "x.jsonl",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "a usage error");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
        .args(["render", "--lighting", "asg", "--lobes", "65", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(
        o.status.code(),
        Some(2),
        "a value out of range is a usage error"
    );
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("--lobes"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn cli_renders_with_sh_lighting() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let render = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
            .arg("render")
            .args(args)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap()
    };
    let o = render(&[
        "--lighting",
        "sh",
        "--degree",
        "3",
        "--frames",
        "2",
        "--size",
        "48x32",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stats = std::fs::read_to_string(out.join("stats.jsonl")).unwrap();
    assert_eq!(stats.lines().count(), 2);
    for line in stats.lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        assert_eq!(v["lights"], 16, "(3 + 1)² coefficients: {line}");
        assert_eq!(v["shadow_maps"], 0, "{line}");
    }
    // The sky lights the spheres: the image is not black.
    let img = image::open(out.join("frame_00001.png")).unwrap().to_rgba8();
    assert_eq!(img.dimensions(), (48, 32));
    assert!(img.pixels().any(|p| p.0[..3].iter().any(|&c| c > 32)));
    // What SH lighting cannot do is a usage error naming the option.
    for (args, named) in [
        (&["--lighting", "sh", "--catcher"][..], "--catcher"),
        (
            &["--lighting", "sh", "--shadow-res", "256"][..],
            "--shadow-res",
        ),
        (&["--lighting", "sh", "--lights", "x.jsonl"][..], "--lights"),
        (&["--lighting", "sh", "--degree", "16"][..], "--degree 16"),
        (&["--lighting", "sh", "--lobes", "4"][..], "--lobes"),
        (&["--degree", "2"][..], "--degree"),
    ] {
        let o = render(args);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(named), "{args:?}: {stderr}");
    }
}

/// An error the device reports outside an error scope (here a texture past the adapter's size
/// limit; on a real run, shadow maps the GPU has no memory for) is kept for the renderer to
/// return, not a panic in wgpu's default handler (`render --shadow-res 8192` with 128 lights
/// exited 101 on "Out of Memory").
#[test]
fn device_errors_are_kept_not_panicked() {
    let gpu = envlight::render::device::Gpu::new().expect("a wgpu adapter (lavapipe on CI)");
    assert_eq!(gpu.take_error(), None);
    let too_wide = gpu.device.limits().max_texture_dimension_2d + 1;
    let _texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("too wide"),
        size: wgpu::Extent3d {
            width: too_wide,
            height: 1,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::R32Float,
        usage: wgpu::TextureUsages::TEXTURE_BINDING,
        view_formats: &[],
    });
    let error = gpu.take_error().expect("the device reported the texture");
    assert!(!error.is_empty());
    assert_eq!(gpu.take_error(), None);
}

/// Compute shadow maps of a side whose one map exceeds the adapter's largest storage binding
/// (8192² on lavapipe, 128 MiB) are refused with a settings error, before any allocation.
#[test]
fn compute_maps_larger_than_a_storage_binding_are_refused() {
    let gpu = envlight::render::device::Gpu::new().expect("a wgpu adapter (lavapipe on CI)");
    let limits = gpu.device.limits();
    let binding = limits
        .max_storage_buffer_binding_size
        .min(limits.max_buffer_size);
    let too_big = (4..32)
        .map(|k| 1u32 << k)
        .take_while(|&r| r <= limits.max_texture_dimension_2d)
        .find(|&r| 4 * u64::from(r) * u64::from(r) > binding);
    let Some(resolution) = too_big else {
        eprintln!(
            "every map side up to {} fits one binding here",
            limits.max_texture_dimension_2d
        );
        return;
    };
    let settings = RenderSettings {
        width: 16,
        height: 16,
        shadow_resolution: resolution,
        shadow_raster: ShadowRaster::Compute,
        ..Default::default()
    };
    let error = Renderer::with_gpu(gpu, Scene::default_scene(), settings)
        .err()
        .expect("refused");
    let text = error.to_string();
    assert!(
        text.contains(&format!("{resolution}² texels"))
            && text.contains("--shadow-raster pipeline"),
        "{text}"
    );
}

/// A light along the view ray of a visible point (v = l there) shades finitely. v·h rounded
/// to just above 1 and pow(1 − v·h, 5) was NaN: one black pixel, reported as "beyond f32's
/// range" (found with the first light below at 160×90 on lavapipe).
#[test]
fn lights_along_the_view_ray_shade_finitely() {
    let scene = Scene::default_scene();
    let camera = scene.camera;
    let mut r = renderer(
        scene,
        RenderSettings {
            width: 160,
            height: 90,
            shadows: false,
            ..Default::default()
        },
    );
    let mut lights = vec![light(
        0,
        Vec3::new(0.076_702_76, 0.221_502_82, 0.972_138_5),
        [5.0; 3],
        0.001,
    )];
    // And lights towards the camera from points around the view's centre.
    for (i, offset) in [[0.0, 0.0], [0.3, 0.1], [-0.2, 0.4], [0.1, -0.3]]
        .iter()
        .enumerate()
    {
        let point = camera.target + Vec3::new(offset[0], offset[1], 0.0);
        lights.push(light(i as u32 + 1, camera.eye - point, [5.0; 3], 0.001));
    }
    for one in &lights {
        let (img, _) = r.render(std::slice::from_ref(one)).unwrap();
        let bad = img.rgba.iter().filter(|c| !c.is_finite()).count();
        assert_eq!(bad, 0, "light {:?}: {bad} non-finite pixel values", one.dir);
    }
}

/// A frame of more lights than the budget controller's range (16,384) is said to be cut when
/// --budget-ms is given (a budget that never binds drew 16,384 of 16,400 without a word).
#[test]
fn cli_budget_says_when_it_cuts_a_large_frame() {
    let dir = tempfile::tempdir().unwrap();
    let lights: Vec<serde_json::Value> = (0..16_400u32)
        .map(|id| {
            let a = f64::from(id) * 0.001;
            serde_json::json!({"id": id, "dir": [a.cos() * 0.6, 0.8, a.sin() * 0.6],
                "rgb": [0.001, 0.001, 0.001], "solid_angle": 0.0007})
        })
        .collect();
    let path = dir.path().join("many.jsonl");
    let frame = serde_json::json!({"seq": 0, "time": 0.0, "lights": lights});
    std::fs::write(&path, format!("{frame}\n")).unwrap();
    let out = dir.path().join("out");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
        .args([
            "render",
            "--size",
            "16x9",
            "--no-shadows",
            "--budget-ms",
            "1e9",
            "--lights",
        ])
        .arg(&path)
        .arg("--out")
        .arg(&out)
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(
        stderr.contains("has 16400 lights; --budget-ms draws at most 16384"),
        "{stderr}"
    );
    let stats = std::fs::read_to_string(out.join("stats.jsonl")).unwrap();
    assert!(stats.contains("\"lights\":16384"), "{stats}");
}

/// A white furnace for the lights' specular term: a metal sphere with f0 = 1 (so F = 1) under
/// the 256 lights of a uniform environment of radiance 1 (the decomposition's own, each with
/// its solid angle, so each widens the GGX lobe) reflects at each pixel GGX's directional albedo
/// E(n·v, α) = ∫ D G₂ / (4 n·v) dl, here from `asg::eval::ggx_reference` on a uniform map. The
/// lights sample the lobe, so single pixels scatter; their mean ratio to E must be within 5 %
/// of 1 (measured on lavapipe: 0.984, 0.975 and 0.964 for roughness 0.3, 0.5 and 0.8). Until
/// 2026-12-04 the shader also scaled each light's widened lobe by (α/α′)², which took that much
/// energy away (0.33 at roughness 0.3, 0.95 at 0.5 without it but with the masking at α′:
/// docs/rendering.md).
#[test]
fn specular_of_a_uniform_environment_keeps_its_energy() {
    use envlight::asg::eval::{ggx_reference, LatLongMap};
    use envlight::decompose::{DecomposeSettings, Decomposer};
    use envlight::envmap::Projection;
    use envlight::HdrFrame;
    let frame = HdrFrame::new(256, 128, vec![[1.0; 3]; 256 * 128], Projection::LatLong).unwrap();
    let lights = Decomposer::new(DecomposeSettings {
        lights: 256,
        filter_taps: None,
        ..DecomposeSettings::default()
    })
    .unwrap()
    .decompose(&frame)
    .lights;
    let uniform = LatLongMap::from_fn(256, 128, |_| [1.0; 3]);
    let camera = Camera::perspective(Vec3::new(0.0, 0.5, 4.0), Vec3::ZERO, 35f32.to_radians());
    for roughness in [0.3f32, 0.5, 0.8] {
        let material = Material {
            base_color: [1.0; 3],
            roughness,
            metallic: 1.0,
            specular: 0.5,
            ..Default::default()
        };
        let scene = Scene::sphere(Vec3::ZERO, 1.0, 160, material, None, camera);
        let mut r = renderer(
            scene,
            RenderSettings {
                width: 64,
                height: 64,
                shadows: false,
                ..Default::default()
            },
        );
        let (img, _) = r.render(&lights).unwrap();
        let alpha = f64::from(roughness * roughness);
        let pixels = sphere_pixels(&r, camera.eye, 64);
        let count = pixels.len();
        assert!(count > 1000, "only {count} pixels checked");
        let sum: f64 = pixels
            .iter()
            .map(|&(x, y, n, v)| {
                let want = ggx_reference(&uniform, n.as_dvec3(), v.as_dvec3(), alpha)[1];
                f64::from(img.pixel(x, y)[1]) / want
            })
            .sum();
        let mean = sum / count as f64;
        eprintln!("roughness {roughness}: mean ratio to the directional albedo {mean:.4} ({count} pixels)");
        assert!(
            (mean - 1.0).abs() <= 0.05,
            "roughness {roughness}: the sphere reflects {mean:.4} of the directional albedo"
        );
    }
}

/// A frame of more lights than the adapter's storage buffers hold is an error that says so
/// (it was a validation error about "buffer binding 1" from the GPU); the renderer still
/// draws the next frame of fewer lights.
#[test]
fn more_lights_than_the_adapter_binds_are_refused_in_words() {
    let mut r = renderer(
        Scene::default_scene(),
        RenderSettings {
            width: 16,
            height: 8,
            shadows: false,
            ..Default::default()
        },
    );
    // 112 bytes a light against lavapipe's (and wgpu's default) 128 MiB: 1,198,372 lights.
    let too_many: Vec<Light> = (0..1_300_000u32)
        .map(|i| light(i, Vec3::new(0.3, 1.0, 0.2), [1e-6; 3], 1e-6))
        .collect();
    let Err(e) = r.render(&too_many) else {
        panic!("a frame of 1,300,000 lights was drawn")
    };
    let e = e.to_string();
    assert!(
        e.contains("a frame of 1300000 lights") && e.contains("give fewer lights"),
        "{e}"
    );
    let (_, stats) = r.render(&too_many[..64]).unwrap();
    assert_eq!(stats.lights, 64);
}

/// sRGB code (0–255) → linear, the decode the base-colour array's format applies.
fn srgb_code_to_linear(code: u8) -> f32 {
    let c = f32::from(code) / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// A 2 × 2 quad in the plane z = 0 facing +Z, seen head-on from z = 3, with texture
/// coordinates u = u_span·(x + 1)/2 and v = (1 − y)/2 (the second set: u = u_span·(1 − x)/2)
/// and tangents along +x, one material, no ground.
fn textured_quad(material: Material, textures: Vec<TextureImage>, u_span: f32) -> Scene {
    use envlight::render::scene::{Sphere, Vertex};
    let corner = |x: f32, y: f32| Vertex {
        position: [x, y, 0.0],
        normal: [0.0, 0.0, 1.0],
        material: 0,
        uv: [u_span * (x + 1.0) / 2.0, (1.0 - y) / 2.0],
        // The second set runs the other way along x.
        uv1: [u_span * (1.0 - x) / 2.0, (1.0 - y) / 2.0],
        // u grows along +x, v down (−y): up the image is +y = cross(+z, +x), so w = +1.
        tangent: [1.0, 0.0, 0.0, 1.0],
        color: envlight::render::scene::WHITE,
    };
    Scene {
        vertices: vec![
            corner(-1.0, -1.0),
            corner(1.0, -1.0),
            corner(1.0, 1.0),
            corner(-1.0, 1.0),
        ],
        indices: vec![0, 1, 2, 0, 2, 3],
        caster_indices: 6,
        materials: vec![material],
        textures,
        ground_material: None,
        camera: Camera::perspective(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, 40f32.to_radians()),
        bounds: Sphere {
            center: Vec3::ZERO,
            radius: 2f32.sqrt(),
        },
        animation: None,
    }
}

/// A `width` × 1 texture whose texel x has colour `texel(x)` (RGBA codes).
fn texture_row(width: u32, texel: impl Fn(u32) -> [u8; 4]) -> TextureImage {
    TextureImage {
        name: "test texture".into(),
        width,
        height: 1,
        rgba: (0..width).flat_map(texel).collect(),
    }
}

/// The mean colour of the pixels whose quad coordinate x (−1…1 across the quad) lies in
/// `x_range`, over the quad's middle rows.
fn mean_over(r: &Renderer, img: &Image, x_range: std::ops::Range<f32>) -> [f32; 3] {
    let eye = Vec3::new(0.0, 0.0, 3.0);
    let (mut sum, mut n) = ([0.0f32; 3], 0);
    for y in 0..img.height {
        for x in 0..img.width {
            let d = r.pixel_ray(x as f32 + 0.5, y as f32 + 0.5);
            let hit = eye + d * (-eye.z / d.z);
            if x_range.contains(&hit.x) && hit.y.abs() < 0.5 {
                let p = img.pixel(x, y);
                for c in 0..3 {
                    sum[c] += p[c];
                }
                n += 1;
            }
        }
    }
    assert!(n > 20, "only {n} pixels in {x_range:?}");
    sum.map(|s| s / n as f32)
}

/// Each channel of `got` within `tolerance` × the brightest channel of `want` (relative to the
/// colour, not to each channel: lavapipe's sRGB decode is within 1% on a dark channel, code 40,
/// but not exact).
fn assert_close(what: &str, got: [f32; 3], want: [f32; 3], tolerance: f32) {
    let scale = want.iter().fold(0.0f32, |m, &v| m.max(v.abs())).max(1e-6);
    for c in 0..3 {
        let err = (got[c] - want[c]).abs() / scale;
        assert!(
            err <= tolerance,
            "{what}: channel {c} is {} where {} was expected ({:.2}% of the colour off; tolerance {:.2}%)",
            got[c],
            want[c],
            100.0 * err,
            100.0 * tolerance
        );
    }
}

/// The textured-quad tests' colours (sRGB codes).
const RED: [u8; 4] = [200, 60, 40, 255];
const BLUE: [u8; 4] = [40, 90, 210, 255];

/// The textured-quad tests' frame: 96 × 96, no shadows, no anisotropic filtering (lavapipe's
/// anisotropic path blurs a magnified texture's texels by about 1% even head-on, past the
/// tests' tolerance; `grazing_textures_are_filtered_anisotropically` tests it).
fn quad_settings() -> RenderSettings {
    RenderSettings {
        width: 96,
        height: 96,
        shadows: false,
        texture_anisotropy: 1,
        ..Default::default()
    }
}

/// Renders a [`textured_quad`] scene under `lights`: the renderer (for [`mean_over`]) and
/// the image.
fn render_quad(scene: Scene, lights: &[Light]) -> (Renderer, Image) {
    let mut r = renderer(scene, quad_settings());
    let (img, _) = r.render(lights).unwrap();
    (r, img)
}

/// The mean colours of a [`textured_quad`] render's left and right regions (x in −0.7…−0.3
/// and 0.3…0.7): the image's first and last quarter at u ≤ 1.
fn quad_halves(r: &Renderer, img: &Image) -> ([f32; 3], [f32; 3]) {
    (mean_over(r, img, -0.7..-0.3), mean_over(r, img, 0.3..0.7))
}

/// The mean colour of the untextured Lambertian quad in the (sRGB-decoded) colour `code`
/// under one frontal light of 3 W/m², over its middle.
fn plain_quad(code: [u8; 4]) -> [f32; 3] {
    let colour = [0, 1, 2].map(|c| srgb_code_to_linear(code[c]));
    let (r, img) = render_quad(
        textured_quad(Material::lambertian(colour), vec![], 1.0),
        &[light(0, Vec3::Z, [3.0, 3.0, 3.0], 0.0)],
    );
    mean_over(&r, &img, -0.5..0.5)
}

/// A base-colour texture shades as a plain material of its texels' (sRGB-decoded) colour;
/// the sampler's wrap modes repeat, clamp and mirror it; a metallic-roughness texture's blue
/// channel scales the metallic factor. Each textured region is compared with the same quad
/// rendered untextured (Lambertian under one frontal light: diffuse = albedo/π · E).
#[test]
fn textured_materials_shade_as_their_texels() {
    use envlight::render::scene::{TextureRef, Wrap};
    let lights = [light(0, Vec3::Z, [3.0, 3.0, 3.0], 0.0)];
    let lambertian = |base_color: [f32; 3]| Material::lambertian(base_color);
    let render = |scene: Scene| render_quad(scene, &lights);
    let (red, blue) = (plain_quad(RED), plain_quad(BLUE));
    // Texels 0–1 red, 2–3 blue: u in [0.125, 0.375] reads only red texel centres, [0.625, 0.875]
    // only blue ones, whatever the filtering.
    let halves = texture_row(4, |x| if x < 2 { RED } else { BLUE });
    for (wrap, u_span, regions) in [
        // One copy across the quad.
        (Wrap::Repeat, 1.0, vec![(-0.7..-0.3, red), (0.3..0.7, blue)]),
        // u from 0 to 2: the right half repeats the texture, is clamped to its edge texel, or
        // mirrors it.
        (
            Wrap::Repeat,
            2.0,
            vec![(0.15..0.35, red), (0.65..0.85, blue)],
        ),
        (
            Wrap::ClampToEdge,
            2.0,
            vec![(0.15..0.35, blue), (0.65..0.85, blue)],
        ),
        (
            Wrap::MirroredRepeat,
            2.0,
            vec![(0.15..0.35, blue), (0.65..0.85, red)],
        ),
    ] {
        let mut material = lambertian([1.0; 3]);
        material.textures.base_color = Some(TextureRef {
            wrap: [wrap; 2],
            ..TextureRef::repeating(0)
        });
        let (r, img) = render(textured_quad(material, vec![halves.clone()], u_span));
        for (x_range, want) in regions {
            let got = mean_over(&r, &img, x_range.clone());
            assert_close(
                &format!("{wrap:?}, u up to {u_span}, x in {x_range:?}"),
                got,
                want,
                0.005,
            );
        }
    }
    // Metallic from the texture's blue channel: 1 on the left (no diffuse; a rough metal of
    // base colour white reflects as specular), 0 on the right (plain Lambertian white).
    let metal = Material {
        base_color: [1.0; 3],
        roughness: 0.6,
        metallic: 1.0,
        specular: 0.5,
        ..Default::default()
    };
    let reference = |metallic: f32| {
        let (r, img) = render(textured_quad(Material { metallic, ..metal }, vec![], 1.0));
        quad_halves(&r, &img)
    };
    let (metal_left, _) = reference(1.0);
    let (_, dielectric_right) = reference(0.0);
    assert!(
        (metal_left[0] - dielectric_right[0]).abs() > 0.05 * dielectric_right[0],
        "the metal and dielectric references must differ for this test to see the texture"
    );
    let metallic_halves = texture_row(4, |x| {
        if x < 2 {
            [0, 255, 255, 255]
        } else {
            [0, 255, 0, 255]
        }
    });
    let mut textured = metal;
    textured.textures.metallic_roughness = Some(TextureRef::repeating(0));
    let (r, img) = render(textured_quad(textured, vec![metallic_halves], 1.0));
    let (left, right) = quad_halves(&r, &img);
    assert_close("metallic 1 from the texture", left, metal_left, 0.005);
    assert_close(
        "metallic 0 from the texture",
        right,
        dielectric_right,
        0.005,
    );
}

/// The ASG pass reads the same base-colour textures: a textured region shades as the plain
/// material of its texel's colour under a lobe.
#[test]
fn asg_lighting_reads_base_colour_textures() {
    use envlight::asg::Asg;
    use envlight::render::scene::TextureRef;
    use glam::DVec3;
    const GREEN: [u8; 4] = [30, 180, 70, 255];
    const GREY: [u8; 4] = [128, 128, 128, 255];
    let settings = quad_settings();
    let lobes = [Asg::new(DVec3::Z, DVec3::X, 4.0, 4.0, [2.0, 2.0, 2.0]).unwrap()];
    let render = |scene: Scene| {
        let mut r = renderer(scene, settings);
        let (img, _) = r.render_asg(&lobes).unwrap();
        (r, img)
    };
    let plain = |code: [u8; 4]| {
        let colour = [0, 1, 2].map(|c| srgb_code_to_linear(code[c]));
        let (r, img) = render(textured_quad(Material::lambertian(colour), vec![], 1.0));
        quad_halves(&r, &img)
    };
    let (green_left, _) = plain(GREEN);
    let (_, grey_right) = plain(GREY);
    let mut material = Material::lambertian([1.0; 3]);
    material.textures.base_color = Some(TextureRef::repeating(0));
    let halves = texture_row(4, |x| if x < 2 { GREEN } else { GREY });
    let (r, img) = render(textured_quad(material, vec![halves], 1.0));
    let (left, right) = quad_halves(&r, &img);
    assert_close("ASG, green texels", left, green_left, 0.005);
    assert_close("ASG, grey texels", right, grey_right, 0.005);
}

/// An unlit material (`KHR_materials_unlit`) shows its base colour times its texture, as its
/// radiance, in the light, ASG and SH passes alike, under any lights and none; the same
/// material lit reflects the lights instead (so the test sees the flag).
#[test]
fn unlit_materials_show_their_base_colour_under_any_light() {
    use envlight::asg::Asg;
    use envlight::render::scene::TextureRef;
    use envlight::sh::ShCoefficients;
    use glam::DVec3;
    const GREEN: [u8; 4] = [30, 180, 70, 255];
    const GREY: [u8; 4] = [128, 128, 128, 255];
    let linear = |code: [u8; 4]| [0, 1, 2].map(|c| srgb_code_to_linear(code[c]) * 0.5);
    let mut material = Material::lambertian([0.5; 3]);
    material.unlit = true;
    material.textures.base_color = Some(TextureRef::repeating(0));
    let halves = texture_row(4, |x| if x < 2 { GREEN } else { GREY });
    let scene = textured_quad(material, vec![halves.clone()], 1.0);
    let lit = textured_quad(
        Material {
            unlit: false,
            ..material
        },
        vec![halves],
        1.0,
    );
    let bright = [light(0, Vec3::Z, [30.0, 20.0, 10.0], 0.0)];
    let grazing = [light(0, Vec3::new(1.0, 0.0, 0.2), [3.0, 3.0, 3.0], 0.0)];
    let lobes = [Asg::new(DVec3::Z, DVec3::X, 4.0, 4.0, [2.0, 2.0, 2.0]).unwrap()];
    let sh = ShCoefficients::from_lights(&bright, 2);
    type Pass<'a> = &'a dyn Fn(&mut Renderer) -> Image;
    let passes: [(&str, Pass); 5] = [
        ("lights, bright", &|r| r.render(&bright).unwrap().0),
        ("lights, grazing", &|r| r.render(&grazing).unwrap().0),
        ("no lights", &|r| r.render(&[]).unwrap().0),
        ("ASG", &|r| r.render_asg(&lobes).unwrap().0),
        ("SH", &|r| r.render_sh(&sh).unwrap().0),
    ];
    for (pass, render) in passes {
        let mut r = renderer(scene.clone(), quad_settings());
        let img = render(&mut r);
        let (left, right) = quad_halves(&r, &img);
        assert_close(&format!("{pass}, green texels"), left, linear(GREEN), 0.005);
        assert_close(&format!("{pass}, grey texels"), right, linear(GREY), 0.005);
        let mut r = renderer(lit.clone(), quad_settings());
        let img = render(&mut r);
        let (left, _) = quad_halves(&r, &img);
        let off = (0..3)
            .map(|c| (left[c] - linear(GREEN)[c]).abs())
            .fold(0.0f32, f32::max);
        assert!(
            off > 0.05,
            "{pass}: the lit material shows its base colour too ({left:?})"
        );
    }
}

/// An occlusion texture scales the light a surface reflects by 1 + strength · (R − 1), and an
/// emissive texture's (sRGB-decoded) texels times the material's emission are added to it —
/// alone under no lights — in the lit and the ASG passes. Each texture keeps its own wrap
/// modes (a clamped base colour beside a mirrored occlusion texture) and its own texture
/// coordinates (the base colour on the second set, the occlusion on the first).
#[test]
fn occlusion_and_emissive_textures_darken_glow_and_keep_their_own_modes() {
    use envlight::asg::Asg;
    use envlight::render::scene::{TextureRef, Wrap};
    use glam::DVec3;
    // Occlusion in R: 64 (0.251 open) on the left texels, 255 (open) on the right.
    const DARK: [u8; 4] = [64, 0, 0, 255];
    const OPEN: [u8; 4] = [255, 0, 0, 255];
    let ao = 64.0 / 255.0;
    let lights = [light(0, Vec3::Z, [3.0, 3.0, 3.0], 0.0)];
    let lobes = [Asg::new(DVec3::Z, DVec3::X, 4.0, 4.0, [2.0, 2.0, 2.0]).unwrap()];
    let occlusion_row = texture_row(4, |x| if x < 2 { DARK } else { OPEN });
    let colour_row = texture_row(4, |x| if x < 2 { RED } else { BLUE });
    let white = Material::lambertian([1.0; 3]);
    let (plain_r, plain_img) = render_quad(textured_quad(white, vec![], 1.0), &lights);
    let (plain_left, plain_right) = quad_halves(&plain_r, &plain_img);
    let plain_asg = {
        let mut r = renderer(textured_quad(white, vec![], 1.0), quad_settings());
        let (img, _) = r.render_asg(&lobes).unwrap();
        quad_halves(&r, &img)
    };
    let scaled = |c: [f32; 3], k: f32| c.map(|v| v * k);
    for strength in [1.0, 0.5] {
        let mut material = white;
        material.textures.occlusion = Some(TextureRef::repeating(0));
        material.textures.occlusion_strength = strength;
        let k = 1.0 + strength * (ao - 1.0);
        let scene = textured_quad(material, vec![occlusion_row.clone()], 1.0);
        let (r, img) = render_quad(scene.clone(), &lights);
        let (left, right) = quad_halves(&r, &img);
        assert_close(
            &format!("occluded texels, strength {strength}"),
            left,
            scaled(plain_left, k),
            0.01,
        );
        assert_close("open texels", right, plain_right, 0.01);
        let mut r = renderer(scene, quad_settings());
        let (img, _) = r.render_asg(&lobes).unwrap();
        let (left, right) = quad_halves(&r, &img);
        assert_close(
            &format!("ASG, occluded texels, strength {strength}"),
            left,
            scaled(plain_asg.0, k),
            0.01,
        );
        assert_close("ASG, open texels", right, plain_asg.1, 0.01);
    }
    // Emission: factor × decoded texel, added to what is reflected.
    let emission = [2.0, 1.0, 0.5];
    let mut glowing = white;
    glowing.emission = emission;
    glowing.textures.emissive = Some(TextureRef::repeating(0));
    let glow = |code: [u8; 4]| [0, 1, 2].map(|c| emission[c] * srgb_code_to_linear(code[c]));
    let scene = textured_quad(glowing, vec![colour_row.clone()], 1.0);
    let (r, img) = render_quad(scene.clone(), &[]);
    let (left, right) = quad_halves(&r, &img);
    assert_close("emission alone, red texels", left, glow(RED), 0.01);
    assert_close("emission alone, blue texels", right, glow(BLUE), 0.01);
    let (r, img) = render_quad(scene.clone(), &lights);
    let (left, _) = quad_halves(&r, &img);
    let sum = |a: [f32; 3], b: [f32; 3]| [0, 1, 2].map(|c| a[c] + b[c]);
    assert_close("emission and light", left, sum(plain_left, glow(RED)), 0.01);
    let mut r = renderer(scene, quad_settings());
    let (img, _) = r.render_asg(&lobes).unwrap();
    let (left, _) = quad_halves(&r, &img);
    assert_close(
        "ASG, emission and light",
        left,
        sum(plain_asg.0, glow(RED)),
        0.01,
    );
    // Wrap modes per texture, u from 0 to 2: the base colour clamps (blue beyond u = 1), the
    // occlusion texture mirrors (open at u = 1.15…1.35, occluded at u = 1.65…1.85).
    let mut material = white;
    material.textures.base_color = Some(TextureRef {
        wrap: [Wrap::ClampToEdge; 2],
        ..TextureRef::repeating(0)
    });
    material.textures.occlusion = Some(TextureRef {
        wrap: [Wrap::MirroredRepeat; 2],
        ..TextureRef::repeating(1)
    });
    let (r, img) = render_quad(
        textured_quad(
            material,
            vec![colour_row.clone(), occlusion_row.clone()],
            2.0,
        ),
        &lights,
    );
    let blue = plain_quad(BLUE);
    assert_close(
        "clamped blue, mirrored open",
        mean_over(&r, &img, 0.15..0.35),
        blue,
        0.01,
    );
    assert_close(
        "clamped blue, mirrored occluded",
        mean_over(&r, &img, 0.65..0.85),
        scaled(blue, ao),
        0.01,
    );
    // Two coordinate sets: the base colour reads the second (u reversed along x), the
    // occlusion texture the first.
    let mut material = white;
    material.textures.base_color = Some(TextureRef {
        channel: 1,
        ..TextureRef::repeating(0)
    });
    material.textures.occlusion = Some(TextureRef::repeating(1));
    let (r, img) = render_quad(
        textured_quad(material, vec![colour_row, occlusion_row], 1.0),
        &lights,
    );
    let (left, right) = quad_halves(&r, &img);
    assert_close("second set blue, occluded", left, scaled(blue, ao), 0.01);
    assert_close("second set red, open", right, plain_quad(RED), 0.01);
}

/// A renderer of a [`textured_quad`] scene with a white Lambertian receiver, 4 × 4, 0.5
/// behind the quad (a caster too), shadowed with `raster` at 256² (the cut-out tests: through
/// a hole the receiver is lit).
fn before_receiver(scene: Scene, raster: ShadowRaster) -> Renderer {
    before_receiver_with(
        scene,
        RenderSettings {
            shadow_raster: raster,
            ..quad_settings()
        },
    )
}

/// [`before_receiver`] with `settings`, shadows on at 256².
fn before_receiver_with(mut scene: Scene, settings: RenderSettings) -> Renderer {
    add_quad(&mut scene, 2.0, -0.5, Material::lambertian([1.0; 3]));
    scene.bounds.radius = 8f32.sqrt();
    renderer(
        scene,
        RenderSettings {
            shadows: true,
            shadow_resolution: 256,
            ..settings
        },
    )
}

/// Adds to `scene` a square of half-side `half` in the plane z = `z`, facing +Z, a caster of
/// `material` (its own), with no texture coordinates.
fn add_quad(scene: &mut Scene, half: f32, z: f32, material: Material) {
    use envlight::render::scene::Vertex;
    scene.materials.push(material);
    let first = scene.vertices.len() as u32;
    for (x, y) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
        scene.vertices.push(Vertex {
            position: [half * x, half * y, z],
            normal: [0.0, 0.0, 1.0],
            material: scene.materials.len() as u32 - 1,
            uv: [0.0; 2],
            uv1: [0.0; 2],
            tangent: [0.0; 4],
            color: envlight::render::scene::WHITE,
        });
    }
    scene.indices.extend([0, 1, 2, 0, 2, 3].map(|i| first + i));
    scene.caster_indices = scene.indices.len() as u32;
}

/// The mean alpha of the pixels [`mean_over`] averages.
fn mean_alpha_over(r: &Renderer, img: &Image, x_range: std::ops::Range<f32>) -> f32 {
    let eye = Vec3::new(0.0, 0.0, 3.0);
    let (mut sum, mut n) = (0.0f32, 0);
    for y in 0..img.height {
        for x in 0..img.width {
            let d = r.pixel_ray(x as f32 + 0.5, y as f32 + 0.5);
            let hit = eye + d * (-eye.z / d.z);
            if x_range.contains(&hit.x) && hit.y.abs() < 0.5 {
                sum += img.pixel(x, y)[3];
                n += 1;
            }
        }
    }
    assert!(n > 0, "no pixel over x in {x_range:?}");
    sum / n as f32
}

/// glTF's BLEND: a blended surface is drawn over what lies behind it by the over operator
/// (premultiplied: colour · α + behind · (1 − α), alpha α + behind's · (1 − α)), after the
/// opaque surfaces and back to front whatever the order of its triangles in the scene; hidden
/// behind an opaque one; casting a shadow that blocks the fraction α of the light (dithered in
/// the maps: two layers of different materials, or the two sides of one, take independent
/// patterns and block 1 − (1 − α₁)(1 − α₂)). In the light pass (either shadow
/// raster) and the ASG pass.
#[test]
fn blended_materials_are_drawn_over_what_lies_behind_them() {
    use envlight::asg::Asg;
    use glam::DVec3;
    let lights = [light(0, Vec3::Z, [3.0, 3.0, 3.0], 0.0)];
    let lit = |albedo: [f32; 3]| albedo.map(|c| 3.0 * c / PI);
    let blend = |albedo: [f32; 3], alpha: f32| Material {
        alpha,
        alpha_mode: AlphaMode::Blend,
        ..Material::lambertian(albedo)
    };
    let over = |front: [f32; 3], alpha: f32, behind: [f32; 3]| {
        [0, 1, 2].map(|c| front[c] * alpha + behind[c] * (1.0 - alpha))
    };
    let (red, blue) = ([1.0, 0.2, 0.1], [0.1, 0.3, 1.0]);
    let half_lit = |albedo: [f32; 3]| lit(albedo).map(|c| 0.5 * c);
    let quarter_lit = |albedo: [f32; 3]| lit(albedo).map(|c| 0.25 * c);
    // Red (α 0.5) over blue (α 0.5), half in red's shadow, over the receiver a quarter lit
    // behind both (two materials, two independent dither patterns: 1 − (1 − ½)(1 − ½) of the
    // light blocked).
    let two_layers = over(
        lit(red),
        0.5,
        over(half_lit(blue), 0.5, quarter_lit([1.0; 3])),
    );
    // Alone: premultiplied colour and alpha over the empty background.
    let (r, img) = render_quad(textured_quad(blend(red, 0.25), vec![], 1.0), &lights);
    assert_close(
        "alone",
        mean_over(&r, &img, -0.5..0.5),
        lit(red).map(|c| 0.25 * c),
        0.01,
    );
    let alpha = mean_alpha_over(&r, &img, -0.5..0.5);
    assert!((alpha - 0.25).abs() < 1e-3, "alone: alpha {alpha}");
    for raster in RASTERS {
        // Before a white receiver under a frontal light, which the square's shadow dims to
        // 1 − α (α a multiple of 1/16, as the dither covers).
        for alpha in [0.25, 0.75] {
            let behind = lit([1.0 - alpha; 3]);
            let mut r = before_receiver(textured_quad(blend(red, alpha), vec![], 1.0), raster);
            let (img, _) = r.render(&lights).unwrap();
            let what = format!("{raster:?}, α {alpha} before the receiver");
            let got = mean_over(&r, &img, -0.5..0.5);
            // The receiver's light through the square, from the green channel (red's is 0.2).
            let through = (got[1] - alpha * lit(red)[1]) / (1.0 - alpha) / lit([1.0; 3])[1];
            eprintln!("{what}: the receiver gets {through:.4} of its light");
            assert_close(&what, got, over(lit(red), alpha, behind), 0.02);
            let a = mean_alpha_over(&r, &img, -0.5..0.5);
            assert!((a - 1.0).abs() < 1e-3, "{what}: alpha {a}");
        }
        // Two blended squares, the near one (red, z = 0) listed first: drawn far to near
        // (`two_layers`).
        let mut scene = textured_quad(blend(red, 0.5), vec![], 1.0);
        add_quad(&mut scene, 1.5, -0.25, blend(blue, 0.5));
        let mut r = before_receiver(scene, raster);
        let (img, _) = r.render(&lights).unwrap();
        let got = mean_over(&r, &img, -0.5..0.5);
        assert_close(&format!("{raster:?}, two layers"), got, two_layers, 0.02);
        // Two sides of one translucent object: two squares of one double-sided material
        // (α 0.5), the far one facing away from the light and the camera (its back seen, lit
        // as its front would be), before the receiver: the receiver a quarter lit, where one
        // pattern left it half lit.
        let mut scene = textured_quad(blend(red, 0.5), vec![], 1.0);
        add_quad(&mut scene, 1.5, -0.25, blend(red, 0.5));
        scene.materials.pop();
        for v in scene.vertices.iter_mut().skip(4) {
            v.material = 0;
            v.normal = [0.0, 0.0, -1.0];
        }
        for t in scene.indices[6..].chunks_exact_mut(3) {
            t.swap(1, 2);
        }
        scene.materials[0].double_sided = true;
        let mut r = before_receiver(scene, raster);
        let (img, _) = r.render(&lights).unwrap();
        let want = over(
            lit(red),
            0.5,
            over(half_lit(red), 0.5, quarter_lit([1.0; 3])),
        );
        let got = mean_over(&r, &img, -0.5..0.5);
        assert_close(&format!("{raster:?}, two sides"), got, want, 0.02);
        // Behind an opaque square: hidden.
        let mut scene = textured_quad(Material::lambertian([0.5; 3]), vec![], 1.0);
        add_quad(&mut scene, 1.5, -0.25, blend(blue, 0.4));
        let mut r = before_receiver(scene, raster);
        let (img, _) = r.render(&lights).unwrap();
        let got = mean_over(&r, &img, -0.5..0.5);
        assert_close(&format!("{raster:?}, hidden"), got, lit([0.5; 3]), 0.02);
    }
    // ASG lighting, shadows off: the blended square over the receiver is the over operator of
    // the square drawn opaque and the receiver alone.
    let lobes = [Asg::new(DVec3::Z, DVec3::X, 4.0, 4.0, [2.0, 2.0, 2.0]).unwrap()];
    let asg_mean = |mut scene: Scene| {
        add_quad(&mut scene, 2.0, -0.5, Material::lambertian([1.0; 3]));
        let mut r = renderer(scene, quad_settings());
        let (img, _) = r.render_asg(&lobes).unwrap();
        mean_over(&r, &img, -0.5..0.5)
    };
    let front = asg_mean(textured_quad(Material::lambertian(red), vec![], 1.0));
    let mut behind_only = textured_quad(Material::lambertian(red), vec![], 1.0);
    behind_only.indices.clear();
    let behind = asg_mean(behind_only);
    let mut scene = textured_quad(blend(red, 0.4), vec![], 1.0);
    add_quad(&mut scene, 1.5, -0.25, blend(blue, 0.4));
    let blended = asg_mean(scene);
    let mut blue_only = textured_quad(Material::lambertian(blue), vec![], 1.0);
    blue_only.indices.clear();
    add_quad(&mut blue_only, 1.5, -0.25, Material::lambertian(blue));
    let blue_front = asg_mean(blue_only);
    assert!(front[0] > 0.1 && behind[0] > 0.1, "{front:?} {behind:?}");
    let want = over(front, 0.4, over(blue_front, 0.4, behind));
    assert_close("ASG, two layers", blended, want, 0.02);
    // Supersampled, the blended layers are drawn into the samples before the resolve: the
    // same two layers (α 0.5) as above, and the ASG pass's as without supersampling.
    let mut scene = textured_quad(blend(red, 0.5), vec![], 1.0);
    add_quad(&mut scene, 1.5, -0.25, blend(blue, 0.5));
    let settings = |supersample| RenderSettings {
        supersample,
        ..quad_settings()
    };
    let mut r = before_receiver_with(scene.clone(), settings(2));
    let (img, _) = r.render(&lights).unwrap();
    let got = mean_over(&r, &img, -0.5..0.5);
    assert_close("supersampled, two layers", got, two_layers, 0.02);
    let (img, _) = r.render_asg(&lobes).unwrap();
    let mut plain = before_receiver_with(scene, settings(1));
    let (plain_img, _) = plain.render_asg(&lobes).unwrap();
    let (got, want) = (
        mean_over(&r, &img, -0.5..0.5),
        mean_over(&plain, &plain_img, -0.5..0.5),
    );
    assert_close("supersampled ASG, two layers", got, want, 0.01);
}

/// The two shadow rasters dither a blended caster alike, facing included: a double-sided
/// blended square turned away from the light (the second dither pattern, chosen by the
/// triangle's facing, which the compute raster derives from its signed area in the map) casts
/// the same shadow with either, pixel for pixel (max difference 6·10⁻⁸ on lavapipe; 0.10 with
/// the compute raster's facing reversed).
#[test]
fn blended_shadows_agree_between_the_rasters() {
    let lights = [light(
        0,
        Vec3::new(0.3, 0.2, 1.0).normalize(),
        [3.0, 3.0, 3.0],
        0.0,
    )];
    let material = Material {
        alpha: 0.5,
        alpha_mode: AlphaMode::Blend,
        double_sided: true,
        ..Material::lambertian([1.0, 0.2, 0.1])
    };
    let images: Vec<Image> = RASTERS
        .iter()
        .map(|&raster| {
            let mut scene = textured_quad(material, vec![], 1.0);
            for t in scene.indices.chunks_exact_mut(3) {
                t.swap(1, 2);
            }
            for v in &mut scene.vertices {
                v.normal = [0.0, 0.0, -1.0];
            }
            let mut r = before_receiver(scene, raster);
            r.render(&lights).unwrap().0
        })
        .collect();
    let worst = images[0]
        .rgba
        .iter()
        .zip(&images[1].rgba)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    eprintln!("blended shadows, pipeline against compute raster: worst {worst:e}");
    assert!(
        worst < 1e-4,
        "the rasters' dithered shadows differ by {worst}"
    );
}

/// Supersampling: with s = 4 each pixel of a glowing triangle's edge is the fraction of its
/// 4 × 4 sample centres inside the triangle (the GPU's samples are the CPU's, but for a sample
/// on the edge itself), so within 1/8 of the exact covered area, and its alpha the same; the
/// image's mean is the triangle's area fraction. Without it the edge pixels are all or nothing.
/// The light and ASG passes resolve the same way; a factor outside 1..=4, or one that makes
/// the frame larger than the GPU allows, is refused in words.
/// The anti-aliasing tests' scene: a triangle glowing white (emission 1, black and
/// non-reflecting, so every pixel's colour and alpha is the fraction of it the triangle
/// covers), seen head-on as [`textured_quad`]'s quad is.
fn glowing_triangle() -> Scene {
    let glow = Material {
        emission: [1.0; 3],
        ..Material::lambertian([0.0; 3])
    };
    let mut scene = textured_quad(glow, vec![], 1.0);
    for (v, p) in
        scene
            .vertices
            .iter_mut()
            .zip([[-0.9, -0.7, 0.0], [0.8, -0.45, 0.0], [-0.2, 0.95, 0.0]])
    {
        v.position = p;
    }
    scene.indices = vec![0, 1, 2];
    scene.caster_indices = 3;
    scene
}

/// The anti-aliasing tests' image size.
const AA_SIZE: (u32, u32) = (40, 32);

/// The fraction of pixel (x, y)'s n × n sample centres inside [`glowing_triangle`]'s triangle,
/// in a `width` × `height` image of `r`'s camera.
fn triangle_coverage(r: &Renderer, scene: &Scene) -> impl Fn(u32, u32, u32) -> f32 {
    use glam::Vec2;
    let (width, height) = AA_SIZE;
    let corners: Vec<Vec2> = scene.vertices[..3]
        .iter()
        .map(|v| {
            let c = r.view_proj() * Vec3::from(v.position).extend(1.0);
            let ndc = c.truncate() / c.w;
            Vec2::new(
                (ndc.x + 1.0) / 2.0 * width as f32,
                (1.0 - ndc.y) / 2.0 * height as f32,
            )
        })
        .collect();
    let inside = move |p: Vec2| {
        let edge = |a: Vec2, b: Vec2| (b - a).perp_dot(p - a);
        let e = [
            edge(corners[0], corners[1]),
            edge(corners[1], corners[2]),
            edge(corners[2], corners[0]),
        ];
        e.iter().all(|&v| v > 0.0) || e.iter().all(|&v| v < 0.0)
    };
    move |x: u32, y: u32, n: u32| {
        let hits = (0..n * n)
            .filter(|k| {
                let sub = Vec2::new((k % n) as f32 + 0.5, (k / n) as f32 + 0.5) / n as f32;
                inside(Vec2::new(x as f32, y as f32) + sub)
            })
            .count();
        hits as f32 / (n * n) as f32
    }
}

#[test]
fn supersampling_resolves_edges_to_their_covered_fraction() {
    use envlight::asg::Asg;
    use glam::DVec3;
    let scene = glowing_triangle();
    let (width, height) = AA_SIZE;
    let settings = |supersample| RenderSettings {
        width,
        height,
        supersample,
        ..quad_settings()
    };
    let render = |supersample| {
        let mut r = renderer(scene.clone(), settings(supersample));
        let (img, _) = r.render(&[]).unwrap();
        (r, img)
    };
    let (r4, img4) = render(4);
    let covered = triangle_coverage(&r4, &scene);
    let (mut partial, mut worst_area, mut off_samples, mut sum) = (0, 0.0f32, 0.0f32, 0.0f32);
    for y in 0..height {
        for x in 0..width {
            let p = img4.pixel(x, y);
            let area = covered(x, y, 64);
            assert!(
                (p[3] - p[0]).abs() < 1e-5,
                "alpha {} ≠ {} at ({x}, {y})",
                p[3],
                p[0]
            );
            if area > 0.0 && area < 1.0 {
                partial += 1;
            }
            worst_area = worst_area.max((p[0] - area).abs());
            off_samples += ((p[0] - covered(x, y, 4)) * 16.0).abs().round();
            sum += area;
        }
    }
    eprintln!(
        "supersampling 4: {partial} edge pixels, worst {worst_area:.4} off the covered area, \
         {off_samples} samples off the CPU's"
    );
    assert!(partial > 40, "{partial} edge pixels");
    assert!(
        worst_area <= 0.13,
        "a pixel {worst_area} off its covered area"
    );
    assert!(
        off_samples <= 3.0,
        "{off_samples} samples differ from the CPU's"
    );
    let mean =
        |img: &Image| img.rgba.chunks(4).map(|p| p[0]).sum::<f32>() / (width * height) as f32;
    let area_fraction = sum / (width * height) as f32;
    assert!((mean(&img4) - area_fraction).abs() < 0.005 * area_fraction);
    // Without supersampling the edge pixels are all or nothing.
    let (_, img1) = render(1);
    assert!(img1.rgba.iter().all(|&v| v == 0.0 || v == 1.0));
    // The ASG pass resolves its samples too (emission only: no lobe reaches a black surface).
    let lobes = [Asg::new(DVec3::Z, DVec3::X, 4.0, 4.0, [2.0, 2.0, 2.0]).unwrap()];
    let mut r = renderer(scene.clone(), settings(4));
    let (asg, _) = r.render_asg(&lobes).unwrap();
    let diff = asg
        .rgba
        .iter()
        .zip(&img4.rgba)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    assert!(diff < 1e-5, "ASG and light passes differ by {diff}");
    for (supersample, size, needle) in [
        (0, (8, 8), "supersampling 0 outside 1..=4"),
        (5, (8, 8), "supersampling 5 outside 1..=4"),
        (4, (8192, 8), "supersampled 4× is 32768x32"),
    ] {
        let e = Renderer::new(
            scene.clone(),
            RenderSettings {
                width: size.0,
                height: size.1,
                supersample,
                ..quad_settings()
            },
        )
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
        assert!(e.contains(needle), "{supersample}: {e}");
    }
}

/// FXAA (`RenderSettings::fxaa`): on the glowing triangle's edges over the transparent
/// background, on a black triangle's there (an edge in alpha only) and on the glowing one's in
/// front of an opaque glowing wall (in colour only), the
/// image is nearer the exactly covered fraction than without it — its summed error at most
/// 0.6 of the aliased image's — colour and alpha blended alike; pixels away from the edges are
/// left exactly as they were; with supersampling it is refused.
#[test]
fn fxaa_brings_edges_towards_their_covered_fraction() {
    let (width, height) = AA_SIZE;
    let render = |scene: &Scene, supersample: u32, fxaa: bool| {
        let settings = RenderSettings {
            width,
            height,
            supersample,
            fxaa,
            ..quad_settings()
        };
        let mut r = renderer(scene.clone(), settings);
        let (img, _) = r.render(&[]).unwrap();
        (r, img)
    };
    let alone = glowing_triangle();
    let mut walled = alone.clone();
    add_quad(
        &mut walled,
        3.0,
        -1.0,
        Material {
            emission: [0.2; 3],
            ..Material::lambertian([0.0; 3])
        },
    );
    // A black silhouette: only its alpha tells it from the empty background.
    let mut black = alone.clone();
    black.materials[0].emission = [0.0; 3];
    let (r, _) = render(&alone, 1, false);
    let covered = triangle_coverage(&r, &alone);
    for (name, scene, background, channel) in [
        ("white silhouette", &alone, 0.0f32, 0),
        ("black silhouette", &black, 0.0, 3),
        ("colour edge", &walled, 0.2, 0),
    ] {
        // The exact image: the triangle's covered fraction over the background, in red (the
        // silhouette's alpha for the black one).
        let exact = |x, y| background + (1.0 - background) * covered(x, y, 64);
        let error = |img: &Image| {
            let mut sum = 0.0f32;
            for y in 0..height {
                for x in 0..width {
                    sum += (img.pixel(x, y)[channel] - exact(x, y)).abs();
                }
            }
            sum
        };
        let (_, aliased) = render(scene, 1, false);
        let (_, smoothed) = render(scene, 1, true);
        let (_, supersampled) = render(scene, 2, false);
        let (e_aliased, e_smoothed) = (error(&aliased), error(&smoothed));
        eprintln!(
            "{name}: summed error aliased {e_aliased:.2}, FXAA {e_smoothed:.2}, supersampled 2 \
             {:.2}",
            error(&supersampled),
        );
        assert!(
            e_smoothed <= 0.6 * e_aliased,
            "{name}: FXAA's error {e_smoothed} against {e_aliased} without"
        );
        let mut changed = 0;
        for y in 0..height {
            for x in 0..width {
                let (a, b) = (aliased.pixel(x, y), smoothed.pixel(x, y));
                // Colour and alpha alike: the glow is white, so alpha follows red over the
                // empty background; over the wall alpha stays 1; a black silhouette stays black.
                let alpha = if background == 0.0 { b[0] } else { 1.0 };
                if channel == 3 {
                    assert_eq!(b[0], 0.0, "{name}: colour at ({x}, {y})");
                } else {
                    assert!(
                        (b[3] - alpha).abs() < 1e-5,
                        "{name}: alpha {} at ({x}, {y})",
                        b[3]
                    );
                }
                let far = (0..9).all(|k| {
                    let (dx, dy) = (k % 3, k / 3);
                    let (nx, ny) = ((x + dx).saturating_sub(1), (y + dy).saturating_sub(1));
                    let c = covered(nx.min(width - 1), ny.min(height - 1), 8);
                    c == covered(x, y, 8) && (c == 0.0 || c == 1.0)
                });
                if far {
                    assert_eq!(a, b, "{name}: ({x}, {y}) is away from the edges");
                } else if a != b {
                    changed += 1;
                }
            }
        }
        assert!(changed > 20, "{name}: {changed} edge pixels changed");
    }
    // With supersampling it would blur the resolved edges (error 11.7 against 6.0 for the
    // supersampling alone, when it was allowed): refused in words.
    let e = Renderer::new(
        alone,
        RenderSettings {
            width,
            height,
            supersample: 2,
            fxaa: true,
            ..quad_settings()
        },
    )
    .err()
    .map(|e| e.to_string())
    .unwrap_or_default();
    assert!(e.contains("FXAA with supersampling 2"), "{e}");
}

/// ASG lighting casts shadows: each lobe is shadowed by a map along its axis with a PCF kernel
/// as wide as the lobe (its solid angle). A square before a white receiver, lit by one lobe
/// from the side: under a narrow lobe the receiver in the square's umbra gets almost none of
/// the light it gets without shadows, under a wide lobe much more (its shadow is soft), and
/// away from the shadow the same as without; with either raster. A shadow-catcher ground under
/// a lobe from above outputs the spheres' shadows as alpha (transparent black before).
#[test]
fn asg_lobes_cast_soft_shadows() {
    use envlight::asg::Asg;
    use glam::DVec3;
    let axis = DVec3::new(0.5, 0.0, 1.0).normalize();
    let lobe = |sharpness: f64| [Asg::new(axis, DVec3::Y, sharpness, sharpness, [2.0; 3]).unwrap()];
    let mut scene = textured_quad(Material::lambertian([0.5; 3]), vec![], 1.0);
    for v in &mut scene.vertices {
        v.position[0] *= 0.3;
        v.position[1] *= 0.3;
    }
    add_quad(&mut scene, 2.0, -1.5, Material::lambertian([1.0; 3]));
    scene.bounds.radius = 3.3;
    // The mean red of the receiver's pixels (where the camera ray meets the plane z = −1.5)
    // within `x` and |y| < `half_y`, past the square.
    let receiver_mean = |r: &Renderer, img: &Image, x: std::ops::Range<f32>, half_y: f32| {
        let eye = Vec3::new(0.0, 0.0, 3.0);
        let (mut sum, mut n) = (0.0f32, 0);
        for py in 0..img.height {
            for px in 0..img.width {
                let d = r.pixel_ray(px as f32 + 0.5, py as f32 + 0.5);
                let at_square = eye + d * (-eye.z / d.z);
                if at_square.x.abs() < 0.32 && at_square.y.abs() < 0.32 {
                    continue;
                }
                let hit = eye + d * ((-1.5 - eye.z) / d.z);
                if x.contains(&hit.x) && hit.y.abs() < half_y {
                    sum += img.pixel(px, py)[0];
                    n += 1;
                }
            }
        }
        assert!(n > 10, "{n} pixels in {x:?}");
        sum / n as f32
    };
    for raster in RASTERS {
        let render = |sharpness: f64, shadows: bool| {
            let mut r = renderer(
                scene.clone(),
                RenderSettings {
                    shadows,
                    shadow_resolution: 256,
                    shadow_raster: raster,
                    ..quad_settings()
                },
            );
            let (img, stats) = r.render_asg(&lobe(sharpness)).unwrap();
            assert_eq!(stats.shadow_maps, usize::from(shadows), "{raster:?}");
            // The square's shadow is centred at x = −1.5 · 0.5 = −0.75.
            let umbra = receiver_mean(&r, &img, -0.87..-0.63, 0.12);
            let lit = receiver_mean(&r, &img, 0.7..1.5, 0.5);
            (umbra, lit)
        };
        let (narrow_umbra, narrow_lit) = render(400.0, true);
        let (free_umbra, free_lit) = render(400.0, false);
        // Sharpness 400: 0.008 sr, an angular radius of 0.05 rad; 30: 0.1 sr, 0.18 rad, whose
        // penumbra (1.7 units from the square to the receiver along the axis) is as wide as
        // the square, so its umbra is gone and the middle is partly lit.
        let (wide_umbra, wide_lit) = render(30.0, true);
        let (wide_free_umbra, wide_free_lit) = render(30.0, false);
        let (narrow, wide) = (narrow_umbra / free_umbra, wide_umbra / wide_free_umbra);
        eprintln!(
            "{raster:?}: umbra keeps {narrow:.3} of its light under a narrow lobe, {wide:.3} \
             under a wide one; lit region {:.4} and {:.4} of its unshadowed value",
            narrow_lit / free_lit,
            wide_lit / wide_free_lit
        );
        assert!(narrow < 0.05, "{raster:?}: narrow lobe's umbra {narrow}");
        assert!(
            (0.2..0.8).contains(&wide),
            "{raster:?}: wide lobe's umbra {wide}"
        );
        assert!((narrow_lit / free_lit - 1.0).abs() < 0.01, "{raster:?}");
        assert!((wide_lit / wide_free_lit - 1.0).abs() < 0.05, "{raster:?}");
    }
    // The shadow catcher: the spheres' shadows under a lobe from above.
    let mut r = default_scene_catcher();
    let above = [Asg::new(
        DVec3::new(0.2, 1.0, 0.3).normalize(),
        DVec3::X,
        400.0,
        400.0,
        [500.0; 3],
    )
    .unwrap()];
    let (img, _) = r.render_asg(&above).unwrap();
    let (mut shadow, mut clear) = (0, 0);
    for p in img.rgba.chunks_exact(4) {
        if p[..3] == [0.0; 3] && p[3] > 0.5 {
            shadow += 1;
        } else if p[3] < 0.01 {
            clear += 1;
        }
    }
    eprintln!("ASG catcher: {shadow} shadow pixels, {clear} clear");
    assert!(shadow > 50 && clear > 1000, "{shadow} {clear}");
}

/// Where the grazing-floor tests' camera is.
const FLOOR_EYE: Vec3 = Vec3::new(0.0, 0.5, 3.0);

/// The grazing-floor tests' light: along the mirror direction of the view of the floor's
/// middle, so the specular lobes are seen at grazing angles.
fn floor_mirror_light() -> Vec3 {
    let view = (FLOOR_EYE - Vec3::new(0.0, 0.0, -4.0)).normalize();
    Vec3::new(-view.x, view.y, -view.z)
}

/// A floor y = 0 from z = 2 to −38, x in −1…1, of `material` (texture coordinates u = (x + 1)/2,
/// v = (2 − z)/2), seen from `eye` towards `target` with a 30° field of view.
fn floor_scene(material: Material, eye: Vec3, target: Vec3) -> Scene {
    use envlight::render::scene::{Sphere, Vertex};
    let corner = |x: f32, z: f32| Vertex {
        position: [x, 0.0, z],
        normal: [0.0, 1.0, 0.0],
        material: 0,
        uv: [(x + 1.0) / 2.0, (2.0 - z) / 2.0],
        uv1: [0.0; 2],
        tangent: [0.0; 4],
        color: envlight::render::scene::WHITE,
    };
    Scene {
        vertices: vec![
            corner(-1.0, 2.0),
            corner(1.0, 2.0),
            corner(1.0, -38.0),
            corner(-1.0, -38.0),
        ],
        indices: vec![0, 1, 2, 0, 2, 3],
        caster_indices: 6,
        materials: vec![material],
        textures: vec![],
        ground_material: None,
        camera: Camera::perspective(eye, target, 30f32.to_radians()),
        bounds: Sphere {
            center: Vec3::new(0.0, 0.0, -18.0),
            radius: 21.0,
        },
        animation: None,
    }
}

/// A [`floor_scene`] of `material` seen at grazing angles from [`FLOOR_EYE`] and lit by one
/// light of 3 W/m² from [`floor_mirror_light`], no shadows.
fn render_floor(material: Material) -> (Renderer, Image) {
    let scene = floor_scene(material, FLOOR_EYE, Vec3::new(0.0, 0.0, -4.0));
    let mut r = renderer(scene, quad_settings());
    let (img, _) = r
        .render(&[light(0, floor_mirror_light(), [3.0, 3.0, 3.0], 0.0)])
        .unwrap();
    (r, img)
}

/// The pixels of a [`render_floor`] image worth comparing: red at least 1% of the image's
/// brightest, away from the floor's edges (where a pixel mixes floor and background), with
/// the floor point each sees.
fn floor_pixels(r: &Renderer, img: &Image) -> Vec<(u32, u32, Vec3)> {
    let peak = img.rgba.chunks(4).map(|p| p[0]).fold(0.0, f32::max);
    let mut out = Vec::new();
    for y in 0..img.height {
        for x in 0..img.width {
            if img.pixel(x, y)[0] < 0.01 * peak {
                continue;
            }
            let d = r.pixel_ray(x as f32 + 0.5, y as f32 + 0.5);
            let hit = FLOOR_EYE + d * (-FLOOR_EYE.y / d.y);
            if hit.x.abs() <= 0.9 && hit.z <= 1.9 && hit.z >= -37.0 {
                out.push((x, y, hit));
            }
        }
    }
    out
}

/// The dielectric Fresnel terms of glTF's KHR_materials_ior and KHR_materials_specular: on a
/// black glossy quad seen head-on under a light from the camera (v = l = n: Schlick's F = F0),
/// an index of refraction of 2.42 reflects ((1.42/3.42)²)/0.04 times the default's light, and
/// a tint and strength scale each channel as F0 does; on a floor seen at grazing angles with
/// the light along the mirror direction, a tint of 2 at strength 0.5 (F0 the default's 0.04,
/// F90 0.5) changes each pixel by Schlick's ratio (0.04 + 0.46 w)/(0.04 + 0.96 w),
/// w = (1 − v·h)⁵ — 1 head-on, towards 0.5 where the view grazes: the grazing reflectance F90
/// is the material's.
#[test]
fn ior_and_specular_set_the_fresnel_reflectance() {
    let glossy = |ior: f32, color: [f32; 3], factor: f32| Material {
        specular: (ior - 1.0) / (ior + 1.0) / 0.4,
        specular_color: color,
        specular_factor: factor,
        roughness: 0.4,
        ..Material::lambertian([0.0; 3])
    };
    let lights = [light(0, Vec3::Z, [3.0, 3.0, 3.0], 0.0)];
    let head_on = |m: Material| {
        let (r, img) = render_quad(textured_quad(m, vec![], 1.0), &lights);
        mean_over(&r, &img, -0.3..0.3)
    };
    let default = head_on(glossy(1.5, [1.0; 3], 1.0));
    assert!(default[0] > 0.01, "{default:?}");
    let diamond = head_on(glossy(2.42, [1.0; 3], 1.0));
    let f0 = (1.42f32 / 3.42).powi(2);
    assert_close("ior 2.42", diamond, default.map(|c| c * f0 / 0.04), 0.005);
    let tinted = head_on(glossy(1.5, [1.0, 0.5, 0.25], 0.5));
    assert_close(
        "tint and factor",
        tinted,
        [0.5, 0.25, 0.125].map(|k| k * default[0]),
        0.005,
    );
    let l = floor_mirror_light();
    let (r, full) = render_floor(glossy(1.5, [1.0; 3], 1.0));
    let (_, half) = render_floor(glossy(1.5, [2.0; 3], 0.5));
    let (mut checked, mut worst, mut grazing) = (0, 0.0f32, 1.0f32);
    for (x, y, hit) in floor_pixels(&r, &full) {
        let v = (FLOOR_EYE - hit).normalize();
        let w = (1.0 - v.dot((v + l).normalize()).clamp(0.0, 1.0)).powi(5);
        let want = (0.04 + 0.46 * w) / (0.04 + 0.96 * w);
        let got = half.pixel(x, y)[0] / full.pixel(x, y)[0];
        worst = worst.max((got / want - 1.0).abs());
        grazing = grazing.min(want);
        checked += 1;
    }
    eprintln!("F90: {checked} pixels, Schlick ratios down to {grazing:.3}, worst {worst:.5} off");
    assert!(checked > 500, "{checked} pixels");
    assert!(grazing < 0.7, "no grazing pixel: ratio at least {grazing}");
    assert!(worst < 0.01, "a pixel {worst} off Schlick's ratio");
}

/// glTF's KHR_materials_clearcoat: a clear coat of roughness r over a black, non-reflecting
/// material reflects exactly as a plain dielectric of roughness r (F0 0.04, F90 1), pixel by
/// pixel on the grazing floor (the coat's Fresnel share times its GGX lobe is the dielectric's
/// Schlick Fresnel times the same lobe); over a white Lambertian quad seen head-on it takes its
/// Fresnel share, 0.04, from the diffuse light, and from the emission; the ASG pass agrees
/// head-on with its dielectric.
#[test]
fn clear_coats_reflect_as_a_dielectric_layer() {
    use envlight::asg::Asg;
    use glam::DVec3;
    let coat = |base: Material| Material {
        clearcoat: 1.0,
        clearcoat_roughness: 0.4,
        ..base
    };
    let black = Material::lambertian([0.0; 3]);
    let dielectric = Material {
        specular: 0.5,
        roughness: 0.4,
        ..black
    };
    // Grazing floor: pixel by pixel.
    let (r, plain) = render_floor(dielectric);
    let (_, coated) = render_floor(coat(black));
    let mut worst = 0.0f32;
    let pixels = floor_pixels(&r, &plain);
    for &(x, y, _) in &pixels {
        let (a, b) = (plain.pixel(x, y), coated.pixel(x, y));
        for c in 0..3 {
            worst = worst.max((b[c] / a[c] - 1.0).abs());
        }
    }
    eprintln!(
        "clear coat against a dielectric: {} pixels, worst {worst:.5} off",
        pixels.len()
    );
    assert!(
        pixels.len() > 500 && worst < 0.005,
        "{} pixels, worst {worst}",
        pixels.len()
    );
    // Head-on: the coat takes its share of the diffuse light and of the emission.
    let lights = [light(0, Vec3::Z, [3.0, 3.0, 3.0], 0.0)];
    let head_on = |m: Material| {
        let (r, img) = render_quad(textured_quad(m, vec![], 1.0), &lights);
        mean_over(&r, &img, -0.3..0.3)
    };
    let coat_alone = head_on(coat(black));
    assert_close("coat alone", coat_alone, head_on(dielectric), 0.005);
    let white = Material::lambertian([1.0; 3]);
    let want = [0, 1, 2].map(|c| 0.96 * head_on(white)[c] + coat_alone[c]);
    assert_close("coat over white", head_on(coat(white)), want, 0.005);
    let glow = Material {
        emission: [2.0, 1.0, 0.5],
        ..black
    };
    let want = head_on(glow).map(|c| 0.96 * c);
    let got = head_on(coat(glow));
    // (The coat's own reflection of the light is there too.)
    let got = [0, 1, 2].map(|c| got[c] - coat_alone[c]);
    assert_close("coat over emission", got, want, 0.005);
    // ASG lighting: head-on the coat's Fresnel at n·v is its F0, 0.04, the dielectric's.
    let lobes = [Asg::new(DVec3::Z, DVec3::X, 4.0, 4.0, [2.0, 2.0, 2.0]).unwrap()];
    let asg = |m: Material| {
        let mut r = renderer(textured_quad(m, vec![], 1.0), quad_settings());
        let (img, _) = r.render_asg(&lobes).unwrap();
        mean_over(&r, &img, -0.3..0.3)
    };
    let plain = asg(dielectric);
    assert!(plain[0] > 1e-3, "{plain:?}");
    assert_close("ASG, coat alone", asg(coat(black)), plain, 0.01);
}

/// The textures of KHR_materials_specular and KHR_materials_clearcoat multiply their factors:
/// on a glossy quad seen head-on under a light from the camera, each half of a two-valued
/// texture shades as the untextured material whose factor is the product, over the same
/// region — the specular texture's A scaling the dielectric reflection, the specular-colour
/// texture (sRGB) tinting F0 before its clamp to 1, the clear-coat texture's R the coat's
/// strength and the clear-coat roughness texture's G its roughness.
#[test]
fn specular_and_clear_coat_textures_multiply_their_factors() {
    use envlight::render::scene::TextureRef;
    let lights = [light(0, Vec3::Z, [3.0, 3.0, 3.0], 0.0)];
    let halves_of = |m: Material, left: [u8; 4], right: [u8; 4]| {
        let row = texture_row(4, |x| if x < 2 { left } else { right });
        let (r, img) = render_quad(textured_quad(m, vec![row], 1.0), &lights);
        quad_halves(&r, &img)
    };
    let plain_halves = |m: Material| {
        let (r, img) = render_quad(textured_quad(m, vec![], 1.0), &lights);
        quad_halves(&r, &img)
    };
    let check = |what: &str, got: ([f32; 3], [f32; 3]), want: ([f32; 3], [f32; 3])| {
        eprintln!(
            "{what}: left {:?} / {:?}, right {:?} / {:?}",
            got.0, want.0, got.1, want.1
        );
        assert!(
            want.0[0].max(want.1[0]) > 1e-3,
            "{what}: too dark to compare"
        );
        assert_close(&format!("{what}, left"), got.0, want.0, 0.01);
        assert_close(&format!("{what}, right"), got.1, want.1, 0.01);
    };
    let glossy = Material {
        specular: 0.5,
        roughness: 0.4,
        ..Material::lambertian([0.0; 3])
    };
    let texture = TextureRef::repeating(0);
    // Specular strength: A = 255 and 64.
    let mut m = glossy;
    m.textures.specular = Some(texture);
    let got = halves_of(m, [0, 0, 0, 255], [255, 255, 255, 64]);
    let full = plain_halves(glossy);
    let scaled = plain_halves(Material {
        specular_factor: 64.0 / 255.0,
        ..glossy
    });
    check("specular texture", got, (full.0, scaled.1));
    // Specular colour: a tint of 50 makes F0 = 0.04 · 50 = 2 before the texture; a white
    // texel leaves it clamped to 1, an sRGB (64, 128, 255) one scales each channel first.
    let mut m = Material {
        specular_color: [50.0; 3],
        ..glossy
    };
    m.textures.specular_color = Some(texture);
    let got = halves_of(m, [255; 4], [64, 128, 255, 255]);
    let tint = [64, 128, 255].map(|c| 50.0 * srgb_code_to_linear(c));
    let want_left = plain_halves(Material {
        specular_color: [25.0; 3],
        ..glossy
    });
    let want_right = plain_halves(Material {
        specular_color: tint,
        ..glossy
    });
    check("specular colour texture", got, (want_left.0, want_right.1));
    // Clear coat over a black, non-reflecting base: strength R = 255 and 102, roughness
    // G = 102 and 255 of a factor of 1.
    let black = Material::lambertian([0.0; 3]);
    let coat = |strength: f32, roughness: f32| Material {
        clearcoat: strength,
        clearcoat_roughness: roughness,
        ..black
    };
    let mut m = coat(1.0, 0.4);
    m.textures.clearcoat = Some(texture);
    let got = halves_of(m, [255, 0, 0, 255], [102, 255, 255, 255]);
    check(
        "clear-coat texture",
        got,
        (
            plain_halves(coat(1.0, 0.4)).0,
            plain_halves(coat(0.4, 0.4)).1,
        ),
    );
    let mut m = coat(1.0, 1.0);
    m.textures.clearcoat_roughness = Some(texture);
    let got = halves_of(m, [0, 102, 0, 255], [0, 255, 0, 255]);
    check(
        "clear-coat roughness texture",
        got,
        (
            plain_halves(coat(1.0, 0.4)).0,
            plain_halves(coat(1.0, 1.0)).1,
        ),
    );
}

/// A clear coat has a normal of its own (KHR_materials_clearcoat): without a clear-coat
/// normal texture it follows the interpolated normal, not the base's normal texture — a coat
/// over a black base with a tilted normal texture shades pixel for pixel as the same coat
/// without one (light and ASG passes) — and with one, a coat over black shades as a plain
/// dielectric (F0 0.04, F90 1) whose normal texture it is, at the texture's scale.
#[test]
fn clear_coats_follow_their_own_normal() {
    use envlight::asg::Asg;
    use envlight::render::scene::TextureRef;
    use glam::DVec3;
    // 30° towards +x in tangent space.
    const TILT_X: [u8; 4] = [191, 128, 238, 255];
    let tilted = || vec![texture_row(1, |_| TILT_X)];
    let lights = [light(
        0,
        Vec3::new(0.5, 0.0, 1.0).normalize(),
        [3.0, 3.0, 3.0],
        0.0,
    )];
    let render = |m: Material, textures: Vec<TextureImage>| {
        render_quad(textured_quad(m, textures, 1.0), &lights)
    };
    // Pixels lit in `a`, and the worst relative difference of `b` there.
    let compare = |a: &Image, b: &Image| {
        let peak = a.rgba.chunks(4).map(|p| p[0]).fold(0.0, f32::max);
        let (mut n, mut worst) = (0, 0.0f32);
        for y in 0..a.height {
            for x in 0..a.width {
                let (p, q) = (a.pixel(x, y), b.pixel(x, y));
                if p[0] < 0.01 * peak {
                    continue;
                }
                n += 1;
                for c in 0..3 {
                    worst = worst.max((q[c] / p[c] - 1.0).abs());
                }
            }
        }
        (n, worst)
    };
    let coat = Material {
        clearcoat: 1.0,
        clearcoat_roughness: 0.4,
        ..Material::lambertian([0.0; 3])
    };
    let (_, bare) = render(coat, vec![]);
    let mut base_normal = coat;
    base_normal.textures.normal = Some(TextureRef::repeating(0));
    let (_, beneath) = render(base_normal, tilted());
    let (n, worst) = compare(&bare, &beneath);
    eprintln!("coat over a normal-textured base: {n} pixels, worst {worst:.5} off the bare coat");
    assert!(n > 500 && worst < 0.002, "{n} pixels, worst {worst}");
    // The tilt does matter where the coat has it as its own normal.
    let mut coat_normal = coat;
    coat_normal.textures.clearcoat_normal = Some(TextureRef::repeating(0));
    for scale in [1.0f32, 0.5] {
        coat_normal.textures.clearcoat_normal_scale = scale;
        let (_, own) = render(coat_normal, tilted());
        let mut dielectric = Material {
            specular: 0.5,
            roughness: 0.4,
            ..Material::lambertian([0.0; 3])
        };
        dielectric.textures.normal = Some(TextureRef::repeating(0));
        dielectric.textures.normal_scale = scale;
        let (_, want) = render(dielectric, tilted());
        let (n, worst) = compare(&want, &own);
        let (_, moved) = compare(&bare, &own);
        eprintln!(
            "coat normal at scale {scale}: {n} pixels, worst {worst:.5} off the dielectric, \
             {moved:.3} off the bare coat"
        );
        assert!(
            n > 500 && worst < 0.005,
            "scale {scale}: {n} pixels, worst {worst}"
        );
        assert!(
            moved > 0.1,
            "scale {scale}: the coat's normal texture changed nothing"
        );
    }
    // The ASG pass: the coat over a normal-textured base is the bare coat.
    let lobes = [Asg::new(
        DVec3::new(0.5, 0.0, 1.0).normalize(),
        DVec3::Y,
        4.0,
        4.0,
        [2.0; 3],
    )
    .unwrap()];
    let asg = |m: Material, textures: Vec<TextureImage>| {
        let mut r = renderer(textured_quad(m, textures, 1.0), quad_settings());
        r.render_asg(&lobes).unwrap().0
    };
    let (n, worst) = compare(&asg(coat, vec![]), &asg(base_normal, tilted()));
    eprintln!("ASG: coat over a normal-textured base: {n} pixels, worst {worst:.5} off");
    assert!(n > 500 && worst < 0.002, "ASG: {n} pixels, worst {worst}");
}

/// A material cut out by its alpha (glTF's MASK; the factor's alpha times the base-colour
/// texture's) is not there where the alpha is below the cutoff: not drawn (light and ASG
/// passes) and casting no shadow, with either shadow raster; an opaque material ignores its
/// alpha.
#[test]
fn cut_out_materials_are_not_drawn_and_cast_no_shadow() {
    use envlight::asg::Asg;
    use envlight::render::scene::TextureRef;
    use glam::DVec3;
    // White; alpha 0 on the left texels, 1 on the right.
    let holes = texture_row(4, |x| [255, 255, 255, if x < 2 { 0 } else { 255 }]);
    let mut cut = Material::lambertian([1.0; 3]);
    cut.textures.base_color = Some(TextureRef::repeating(0));
    cut.alpha_mode = AlphaMode::Mask(0.5);
    let lights = [light(0, Vec3::Z, [3.0, 3.0, 3.0], 0.0)];
    let lit_white = 3.0 / std::f32::consts::PI;
    let opaque = |img: &Image, r: &Renderer, x_range| mean_over(r, img, x_range);
    // Alone: the left half is empty (transparent black), the right half drawn.
    let (r, img) = render_quad(textured_quad(cut, vec![holes.clone()], 1.0), &lights);
    let (left, right) = quad_halves(&r, &img);
    assert_close("cut-out half", left, [0.0; 3], 1e-6);
    assert_close("kept half", right, [lit_white; 3], 0.01);
    let mut asg_renderer = renderer(
        textured_quad(cut, vec![holes.clone()], 1.0),
        quad_settings(),
    );
    let lobes = [Asg::new(DVec3::Z, DVec3::X, 4.0, 4.0, [2.0, 2.0, 2.0]).unwrap()];
    let (img, _) = asg_renderer.render_asg(&lobes).unwrap();
    let (left, right) = quad_halves(&asg_renderer, &img);
    assert_close("ASG, cut-out half", left, [0.0; 3], 1e-6);
    assert!(right[0] > 0.1, "ASG, kept half: {right:?}");
    // An opaque material ignores its alpha.
    let mut opaque_material = cut;
    opaque_material.alpha_mode = AlphaMode::Opaque;
    let (r, img) = render_quad(
        textured_quad(opaque_material, vec![holes.clone()], 1.0),
        &lights,
    );
    assert_close("opaque", opaque(&img, &r, -0.7..-0.3), [lit_white; 3], 0.01);
    // Before a white receiver 0.5 behind, under a frontal light: through the hole the receiver
    // is lit (the cut-out part casts no shadow); beside it, the kept half is drawn.
    for raster in [ShadowRaster::Pipeline, ShadowRaster::Compute] {
        let scene = textured_quad(cut, vec![holes.clone()], 1.0);
        let mut r = before_receiver(scene, raster);
        let (img, stats) = r.render(&lights).unwrap();
        assert_eq!(stats.shadow_maps, 1);
        let (through, kept) = quad_halves(&r, &img);
        assert_close(
            &format!("{raster:?}: receiver through the hole"),
            through,
            [lit_white; 3],
            0.02,
        );
        assert_close(
            &format!("{raster:?}: kept half"),
            kept,
            [lit_white; 3],
            0.02,
        );
    }
}

/// glTF's doubleSided: a quad seen from behind (wound clockwise on screen, its normals away
/// from the camera) is shaded with its normal reversed — lit by a light on the viewer's side as
/// its front is — when double-sided, and not drawn when single-sided, in the light and ASG
/// passes; seen from the front both are drawn.
#[test]
fn back_faces_are_reversed_when_double_sided_and_not_drawn_when_single_sided() {
    use envlight::asg::Asg;
    use glam::DVec3;
    let lights = [light(0, Vec3::Z, [3.0, 3.0, 3.0], 0.0)];
    let lobes = [Asg::new(DVec3::Z, DVec3::X, 4.0, 4.0, [2.0, 2.0, 2.0]).unwrap()];
    let lit_white = [3.0 / std::f32::consts::PI; 3];
    let asg_mean = |scene: Scene| {
        let mut r = renderer(scene, quad_settings());
        let (img, _) = r.render_asg(&lobes).unwrap();
        mean_over(&r, &img, -0.5..0.5)
    };
    for double_sided in [true, false] {
        let material = Material {
            double_sided,
            ..Material::lambertian([1.0; 3])
        };
        let front = textured_quad(material, vec![], 1.0);
        let mut back = front.clone();
        for triangle in back.indices.chunks_exact_mut(3) {
            triangle.swap(1, 2);
        }
        for v in &mut back.vertices {
            v.normal = [0.0, 0.0, -1.0];
        }
        let (r, img) = render_quad(front.clone(), &lights);
        let what = |side: &str| format!("{side}, double-sided {double_sided}");
        assert_close(
            &what("front"),
            mean_over(&r, &img, -0.5..0.5),
            lit_white,
            0.01,
        );
        let (r, img) = render_quad(back.clone(), &lights);
        let want = if double_sided { lit_white } else { [0.0; 3] };
        assert_close(&what("back"), mean_over(&r, &img, -0.5..0.5), want, 0.01);
        let front_asg = asg_mean(front);
        assert!(front_asg[0] > 0.1, "{}: {front_asg:?}", what("ASG, front"));
        let want = if double_sided { front_asg } else { [0.0; 3] };
        assert_close(&what("ASG, back"), asg_mean(back), want, 0.01);
    }
}

/// Textures are filtered anisotropically where the adapter can: stripes across a floor seen
/// at a grazing angle keep their contrast far away, where the isotropic mip level — chosen by
/// the footprint's long axis, along the view — averages them to grey. An anisotropy outside
/// 1..=16 is refused in words.
#[test]
fn grazing_textures_are_filtered_anisotropically() {
    use envlight::render::scene::TextureRef;
    // 256 texels a side, columns alternating black and white every 8: gone by mip level 3.
    let stripes = TextureImage {
        name: "stripes".into(),
        width: 256,
        height: 256,
        rgba: (0..256 * 256)
            .flat_map(|i| {
                let c = if (i % 256) / 8 % 2 == 0 { 0 } else { 255 };
                [c, c, c, 255]
            })
            .collect(),
    };
    let mut material = Material::lambertian([1.0; 3]);
    material.textures.base_color = Some(TextureRef::repeating(0));
    // One copy of the image across the floor, 20 along.
    let mut scene = floor_scene(
        material,
        Vec3::new(0.0, 0.25, 3.0),
        Vec3::new(0.0, 0.0, -10.0),
    );
    scene.textures.push(stripes);
    for bad in [0, 17] {
        let settings = RenderSettings {
            texture_anisotropy: bad,
            ..quad_settings()
        };
        let e = Renderer::new(scene.clone(), settings)
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains(&format!("texture anisotropy {bad} outside 1..=16")),
            "{e}"
        );
    }
    let mut r = renderer(
        scene,
        RenderSettings {
            texture_anisotropy: 16,
            ..quad_settings()
        },
    );
    let anisotropic = r
        .gpu()
        .adapter
        .get_downlevel_capabilities()
        .flags
        .contains(wgpu::DownlevelFlags::ANISOTROPIC_FILTERING);
    let (img, _) = r
        .render(&[light(0, Vec3::Y, [3.0, 3.0, 3.0], 0.0)])
        .unwrap();
    // Per image row: the floor's pixels' contrast (max − min over their mean).
    let contrast = |y: u32| {
        let values: Vec<f32> = (0..img.width)
            .map(|x| img.pixel(x, y))
            .filter(|p| p[3] > 0.0)
            .map(|p| p[0])
            .collect();
        let mean = values.iter().sum::<f32>() / values.len().max(1) as f32;
        let (lo, hi) = values
            .iter()
            .fold((f32::MAX, f32::MIN), |(lo, hi), &v| (lo.min(v), hi.max(v)));
        (
            values.len(),
            if mean > 0.0 { (hi - lo) / mean } else { 0.0 },
        )
    };
    // The farthest rows with at least 24 floor pixels.
    let far: Vec<f32> = (0..img.height)
        .map(contrast)
        .filter(|&(n, _)| n >= 24)
        .take(4)
        .map(|(_, c)| c)
        .collect();
    // The best resolved row (the near ones: 2, black against white).
    let near = (0..img.height)
        .map(|y| contrast(y).1)
        .fold(0.0f32, f32::max);
    eprintln!("anisotropic filtering {anisotropic}; contrast far {far:?}, near {near}");
    assert!(near > 1.5, "the near stripes must be resolved: {near}");
    assert!(
        anisotropic,
        "the adapter ({}) does not filter anisotropically",
        r.gpu().info.name
    );
    for c in far {
        assert!(c > 0.5, "far stripes averaged away: contrast {c}");
    }
}

/// glTF's COLOR_0: the vertex colour, interpolated, multiplies the base colour (a quad red on
/// its left edge and blue on its right shades at x = −0.5 as the albedo ¾ red + ¼ blue), and its
/// alpha the cut-out's (alpha 0 on the left edge, 1 on the right: the left half is gone and
/// casts no shadow, with both shadow rasters).
#[test]
fn vertex_colours_multiply_the_base_colour_and_its_alpha() {
    let lights = [light(0, Vec3::Z, [3.0, 3.0, 3.0], 0.0)];
    let unorm = |c: [f32; 4]| c.map(|v| (v * 65535.0).round() as u16);
    let (red, blue) = ([0.8, 0.2, 0.1], [0.1, 0.3, 0.9]);
    let coloured = |scene: &mut Scene, left: [f32; 4], right: [f32; 4]| {
        for v in &mut scene.vertices[..4] {
            v.color = unorm(if v.position[0] < 0.0 { left } else { right });
        }
    };
    let mut scene = textured_quad(Material::lambertian([1.0; 3]), vec![], 1.0);
    coloured(
        &mut scene,
        [red[0], red[1], red[2], 1.0],
        [blue[0], blue[1], blue[2], 1.0],
    );
    let (r, img) = render_quad(scene, &lights);
    let albedo = [0, 1, 2].map(|c| 0.75 * red[c] + 0.25 * blue[c]);
    let (plain_r, plain_img) = render_quad(
        textured_quad(Material::lambertian(albedo), vec![], 1.0),
        &lights,
    );
    assert_close(
        "vertex colour at x = -0.5",
        mean_over(&r, &img, -0.7..-0.3),
        mean_over(&plain_r, &plain_img, -0.7..-0.3),
        0.01,
    );
    let cut = Material {
        alpha_mode: AlphaMode::Mask(0.5),
        ..Material::lambertian([1.0; 3])
    };
    let lit_white = [3.0 / PI; 3];
    for raster in [ShadowRaster::Pipeline, ShadowRaster::Compute] {
        let mut scene = textured_quad(cut, vec![], 1.0);
        coloured(&mut scene, [1.0, 1.0, 1.0, 0.0], [1.0; 4]);
        let mut r = before_receiver(scene, raster);
        let (img, _) = r.render(&lights).unwrap();
        let (through, kept) = quad_halves(&r, &img);
        assert_close(
            &format!("{raster:?}: through the cut half"),
            through,
            lit_white,
            0.02,
        );
        assert_close(&format!("{raster:?}: kept half"), kept, lit_white, 0.02);
    }
}

/// A normal texture turns the shading normal in the tangent frame: x along the tangent
/// (increasing u), y up the image (the bitangent cross(n, t)·w), scaled by the material's
/// normal scale. Each tilted half of the quad is compared with the exact Lambertian ratio
/// n·l / n_flat·l of its decoded texel under a light tilted the same way, and the other way.
#[test]
fn normal_textures_turn_the_shading_normal_in_the_tangent_frame() {
    use envlight::render::scene::TextureRef;
    const FLAT: [u8; 4] = [128, 128, 255, 255];
    // 30° towards +x (red) and towards +y (green) in tangent space.
    const TILT_X: [u8; 4] = [191, 128, 238, 255];
    const TILT_Y: [u8; 4] = [128, 191, 238, 255];
    let decode = |code: [u8; 4], scale: f32| {
        let m = [0, 1, 2].map(|c| f32::from(code[c]) / 255.0 * 2.0 - 1.0);
        Vec3::new(m[0] * scale, m[1] * scale, m[2]).normalize()
    };
    for (tilt, axis) in [(TILT_X, Vec3::X), (TILT_Y, Vec3::Y)] {
        for scale in [1.0f32, 0.5] {
            for toward in [1.0f32, -1.0] {
                let l = (Vec3::Z + toward * axis).normalize();
                let lights = [light(0, l, [3.0, 3.0, 3.0], 0.0)];
                let mut material = Material::lambertian([0.8; 3]);
                material.textures.normal = Some(TextureRef::repeating(0));
                material.textures.normal_scale = scale;
                let halves = texture_row(4, |x| if x < 2 { tilt } else { FLAT });
                let (r, img) = render_quad(textured_quad(material, vec![halves], 1.0), &lights);
                let (tilted, flat) = quad_halves(&r, &img);
                let want = decode(tilt, scale).dot(l) / decode(FLAT, scale).dot(l);
                let got = tilted[1] / flat[1];
                assert!(
                    (got - want).abs() <= 0.005 * want,
                    "tilt along {axis}, scale {scale}, light {l}: tilted / flat {got}, expected \
                     {want}"
                );
            }
        }
    }
}

/// More texture layers in one array than the GPU allows is refused with the counts, not a
/// validation panic; one fewer renders.
#[test]
fn more_texture_layers_than_the_gpu_allows_are_refused_in_words() {
    use envlight::render::scene::TextureRef;
    let settings = RenderSettings {
        width: 16,
        height: 16,
        shadows: false,
        ..Default::default()
    };
    let limit = renderer(Scene::default_scene(), settings)
        .gpu()
        .device
        .limits()
        .max_texture_array_layers;
    let scene = |layers: u32| {
        let textures = (0..layers)
            .map(|i| texture_row(1, |_| [i as u8, 0, 0, 255]))
            .collect();
        let mut scene = textured_quad(Material::lambertian([1.0; 3]), textures, 1.0);
        scene.materials = (0..layers)
            .map(|image| {
                let mut m = Material::lambertian([1.0; 3]);
                m.textures.base_color = Some(TextureRef::repeating(image));
                m
            })
            .collect();
        scene
    };
    let e = Renderer::new(scene(limit + 1), settings)
        .err()
        .expect("more layers than the limit")
        .to_string();
    assert!(
        e.contains(&format!("{} texture layers", limit + 1)) && e.contains(&limit.to_string()),
        "{e}"
    );
    renderer(scene(limit), settings).render(&[]).unwrap();
}

/// `envlight render --scene` on a textured glTF (a quad with a base-colour and a normal
/// texture in a PNG beside it, and features the renderer does not draw): it renders, logs the
/// texture layers it made and names in one warning what it leaves out; without the PNG it
/// fails naming it.
#[test]
fn cli_renders_a_textured_gltf_and_names_what_it_does_not_draw() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    image::RgbaImage::from_fn(8, 8, |x, y| {
        image::Rgba(if (x + y) % 2 == 0 {
            [230, 200, 40, 255]
        } else {
            [128, 128, 255, 255]
        })
    })
    .save(d.join("tex.png"))
    .unwrap();
    let positions: [f32; 12] = [-1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 2.0, 0.0, -1.0, 2.0, 0.0];
    let uvs: [f32; 8] = [0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0];
    let mut bin: Vec<u8> = positions
        .iter()
        .chain(&uvs)
        .flat_map(|f| f.to_le_bytes())
        .collect();
    bin.extend([0u16, 1, 2, 0, 2, 3].iter().flat_map(|i| i.to_le_bytes()));
    std::fs::write(d.join("quad.bin"), &bin).unwrap();
    let gltf = r#"{"asset":{"version":"2.0"},
        "extensionsUsed":["KHR_materials_emissive_strength","KHR_materials_sheen","KHR_materials_specular",
                          "KHR_materials_transmission"],
        "scene":0,"scenes":[{"nodes":[0]}],"nodes":[{"mesh":0}],
        "meshes":[{"primitives":[{"attributes":{"POSITION":0,"TEXCOORD_0":1},"indices":2,"material":0}]}],
        "materials":[{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}},"normalTexture":{"index":1},
                      "emissiveFactor":[1,0,0],"alphaMode":"BLEND",
                      "extensions":{"KHR_materials_specular":{"specularFactor":0.5,"specularTexture":{"index":0}},
                                    "KHR_materials_sheen":{"sheenColorFactor":[0.5,0.5,0.5],"sheenColorTexture":{"index":0}}}}],
        "textures":[{"source":0},{"source":1}],"images":[{"uri":"tex.png"},{"uri":"tex.png"}],
        "accessors":[{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[-1,0,0],"max":[1,2,0]},
                     {"bufferView":1,"componentType":5126,"count":4,"type":"VEC2"},
                     {"bufferView":2,"componentType":5123,"count":6,"type":"SCALAR"}],
        "bufferViews":[{"buffer":0,"byteLength":48},{"buffer":0,"byteOffset":48,"byteLength":32},
                       {"buffer":0,"byteOffset":80,"byteLength":12}],
        "buffers":[{"byteLength":92,"uri":"quad.bin"}]}"#;
    std::fs::write(d.join("quad.gltf"), gltf).unwrap();
    let render = || {
        std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
            .args(["render", "--size", "32x24", "--scene"])
            .arg(d.join("quad.gltf"))
            .arg("--out")
            .arg(d.join("out"))
            .output()
            .unwrap()
    };
    let o = render();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    for needle in [
        // The image as base colour (sRGB), and as normal texture and specular texture (data).
        "textures: 3 layers of 8²",
        "not drawn",
        "scene: 4 triangles (2 casting shadows), 2 materials (1 blended, 1 emissive, 1 \
         textured), 2 texture images",
        "extension KHR_materials_transmission",
        "KHR_materials_sheen textures (its factors are drawn)",
    ] {
        assert!(
            stderr.contains(needle),
            "{needle:?} missing from:\n{stderr}"
        );
    }
    // What is drawn is not named: the normal texture, the emission and its strength, the
    // blending, the specular texture.
    let left_out = stderr.split("textures): ").nth(1).unwrap_or("");
    let left_out = left_out.lines().next().unwrap_or("");
    for drawn in [
        "normal",
        "emissi",
        "blend",
        "KHR_materials_specular",
        "specularTexture",
    ] {
        assert!(!left_out.contains(drawn), "{drawn}: {stderr}");
    }
    let png = image::open(d.join("out/frame_00000.png")).unwrap();
    assert_eq!((png.width(), png.height()), (32, 24));
    std::fs::remove_file(d.join("tex.png")).unwrap();
    let o = render();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        stderr.contains("quad.gltf") && stderr.contains("image 0") && stderr.contains("tex.png"),
        "{stderr}"
    );
}

/// `envlight render --eye --look-at --fov` place the camera (logged in words) and change the
/// image; a camera whose eye is where it looks, or a field of view outside 1..=179°, is a
/// usage error naming the problem (as is --fxaa with supersampling).
#[test]
fn cli_places_the_camera_where_asked() {
    let dir = tempfile::tempdir().unwrap();
    let render = |out: &str, camera: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
            .args(["render", "--size", "24x16", "-n", "8", "--out"])
            .arg(dir.path().join(out))
            .args(camera)
            .output()
            .unwrap()
    };
    let o = render(
        "placed",
        &["--eye", "-1,2,6", "--look-at", "0,0.5,0", "--fov", "30"],
    );
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(
        stderr.contains(
            "camera: eye (-1.000, 2.000, 6.000), looking at (0.000, 0.500, 0.000), vertical \
             field of view 30.0°"
        ),
        "{stderr}"
    );
    let o = render("plan", &["--eye", "0,6,0.01", "--ortho-height", "3"]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(
        stderr.contains("orthographic, 3.000 units high"),
        "{stderr}"
    );
    let o = render("fitted", &[]);
    assert!(o.status.success());
    let png = |out: &str| image::open(dir.path().join(out).join("frame_00000.png")).unwrap();
    assert_ne!(png("placed").to_rgba8(), png("fitted").to_rgba8());
    for (camera, needle) in [
        (
            &["--eye", "0,0.5,0", "--look-at", "0,0.5,0"][..],
            "is where it looks",
        ),
        (
            &["--fov", "180"][..],
            "field of view 180° is outside 1..=179°",
        ),
        (&["--eye", "1,2"][..], "\"1,2\" is not three numbers X,Y,Z"),
        (
            &["--fov", "30", "--ortho-height", "2"][..],
            "cannot be used with",
        ),
        (
            &["--ortho-height", "0"][..],
            "orthographic height 0 is not a positive number",
        ),
        (
            &["--fxaa", "--supersample", "2"][..],
            "--fxaa with --supersample above 1",
        ),
    ] {
        let o = render("bad", camera);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{camera:?}: {stderr}");
        assert!(stderr.contains(needle), "{camera:?}: {stderr}");
    }
}

/// A base-colour texture's KHR_texture_transform moves, turns and scales where the image is
/// read: an offset of half the image swaps the quad's halves, and a quarter turn
/// counter-clockwise reads a texture that varies down the image (v) along the quad's u (as the
/// extension's matrix R = [[cos, −sin], [sin, cos]] does; the other sense would swap the halves).
#[test]
fn texture_transforms_move_and_turn_the_image() {
    use envlight::render::scene::TextureRef;
    let lights = [light(0, Vec3::Z, [3.0, 3.0, 3.0], 0.0)];
    let render = |scene: Scene| {
        let (r, img) = render_quad(scene, &lights);
        quad_halves(&r, &img)
    };
    let (red, blue) = (plain_quad(RED), plain_quad(BLUE));
    let textured = |image: TextureImage, transform: [[f32; 3]; 2]| {
        let mut material = Material::lambertian([1.0; 3]);
        material.textures.base_color = Some(TextureRef {
            transform,
            ..TextureRef::repeating(0)
        });
        render(textured_quad(material, vec![image], 1.0))
    };
    // Red on the left half of the image, blue on the right; offset u by ½.
    let halves = texture_row(4, |x| if x < 2 { RED } else { BLUE });
    let (left, right) = textured(halves, [[1.0, 0.0, 0.5], [0.0, 1.0, 0.0]]);
    assert_close("offset ½: left", left, blue, 0.005);
    assert_close("offset ½: right", right, red, 0.005);
    // Red on the top half, blue on the bottom (a 1 × 4 column); a quarter turn reads v' = u.
    let column = TextureImage {
        name: "column".into(),
        width: 1,
        height: 4,
        rgba: [RED, RED, BLUE, BLUE].concat(),
    };
    let (c, s) = (0.0f32, 1.0f32);
    let (left, right) = textured(column, [[c, -s, 0.0], [s, c, 0.0]]);
    assert_close("quarter turn: left", left, red, 0.005);
    assert_close("quarter turn: right", right, blue, 0.005);
}

/// An orthographic camera (a glTF file's, `Camera::orthographic`) projects along parallel
/// rays and sees every point from one direction. Its image of the unit sphere is a disc of the
/// radius its half-height gives (64×64 pixels over a half-height of 2: 16 pixels, π·16² ≈ 804
/// pixels of disc) from near and from far — a perspective camera's disc would shrink 3× from
/// 4 to 12 units away. On a glossy floor seen obliquely under one light, its every pixel has
/// the radiance of the perspective camera's centre pixel, whose ray runs along the same view
/// direction, where the perspective image's centre column varies by tens of per cent (its
/// view direction changes down the image): the shading takes the view vector from the
/// camera's `viewer` (w = 0: a direction), not from the eye.
#[test]
fn orthographic_cameras_project_in_parallel_and_see_from_one_direction() {
    for distance in [4.0, 12.0] {
        let camera = Camera::orthographic(Vec3::new(0.0, 0.0, distance), Vec3::ZERO, 2.0);
        let scene = Scene::sphere(
            Vec3::ZERO,
            1.0,
            128,
            Material::lambertian([0.8; 3]),
            None,
            camera,
        );
        let mut r = renderer(
            scene,
            RenderSettings {
                width: 64,
                height: 64,
                ..Default::default()
            },
        );
        let (img, _) = r.render(&[light(0, Vec3::Z, [3.0; 3], 0.0)]).unwrap();
        let disc = img.rgba.chunks(4).filter(|p| p[0] > 0.05).count();
        let want = PI * 16.0 * 16.0;
        eprintln!("orthographic disc from {distance}: {disc} pixels (want {want:.0})");
        assert!(
            (disc as f32 / want - 1.0).abs() < 0.04,
            "from {distance}: a disc of {disc} pixels, not {want:.0}"
        );
    }
    let glossy = Material {
        specular: 0.5,
        roughness: 0.3,
        ..Material::lambertian([0.0; 3])
    };
    let target = Vec3::new(0.0, 0.0, -4.0);
    let eye = target + 6.0 * Vec3::new(0.0, 1.0, 1.0).normalize();
    let lights = [light(0, Vec3::new(0.0, 1.0, -0.7), [3.0; 3], 0.0)];
    let render = |camera: Camera, size: u32| {
        let mut scene = floor_scene(glossy, eye, target);
        scene.camera = camera;
        let mut r = renderer(
            scene,
            RenderSettings {
                width: size,
                height: size,
                ..quad_settings()
            },
        );
        r.render(&lights).unwrap().0
    };
    let ortho = render(Camera::orthographic(eye, target, 0.4), 48);
    let red: Vec<f32> = ortho.rgba.chunks(4).map(|p| p[0]).collect();
    let (low, high) = red
        .iter()
        .fold((f32::MAX, 0.0f32), |(l, h), &c| (l.min(c), h.max(c)));
    let mean = red.iter().sum::<f32>() / red.len() as f32;
    let perspective = render(Camera::perspective(eye, target, 30f32.to_radians()), 49);
    let centre = perspective.pixel(24, 24)[0];
    let column: Vec<f32> = (0..49).map(|y| perspective.pixel(24, y)[0]).collect();
    let spread = column.iter().fold(0.0f32, |m, &c| m.max(c))
        / column.iter().fold(f32::MAX, |m, &c| m.min(c));
    eprintln!(
        "orthographic floor: red {low:.5}..{high:.5} (mean {mean:.5}); perspective centre \
         {centre:.5}, its centre column varies {spread:.2}×"
    );
    assert!(low > 0.0 && high / low < 1.01, "{low}..{high}");
    assert!((mean / centre - 1.0).abs() < 0.01, "{mean} vs {centre}");
    assert!(spread > 1.3, "the perspective view varies only {spread}×");
}

/// glTF's KHR_materials_sheen (src/render/sheen.rs): on a sphere of a Lambertian base under
/// five lights, every pixel away from the silhouette is Σ (albedo/π · (1 − max(colour) ·
/// E(n·v)) + colour · D · V) (n·l) E_l with the Charlie distribution and visibility and the
/// sheen's directional albedo E, computed on the CPU (`sheen::fibres`, `sheen::beneath`: E
/// integrated at each pixel's n·v, where the shaders interpolate 16 cosines); a sheen over a black
/// base, alone. The ASG pass takes each lobe's sheen as that of a directional light of the
/// lobe's power along its axis: its sheen-only sphere against that on the CPU.
#[test]
fn sheen_reflects_its_brdf_and_dims_the_base_by_its_albedo() {
    use envlight::render::sheen;
    let camera = reference_sphere_camera();
    let lights = vec![
        light(0, Vec3::new(0.3, 1.0, 0.5), [3.0, 2.8, 2.5], 0.0),
        light(1, Vec3::new(-1.0, 0.2, 0.4), [0.6, 0.8, 1.2], 0.0),
        light(2, Vec3::new(0.8, -0.3, 0.6), [0.4, 0.3, 0.2], 0.0),
        light(3, Vec3::new(0.0, 0.1, -1.0), [1.0, 1.0, 1.0], 0.0),
        light(4, Vec3::new(-0.2, 0.9, 0.9), [0.25, 0.5, 0.25], 0.0),
    ];
    let colour = [1.0, 0.6, 0.3];
    let roughness = 0.5;
    // Stated tolerance: 1% of the pixel's brightest channel.
    let tolerance = 0.01;
    let check = |name: &str, albedo: [f32; 3], lobes: Option<Vec<envlight::asg::Asg>>| {
        let material = Material {
            sheen_color: colour,
            sheen_roughness: roughness,
            ..Material::lambertian(albedo)
        };
        let mut r = reference_sphere(material, camera);
        let img = match &lobes {
            Some(lobes) => r.render_asg(lobes).unwrap().0,
            None => r.render(&lights).unwrap().0,
        };
        let (mut worst, mut checked) = (0.0f32, 0);
        let mut failures = Vec::new();
        for (x, y, n, v) in sphere_pixels(&r, camera.eye, 96) {
            let mut want = [0.0f32; 3];
            let beneath = if albedo == [0.0; 3] {
                0.0
            } else {
                sheen::beneath(colour, roughness, n.dot(v))
            };
            // `e_base`: the irradiance the base takes from the light; `e_sheen`: the sheen's.
            let mut add = |l: Vec3, e_base: [f32; 3], e_sheen: [f32; 3]| {
                let fibres = sheen::fibres(colour, roughness, n, v, l);
                for c in 0..3 {
                    want[c] += albedo[c] / PI * beneath * e_base[c] + fibres[c] * e_sheen[c];
                }
            };
            match &lobes {
                None => {
                    for l in &lights {
                        let d = Vec3::from_array(l.dir);
                        let cos = n.dot(d).max(0.0);
                        let e = l.rgb.map(|c| c * cos);
                        add(d, e, e);
                    }
                }
                Some(lobes) => {
                    for lobe in lobes {
                        let axis = Vec3::from_array(lobe.axis.map(|c| c as f32));
                        let cos = n.dot(axis).max(0.0);
                        add(
                            axis,
                            lobe.irradiance(n.as_dvec3()).map(|c| c as f32),
                            lobe.integral().map(|c| c as f32 * cos),
                        );
                    }
                }
            }
            let got = img.pixel(x, y);
            let peak = want.iter().fold(0.0f32, |m, &c| m.max(c));
            for c in 0..3 {
                let err = (got[c] - want[c]).abs() / peak.max(1e-6);
                worst = worst.max(err);
                if err > tolerance {
                    failures.push(format!(
                        "pixel ({x},{y}) channel {c}: GPU {} vs CPU {}",
                        got[c], want[c]
                    ));
                }
            }
            checked += 1;
        }
        fail_with_image(name, &img, &failures);
        eprintln!(
            "{name}: {checked} pixels, worst {:.3}% of the pixel's brightest channel",
            worst * 100.0
        );
        assert!(checked > 2500, "only {checked} pixels checked");
    };
    check("sheen_over_lambertian", [0.5, 0.5, 0.5], None);
    check("sheen_alone", [0.0; 3], None);
    check("asg_sheen_alone", [0.0; 3], Some(test_lobes()));
    check("asg_sheen_over_lambertian", [0.5; 3], Some(test_lobes()));
}

/// The animated fixture (tests/data/animated) and its still twin, posed as clip "turn" poses
/// the animated one at 1 s.
fn animated_fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/animated")
        .join(name)
}

/// The settings of the animation tests: 160×120, shadow maps of 256² drawn by `raster`.
fn pose_settings(raster: ShadowRaster) -> RenderSettings {
    RenderSettings {
        width: 160,
        height: 120,
        shadow_resolution: 256,
        shadow_raster: raster,
        ..RenderSettings::default()
    }
}

/// The still file of an animated scene's pose, given the animated scene's bounds, camera
/// (fitted to the bounds where the file has none) and ground (its 4 vertices last: it lies
/// under the lowest pose of every clip there), rendered under `lights` as the reference of
/// that pose.
fn still_reference(animated: &Scene, still: Scene, lights: &[Light]) -> Image {
    let mut still = still;
    assert!(still.animation.is_none());
    still.bounds = animated.bounds;
    still.camera = animated.camera;
    let ground = still.vertices.len() - 4;
    assert_eq!(ground + 4, animated.vertices.len());
    still.vertices[ground..].copy_from_slice(&animated.vertices[ground..]);
    renderer(still, pose_settings(ShadowRaster::default()))
        .render(lights)
        .unwrap()
        .0
}

/// Poses `r` at `t` seconds and renders it; fails (the image written as `tag`) unless it is
/// `reference` to rounding: a mean relative difference of at most 10⁻⁴ and a 99.9th
/// percentile of at most 0.02. Returns the image.
fn assert_posed_like(
    r: &mut Renderer,
    t: f64,
    lights: &[Light],
    reference: &Image,
    tag: &str,
) -> Image {
    r.set_scene_time(t);
    let posed = r.render(lights).unwrap().0;
    let (mean, p999, _) = relative_differences(reference, &posed);
    eprintln!("{tag} at {t} s: mean {mean}, p999 {p999}");
    if mean > 1e-4 || p999 > 0.02 {
        fail_with_image(
            tag,
            &posed,
            &[format!(
                "{tag}: posed at {t} s, not the reference: mean {mean}, 99.9th percentile {p999}"
            )],
        );
    }
    posed
}

/// An animated glTF scene posed at a time renders as a still file of that pose does: the
/// vertices uploaded again, the shadow maps of the moved casters and the lights' visibility
/// follow the pose. The still file gets the animated scene's bounds (the shadow maps are
/// fitted to every pose of the clip, which a still file does not know), so the images agree
/// to rounding; at another time they do not.
#[test]
fn animated_scenes_render_as_the_still_pose_they_reach() {
    let lights = sky_lights(48);
    let animated = Scene::load(&animated_fixture("turning_boxes.gltf"), true).unwrap();
    let still = Scene::load(&animated_fixture("turned_boxes.gltf"), true).unwrap();
    let reference = still_reference(&animated, still, &lights);
    for raster in RASTERS {
        let mut r = renderer(animated.clone(), pose_settings(raster));
        let tag = format!("animated_{raster:?}");
        let posed = assert_posed_like(&mut r, 1.0, &lights, &reference, &tag);
        // At 0.2 s the base has turned 9°, not 45°: a different image. And the loop: 3 s is
        // 1 s again.
        r.set_scene_time(0.2);
        let early = r.render(&lights).unwrap().0;
        let (mean, _, _) = relative_differences(&reference, &early);
        eprintln!("{raster:?}: 0.2 s vs still: mean {mean}");
        assert!(
            mean > 0.01,
            "{raster:?}: at 0.2 s only {mean} from the 1 s pose"
        );
        r.set_scene_time(3.0);
        let looped = r.render(&lights).unwrap().0;
        assert_eq!(looped.rgba, posed.rgba, "{raster:?}: 3 s is not 1 s");
    }
}

/// Blended (see-through, double-sided) boxes turning: posed at 1 s they render as the still
/// file of that pose, and at 1.9 s as the scene posed before its renderer was made, blended
/// alike — their triangles sorted back to front again for each pose, not kept in the rest
/// pose's order.
#[test]
fn animated_blended_scenes_sort_their_triangles_for_each_pose() {
    let dir = tempfile::tempdir().unwrap();
    let see_through = |name: &str| {
        let text = std::fs::read_to_string(animated_fixture(name)).unwrap();
        let mut json: serde_json::Value = serde_json::from_str(&text).unwrap();
        for material in json["materials"].as_array_mut().unwrap() {
            material["alphaMode"] = "BLEND".into();
            material["doubleSided"] = true.into();
            material["pbrMetallicRoughness"]["baseColorFactor"][3] = 0.4.into();
        }
        let path = dir.path().join(name);
        std::fs::write(&path, json.to_string()).unwrap();
        path
    };
    let lights = sky_lights(48);
    let animated = Scene::load(&see_through("turning_boxes.gltf"), true).unwrap();
    let still = Scene::load(&see_through("turned_boxes.gltf"), true).unwrap();
    // Near the end of the clip (85° turned) the faces that were the sides at rest are the
    // front and back: the rest order draws them in the wrong order. The reference there is the
    // scene posed before the renderer was made (sorted for that pose when it was set up).
    let mut turned_far = animated.clone();
    turned_far.animate(1.9);
    let references = [
        (1.0, still_reference(&animated, still, &lights)),
        (
            1.9,
            renderer(turned_far, pose_settings(ShadowRaster::default()))
                .render(&lights)
                .unwrap()
                .0,
        ),
    ];
    let mut r = renderer(animated, pose_settings(ShadowRaster::default()));
    for (t, reference) in references {
        assert_posed_like(&mut r, t, &lights, &reference, "blended");
    }
}

/// A mesh that morph targets shape renders, at 1.5 s of its clip, as the still file of that
/// shape (tests/data/animated/make_morphed.py), with either shadow raster; its rest shape
/// (flat) is a different image.
#[test]
fn morphing_scenes_render_as_the_still_shape_they_reach() {
    let lights = sky_lights(48);
    let animated = Scene::load(&animated_fixture("morphing_tent.gltf"), true).unwrap();
    let still = Scene::load(&animated_fixture("morphed_tent.gltf"), true).unwrap();
    let reference = still_reference(&animated, still, &lights);
    for raster in RASTERS {
        let mut r = renderer(animated.clone(), pose_settings(raster));
        assert_posed_like(
            &mut r,
            1.5,
            &lights,
            &reference,
            &format!("morphed_{raster:?}"),
        );
        r.set_scene_time(0.0);
        let rest = r.render(&lights).unwrap().0;
        let (mean, _, _) = relative_differences(&reference, &rest);
        eprintln!("{raster:?}: rest vs still: mean {mean}");
        // (0.0095 here: the sheets cover a small part of the frame.)
        assert!(
            mean > 2e-3,
            "{raster:?}: the rest shape only {mean} from 1.5 s"
        );
    }
}

/// `envlight render --scene` plays the scene's animation on the frames' times: a frame at 1 s
/// is the frame at 0 s with `--animation-start 1`; `--animation none` holds the rest pose; an
/// unknown clip is refused naming those the file has.
#[test]
fn cli_plays_animations_on_the_frames_times() {
    let dir = tempfile::tempdir().unwrap();
    let frame = |seq: u64, time: f64| {
        serde_json::json!({"seq": seq, "time": time, "lights": sky_lights(8)}).to_string()
    };
    let two = dir.path().join("two.jsonl");
    std::fs::write(&two, format!("{}\n{}\n", frame(0, 0.0), frame(1, 1.0))).unwrap();
    let one = dir.path().join("one.jsonl");
    std::fs::write(&one, format!("{}\n", frame(0, 0.0))).unwrap();
    let render = |lights: &Path, out: &str, extra: &[&str]| {
        let out = dir.path().join(out);
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
            .args([
                "render",
                "--size",
                "64x48",
                "--shadow-res",
                "64",
                "--exposure",
                "1",
            ])
            .arg("--scene")
            .arg(animated_fixture("turning_boxes.gltf"))
            .arg("--lights")
            .arg(lights)
            .arg("--out")
            .arg(&out)
            .args(extra)
            .env_remove("XDG_RUNTIME_DIR")
            .output()
            .unwrap();
        (o, out)
    };
    let pixels = |path: PathBuf| image::open(path).unwrap().to_rgba8().into_raw();
    let (o, played) = render(&two, "played", &["--animation", "turn"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        stderr.contains("animation 0 (\"turn\"): 2.000 s"),
        "{stderr}"
    );
    let (o, started) = render(
        &one,
        "started",
        &["--animation", "0", "--animation-start", "1"],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let at_one = pixels(played.join("frame_00001.png"));
    assert_eq!(at_one, pixels(started.join("frame_00000.png")));
    assert_ne!(at_one, pixels(played.join("frame_00000.png")));
    let (o, rest) = render(&two, "rest", &["--animation", "none"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        pixels(rest.join("frame_00000.png")),
        pixels(rest.join("frame_00001.png"))
    );
    let (o, _) = render(&one, "unknown", &["--animation", "run"]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        stderr.contains("invalid --animation \"run\": the scene has no animation named \"run\": it has 0 \"turn\", 1 \"hop\""),
        "{stderr}"
    );
}
