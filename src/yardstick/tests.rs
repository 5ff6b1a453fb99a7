use super::*;
use crate::light::LightFrame;

fn latlong(width: u32, height: u32, f: impl Fn(u32, u32) -> [f32; 3]) -> HdrFrame {
    let pixels = (0..height)
        .flat_map(|y| (0..width).map(move |x| (x, y)))
        .map(|(x, y)| f(x, y))
        .collect();
    HdrFrame::new(width, height, pixels, Projection::LatLong).unwrap()
}

/// Σ rgb·Ω at full resolution.
fn integral(frame: &HdrFrame) -> [f64; 3] {
    let omega = Projection::LatLong.solid_angles(frame.width, frame.height);
    let mut sum = [0.0; 3];
    for (p, om) in frame.pixels.iter().zip(omega) {
        add_scaled(&mut sum, p.map(f64::from), om);
    }
    sum
}

fn assert_total(lights: &LightFrame, expected: [f64; 3], tol: f64) {
    let total = lights.total_rgb();
    for c in 0..3 {
        let rel = (total[c] - expected[c]).abs() / expected[c].abs().max(1e-300);
        assert!(rel < tol, "channel {c}: {} vs {}", total[c], expected[c]);
    }
}

/// A smooth sky-like map with a small bright spot.
fn synthetic() -> HdrFrame {
    latlong(256, 128, |x, y| {
        let v = 1.0 + (x as f32 * 0.05).sin() * 0.5 + y as f32 / 128.0;
        if (100..103).contains(&x) && (30..32).contains(&y) {
            [500.0, 400.0, 300.0]
        } else {
            [v, 0.8 * v, 0.6 * v + 0.1]
        }
    })
}

fn angle_deg(a: [f32; 3], b: DVec3) -> f64 {
    let a = DVec3::from_array(a.map(f64::from)).normalize();
    a.dot(b.normalize()).clamp(-1.0, 1.0).acos().to_degrees()
}

#[test]
fn evaluation_points_are_as_documented() {
    let dirs = evaluation_directions();
    assert_eq!(dirs.len(), 1024);
    assert!(dirs.iter().all(|d| (d.length() - 1.0).abs() < 1e-12));
    let mean = dirs.iter().copied().sum::<DVec3>() / dirs.len() as f64;
    assert!(mean.length() < 1e-2, "Fibonacci sphere is balanced");
    let points = ground_points();
    assert!(points.len() >= 400);
    assert!(points
        .iter()
        .all(|p| p.y == 0.0 && p.length() >= 0.05 - 1e-12));
    assert!(points.iter().any(|p| (p.length() - 3.0).abs() < 1e-9));
}

#[test]
fn constant_map_irradiance_is_pi() {
    let frame = latlong(512, 256, |_, _| [1.0; 3]);
    let map = ReferenceMap::new(&frame, 256).unwrap();
    assert_eq!((map.width(), map.height(), map.factor()), (256, 128, 2));
    let total: f64 = map.solid_angles().iter().sum();
    assert!((total - 4.0 * PI).abs() < 1e-9);
    let truth = map.truth();
    for e in &truth.diffuse {
        for c in e {
            assert!((c - PI).abs() < 1e-3, "E = {c}");
        }
    }
    // The normalised Phong lobes integrate to 1 over the hemisphere.
    for g in truth.glossy16.iter().chain(&truth.glossy128) {
        assert!((g[1] - 1.0).abs() < 2e-2, "G = {}", g[1]);
    }
}

#[test]
fn downsampling_preserves_energy_for_odd_sizes() {
    let frame = latlong(101, 51, |x, y| [x as f32, y as f32, 1.0]);
    let map = ReferenceMap::new(&frame, 32).unwrap();
    assert_eq!(map.factor(), 4);
    assert_eq!((map.width(), map.height()), (26, 13));
    let (a, b) = (map.integral(), integral(&frame));
    for c in 0..3 {
        assert!((a[c] - b[c]).abs() <= 1e-12 * b[c]);
    }
}

