//! ASG lobes and fitting: closed forms against numerical integration, analytic gradients against
//! finite differences, fits on the real HDRIs in tests/data, temporal stability on the sky.

use envlight::asg::eval::{ggx_reference, LatLongMap};
use envlight::asg::fit::{
    centroid_step, fast_loss_gradient, initial_lobes, loss, loss_gradient, perturb, AsgFitter,
    FitSettings, FitTarget, Norm,
};
use envlight::asg::{
    integral, integral_approx, Asg, AsgError, GGX_OFF_NORMAL_TOLERANCE, GGX_TOLERANCE,
    IRRADIANCE_TOLERANCE, MIN_BANDWIDTH,
};
use envlight::capture::sky::{render_sky, SkyOptions, SkySource};
use envlight::capture::FrameSource;
use envlight::envmap::Projection;
use envlight::HdrFrame;
use glam::DVec3;
use std::path::Path;

fn read_hdr(name: &str) -> HdrFrame {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name);
    let image = image::open(&path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_rgb32f();
    let (w, h) = image.dimensions();
    let pixels = image.pixels().map(|p| p.0).collect();
    let mut frame = HdrFrame::new(w, h, pixels, Projection::LatLong).unwrap();
    frame.sanitize();
    frame
}

/// A lobe with its axis at +Y (the lat-long pole, where rows are densest).
fn polar_lobe(lambda: f64, mu: f64) -> Asg {
    Asg::new(
        DVec3::Y,
        DVec3::new(1.0, 0.0, 0.3),
        lambda,
        mu,
        [1.0, 0.5, 0.25],
    )
    .unwrap()
}

/// ∫ f over the sphere on a fine lat-long grid (exact pixel solid angles).
fn quadrature(width: u32, height: u32, f: impl Fn(DVec3) -> f64) -> f64 {
    let omegas = Projection::LatLong.solid_angles(width, height);
    let mut s = 0.0;
    for y in 0..height {
        for x in 0..width {
            let d = Projection::LatLong
                .pixel_to_direction(width, height, f64::from(x) + 0.5, f64::from(y) + 0.5)
                .unwrap();
            s += f(d) * omegas[(y * width + x) as usize];
        }
    }
    s
}

#[test]
fn closed_form_integral_matches_numerical_integration() {
    for &(l, m) in &[
        (0.25, 0.25),
        (1.0, 3.0),
        (10.0, 10.0),
        (40.0, 400.0),
        (2000.0, 5000.0),
    ] {
        let g = polar_lobe(l, m);
        let numeric = quadrature(512, 4096, |d| g.shape(d));
        let exact = integral(l, m);
        assert!(
            (exact - numeric).abs() <= 5e-4 * numeric,
            "λ={l} μ={m}: closed form {exact} vs numerical {numeric}"
        );
        // Xu et al.'s form: within its bound e^{−min(λ,μ)} (plus the quadrature's error).
        let xu = integral_approx(l, m);
        assert!((xu - numeric) / xu <= (-f64::min(l, m)).exp() + 1e-4);
        let rgb = g.integral();
        assert!((rgb[1] - 0.5 * exact).abs() < 1e-12);
    }
}

#[test]
fn lambert_approximation_matches_numerical_integration() {
    let normals = envlight::asg::fit::fibonacci_sphere(40);
    let mut worst: f64 = 0.0;
    for &(l, m) in &[
        (0.25, 0.25),
        (1.0, 1.0),
        (4.0, 4.0),
        (2.0, 16.0),
        (30.0, 30.0),
        (500.0, 500.0),
        (100.0, 800.0),
    ] {
        let g = polar_lobe(l, m);
        let total = integral(l, m);
        for &n in &normals {
            let reference = quadrature(256, 1024, |d| g.shape(d) * n.dot(d).max(0.0));
            let approx = g.irradiance(n)[0];
            let err = (approx - reference).abs() / total;
            worst = worst.max(err);
            assert!(
                err <= IRRADIANCE_TOLERANCE,
                "λ={l} μ={m} n={n}: {approx} vs {reference} (∫G = {total})"
            );
        }
    }
    eprintln!("worst Lambert error / ∫G: {worst:.4}");
}

#[test]
fn ggx_approximation_matches_numerical_integration() {
    let mut worst: f64 = 0.0;
    for &alpha in &[0.1, 0.3, 0.6, 1.0] {
        for &(l, m) in &[(2.0, 2.0), (10.0, 40.0), (100.0, 100.0)] {
            for &tilt in &[0.0f64, 0.1, 0.25] {
                // Lobe near the reflection direction (n = v = +Z, r = +Z), tilted about X.
                let axis = DVec3::new(0.0, tilt.sin(), tilt.cos());
                let g = Asg::new(axis, DVec3::X, l, m, [1.0; 3]).unwrap();
                let map = LatLongMap::from_fn(1024, 512, |d| g.eval(d));
                let reference = ggx_reference(&map, DVec3::Z, DVec3::Z, alpha)[0];
                let approx = g.ggx_specular(DVec3::Z, DVec3::Z, alpha, 1.0)[0];
                // Relative to the lobe's on-axis response, so tails far off r are not judged
                // by a vanishing denominator.
                let head_map = LatLongMap::from_fn(1024, 512, |d| {
                    Asg::new(DVec3::Z, DVec3::X, l, m, [1.0; 3])
                        .unwrap()
                        .eval(d)
                });
                let head = ggx_reference(&head_map, DVec3::Z, DVec3::Z, alpha)[0];
                let err = (approx - reference).abs() / head;
                worst = worst.max(err);
                assert!(
                    err <= GGX_TOLERANCE,
                    "α={alpha} λ={l} μ={m} tilt={tilt}: {approx} vs {reference} (on-axis {head})"
                );
            }
        }
    }
    eprintln!("worst GGX error / on-axis response: {worst:.4}");
}

