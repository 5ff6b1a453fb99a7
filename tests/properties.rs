//! Property tests (proptest): the decomposition never panics or produces NaN on arbitrary small
//! maps — including NaN, ±Inf and negative pixels — and always conserves energy; the 2D warp
//! inverts itself on arbitrary weight images; the temporal filter keeps ids and energy on
//! arbitrary light sequences; an ASG lobe's GGX specular is finite and never exceeds a mirror's
//! for any lobe, surface and view.

use envlight::decompose::{
    frame_integral, DecomposeSettings, Decomposer, PiecewiseConstant2d, Warp,
};
use envlight::envmap::Projection;
use envlight::HdrFrame;
use proptest::prelude::*;

/// A pixel value: mostly ordinary radiance, sometimes 0, huge, NaN, ±Inf or negative.
fn channel() -> impl Strategy<Value = f32> {
    prop_oneof![
        6 => 0.0f32..10.0,
        2 => Just(0.0f32),
        1 => 1e3f32..1e6,
        1 => prop_oneof![
            Just(f32::NAN),
            Just(f32::INFINITY),
            Just(f32::NEG_INFINITY),
            -1e4f32..0.0
        ],
    ]
}

/// A small lat-long frame (W = 2H). With a 16-wide working map, frames at least 16 wide whose
/// sides are multiples of ⌊W/16⌋ take the box-filter path, the others (narrower ones cut into
/// sub-pixels) the index-table path.
fn frame() -> impl Strategy<Value = HdrFrame> {
    (2u32..24).prop_flat_map(|h| {
        let w = 2 * h;
        prop::collection::vec([channel(), channel(), channel()], (w * h) as usize).prop_map(
            move |pixels| HdrFrame::new(w, h, pixels, Projection::LatLong).expect("size matches"),
        )
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn decomposition_is_finite_and_conserves_energy(
        frame in frame(),
        n in 1usize..300,
        filter in any::<bool>(),
        merge in any::<bool>(),
        gamma in prop_oneof![Just(0.5f64), Just(0.75), Just(1.0), 0.1f64..1.0],
        working_width in prop_oneof![Just(16u32), Just(256)],
        hierarchical in any::<bool>(),
    ) {
        let mut sanitized = frame.clone();
        sanitized.sanitize();
        let truth = frame_integral(&sanitized);
        let settings = DecomposeSettings {
            lights: n,
            pdf_exponent: gamma,
            filter_taps: if filter { DecomposeSettings::default().filter_taps } else { None },
            merge_spacing_fraction: merge.then_some(0.25),
            working_width,
            warp: if hierarchical { Warp::Hierarchical } else { Warp::Rows },
            ..DecomposeSettings::default()
        };
        let mut decomposer = Decomposer::new(settings).expect("valid settings");
        // The unsanitised frame: the decomposition must cope with bad pixels on its own.
        let lights = decomposer.decompose(&frame);
        prop_assert!(lights.lights.len() <= n);
        if !merge {
            prop_assert_eq!(lights.lights.len(), n);
        }
        for l in &lights.lights {
            prop_assert!(l.dir.iter().chain(&l.rgb).all(|c| c.is_finite()), "{:?}", l);
            prop_assert!(l.rgb.iter().all(|&c| c >= 0.0) && l.solid_angle >= 0.0);
            let len = l.dir.iter().map(|c| c * c).sum::<f32>().sqrt();
            prop_assert!((len - 1.0).abs() < 1e-3, "direction not unit: {:?}", l.dir);
        }
        let sum = lights.total_rgb();
        for c in 0..3 {
            prop_assert!((sum[c] - truth[c]).abs() <= 1e-3 * truth[c] + 1e-9,
                "channel {}: lights {} vs map {}", c, sum[c], truth[c]);
        }
    }

    #[test]
    fn warp_inverts_itself(
        (w, h, weights) in (1usize..20, 1usize..12).prop_flat_map(|(w, h)| {
            (Just(w), Just(h), prop::collection::vec(prop_oneof![3 => 0.0f64..100.0, 1 => Just(0.0)], w * h))
        }),
        u in prop::array::uniform2(0.0f64..1.0),
    ) {
        let dist = PiecewiseConstant2d::new(&weights, w, h);
        let (p, pdf) = dist.sample(u);
        prop_assert!(p.iter().all(|c| (0.0..=1.0).contains(c)));
        prop_assert!(pdf.is_finite() && pdf >= 0.0);
        if pdf > 0.0 {
            let v = dist.invert(p);
            prop_assert!((u[0] - v[0]).abs() < 1e-9 && (u[1] - v[1]).abs() < 1e-9,
                "{:?} -> {:?} -> {:?}", u, p, v);
        }
    }
}

/// One frame's raw lights for the filter property: ids 0..n with some left out, each at one of
/// a few sun directions (0.2° apart) or elsewhere, with powers from 0 to huge; ids 0 and 1 are
/// always there and hold a sun (bright lights, whose pixels change hands, once the frame has
/// enough dim lights).
fn light_list() -> impl Strategy<Value = Vec<envlight::Light>> {
    prop::collection::vec(
        (
            any::<bool>(),
            0u32..6,
            prop_oneof![3 => 0.0f32..2.0, 1 => Just(0.0f32), 2 => 1e2f32..1e5],
        ),
        1..40,
    )
    .prop_map(|specs| {
        specs
            .into_iter()
            .enumerate()
            .filter(|(i, (present, _, _))| *present || *i < 2)
            .map(|(i, (_, place, power))| {
                let (place, power) = if i < 2 {
                    (place % 4, 1e6 + 10.0 * power)
                } else {
                    (place, power)
                };
                let a = if place < 4 {
                    f32::from(place as u8) * 0.2f32.to_radians()
                } else {
                    1.0 + i as f32 * 0.1
                };
                envlight::Light {
                    id: i as u32,
                    dir: [a.sin(), a.cos(), 0.0],
                    rgb: [power, 0.5 * power, 0.25 * power],
                    solid_angle: 1e-4,
                }
            })
            .collect()
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// The temporal filter, every `bright_history`, on arbitrary sequences (ids coming and
    /// going, suns' pixels changing hands): lights stay finite with unit directions and
    /// non-negative rgb, ids stay unique and in order, `blend` and `fold` keep exactly the
    /// input's ids, `fade` adds only ids from FADING_ID_BASE; and where the id set holds for a
    /// whole window, Σ rgb is the filtered Σ rgb.
    #[test]
    fn the_filter_keeps_ids_and_energy(
        frames in prop::collection::vec(light_list(), 1..16),
        taps in prop_oneof![
            Just(envlight::decompose::filter::DEFAULT_TAPS.to_vec()),
            prop::collection::vec(0.0f64..4.0, 1..6).prop_map(|mut t| { t[0] += 0.1; t }),
        ],
    ) {
        use envlight::decompose::filter::FADING_ID_BASE;
        use envlight::decompose::{BrightHistory, FirFilter};
        let total = |l: &[envlight::Light]| -> f64 { l.iter().map(|l| f64::from(l.rgb[0])).sum() };
        let ids = |l: &[envlight::Light]| -> Vec<u32> { l.iter().map(|l| l.id).collect() };
        let weights: f64 = taps.iter().sum();
        for bright in BrightHistory::ALL {
            let mut filter = FirFilter::new(&taps).unwrap().with_bright_history(bright);
            for (t, frame) in frames.iter().enumerate() {
                let mut lights = frame.clone();
                filter.apply(&mut lights);
                prop_assert!(lights.windows(2).all(|w| w[0].id < w[1].id), "{:?}", ids(&lights));
                for l in &lights {
                    let len = l.dir.iter().map(|c| c * c).sum::<f32>().sqrt();
                    prop_assert!((len - 1.0).abs() < 1e-4, "{bright:?}: {l:?}");
                    prop_assert!(l.rgb.iter().all(|c| c.is_finite() && *c >= 0.0), "{l:?}");
                }
                let (kept, extra): (Vec<&envlight::Light>, Vec<&envlight::Light>) =
                    lights.iter().partition(|l| l.id < FADING_ID_BASE);
                prop_assert_eq!(kept.iter().map(|l| l.id).collect::<Vec<_>>(), ids(frame));
                if bright != BrightHistory::Fade {
                    prop_assert!(extra.is_empty());
                }
                let window = taps.len();
                let steady = t + 1 >= window
                    && (0..window).all(|k| ids(&frames[t - k]) == ids(frame));
                if steady {
                    let want: f64 = (0..window)
                        .map(|k| taps[k] / weights * total(&frames[t - k]))
                        .sum();
                    let got = total(&lights);
                    prop_assert!(
                        (got - want).abs() <= 1e-5 * want.max(1.0),
                        "{bright:?} frame {t}: {got} against {want}"
                    );
                }
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// `Asg::ggx_specular` for lobes of any width (λ, μ from `MIN_BANDWIDTH` to
    /// `MAX_BANDWIDTH`) and any axis, surfaces from mirror to fully rough and views down to
    /// grazing: finite, non-negative and at most f0·c, what a mirror reflects of the lobe's peak
    /// (the bound the module doc derives; both product planes and the NDF mixture keep it).
    #[test]
    fn asg_specular_is_finite_and_bounded_by_a_mirror(
        axis in (0.0f64..1.0, 0.0f64..1.0),
        hint in (0.0f64..1.0, 0.0f64..1.0),
        normal in (0.0f64..1.0, 0.0f64..1.0),
        view in (0.0f64..1.0, 0.0f64..1.0),
        log_bandwidths in (0.0f64..1.0, 0.0f64..1.0),
        alpha in prop_oneof![Just(0.0f64), 0.0f64..1.0, Just(1.0f64)],
    ) {
        use envlight::asg::{Asg, MAX_BANDWIDTH, MIN_BANDWIDTH};
        // Uniform on the sphere: the equal-area octahedral map of the unit square.
        use envlight::wavelet::sphere::square_to_sphere as unit;
        let span = (MAX_BANDWIDTH / MIN_BANDWIDTH).ln();
        let lambda = MIN_BANDWIDTH * (span * log_bandwidths.0).exp();
        let mu = MIN_BANDWIDTH * (span * log_bandwidths.1).exp();
        let n = unit(normal.0, normal.1);
        let mut v = unit(view.0, view.1);
        if n.dot(v) < 0.0 {
            v = -v;
        }
        let lobe = Asg::new(unit(axis.0, axis.1), unit(hint.0, hint.1), lambda, mu, [1.0, 0.5, 2.0]);
        let Some(lobe) = lobe else { return Ok(()); };
        let s = lobe.ggx_specular(n, v, alpha, 0.9);
        for (c, peak) in s.iter().zip([1.0, 0.5, 2.0]) {
            prop_assert!(c.is_finite() && *c >= 0.0, "{s:?}");
            prop_assert!(*c <= 0.9 * peak * (1.0 + 1e-9), "{s:?} above the mirror's {}", 0.9 * peak);
        }
    }
}

/// A lens calibration of any model, field of view (from the narrowest accepted to almost
/// 360°), image circle (centre anywhere near the image, radius from a pixel to twice the
/// image) and rotation, or the angular map.
fn lens() -> impl Strategy<Value = Projection> {
    use envlight::envmap::{FisheyeCalibration, FisheyeModel, MIN_FOV_DEG};
    let model = prop_oneof![
        Just(FisheyeModel::Equidistant),
        Just(FisheyeModel::Equisolid),
        Just(FisheyeModel::Stereographic),
        Just(FisheyeModel::Orthographic),
    ];
    let fisheye = (
        model,
        prop_oneof![Just(180.0f64), MIN_FOV_DEG..359.9],
        prop::option::of((-0.25f64..1.25, -0.25f64..1.25)),
        prop::option::of(1.0f64..2.0),
        0.0f64..360.0,
    );
    prop_oneof![
        1 => Just(Projection::AngularMap),
        4 => fisheye.prop_map(|(model, fov_deg, center, radius, rotation_deg)| {
            Projection::Fisheye(FisheyeCalibration {
                model,
                // Relative to a 1 × 1 image; scaled to the frame's size below.
                center: center.map(|(x, y)| [x, y]),
                radius,
                fov_deg,
                rotation_deg,
            })
        }),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// Uniform frames through any lens on small images (pixels far larger than a working
    /// pixel, straddling many, cut across the image circle's edge; the resampling's table
    /// path): the lights are finite, their solid angles sum to the part of the sphere the frame
    /// sees (4π for the angular map, less for a fisheye) and their rgb to the frame's
    /// integral, and where the image sees the whole sphere (the angular map) no light is
    /// without power.
    #[test]
    fn lenses_on_small_frames_conserve_solid_angle_and_energy(
        projection in lens(),
        (w, h) in (1u32..40, 1u32..40),
        n in prop_oneof![Just(16usize), Just(256), 1usize..600],
    ) {
        use envlight::envmap::FisheyeCalibration;
        let projection = match projection {
            Projection::Fisheye(cal) => Projection::Fisheye(FisheyeCalibration {
                center: cal.center.map(|[x, y]| [x * f64::from(w), y * f64::from(h)]),
                radius: cal.radius.map(|r| r * f64::from(w.max(h))),
                ..cal
            }),
            other => other,
        };
        if let Projection::Fisheye(cal) = projection {
            if cal.validate(w, h).is_err() {
                return Ok(()); // refused with an error (the circle holds no pixel centre)
            }
        }
        let frame = HdrFrame::new(w, h, vec![[1.0, 0.5, 0.25]; (w * h) as usize], projection)
            .expect("size matches");
        let mut decomposer = Decomposer::new(DecomposeSettings {
            lights: n,
            filter_taps: None,
            ..DecomposeSettings::default()
        })
        .unwrap();
        let lights = decomposer.decompose(&frame).lights;
        let what = format!("{projection:?} {w}x{h}, {n} lights");
        for l in &lights {
            prop_assert!(
                l.rgb.iter().chain(&l.dir).all(|c| c.is_finite()) && l.solid_angle.is_finite(),
                "{what}: {l:?}"
            );
        }
        let truth = frame_integral(&frame);
        if truth[0] > 0.0 {
            let solid_angle: f64 = lights.iter().map(|l| f64::from(l.solid_angle)).sum();
            let seen: f64 = projection.solid_angles(w, h).iter().sum();
            prop_assert!((solid_angle - seen).abs() < 1e-4, "{what}: {solid_angle} of {seen}");
            for (c, want) in truth.iter().enumerate() {
                let sum: f64 = lights.iter().map(|l| f64::from(l.rgb[c])).sum();
                prop_assert!((sum - want).abs() <= 1e-4 * want, "{what}: {sum} against {want}");
            }
        }
        if projection == Projection::AngularMap {
            let dark = lights.iter().filter(|l| l.rgb[0] <= 0.0).count();
            prop_assert_eq!(dark, 0, "{}: lights without power", what);
        }
    }
}