#[test]
fn single_bright_pixel_light_has_no_error() {
    let (bx, by) = (21, 9);
    let frame = latlong(64, 32, |x, y| {
        if (x, y) == (bx, by) {
            [1000.0, 800.0, 600.0]
        } else {
            [0.0; 3]
        }
    });
    let map = ReferenceMap::new(&frame, 64).unwrap();
    assert_eq!(map.factor(), 1);
    let d = Projection::LatLong
        .pixel_to_direction(64, 32, f64::from(bx) + 0.5, f64::from(by) + 0.5)
        .unwrap();
    let omega = Projection::LatLong.solid_angles(64, 32)[(by * 64) as usize];
    let light = Light {
        id: 0,
        dir: d.as_vec3().to_array(),
        rgb: [1000.0, 800.0, 600.0].map(|c: f64| (c * omega) as f32),
        solid_angle: omega as f32,
    };
    let report = evaluate(&map, &[light]);
    assert!(report.diffuse < 1e-3, "{report:?}");
    assert!(
        report.glossy16 < 1e-3 && report.glossy128 < 1e-3,
        "{report:?}"
    );
    assert!(
        report.ground_shadow < 1e-3 && report.energy < 1e-6,
        "{report:?}"
    );
    assert_eq!(report.diffuse, diffuse_irradiance_error(&map, &[light]));
    assert_eq!(report.glossy128, glossy_error(&map, &[light], 128));
    assert_eq!(report.ground_shadow, ground_shadow_error(&map, &[light]));
    // A light pointing elsewhere is a large error; no lights is an error of exactly 1.
    let wrong = Light {
        dir: [-d.x as f32, d.y as f32, -d.z as f32],
        ..light
    };
    assert!(diffuse_irradiance_error(&map, &[wrong]) > 0.5);
    let none = evaluate(&map, &[]);
    assert_eq!((none.diffuse, none.energy), (1.0, 1.0));
    // An exponent without cached truth computes its own.
    assert!(glossy_error(&map, &[light], 4) < 1e-3);
}

#[test]
fn ground_shadow_truth_under_constant_map() {
    let frame = latlong(512, 256, |_, _| [1.0; 3]);
    let map = ReferenceMap::new(&frame, 256).unwrap();
    let truth = map.truth();
    let points = ground_points();
    for (p, e) in points.iter().zip(&truth.ground) {
        let r = p.length();
        // The sphere seen from p is a cap of half-angle asin(1/√(1+r²)) around an axis at
        // elevation of the same angle; its cosine-weighted solid angle is π(1+r²)^(-3/2).
        let expected = PI * (1.0 - (1.0 + r * r).powf(-1.5));
        if (r - 3.0).abs() < 1e-9 {
            assert!(
                (e[1] - expected).abs() < 1e-2 * PI,
                "r=3: {} vs {expected}",
                e[1]
            );
            assert!(e[1] > 0.95 * PI && e[1] < PI);
        }
        if r < 0.06 {
            assert!(e[1] < 0.05 * PI, "next to the contact point: {}", e[1]);
        }
        assert!(
            (e[1] - expected).abs() < 0.03 * PI,
            "r={r}: {} vs {expected}",
            e[1]
        );
    }
}

#[test]
fn black_map_has_zero_truth_and_finite_errors() {
    let frame = latlong(32, 16, |_, _| [0.0; 3]);
    let map = ReferenceMap::new(&frame, 32).unwrap();
    let report = evaluate(&map, &[]);
    assert_eq!(
        report,
        QualityReport {
            diffuse: 0.0,
            glossy16: 0.0,
            glossy128: 0.0,
            ground_shadow: 0.0,
            energy: 0.0
        }
    );
}

#[test]
fn rejects_bad_frames() {
    let mut frame = latlong(8, 4, |_, _| [1.0; 3]);
    frame.projection = Projection::AngularMap;
    assert_eq!(
        ReferenceMap::new(&frame, 8).unwrap_err(),
        YardstickError::NotLatLong("angular")
    );
    assert!(median_cut(&frame, 4).is_err());
    let mut frame = latlong(8, 4, |_, _| [1.0; 3]);
    frame.pixels.pop();
    assert!(matches!(
        ReferenceMap::new(&frame, 8),
        Err(YardstickError::PixelCount { .. })
    ));
    assert!(median_cut(&frame, 4).is_err());
    let frame = latlong(8, 4, |_, _| [1.0; 3]);
    assert_eq!(median_cut(&frame, 0).unwrap_err(), YardstickError::NoLights);
}

#[test]
fn median_cut_sums_to_integral() {
    let frame = synthetic();
    let expected = integral(&frame);
    for n in [1, 7, 64, 100, 256] {
        let lights = median_cut(&frame, n).unwrap();
        if n == 256 {
            // Rounds split the 3×2 bright spot down to single pixels, which stop splitting.
            assert!((250..=256).contains(&lights.lights.len()));
        } else {
            assert_eq!(lights.lights.len(), n);
        }
        assert_total(&lights, expected, 1e-6);
        let omega: f64 = lights.lights.iter().map(|l| f64::from(l.solid_angle)).sum();
        assert!((omega - 4.0 * PI).abs() < 1e-5, "regions tile the sphere");
        for (i, l) in lights.lights.iter().enumerate() {
            assert_eq!(l.id as usize, i);
            let len = DVec3::from_array(l.dir.map(f64::from)).length();
            assert!((len - 1.0).abs() < 1e-5);
        }
        let map = ReferenceMap::new(&frame, 128).unwrap();
        assert!(energy_error(&map, &lights.lights) < 1e-6);
    }
}