/// Views away from the normal: the GGX lobe warps into an anisotropic lobe that narrows across
/// the plane of incidence as n·v falls (module doc of `envlight::asg`). Same lobes and α as at
/// normal incidence, lobes on the mirror direction and tilted off it, n·v down to 0.25.
#[test]
fn ggx_approximation_holds_off_normal_incidence() {
    let mut worst: f64 = 0.0;
    let n = DVec3::Y;
    for &alpha in &[0.1, 0.3, 0.6, 1.0] {
        for &n_v in &[0.8f64, 0.5, 0.25] {
            let view = DVec3::new((1.0 - n_v * n_v).sqrt(), n_v, 0.0);
            let r = 2.0 * n_v * n - view;
            for &(l, m) in &[(2.0, 2.0), (10.0, 40.0), (100.0, 100.0)] {
                for &tilt in &[0.0f64, 0.2] {
                    // Tilted across the plane of incidence, where the warped lobe is narrow.
                    let axis = (r + DVec3::Z * tilt).normalize();
                    let g = Asg::new(axis, DVec3::Z, l, m, [1.0; 3]).unwrap();
                    let map = LatLongMap::from_fn(1024, 512, |d| g.eval(d));
                    let reference = ggx_reference(&map, n, view, alpha)[0];
                    let approx = g.ggx_specular(n, view, alpha, 1.0)[0];
                    let on_axis = Asg::new(r, DVec3::Z, l, m, [1.0; 3]).unwrap();
                    let head_map = LatLongMap::from_fn(1024, 512, |d| on_axis.eval(d));
                    let head = ggx_reference(&head_map, n, view, alpha)[0];
                    let err = (approx - reference).abs() / head;
                    worst = worst.max(err);
                    assert!(
                        err <= GGX_OFF_NORMAL_TOLERANCE,
                        "α={alpha} n·v={n_v} λ={l} μ={m} tilt={tilt}: {approx} vs {reference} \
                         (on-axis {head})"
                    );
                }
            }
        }
    }
    eprintln!("worst off-normal GGX error / on-axis response: {worst:.4}");
}

/// A smooth environment made of wide, overlapping lobes (as a fit to a sky or an overcast frame
/// gives): each lobe is also seen from far off its axis, where its tangent-plane product with
/// the GGX lobe must follow the lobe's own fall-off (the GGX lobe is foreshortened there). The
/// sum over the lobes matches the exact reflection of their sum, at every normal and view tried,
/// within 15 %. Measured (2026-12-04, the NDF as two Gaussians and the product also taken in the
/// mirror direction's plane): worst 1.3 % for α = 0.05, 3.3 % for α = 0.12, 11.8 % for α = 0.3
/// (at n·v = 0.4, too little). With one Gaussian and the lobe's plane only, the day before:
/// 5.5 %, 10 % and 20 % (a lobe 90° from the mirror direction reflected nothing, a wide lobe on
/// it a third too much); the isotropic GGX lobe of Xu et al.'s formula, used before that,
/// reflected up to 2.5 times the exact value here.
#[test]
fn ggx_specular_of_an_environment_of_wide_lobes() {
    const WIDE_LOBES_TOLERANCE: f64 = 0.15;
    let axes = [
        DVec3::X,
        -DVec3::X,
        DVec3::Y,
        -DVec3::Y,
        DVec3::Z,
        -DVec3::Z,
        DVec3::new(1.0, 1.0, 1.0),
        DVec3::new(-1.0, 1.0, -1.0),
    ];
    let lobes: Vec<Asg> = axes
        .iter()
        .zip([0.5, 0.8, 1.0, 0.6, 0.7, 0.9, 3.0, 2.0])
        .map(|(&axis, lambda)| Asg::new(axis, DVec3::Z, lambda, 1.2, [0.6; 3]).unwrap())
        .collect();
    let map = LatLongMap::from_fn(1024, 512, |d| {
        [lobes.iter().map(|g| g.eval(d)[0]).sum::<f64>(); 3]
    });
    let mut worst: f64 = 0.0;
    for n in [DVec3::Y, DVec3::Z, DVec3::new(0.3, 0.8, 0.5).normalize()] {
        let t = n.any_orthonormal_vector();
        for &alpha in &[0.05, 0.12, 0.3] {
            for &n_v in &[1.0f64, 0.7, 0.4] {
                let view = n * n_v + t * (1.0 - n_v * n_v).sqrt();
                let approx: f64 = lobes
                    .iter()
                    .map(|g| g.ggx_specular(n, view, alpha, 1.0)[0])
                    .sum();
                let reference = ggx_reference(&map, n, view, alpha)[0];
                let err = (approx - reference).abs() / reference;
                worst = worst.max(err);
                assert!(
                    err <= WIDE_LOBES_TOLERANCE,
                    "n={n} α={alpha} n·v={n_v}: {approx} vs {reference}"
                );
            }
        }
    }
    eprintln!("worst error of the lobes' sum: {worst:.4}");
}

/// A surface reflects at most what a mirror would: under a lobe of peak radiance c the specular
/// radiance is at most f0·c, at every view down to grazing, for sharp and wide lobes and
/// rough and smooth surfaces (the isotropic lobe used before reflected up to 7.5 times that).
#[test]
fn ggx_specular_never_reflects_more_than_a_mirror() {
    let n = DVec3::Y;
    let mut worst: f64 = 0.0;
    for &alpha in &[0.002, 0.05, 0.3, 1.0] {
        for &n_v in &[1.0f64, 0.5, 0.1, 0.03, 0.01] {
            let view = DVec3::new((1.0 - n_v * n_v).sqrt(), n_v, 0.0);
            let r = 2.0 * n_v * n - view;
            for &(l, m) in &[
                (MIN_BANDWIDTH, MIN_BANDWIDTH),
                (0.5, 3.0),
                (50.0, 5.0),
                (1e4, 1e4),
            ] {
                for axis in [r, n, (r + n).normalize(), DVec3::new(0.3, 0.2, 0.9)] {
                    let g = Asg::new(axis, DVec3::Z, l, m, [1.0; 3]).unwrap();
                    let s = g.ggx_specular(n, view, alpha, 1.0)[0];
                    worst = worst.max(s);
                    assert!(
                        (0.0..=1.0 + 1e-9).contains(&s),
                        "α={alpha} n·v={n_v} λ={l} μ={m} axis={axis}: {s}"
                    );
                }
            }
        }
    }
    eprintln!("largest specular response to a unit lobe: {worst:.4}");
}

fn small_target(name: &str, height: u32) -> FitTarget {
    FitTarget::from_frame(&read_hdr(name), height, 64).unwrap()
}

fn check_gradients(norm: Norm, rel_tol: f64) {
    let target = small_target("rooitou_park_1k.hdr", 16);
    let settings = FitSettings {
        norm,
        diffuse_weight: 0.7,
        temporal_weight: 0.3,
        ..FitSettings::default()
    };
    let lobes: Vec<Asg> = initial_lobes(&target, 4)
        .into_iter()
        .map(|a| Asg {
            mu: a.mu * 1.7 + 0.3,
            rgb: a.rgb.map(|c| c * 1.1),
            ..a
        })
        .collect();
    // A previous frame that differs, so the temporal norm is away from its kink at 0.
    let prev: Vec<Asg> = lobes
        .iter()
        .map(|a| perturb(a, [0.02, -0.01, 0.015, 0.1, -0.1, 0.05, 0.1, -0.05]))
        .collect();
    let (_, grad) = loss_gradient(&target, &lobes, Some(&prev), &settings);
    let h = 1e-5;
    let mut max_abs: f64 = 0.0;
    let mut max_err: f64 = 0.0;
    for (k, lobe) in lobes.iter().enumerate() {
        for p in 0..8 {
            let mut d = [0.0; 8];
            d[p] = h;
            let mut plus = lobes.clone();
            plus[k] = perturb(lobe, d);
            d[p] = -h;
            let mut minus = lobes.clone();
            minus[k] = perturb(lobe, d);
            let fd = (loss(&target, &plus, Some(&prev), &settings).total
                - loss(&target, &minus, Some(&prev), &settings).total)
                / (2.0 * h);
            max_abs = max_abs.max(fd.abs());
            max_err = max_err.max((fd - grad[k][p]).abs());
        }
    }
    assert!(max_abs > 0.0);
    assert!(
        max_err <= rel_tol * max_abs,
        "{norm:?}: max |analytic − finite difference| = {max_err:e}, max |gradient| = {max_abs:e}"
    );
}

#[test]
fn gradients_agree_with_finite_differences_l2() {
    check_gradients(Norm::L2, 1e-4);
}

#[test]
fn gradients_agree_with_finite_differences_l1() {
    // L1 has kinks where a pixel's residual changes sign; a few pixels may cross within ±h.
    check_gradients(Norm::L1, 2e-2);
}

#[test]
fn fast_kernel_matches_the_exact_loss_and_gradient() {
    // The f32 tiled kernel the optimiser uses against the exact f64 sums, on a real map with
    // narrow (culled) and wide lobes, both norms. The seeded lobes are scaled off the data:
    // a seed lobe reproduces its seed pixel exactly, and at a residual of 0 the L1 gradient's
    // sign is a matter of rounding (f32 and f64 may take either side of the kink).
    let target = small_target("rooitou_park_1k.hdr", 48);
    let mut lobes: Vec<Asg> = initial_lobes(&target, 12)
        .into_iter()
        .map(|a| Asg {
            rgb: a.rgb.map(|c| c * 1.1),
            ..a
        })
        .collect();
    lobes.push(
        Asg::new(
            DVec3::new(0.2, 0.3, -0.9),
            DVec3::X,
            0.4,
            3.0,
            [0.2, 0.3, 0.5],
        )
        .unwrap(),
    );
    lobes.push(Asg::new(DVec3::new(-0.5, 0.8, 0.1), DVec3::Y, 900.0, 40.0, [5.0; 3]).unwrap());
    for norm in [Norm::L1, Norm::L2] {
        let settings = FitSettings {
            norm,
            ..FitSettings::default()
        };
        let (exact, ge) = loss_gradient(&target, &lobes, None, &settings);
        let (fast, gf) = fast_loss_gradient(&target, &lobes, &settings);
        let rel = (fast.total - exact.total).abs() / exact.total;
        assert!(
            rel < 1e-5,
            "{norm:?}: loss {} vs {}",
            fast.total,
            exact.total
        );
        let max = ge.iter().flatten().fold(0.0f64, |m, g| m.max(g.abs()));
        let err = ge
            .iter()
            .flatten()
            .zip(gf.iter().flatten())
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(
            err <= 1e-3 * max,
            "{norm:?}: max |fast − exact| gradient {err:e} of max {max:e}"
        );
    }
}

#[test]
fn tile_subsets_partition_the_map() {
    // The optimiser's stratified subsets (fast module doc, step 5): every tile is in exactly one
    // subset of a stride, so the subsets' estimates (each scaled by the stride) average to the
    // whole map's loss and gradient sums, and no subset alone is the whole map.
    use envlight::asg::fast::{reconstruction, KLobe, Subset};
    let target = small_target("rooitou_park_1k.hdr", 48);
    let lobes: Vec<KLobe> = initial_lobes(&target, 10)
        .iter()
        .map(|a| KLobe {
            x: DVec3::from(a.tangent),
            y: DVec3::from(a.bitangent),
            z: DVec3::from(a.axis),
            lambda: a.lambda,
            mu: a.mu,
            c: a.rgb.map(|c| c / target.mean),
        })
        .collect();
    let px = target.tiled();
    let (whole, ws) = reconstruction(px, &lobes, Norm::L1, 1, true, Subset::ALL);
    for stride in [2, 3, 4] {
        let mut loss = 0.0;
        let mut lambda = vec![0.0; lobes.len()];
        for phase in 0..stride {
            let (l, s) = reconstruction(px, &lobes, Norm::L1, 2, true, Subset::new(stride, phase));
            assert!(
                (l - whole).abs() > 1e-6 * whole,
                "stride {stride}, phase {phase}: the subset saw the whole map"
            );
            loss += l / stride as f64;
            for (a, b) in lambda.iter_mut().zip(&s) {
                *a += b.lambda / stride as f64;
            }
        }
        assert!(
            (loss - whole).abs() <= 1e-9 * whole,
            "stride {stride}: mean of subsets {loss} vs whole {whole}"
        );
        let max = ws.iter().fold(0.0f64, |m, s| m.max(s.lambda.abs()));
        for (a, b) in lambda.iter().zip(&ws) {
            assert!(
                (a - b.lambda).abs() <= 1e-9 * max,
                "stride {stride}: ∂λ {a} vs {}",
                b.lambda
            );
        }
    }
}