#[test]
fn median_cut_one_light_and_odd_counts() {
    let frame = synthetic();
    let one = median_cut(&frame, 1).unwrap();
    assert_eq!(one.lights.len(), 1);
    assert_total(&one, integral(&frame), 1e-6);
    for n in [3, 5, 6, 37, 255] {
        assert_eq!(median_cut(&frame, n).unwrap().lights.len(), n);
    }
}

#[test]
fn median_cut_finds_a_bright_pixel() {
    let (bx, by) = (77, 23);
    let (w, h) = (128, 64);
    let frame = latlong(w, h, |x, y| {
        if (x, y) == (bx, by) {
            [1e4; 3]
        } else {
            [0.1, 0.2, 0.3]
        }
    });
    let d = Projection::LatLong
        .pixel_to_direction(w, h, f64::from(bx) + 0.5, f64::from(by) + 0.5)
        .unwrap();
    let pixel_deg = (PI / f64::from(h)).to_degrees();
    for n in [16, 64, 10] {
        let lights = median_cut(&frame, n).unwrap();
        let brightest = lights
            .lights
            .iter()
            .max_by(|a, b| a.luminance().total_cmp(&b.luminance()))
            .unwrap();
        let angle = angle_deg(brightest.dir, d);
        assert!(angle < pixel_deg, "n={n}: {angle}° off");
    }
}

#[test]
fn median_cut_black_map_gives_finite_zero_lights() {
    let frame = latlong(64, 32, |_, _| [0.0; 3]);
    for n in [1, 16, 13] {
        let lights = median_cut(&frame, n).unwrap();
        assert_eq!(lights.lights.len(), n);
        for l in &lights.lights {
            assert_eq!(l.rgb, [0.0; 3]);
            assert!(l.dir.iter().all(|c| c.is_finite()));
            assert!(l.solid_angle.is_finite() && l.solid_angle > 0.0);
        }
    }
    // Bad values count as black.
    let frame = latlong(8, 4, |x, _| {
        if x == 0 {
            [f32::NAN, -1.0, f32::INFINITY]
        } else {
            [0.0; 3]
        }
    });
    let lights = median_cut(&frame, 4).unwrap();
    assert!(lights
        .lights
        .iter()
        .all(|l| l.rgb == [0.0; 3] && l.dir.iter().all(|c| c.is_finite())));
}

#[test]
fn median_cut_stops_at_single_pixels() {
    let frame = latlong(2, 1, |x, _| [x as f32 + 1.0; 3]);
    assert_eq!(median_cut(&frame, 8).unwrap().lights.len(), 2);
    assert_eq!(median_cut(&frame, 7).unwrap().lights.len(), 2);
}

#[test]
fn median_cut_splits_the_energy_evenly() {
    // A constant map: with power-of-two n every region holds about the same energy.
    let frame = latlong(256, 128, |_, _| [1.0; 3]);
    let lights = median_cut(&frame, 16).unwrap();
    let mean = 4.0 * PI / 16.0;
    for l in &lights.lights {
        let e = f64::from(l.rgb[0]);
        assert!((e - mean).abs() < 0.05 * mean, "{e} vs {mean}");
    }
}

#[test]
fn coarse_reference_agrees_with_full_resolution_on_a_low_sun() {
    // Sky plus a 2×2-pixel sun 8° above the horizon: the coarse reference keeps the sun's block
    // at full resolution, so its yardsticks match the full-resolution ones.
    let (w, h) = (512, 256);
    let frame = latlong(w, h, |x, y| {
        if (300..302).contains(&x) && (116..118).contains(&y) {
            [2e5, 1.8e5, 1.5e5]
        } else if y < h / 2 {
            [0.3, 0.5, 1.0]
        } else {
            [0.1, 0.1, 0.05]
        }
    });
    let coarse = ReferenceMap::new(&frame, 64).unwrap();
    let full = ReferenceMap::new(&frame, w).unwrap();
    assert_eq!((coarse.factor(), full.factor()), (8, 1));
    assert!(coarse.refined_blocks() >= 1 && full.refined_blocks() == 0);
    let total: f64 = coarse.solid_angles().iter().sum();
    assert!((total - 4.0 * PI).abs() < 1e-9);
    for n in [16, 64] {
        let lights = median_cut(&frame, n).unwrap();
        let (a, b) = (
            evaluate(&coarse, &lights.lights),
            evaluate(&full, &lights.lights),
        );
        for (x, y) in [
            (a.diffuse, b.diffuse),
            (a.glossy16, b.glossy16),
            (a.ground_shadow, b.ground_shadow),
        ] {
            assert!((x - y).abs() < 0.1 * y + 1e-3, "n={n}: {a:?} vs {b:?}");
        }
    }
}