#[test]
fn target_directions_are_the_latlong_pixel_centres() {
    // The target computes its directions row by row; they must be the projection's own.
    let target = small_target("venice_sunset_1k.hdr", 24);
    for y in 0..target.height {
        for x in 0..target.width {
            let d = Projection::LatLong
                .pixel_to_direction(
                    target.width,
                    target.height,
                    f64::from(x) + 0.5,
                    f64::from(y) + 0.5,
                )
                .unwrap();
            assert_eq!(target.directions[(y * target.width + x) as usize], d);
        }
    }
}

#[test]
fn centroid_step_puts_a_narrow_lobe_back_on_its_light() {
    // A sun-like lobe over a wide sky lobe; the fitted sun lobe is 1.2° off (about 1.1 of its
    // standard deviations): the warm start's centroid step puts it back, the sky lobe stays.
    let (w, h) = (256u32, 128u32);
    let sun = Asg::new(
        DVec3::new(0.3, 0.5, -0.8).normalize(),
        DVec3::Y,
        1500.0,
        1500.0,
        [50.0; 3],
    )
    .unwrap();
    let sky = Asg::new(DVec3::Y, DVec3::X, 1.0, 1.0, [0.5; 3]).unwrap();
    let mut radiance = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let d = Projection::LatLong
                .pixel_to_direction(w, h, f64::from(x) + 0.5, f64::from(y) + 0.5)
                .unwrap();
            radiance.push([0, 1, 2].map(|c| sun.rgb[c] * sun.shape(d) + sky.rgb[c] * sky.shape(d)));
        }
    }
    let target = FitTarget::from_latlong(w, h, radiance, 64).unwrap();
    let axis = DVec3::from(sun.axis);
    let turn = axis.cross(DVec3::Y).normalize() * 1.2f64.to_radians();
    let off = perturb(&sun, [turn.x, turn.y, turn.z, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let before = DVec3::from(off.axis).angle_between(axis).to_degrees();
    let out = centroid_step(&target, &[off, sky]);
    let after = DVec3::from(out[0].axis).angle_between(axis).to_degrees();
    eprintln!("sun lobe off by {before:.3}° before the centroid step, {after:.3}° after");
    assert!(
        before > 1.1 && after < 0.1 * before,
        "{before}° -> {after}°"
    );
    assert_eq!(out[1], sky, "the wide lobe moved");
    let frame = DVec3::from(out[0].tangent).dot(DVec3::from(out[0].axis));
    assert!(frame.abs() < 1e-9, "frame no longer orthogonal: {frame}");
}

#[test]
fn half_resolution_target_keeps_the_energy() {
    let target = small_target("venice_sunset_1k.hdr", 32);
    let half = target.half().unwrap();
    assert_eq!((half.width, half.height), (32, 16));
    let energy = |t: &FitTarget| {
        t.radiance
            .iter()
            .zip(&t.weights)
            .map(|(p, w)| w * (p[0] + p[1] + p[2]))
            .sum::<f64>()
    };
    let (a, b) = (energy(&target), energy(&half));
    assert!((a - b).abs() <= 1e-12 * a, "{a} vs {b}");
    let smallest = half.half().unwrap().half().unwrap().half().unwrap();
    assert_eq!(smallest.height, 2);
    assert!(smallest.half().is_none());
}

#[test]
fn warm_refit_with_temporal_loss_follows_the_map() {
    // Issue 6: with L_T as a subgradient and the best total loss returned, a warm refit gave
    // back the previous lobes unchanged. With the proximal step the lobes follow the sun.
    let options = SkyOptions {
        width: 128,
        height: 64,
        sun_speed_deg_per_s: 60.0,
        clouds: false,
        ..SkyOptions::default()
    };
    let settings = FitSettings {
        height: 32,
        iterations: 400,
        warm_iterations: 20,
        threads: 1,
        ..FitSettings::default()
    };
    assert!(settings.temporal_weight > 0.0);
    let mut fitter = AsgFitter::new(settings.clone()).unwrap();
    let t0 = FitTarget::from_frame(&render_sky(&options, 0.0), 32, 256).unwrap();
    let t1 = FitTarget::from_frame(&render_sky(&options, 0.1), 32, 256).unwrap();
    let first = fitter.fit_target(&t0).lobes;
    let refit = fitter.fit_target(&t1);
    assert!(refit.warm);
    assert_ne!(refit.lobes, first, "the refit returned the previous lobes");
    let plain = FitSettings {
        temporal_weight: 0.0,
        ..settings
    };
    let before = loss(&t1, &first, None, &plain).total;
    let after = loss(&t1, &refit.lobes, None, &plain).total;
    eprintln!("frame 1: previous lobes {before:.5}, warm refit {after:.5}");
    assert!(after < before, "refit {after} vs previous lobes {before}");
}

/// Two fitters through the same first frame, then the same warm refit, one asking for the
/// refit's loss.
fn refit_with_and_without_loss(
    settings: FitSettings,
) -> (FitTarget, [envlight::asg::fit::FitResult; 2]) {
    let options = SkyOptions::default();
    let t0 = FitTarget::from_frame(&render_sky(&options, 0.0), 32, 128).unwrap();
    let t1 = FitTarget::from_frame(&render_sky(&options, 0.1), 32, 128).unwrap();
    let refit = |warm_loss| {
        let mut fitter = AsgFitter::new(FitSettings {
            warm_loss,
            ..settings.clone()
        })
        .unwrap();
        let first = fitter.fit_target(&t0);
        assert!(
            !first.warm && first.loss.is_some(),
            "first frame: {first:?}"
        );
        fitter.fit_target(&t1)
    };
    (t1.clone(), [refit(false), refit(true)])
}

#[test]
fn warm_refit_reports_its_loss_only_when_asked() {
    // The default warm refit (L_T on, subsets of the tiles) returns its last iterate: without
    // `warm_loss` the whole-map evaluation is skipped, the lobes are the same bits.
    let settings = settings_small();
    let (t1, [quiet, asked]) = refit_with_and_without_loss(settings.clone());
    assert!(quiet.warm && asked.warm);
    assert_eq!(quiet.loss, None);
    assert_eq!(quiet.lobes, asked.lobes);
    assert_eq!(quiet.initial_loss, asked.initial_loss);
    // The reported loss is the returned lobes' whole-map L_R + w_D·L_D (fast kernel against
    // the exact sums; L_T is measured from the centroid-moved start, not checked here).
    let l = asked.loss.expect("warm_loss asks for the refit's loss");
    let exact = loss(&t1, &asked.lobes, None, &settings);
    for (what, a, b) in [
        ("L_R", l.reconstruction, exact.reconstruction),
        ("L_D", l.diffuse, exact.diffuse),
    ] {
        assert!(
            (a - b).abs() <= 1e-4 * b.abs(),
            "{what}: reported {a}, exact {b}"
        );
    }
    assert!(l.temporal > 0.0 && l.total > l.reconstruction + l.diffuse);
}

#[test]
fn warm_refit_without_temporal_loss_keeps_its_best_iterate() {
    // Whole-map iterations without L_T return the best iterate, which needs the last loss:
    // it is evaluated (and reported) whether asked or not, and both choose the same lobes.
    let settings = FitSettings {
        temporal_weight: 0.0,
        warm_subset: 1,
        ..settings_small()
    };
    let (t1, [quiet, asked]) = refit_with_and_without_loss(settings.clone());
    assert_eq!(quiet.lobes, asked.lobes);
    let l = quiet
        .loss
        .expect("the best-iterate choice evaluates the loss");
    assert_eq!(Some(l), asked.loss);
    let exact = loss(&t1, &quiet.lobes, None, &settings).total;
    assert!(
        (l.total - exact).abs() <= 1e-4 * exact,
        "{l:?} vs exact {exact}"
    );
    // With subsets and no L_T only the last iterate has a whole-map loss: it is returned and
    // the evaluation skipped unless asked.
    let (_, [quiet, asked]) = refit_with_and_without_loss(FitSettings {
        warm_subset: 4,
        ..settings
    });
    assert_eq!(quiet.loss, None);
    assert!(asked.loss.is_some());
    assert_eq!(quiet.lobes, asked.lobes);
}

fn settings_small() -> FitSettings {
    FitSettings {
        lobes: 8,
        height: 32,
        iterations: 150,
        warm_iterations: 20,
        diffuse_normals: 128,
        threads: 2,
        ..FitSettings::default()
    }
}

#[test]
fn fits_on_real_hdris_lower_the_loss_and_keep_energy() {
    for name in [
        "rooitou_park_1k.hdr",
        "studio_small_03_1k.hdr",
        "venice_sunset_1k.hdr",
    ] {
        let frame = read_hdr(name);
        // The default K = 16 on a 64×32 map, 1,200 iterations on the default subsets of 1/4
        // of the tiles (the cost of 300 whole-map ones).
        let settings = FitSettings {
            lobes: 16,
            iterations: 1200,
            ..settings_small()
        };
        let mut fitter = AsgFitter::new(settings).unwrap();
        let target = FitTarget::from_frame(&frame, 32, 128).unwrap();
        let result = fitter.fit_target(&target);
        assert_eq!(result.lobes.len(), 16);
        let fitted = result.loss.expect("a first frame reports its loss");
        assert!(
            fitted.total < 0.8 * result.initial_loss.total,
            "{name}: loss {fitted:?} from {:?}",
            result.initial_loss
        );
        let mut e = [0.0; 3];
        for l in &result.lobes {
            let i = l.integral();
            for c in 0..3 {
                e[c] += i[c];
            }
        }
        let err = envlight::asg::eval::energy_error(e, target.integral);
        assert!(err < 0.02, "{name}: energy error {err}");
        eprintln!(
            "{name}: loss {:.4} -> {:.4}, energy error {err:.4}",
            result.initial_loss.total, fitted.total
        );
    }
}

#[test]
fn fit_is_deterministic_across_thread_counts() {
    let target = small_target("noon_grass_1k.hdr", 16);
    let mut s = settings_small();
    s.iterations = 30;
    s.threads = 1;
    let a = AsgFitter::new(s.clone()).unwrap().fit_target(&target);
    s.threads = 2;
    let b = AsgFitter::new(s).unwrap().fit_target(&target);
    assert_eq!(a, b);
}

/// Asserts that two targets are equal field by field, bit for bit, tiles included (through
/// the fast kernel's sums, which read every tiled value).
fn assert_same_target(a: &FitTarget, b: &FitTarget, what: &str) {
    use envlight::asg::fast::{reconstruction, KLobe, Subset};
    assert_eq!((a.width, a.height), (b.width, b.height), "{what}: size");
    assert!(a.directions == b.directions, "{what}: directions");
    assert!(a.radiance == b.radiance, "{what}: radiance");
    assert!(a.weights == b.weights, "{what}: weights");
    assert!(a.normals == b.normals, "{what}: normals");
    assert!(a.diffuse == b.diffuse, "{what}: diffuse ground truth");
    assert_eq!(a.mean.to_bits(), b.mean.to_bits(), "{what}: mean");
    assert_eq!(a.integral, b.integral, "{what}: integral");
    let lobes: Vec<KLobe> = initial_lobes(b, 6)
        .iter()
        .map(|l| KLobe {
            x: DVec3::from(l.tangent),
            y: DVec3::from(l.bitangent),
            z: DVec3::from(l.axis),
            lambda: l.lambda,
            mu: l.mu,
            c: l.rgb.map(|c| c / b.mean),
        })
        .collect();
    let (la, sa) = reconstruction(a.tiled(), &lobes, Norm::L1, 1, true, Subset::ALL);
    let (lb, sb) = reconstruction(b.tiled(), &lobes, Norm::L1, 1, true, Subset::ALL);
    assert_eq!(la.to_bits(), lb.to_bits(), "{what}: tiled loss");
    assert_eq!(sa, sb, "{what}: tiled gradient sums");
}

#[test]
fn refilled_target_equals_a_fresh_one() {
    // The fitter reuses its target from frame to frame (target module doc, step 4): a refill
    // must give what a target made from scratch gives, for the exact box filter (the 512x256
    // sky to 256 rows, one pixel each; the 1k HDRIs to 256 and 64 rows) and the general
    // resampling (to 48 rows).
    let sky = SkyOptions::default();
    let (roo, studio) = (
        read_hdr("rooitou_park_1k.hdr"),
        read_hdr("studio_small_03_1k.hdr"),
    );
    for height in [256, 64, 48] {
        let mut target = FitTarget::from_frame(&render_sky(&sky, 0.0), height, 96).unwrap();
        let _ = target.tiled();
        for (name, frame) in [
            ("rooitou", &roo),
            ("sky at 0.5 s", &render_sky(&sky, 0.5)),
            ("studio", &studio),
        ] {
            target.refill(frame).unwrap();
            let fresh = FitTarget::from_frame(frame, height, 96).unwrap();
            assert_same_target(&target, &fresh, &format!("{name} at {height} rows"));
        }
        // A bad frame is refused and leaves the target as it was.
        let bad = HdrFrame {
            width: 4,
            height: 2,
            pixels: vec![[0.0; 3]; 3],
            projection: Projection::LatLong,
            time: 0.0,
            seq: 0,
        };
        assert!(matches!(
            target.refill(&bad),
            Err(AsgError::PixelCount { .. })
        ));
        let fresh = FitTarget::from_frame(&studio, height, 96).unwrap();
        assert_same_target(&target, &fresh, "after a refused frame");
    }
}

#[test]
fn fitter_reusing_its_target_fits_like_fresh_targets() {
    // `AsgFitter::fit_frame` refills one target; fitting fresh targets gives the same bits.
    let s = FitSettings {
        warm_iterations: 8,
        threads: 1,
        ..settings_small()
    };
    let (mut reusing, mut fresh) = (
        AsgFitter::new(s.clone()).unwrap(),
        AsgFitter::new(s.clone()).unwrap(),
    );
    let roo = read_hdr("rooitou_park_1k.hdr");
    let sky = SkyOptions::default();
    let frames = [render_sky(&sky, 0.0), render_sky(&sky, 0.1), roo];
    for (i, frame) in frames.iter().enumerate() {
        let a = reusing.fit_frame(frame).unwrap();
        let target = FitTarget::from_frame(frame, s.height, s.diffuse_normals).unwrap();
        let b = fresh.fit_target(&target);
        assert_eq!(a, b, "frame {i}");
    }
    assert!(reusing.target().is_some());
}

/// Mean per-frame parameter change Σ_i ‖Δg_i‖ over a sky sequence (axis change in radians plus
/// relative amplitude change).
fn sky_parameter_change(temporal_weight: f64) -> f64 {
    let options = SkyOptions {
        width: 64,
        height: 32,
        sun_speed_deg_per_s: 15.0,
        frames: Some(8),
        ..SkyOptions::default()
    };
    let mut source = SkySource::new(options).unwrap();
    let mut fitter = AsgFitter::new(FitSettings {
        temporal_weight,
        ..settings_small()
    })
    .unwrap();
    let mut prev: Option<Vec<Asg>> = None;
    let mut total = 0.0;
    let mut steps = 0;
    while let Some(frame) = source.next_frame().unwrap() {
        let lobes = fitter.fit_frame(&frame).unwrap().lobes;
        if let Some(p) = &prev {
            for (a, b) in lobes.iter().zip(p) {
                let angle = DVec3::from(a.axis).angle_between(DVec3::from(b.axis));
                let ca = a.rgb.iter().sum::<f64>();
                let cb = b.rgb.iter().sum::<f64>();
                total += angle + (ca - cb).abs() / cb.max(1e-12);
            }
            steps += 1;
        }
        prev = Some(lobes);
    }
    total / steps as f64
}

#[test]
fn temporal_loss_reduces_parameter_change_on_the_sky() {
    let without = sky_parameter_change(0.0);
    let with = sky_parameter_change(FitSettings::default().temporal_weight);
    eprintln!("per-frame parameter change: without L_T {without:.4}, with {with:.4}");
    assert!(with < without, "with L_T {with} vs without {without}");
}

#[test]
fn bad_inputs_give_errors_not_panics() {
    for k in [0, 65] {
        let r = AsgFitter::new(FitSettings {
            lobes: k,
            ..FitSettings::default()
        });
        assert_eq!(r.unwrap_err(), AsgError::LobeCount(k));
    }
    let e = AsgFitter::new(FitSettings {
        learning_rate: f64::NAN,
        ..FitSettings::default()
    })
    .unwrap_err();
    assert!(e.to_string().contains("learning_rate"), "{e}");
    let bad = HdrFrame {
        width: 4,
        height: 2,
        pixels: vec![[0.0; 3]; 3],
        projection: Projection::LatLong,
        time: 0.0,
        seq: 0,
    };
    let mut fitter = AsgFitter::new(settings_small()).unwrap();
    assert!(matches!(
        fitter.fit_frame(&bad),
        Err(AsgError::PixelCount { .. })
    ));
    // Black, NaN-filled and single-pixel frames fit to finite (dark) lobes.
    for pixels in [vec![[0.0f32; 3]; 8], vec![[f32::NAN; 3]; 8]] {
        let frame = HdrFrame::new(4, 2, pixels, Projection::LatLong).unwrap();
        let r = fitter.fit_frame(&frame).unwrap();
        assert!(r
            .lobes
            .iter()
            .all(|l| l.rgb.iter().all(|c| c.is_finite() && *c < 1e-6)));
        assert!(r.loss.is_some_and(|l| l.total.is_finite()));
        // A black frame left nothing to warm-start from: the next one is fitted afresh.
        let r = fitter.fit_frame(&frame).unwrap();
        assert!(!r.warm && r.lobes.iter().all(|l| l.rgb.iter().all(|c| c.is_finite())));
    }
    let tiny = HdrFrame::new(1, 1, vec![[5.0, 1.0, 0.0]], Projection::LatLong).unwrap();
    let r = AsgFitter::new(settings_small())
        .unwrap()
        .fit_frame(&tiny)
        .unwrap();
    let l = r.loss.expect("a first frame reports its loss");
    assert!(l.total.is_finite() && l.total < r.initial_loss.total.max(1e-9) + 1e-9);
}

#[test]
fn fit_asg_command_prints_one_json_line_per_frame() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
        .args([
            "fit-asg",
            "--frames",
            "2",
            "--height",
            "8",
            "--iterations",
            "20",
            "--lobes",
            "4",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    let lines: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 2);
    for (i, v) in lines.iter().enumerate() {
        assert_eq!(v["seq"], i as u64);
        assert!(v["time"].is_number() && v["loss"].as_f64().unwrap().is_finite());
        let lobes = v["lobes"].as_array().unwrap();
        assert_eq!(lobes.len(), 4);
        for l in lobes {
            let axis: Vec<f64> = l["axis"]
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect();
            let n = axis.iter().map(|x| x * x).sum::<f64>().sqrt();
            assert!((n - 1.0).abs() < 1e-9);
            for key in ["tangent", "bitangent", "rgb"] {
                assert_eq!(l[key].as_array().unwrap().len(), 3, "{key}");
            }
            assert!(l["lambda"].as_f64().unwrap() > 0.0 && l["mu"].as_f64().unwrap() > 0.0);
        }
    }
    let bad = std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
        .args(["fit-asg", "--lobes", "65"])
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("lobe count 65"));
}

/// rooitou_park and a small, quick fit of it (4 lobes, 16 rows, 200 iterations, one thread).
fn small_rooitou_fit() -> (HdrFrame, FitSettings) {
    let settings = FitSettings {
        lobes: 4,
        height: 16,
        iterations: 200,
        threads: 1,
        ..FitSettings::default()
    };
    (read_hdr("rooitou_park_1k.hdr"), settings)
}

/// `frame` with every pixel times `scale`.
fn scaled(frame: &HdrFrame, scale: f32) -> HdrFrame {
    let mut scaled = frame.clone();
    scaled
        .pixels
        .iter_mut()
        .for_each(|p| *p = p.map(|c| c * scale));
    scaled
}

/// The fit does not depend on the map's scale: a map and the same map times 2^50 (about 1e15)
/// or 2^−100 (about 8e−31) or 2^−130 (about 7e−40, f32 subnormals) give the same loss, and
/// lobes scaled by the same factor. The amplitude bounds were absolute: at 1e15 every lobe
/// stuck at e^25 (loss 2, worse than black), at 1e−30 at e^−60; and the seeds' floor was
/// absolute (1e−36), so a map of 1e−45 was seeded at 29,000 times its energy (an audit).
#[test]
fn the_fit_does_not_depend_on_the_maps_scale() {
    let (frame, settings) = small_rooitou_fit();
    let fit = |scale: f32| {
        let mut fitter = AsgFitter::new(settings.clone()).unwrap();
        fitter.fit_frame(&scaled(&frame, scale)).unwrap()
    };
    let unit = fit(1.0);
    let unit_loss = unit.loss.unwrap().total;
    for exponent in [50, -100, -130] {
        let scale = 2f32.powi(exponent);
        let scaled = fit(scale);
        let loss = scaled.loss.unwrap().total;
        assert!(
            (loss - unit_loss).abs() <= 1e-3 * unit_loss,
            "scale 2^{exponent}: loss {loss} vs {unit_loss}"
        );
        for (a, b) in unit.lobes.iter().zip(&scaled.lobes) {
            let ratio = b.rgb[1] / (a.rgb[1] * f64::from(scale));
            assert!(
                (ratio - 1.0).abs() < 1e-2,
                "scale 2^{exponent}: {a:?} vs {b:?}"
            );
        }
    }
}