#[test]
fn areal_reference_splits_only_the_bright_pixels_and_keeps_their_energy() {
    let frame = synthetic();
    let plain = ReferenceMap::new(&frame, 64).unwrap();
    assert_eq!(plain.factor(), 4);
    assert!(plain.refined_blocks() >= 1, "the spot's blocks are kept");
    let areal = ReferenceMap::with_areal_bright_pixels(&frame, 64, 4).unwrap();
    let fine_pixels = plain.refined_blocks() * 16;
    assert_eq!(
        areal.directions().len(),
        plain.directions().len() + fine_pixels * 15,
        "each full-resolution pixel of a bright block becomes 4 × 4 samples, nothing else"
    );
    let (a, p) = (areal.integral(), plain.integral());
    for c in 0..3 {
        assert!(
            (a[c] - p[c]).abs() < 1e-12 * p[c],
            "channel {c}: {a:?} vs {p:?}"
        );
    }
    let total: f64 = areal.solid_angles().iter().sum();
    assert!(
        (total - 4.0 * PI).abs() < 1e-9,
        "solid angles sum to {total}"
    );
    for d in areal.directions() {
        assert!((d.length() - 1.0).abs() < 1e-12);
    }
}

#[test]
fn areal_reference_gives_a_sun_pixel_a_penumbra() {
    // One bright pixel (5.6° wide) and nothing else. As a point it lights each ground point
    // fully or not at all; as an area, ground points near the sphere's shadow edge see part of
    // it.
    let frame = latlong(64, 32, |x, y| {
        if (x, y) == (20, 10) {
            [1e4, 1e4, 1e4]
        } else {
            [0.0; 3]
        }
    });
    let sun_height = Projection::LatLong
        .pixel_to_direction(64, 32, 20.5, 10.5)
        .unwrap()
        .y;
    let full = lum([1e4; 3]) * Projection::LatLong.solid_angles(64, 32)[10 * 64] * sun_height;
    let shares = |reference: &ReferenceMap| -> Vec<f64> {
        reference
            .truth()
            .ground
            .iter()
            .map(|&g| lum(g) / full)
            .collect()
    };
    let plain = shares(&ReferenceMap::new(&frame, 16).unwrap());
    assert!(plain
        .iter()
        .all(|&s| s.abs() < 1e-9 || (s - 1.0).abs() < 1e-9));
    let areal = shares(&ReferenceMap::with_areal_bright_pixels(&frame, 16, 8).unwrap());
    let partial = areal.iter().filter(|&&s| s > 0.05 && s < 0.95).count();
    assert!(partial >= 3, "{partial} ground points in the penumbra");
    for (a, p) in areal.iter().zip(&plain) {
        assert!(a.abs() < 1.1 && (a - p).abs() < 1.1, "{a} against {p}");
    }
    let (lit_a, lit_p): (f64, f64) = (areal.iter().sum(), plain.iter().sum());
    assert!(
        (lit_a - lit_p).abs() < 0.1 * lit_p,
        "{lit_a} against {lit_p}"
    );
}

#[test]
fn low_passed_keeps_a_constant_and_delays_a_step() {
    let step: Vec<Vec<[f64; 3]>> = (0..6)
        .map(|t| vec![if t < 2 { [1.0; 3] } else { [3.0, 5.0, 7.0] }])
        .collect();
    let out = low_passed(&step, &[1.0, 2.0, 1.0]);
    let red: Vec<f64> = out.iter().map(|v| v[0][0]).collect();
    assert_eq!(red, [1.0, 1.0, 1.5, 2.5, 3.0, 3.0]);
    assert_eq!(out[3][0], [2.5, 4.0, 5.5]);
    let constant = vec![vec![[2.0, 4.0, 8.0]; 3]; 4];
    assert_eq!(
        low_passed(&constant, &[1.0, 6.0, 15.0, 20.0, 15.0, 6.0, 1.0]),
        constant
    );
    assert_eq!(low_passed(&step, &[0.0, 0.0]), step);
    assert_eq!(low_passed(&step, &[f64::NAN]), step);
}