/// A warm chain recovers from a frame that gives it nothing to follow: after an all-black
/// frame (lobes of zero amplitude), across a jump of the map's scale by 2^±30 (an exposure
/// change) and up a ramp of 3× steps, the next fit's loss and integral match a fit of that
/// frame from scratch. The warm
/// refit started from the zero lobes, whose log-amplitudes sat at the bound and never climbed
/// back: every later frame came out black (loss 2) in `fit-asg` and the daemon's ASG stream.
#[test]
fn a_warm_chain_recovers_from_a_black_frame_and_a_scale_jump() {
    let (frame, settings) = small_rooitou_fit();
    let scaled = |scale: f32| scaled(&frame, scale);
    let green = |r: &envlight::asg::fit::FitResult| -> f64 {
        r.lobes.iter().map(|l| l.integral()[1]).sum()
    };
    // The scales of the frames before the last (after a first frame at 1), and the last.
    let chains: [(&[f32], f32); 4] = [
        (&[0.0], 1.0),
        (&[1.0], 2f32.powi(30)),
        (&[1.0], 2f32.powi(-30)),
        // A ramp whose steps are each below the old 4× trigger (compared map to map).
        (&[3.0, 9.0, 27.0], 81.0),
    ];
    for (between, after) in chains {
        let before = between[between.len() - 1];
        let mut fitter = AsgFitter::new(settings.clone()).unwrap();
        fitter.fit_frame(&frame).unwrap();
        for &scale in between {
            fitter.fit_frame(&scaled(scale)).unwrap();
        }
        let warm = fitter.fit_frame(&scaled(after)).unwrap();
        let mut cold_fitter = AsgFitter::new(settings.clone()).unwrap();
        let cold = cold_fitter.fit_frame(&scaled(after)).unwrap();
        // The map term alone (no temporal term) of each fit, on the same target.
        let map_loss =
            |lobes: &[Asg]| loss(cold_fitter.target().unwrap(), lobes, None, &settings).total;
        let (warm_loss, cold_loss) = (map_loss(&warm.lobes), map_loss(&cold.lobes));
        assert!(
            warm_loss <= 1.5 * cold_loss,
            "{before} then {after}: loss {warm_loss} after the change, {cold_loss} from scratch"
        );
        let ratio = green(&warm) / green(&cold);
        assert!(
            (ratio - 1.0).abs() < 0.05,
            "{before} then {after}: integral {} vs {} from scratch",
            green(&warm),
            green(&cold)
        );
    }
}

/// A frame whose size is no multiple of the fit map keeps its integral in the fit target,
/// wherever a one-pixel sun lies, and so does a refill of it (the target's resampling took at
/// most 8 × 8 point samples per fit pixel: in a 2000 × 1000 map a sun was missed or counted up
/// to 3.8 times over, by where it lay; found by an audit).
#[test]
fn the_fit_target_of_an_inexact_size_keeps_a_one_pixel_sun() {
    let (w, h) = (2000u32, 1000u32);
    let omegas = Projection::LatLong.solid_angles(w, h);
    let sky_integral: f64 = omegas.iter().sum();
    let mut reused: Option<FitTarget> = None;
    for (sx, sy) in [
        (700u32, 301u32),
        (701, 300),
        (702, 301),
        (1999, 0),
        (0, 999),
    ] {
        let mut pixels = vec![[1.0f32; 3]; (w * h) as usize];
        let sun = (sy * w + sx) as usize;
        pixels[sun] = [1e6, 5e5, 2e5];
        let expected: [f64; 3] =
            std::array::from_fn(|c| sky_integral + (f64::from(pixels[sun][c]) - 1.0) * omegas[sun]);
        let frame = HdrFrame::new(w, h, pixels, Projection::LatLong).unwrap();
        let fresh = FitTarget::from_frame(&frame, 64, 64).unwrap();
        let target = match reused.as_mut() {
            Some(t) => {
                t.refill(&frame).unwrap();
                &*t
            }
            None => reused.insert(fresh.clone()),
        };
        for t in [&fresh, target] {
            for (c, (got, want)) in t.integral.iter().zip(expected).enumerate() {
                let e = (got - want).abs() / want;
                assert!(e < 1e-6, "sun at ({sx}, {sy}), channel {c}: {e}");
            }
        }
        assert_eq!(fresh.radiance, target.radiance);
    }
}

/// A uniform lat-long frame of a size that is no multiple of the map stays uniform in the fit
/// target, upsampled or downsampled (each source pixel whole to the fit pixel of its centre
/// striped it: 0.62 to 1.64 for 300 × 150 at 128 × 64; an audit), and keeps its integral.
#[test]
fn the_fit_target_of_a_uniform_frame_of_any_size_is_uniform() {
    for (w, h) in [
        (300u32, 150u32),
        (1000, 500),
        (17, 9),
        (1, 1),
        (2, 1),
        (130, 65),
        // Wider than a row of sums per source column is kept for (columns first), and fewer
        // source rows than fit rows.
        (70_000, 70),
        (100_000, 1),
    ] {
        let frame = HdrFrame::new(
            w,
            h,
            vec![[1.0, 0.5, 2.0]; (w * h) as usize],
            Projection::LatLong,
        )
        .unwrap();
        let target = FitTarget::from_frame(&frame, 64, 16).unwrap();
        for p in &target.radiance {
            for (got, want) in p.iter().zip([1.0, 0.5, 2.0]) {
                assert!((got - want).abs() < 1e-9, "{w}x{h}: {p:?}");
            }
        }
        let sphere = 4.0 * std::f64::consts::PI;
        assert!(
            (target.integral[0] - sphere).abs() < 1e-9 * sphere,
            "{w}x{h}"
        );
    }
}

/// A fisheye or angular frame: a uniform frame stays uniform in the fit target wherever the
/// frame sees (binning each source pixel whole to the fit pixel of its centre made a uniform
/// 1001 × 1001 angular frame range 0 to 54.5 at height 256, and the fit grew needle lobes on
/// the stripes; an audit), and a one-pixel sun keeps its energy within 5 % (measured: 0.980 to
/// 1.007 at these places, the worst within a few rows of a pole).
#[test]
fn the_fit_target_of_a_fisheye_or_angular_frame_is_uniform_and_keeps_a_sun() {
    use envlight::envmap::FisheyeCalibration;
    for (projection, side, height) in [
        (Projection::AngularMap, 1001u32, 64u32),
        (Projection::AngularMap, 1001, 256),
        (Projection::AngularMap, 257, 64),
        (Projection::Fisheye(FisheyeCalibration::default()), 1001, 64),
        (
            Projection::Fisheye(FisheyeCalibration::default()),
            1001,
            256,
        ),
    ] {
        let what = format!("{} {side}x{side} at height {height}", projection.name());
        let frame = HdrFrame::new(
            side,
            side,
            vec![[1.0, 0.5, 2.0]; (side * side) as usize],
            projection,
        )
        .unwrap();
        let target = FitTarget::from_frame(&frame, height, 16).unwrap();
        let mut seen = 0;
        for (p, d) in target.radiance.iter().zip(&target.directions) {
            if *p == [0.0; 3] {
                // Only a fisheye's lower hemisphere is unseen.
                assert!(
                    matches!(projection, Projection::Fisheye(_)) && d.y < 0.0,
                    "{what}: a fit pixel at {d} is 0"
                );
                continue;
            }
            seen += 1;
            for (got, want) in p.iter().zip([1.0, 0.5, 2.0]) {
                assert!((got - want).abs() < 1e-6, "{what}: {p:?} at {d}");
            }
        }
        assert!(
            seen >= target.radiance.len() / 2,
            "{what}: {seen} pixels seen"
        );
        // A one-pixel sun at a few places: the target's integral against the frame's.
        let omegas = projection.solid_angles(side, side);
        for (sx, sy) in [
            (side / 2, side / 2),
            (side / 3, side / 5),
            (side / 2 + 7, side / 4),
        ] {
            let sun = (sy * side + sx) as usize;
            if omegas[sun] == 0.0 {
                continue;
            }
            let mut pixels = vec![[0.0f32; 3]; (side * side) as usize];
            pixels[sun] = [1e6; 3];
            let frame = HdrFrame::new(side, side, pixels, projection).unwrap();
            let target = FitTarget::from_frame(&frame, height, 16).unwrap();
            let ratio = target.integral[0] / (1e6 * omegas[sun]);
            assert!(
                (ratio - 1.0).abs() < 0.05,
                "{what}: sun at ({sx}, {sy}) kept {ratio} of its energy"
            );
        }
    }
}
