//! Integration tests of the camera path without a camera: bracket merging and response
//! recovery on synthetic exposures of the shared HDRIs, image-circle detection on synthetic
//! fisheye frames rendered from them, the device-loss wrapper with a fake source, the
//! `[camera]` config, and a real-device test that runs only where /dev/video* exists.

mod test_data;

use envlight::capture::bracket::{
    merge_brackets, recover_response, Bracket, MergeLimits, SolveSettings,
};
use envlight::capture::image_file::read_hdr_image;
use envlight::capture::pixel_format::{CodeImage, YuvMatrix};
use envlight::capture::resilient::{ResilientSource, RetryPolicy};
use envlight::capture::response::{Radiometry, ResponseCurve, ResponseModel};
use envlight::capture::{CaptureError, FrameSource};
use envlight::config::{RawConfig, SourceKind};
use envlight::envmap::fisheye_detect::{detect_image_circle, render_fisheye};
use envlight::envmap::{FisheyeCalibration, FisheyeModel, Projection};
use envlight::frame::HdrFrame;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use test_data::{data, HDRIS};

/// Small deterministic normal noise (xorshift64* + Box–Muller).
struct Noise(u64);

impl Noise {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        ((self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let (u, v) = (self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// A shared HDRI box-filtered down by `factor` (a small radiance map with its real range).
fn small_hdri(name: &str, factor: u32) -> (u32, u32, Vec<[f32; 3]>) {
    let img = read_hdr_image(&data(name)).unwrap_or_else(|e| panic!("{e}"));
    let (w, h) = (img.width / factor, img.height / factor);
    let mut out = vec![[0.0f32; 3]; (w * h) as usize];
    for y in 0..h {
        for x in 0..w {
            let mut s = [0.0f64; 3];
            for j in 0..factor {
                for i in 0..factor {
                    let p = img.pixels[((y * factor + j) * img.width + x * factor + i) as usize];
                    for c in 0..3 {
                        s[c] += f64::from(p[c]);
                    }
                }
            }
            out[(y * w + x) as usize] = s.map(|v| (v / f64::from(factor * factor)) as f32);
        }
    }
    (w, h, out)
}

fn srgb_encode(x: f64) -> f64 {
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// An 8-bit exposure of radiance `e` for `t` seconds through `encode` (relative exposure → code),
/// with 1% multiplicative (shot-like) and 0.03% of full scale additive (read) noise, clipped at
/// full scale.
const READ_NOISE: f64 = 3e-4;

fn expose(
    e: &[[f32; 3]],
    w: u32,
    h: u32,
    t: f64,
    encode: &dyn Fn(f64) -> f64,
    noise: &mut Noise,
) -> CodeImage {
    let pixels = e
        .iter()
        .map(|p| {
            p.map(|v| {
                let x =
                    f64::from(v) * t * (1.0 + 0.01 * noise.normal()) + READ_NOISE * noise.normal();
                ((encode(x.clamp(0.0, 1.0)) * 255.0).round() / 255.0) as f32
            })
        })
        .collect();
    CodeImage {
        width: w,
        height: h,
        pixels,
    }
}

fn quantile(mut v: Vec<f64>, q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// Exposure times 2 stops apart from just below the brightest channel value's clipping point to
/// where the 1st-percentile value reaches 10% of full scale (at most 14 brackets).
fn bracket_times(e: &[[f32; 3]]) -> (Vec<f64>, f64) {
    let vals: Vec<f64> = e
        .iter()
        .flatten()
        .map(|&v| f64::from(v))
        .filter(|&v| v > 0.0)
        .collect();
    let max = vals.iter().copied().fold(0.0, f64::max);
    let p1 = quantile(vals, 0.01);
    let mut times = vec![0.5 / max];
    while times.len() < 14 && times[times.len() - 1] * p1 < 0.1 {
        let last = times[times.len() - 1];
        times.push(last * 4.0);
    }
    (times, p1)
}

#[test]
fn bracket_merge_recovers_the_hdri_radiance_within_2_percent() {
    let mut noise = Noise(0x1234_5678_9abc_def1);
    for name in [
        "noon_grass_1k.hdr",
        "venice_sunset_1k.hdr",
        "st_peters_square_night_1k.hdr",
    ] {
        let (w, h, e) = small_hdri(name, 8);
        let (times, floor) = bracket_times(&e);
        let brackets: Vec<Bracket> = times
            .iter()
            .map(|&t| Bracket {
                image: expose(&e, w, h, t, &srgb_encode, &mut noise),
                exposure_s: t,
                gain: 1.0,
            })
            .collect();
        // the exposures do clip: the longest one saturates most of the image
        let clipped = brackets[brackets.len() - 1]
            .image
            .pixels
            .iter()
            .flatten()
            .filter(|&&v| v >= 0.98)
            .count();
        assert!(
            clipped * 2 > e.len() * 3,
            "{name}: longest exposure clips {clipped}"
        );
        let merged = merge_brackets(
            &brackets,
            &ResponseModel::Srgb,
            255.0,
            &Radiometry::default(),
            MergeLimits::default(),
        )
        .unwrap();
        let mut errs = Vec::new();
        for (m, t) in merged.iter().zip(&e) {
            for c in 0..3 {
                let truth = f64::from(t[c]);
                if truth >= floor {
                    errs.push((f64::from(m[c]) - truth) / truth);
                }
            }
        }
        let n = errs.len();
        assert!(
            n * 100 >= e.len() * 3 * 98,
            "{name}: only {n} samples in range"
        );
        let rms = (errs.iter().map(|e| e * e).sum::<f64>() / n as f64).sqrt();
        let p99 = quantile(errs.iter().map(|e| e.abs()).collect(), 0.99);
        let bias = errs.iter().sum::<f64>() / n as f64;
        eprintln!(
            "{name}: {} brackets, {n} samples, relative error rms {:.3}%, p99 {:.3}%, mean {:+.3}%",
            times.len(),
            rms * 100.0,
            p99 * 100.0,
            bias * 100.0
        );
        assert!(rms < 0.02, "{name}: rms {rms}");
        assert!(bias.abs() < 0.005, "{name}: bias {bias}");
    }
}

/// The median green radiance of a map.
fn median_green(e: &[[f32; 3]]) -> f64 {
    let mut lum: Vec<f64> = e.iter().map(|p| f64::from(p[1])).collect();
    lum.sort_by(f64::total_cmp);
    lum[lum.len() / 2]
}

/// Six exposures of the map through the made-up curve, two stops apart, from the median pixel
/// near black to it near clipping, so that the samples cover every part of the code range.
fn six_brackets(e: &[[f32; 3]], w: u32, h: u32, median: f64, noise: &mut Noise) -> Vec<Bracket> {
    (-4..=1)
        .map(|k| 0.3 / median * 4f64.powi(k))
        .map(|t| Bracket {
            image: expose(e, w, h, t, &curve_encode, noise),
            exposure_s: t,
            gain: 1.0,
        })
        .collect()
}

/// A region clipped in every bracket (a window, a lamp) carries no data; the recovery ignores
/// it instead of failing on a singular system, and finds the same curve. A scene that is
/// clipped or black everywhere is an error that says so.
#[test]
fn response_recovery_ignores_pixels_clipped_in_every_bracket() {
    let (w, h, mut e) = small_hdri("rooitou_park_1k.hdr", 8);
    let median = median_green(&e);
    // The top eighth of the rows: far brighter than the longest exposure can hold.
    let clipped_rows = (h / 8) as usize;
    for p in &mut e[..clipped_rows * w as usize] {
        *p = [1e9; 3];
    }
    let brackets = six_brackets(&e, w, h, median, &mut Noise(7));
    let clipped_everywhere = brackets.iter().all(|b| {
        b.image.pixels[..clipped_rows * w as usize]
            .iter()
            .all(|p| p.iter().all(|&v| v >= 1.0))
    });
    assert!(
        clipped_everywhere,
        "the bright rows are not clipped in every bracket"
    );
    let curve = recover_response(&brackets, SolveSettings::default()).unwrap();
    let mid = 128;
    let mut worst: f64 = 0.0;
    for c in 0..3 {
        for z in 64..=240 {
            let g = curve.values[c][z].ln() - curve.values[c][mid].ln();
            let truth = curve_decode(z as f64 / 255.0).ln() - curve_decode(mid as f64 / 255.0).ln();
            worst = worst.max((g - truth).abs());
        }
    }
    assert!(worst < 0.05, "worst ln difference {worst}");

    // Everything clipped: an error naming the cause.
    let white: Vec<Bracket> = brackets
        .iter()
        .map(|b| {
            let mut b = b.clone();
            b.image.pixels.iter_mut().for_each(|p| *p = [1.0; 3]);
            b
        })
        .collect();
    let e = recover_response(&white, SolveSettings::default()).unwrap_err();
    assert!(e.to_string().contains("clipped"), "{e}");
}

/// Exposures that cannot be the images' are refused before a curve is written: listed in
/// another order than the images (a decreasing curve), or nearly equal (a flat one).
#[test]
fn exposures_out_of_order_or_too_close_are_refused() {
    let (w, h, e) = small_hdri("rooitou_park_1k.hdr", 8);
    let brackets = six_brackets(&e, w, h, median_green(&e), &mut Noise(7));
    let mut reversed = brackets.clone();
    let times: Vec<f64> = brackets.iter().rev().map(|b| b.exposure_s).collect();
    for (b, t) in reversed.iter_mut().zip(times) {
        b.exposure_s = t;
    }
    let err = recover_response(&reversed, SolveSettings::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("darker than") && err.contains("order"),
        "{err}"
    );
    let mut close = brackets[..2].to_vec();
    close[1].exposure_s = close[0].exposure_s * 1.000_000_1;
    let err = recover_response(&close, SolveSettings::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("span only"), "{err}");
    // One swapped pair is found too.
    let mut swapped = brackets.clone();
    let (a, b) = (swapped[2].exposure_s, swapped[3].exposure_s);
    swapped[2].exposure_s = b;
    swapped[3].exposure_s = a;
    let err = recover_response(&swapped, SolveSettings::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("bracket 3") && err.contains("bracket 4"),
        "{err}"
    );
    // One image given for two exposures (the solve said "singular … or a smoothness weight
    // lambda above its 100"; found by an audit).
    let mut twice = brackets.clone();
    twice[4].image = twice[1].image.clone();
    let err = recover_response(&twice, SolveSettings::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("brackets 2 and 5") && err.contains("same pixels"),
        "{err}"
    );
}

/// A made-up camera curve with a shoulder: code v = (1 + k)·y/(y + k) with y = X^0.45.
const K: f64 = 0.6;
fn curve_encode(x: f64) -> f64 {
    let y = x.max(0.0).powf(0.45);
    (1.0 + K) * y / (y + K)
}
fn curve_decode(v: f64) -> f64 {
    let y = v * K / (1.0 + K - v);
    y.powf(1.0 / 0.45)
}

#[test]
fn response_recovery_finds_a_known_curve() {
    let (w, h, e) = small_hdri("rooitou_park_1k.hdr", 8);
    let brackets = six_brackets(&e, w, h, median_green(&e), &mut Noise(42));
    let curve = recover_response(&brackets, SolveSettings::default()).unwrap();
    let mid = 128;
    // Codes whose exposure is below 10× the read noise (SNR < 10) carry no information about
    // the curve; compare from there to the top end.
    let z_lo = (0..256)
        .find(|&z| curve_decode(z as f64 / 255.0) >= 10.0 * READ_NOISE)
        .unwrap_or(255);
    assert!(z_lo < 64, "{z_lo}");
    let mut worst: f64 = 0.0;
    for c in 0..3 {
        let g = |z: usize| curve.values[c][z].ln() - curve.values[c][mid].ln();
        let truth =
            |z: usize| curve_decode(z as f64 / 255.0).ln() - curve_decode(mid as f64 / 255.0).ln();
        for z in z_lo..=240 {
            worst = worst.max((g(z) - truth(z)).abs());
        }
    }
    eprintln!("recovered ln-curve: worst difference {worst:.4} over codes {z_lo}..=240");
    assert!(worst < 0.05, "worst ln difference {worst}");
    // the sRGB curve, a plausible wrong answer, is far from the recovered one
    let srgb_diff = (0..3)
        .flat_map(|c| (z_lo..=240).map(move |z| (c, z)))
        .map(|(c, z)| {
            let s = |z: usize| {
                ResponseModel::Srgb
                    .relative_exposure(c, z as f64 / 255.0, 255.0)
                    .ln()
            };
            ((curve.values[c][z].ln() - curve.values[c][mid].ln()) - (s(z) - s(mid))).abs()
        })
        .fold(0.0, f64::max);
    assert!(srgb_diff > 0.2, "{srgb_diff}");

    // the curve file round-trips and linearises the brackets: merged ∝ true radiance
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("response.txt");
    curve.write(&path, "test").unwrap();
    let back = ResponseCurve::read(&path).unwrap();
    let model = ResponseModel::Curve(Arc::new(back));
    let merged = merge_brackets(
        &brackets,
        &model,
        255.0,
        &Radiometry::default(),
        MergeLimits::default(),
    )
    .unwrap();
    // The darkest 1% of the green values are left out (noise dominates them).
    let mut green: Vec<f64> = e.iter().map(|p| f64::from(p[1])).collect();
    green.sort_by(f64::total_cmp);
    let darkest_percent = green[green.len() / 100];
    let ratios: Vec<f64> = merged
        .iter()
        .zip(&e)
        .flat_map(|(m, t)| (0..3).map(move |c| (f64::from(m[c]), f64::from(t[c]))))
        .filter(|&(_, t)| t > darkest_percent)
        .map(|(m, t)| m / t)
        .collect();
    let scale = quantile(ratios.clone(), 0.5);
    let rms = (ratios
        .iter()
        .map(|r| (r / scale - 1.0).powi(2))
        .sum::<f64>()
        / ratios.len() as f64)
        .sqrt();
    eprintln!(
        "merge through the recovered curve: relative rms {:.3}%",
        rms * 100.0
    );
    assert!(rms < 0.03, "{rms}");
}

#[test]
fn image_circle_is_found_within_a_pixel_on_synthetic_fisheye_frames() {
    let models = FisheyeModel::ALL;
    let mut noise = Noise(7);
    let mut worst: f64 = 0.0;
    for (k, name) in HDRIS.iter().enumerate() {
        let img = read_hdr_image(&data(name)).unwrap_or_else(|e| panic!("{e}"));
        let (w, h) = (240u32, 180u32);
        let truth = FisheyeCalibration {
            model: models[k % 4],
            center: Some([118.37 + 1.9 * k as f64, 91.61 - 1.3 * k as f64]),
            radius: Some(78.4 + 1.7 * k as f64),
            fov_deg: [180.0, 185.0, 170.0][k % 3],
            rotation_deg: 25.0 * k as f64,
        };
        let mut frame = render_fisheye(&img.pixels, img.width, img.height, &truth, w, h, 4);
        // sensor noise and a small black-level offset everywhere
        let mut lum: Vec<f32> = frame.iter().map(|p| p[1]).filter(|&v| v > 0.0).collect();
        lum.sort_by(f32::total_cmp);
        let level = f64::from(lum[lum.len() / 2]);
        for p in &mut frame {
            for c in p.iter_mut() {
                *c = (f64::from(*c) * (1.0 + 0.01 * noise.normal())
                    + level * (0.002 + 0.002 * noise.normal()))
                .max(0.0) as f32;
            }
        }
        let found = detect_image_circle(&frame, w, h).unwrap_or_else(|e| panic!("{name}: {e}"));
        let [cx, cy] = truth.center.unwrap_or_default();
        let r = truth.radius.unwrap_or_default();
        let err = (found.center[0] - cx)
            .abs()
            .max((found.center[1] - cy).abs())
            .max((found.radius - r).abs());
        eprintln!(
            "{name} ({}): centre ({:.3}, {:.3}) vs ({cx}, {cy}), radius {:.3} vs {r}, {} points, \
             rms residual {:.3} px",
            truth.model.name(),
            found.center[0],
            found.center[1],
            found.radius,
            found.points,
            found.rms_residual
        );
        worst = worst.max(err);
        assert!(err < 1.0, "{name}: {found:?}");
    }
    eprintln!("worst centre/radius error {worst:.3} px");
}

// ----------------------------------------------------------------------------------------------
// Device loss

/// A fake camera: frames until `fail_after` frames, then EIO ("unplugged"), and the opener
/// fails while `present` is false.
struct FakeCamera {
    frames: u64,
    fail_after: u64,
    present: Arc<AtomicBool>,
}

impl FrameSource for FakeCamera {
    fn next_frame(&mut self) -> Result<Option<HdrFrame>, CaptureError> {
        if self.frames == self.fail_after {
            self.present.store(false, Ordering::SeqCst);
        }
        if !self.present.load(Ordering::SeqCst) {
            return Err(CaptureError::Io {
                path: "/dev/video-fake".into(),
                source: std::io::Error::from_raw_os_error(5),
            });
        }
        let mut f = HdrFrame::new(2, 1, vec![[1.0; 3]; 2], Projection::LatLong).unwrap();
        f.time = self.frames as f64 / 30.0;
        self.frames += 1;
        Ok(Some(f))
    }
    fn describe(&self) -> String {
        "fake camera".into()
    }
}

fn fake_source(
    present: Arc<AtomicBool>,
    opens: Arc<AtomicU64>,
    policy: RetryPolicy,
) -> ResilientSource {
    ResilientSource::new("fake camera", policy, move || {
        let first = opens.fetch_add(1, Ordering::SeqCst) == 0;
        if present.load(Ordering::SeqCst) {
            Ok(Box::new(FakeCamera {
                frames: 0,
                // unplugged once, after 3 frames
                fail_after: if first { 3 } else { u64::MAX },
                present: present.clone(),
            }) as Box<dyn FrameSource>)
        } else {
            Err(CaptureError::Io {
                path: "/dev/video-fake".into(),
                source: std::io::Error::from_raw_os_error(19),
            })
        }
    })
}

fn wait_until(what: &str, f: impl Fn() -> bool) {
    let start = Instant::now();
    while !f() {
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "timed out waiting for {what}"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
}

#[test]
fn device_loss_is_stale_retried_with_backoff_and_resumes() {
    let present = Arc::new(AtomicBool::new(true));
    let opens = Arc::new(AtomicU64::new(0));
    let policy = RetryPolicy {
        initial_backoff: Duration::from_millis(1),
        max_backoff: Duration::from_millis(8),
        max_attempts: None,
    };
    let mut src = fake_source(present.clone(), opens.clone(), policy);
    let health = src.health().expect("a resilient source has health");
    let (tx, rx) = crossbeam_channel::bounded::<HdrFrame>(16);
    let worker = std::thread::Builder::new()
        .name("fake-capture".into())
        .spawn(move || {
            while let Ok(Some(frame)) = src.next_frame() {
                if tx.send(frame).is_err() {
                    break;
                }
            }
        })
        .unwrap();
    let mut frames: Vec<HdrFrame> = (0..3).map(|_| rx.recv().unwrap()).collect();
    // the camera is unplugged after 3 frames: stale, retried, error recorded
    wait_until("stale", || health.is_stale());
    wait_until("several attempts", || health.reconnect_attempts() >= 4);
    assert!(rx.try_recv().is_err(), "no frames while the device is gone");
    let err = health.last_error();
    assert!(err.contains("/dev/video-fake"), "{err}");
    assert!(opens.load(Ordering::SeqCst) >= 4);
    // it comes back
    present.store(true, Ordering::SeqCst);
    frames.push(rx.recv_timeout(Duration::from_secs(10)).unwrap());
    wait_until("fresh", || !health.is_stale());
    assert_eq!(health.reconnect_attempts(), 0);
    assert!(health.failures_total() >= 4);
    let seqs: Vec<u64> = frames.iter().map(|f| f.seq).collect();
    assert_eq!(
        seqs,
        vec![0, 1, 2, 3],
        "sequence numbers continue across the reconnect"
    );
    assert!(
        frames.windows(2).all(|w| w[1].time >= w[0].time),
        "times never decrease across the reconnect"
    );
    health.request_stop();
    drop(rx);
    worker.join().unwrap();
}

#[test]
fn retry_backoff_doubles_up_to_the_cap_and_attempts_are_bounded() {
    let p = RetryPolicy {
        initial_backoff: Duration::from_millis(100),
        max_backoff: Duration::from_millis(700),
        max_attempts: None,
    };
    let waits: Vec<u128> = (1..=6).map(|a| p.backoff(a).as_millis()).collect();
    assert_eq!(waits, vec![100, 200, 400, 700, 700, 700]);
    assert_eq!(p.backoff(u64::MAX), Duration::from_millis(700));
    // a device that never appears: the error after max_attempts names it
    let policy = RetryPolicy {
        initial_backoff: Duration::from_millis(1),
        max_backoff: Duration::from_millis(1),
        max_attempts: Some(3),
    };
    let opens = Arc::new(AtomicU64::new(0));
    let mut src = fake_source(Arc::new(AtomicBool::new(false)), opens.clone(), policy);
    let err = src.next_frame().unwrap_err();
    assert!(err.to_string().contains("/dev/video-fake"), "{err}");
    assert_eq!(opens.load(Ordering::SeqCst), 3);
    // a settings error before the first open is not retried
    let tries = Arc::new(AtomicU64::new(0));
    let t2 = tries.clone();
    let mut src = ResilientSource::new("named camera", RetryPolicy::default(), move || {
        t2.fetch_add(1, Ordering::SeqCst);
        Err(CaptureError::InvalidSettings(
            "no camera named \"x\"".into(),
        ))
    });
    let err = src.next_frame().unwrap_err();
    assert!(err.to_string().contains("no camera named"), "{err}");
    assert_eq!(tries.load(Ordering::SeqCst), 1);
    // a stop request ends the retries with the end of the stream
    let mut src = fake_source(
        Arc::new(AtomicBool::new(false)),
        opens,
        RetryPolicy::default(),
    );
    src.health().unwrap().request_stop();
    assert!(src.next_frame().unwrap().is_none());
}

// ----------------------------------------------------------------------------------------------
// Config

#[test]
fn camera_config_validates_and_names_bad_keys() {
    let text = r#"
[source]
kind = "v4l2"
projection = "fisheye"
[source.fisheye]
center = [640.0, 480.0]
radius = 470.0
[camera]
device = "/dev/video2"
formats = ["Y16", "YUYV", "MJPG"]
width = 1280
height = 960
response = "logarithmic"
log_a = 60.0
log_b = 300.0
white_balance = [1.1, 1.0, 0.9]
scale = 2.5
bracket_exposures_s = [0.001, 0.004, 0.016]
"#;
    let cfg = RawConfig::parse(text, Path::new("t.toml"))
        .unwrap()
        .validate()
        .unwrap();
    assert_eq!(cfg.source.kind, SourceKind::V4l2);
    assert_eq!(cfg.camera.device, "/dev/video2");
    assert_eq!(cfg.camera.formats.len(), 3);
    assert_eq!(
        cfg.camera.response,
        ResponseModel::Logarithmic { a: 60.0, b: 300.0 }
    );
    assert_eq!(cfg.camera.bracket_exposures_s, vec![0.001, 0.004, 0.016]);
    assert!(matches!(cfg.camera.projection, Projection::Fisheye(_)));
    let bad = |extra: &str| {
        let t = format!("[camera]\n{extra}\n");
        match RawConfig::parse(&t, Path::new("t.toml")).and_then(|r| r.validate()) {
            Ok(_) => panic!("accepted {extra}"),
            Err(e) => e.to_string(),
        }
    };
    let m = bad("response = \"log\"");
    assert!(m.contains("camera.response") && m.contains("log"), "{m}");
    let m = bad("response = \"logarithmic\"\nlog_a = 1.0");
    assert!(m.contains("log_b"), "{m}");
    let m = bad("response = \"curve\"\ncurve = \"/nonexistent/curve.txt\"");
    assert!(
        m.contains("camera.curve") && m.contains("/nonexistent/curve.txt"),
        "{m}"
    );
    let m = bad("formats = [\"Y444\"]");
    assert!(m.contains("camera.formats") && m.contains("Y444"), "{m}");
    // The error lists what is supported.
    assert!(
        m.contains("VUYA") && m.contains("pREE") && m.contains("NM12"),
        "{m}"
    );
    let m = bad("white_balance = [1.0, -1.0, 1.0]");
    assert!(m.contains("camera.white_balance"), "{m}");
    let m = bad("bracket_exposures_s = [0.01, 0.0]");
    assert!(m.contains("camera.bracket_exposures_s"), "{m}");
    let m = bad("gamma = 0.0\nresponse = \"gamma\"");
    assert!(m.contains("camera.gamma"), "{m}");
    let m = bad("exposure = 1.0");
    assert!(m.contains("exposure"), "{m}");
    let m = bad("width = 0");
    assert!(m.contains("camera.width"), "{m}");
    let m = bad("yuv_matrix = \"bt2100\"");
    assert!(
        m.contains("camera.yuv_matrix") && m.contains("bt2020"),
        "{m}"
    );
    // HDR video: BT.2020's matrix with a PQ or an HLG response.
    for (response, model) in [("pq", ResponseModel::Pq), ("hlg", ResponseModel::Hlg)] {
        let t = format!("[camera]\nresponse = \"{response}\"\nyuv_matrix = \"bt2020\"\n");
        let cfg = RawConfig::parse(&t, Path::new("t.toml"))
            .and_then(|r| r.validate())
            .unwrap_or_else(|e| panic!("{response}: {e}"));
        assert_eq!(cfg.camera.response, model);
        assert_eq!(cfg.camera.yuv_matrix, YuvMatrix::Bt2020);
    }
}

// ----------------------------------------------------------------------------------------------
// A real device

#[test]
fn real_device_delivers_a_frame_when_present() {
    use envlight::capture::pixel_format::PixelFormat;
    use envlight::capture::v4l2::{device_nodes, list_devices, CameraSettings, V4l2Source};
    if device_nodes().is_empty() {
        println!("skipped: no /dev/video* device");
        return;
    }
    let mut opened = 0;
    for (path, info) in list_devices() {
        let info = match info {
            Ok(i) => i,
            Err(e) => {
                println!("{}: {e}", path.display());
                continue;
            }
        };
        println!("{info}");
        let Some(fm) = info.formats.iter().find(|f| f.supported) else {
            continue;
        };
        let size = fm
            .sizes
            .first()
            .and_then(|(s, _)| s.split_once('x'))
            .and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)))
            .unwrap_or((640, 480));
        let settings = CameraSettings {
            device: path.display().to_string(),
            formats: PixelFormat::all(),
            width: size.0,
            height: size.1,
            ..Default::default()
        };
        let mut src = match V4l2Source::open(&settings) {
            Ok(s) => s,
            Err(e) => {
                println!("{}: cannot open: {e}", path.display());
                continue;
            }
        };
        let a = src.next_frame().unwrap().unwrap();
        let b = src.next_frame().unwrap().unwrap();
        assert!(a
            .pixels
            .iter()
            .flatten()
            .all(|v| v.is_finite() && *v >= 0.0));
        assert_eq!(b.seq, a.seq + 1);
        assert!(b.time >= a.time, "driver timestamps run forwards");
        println!("{}: {} frames ok", src.describe(), 2);
        opened += 1;
    }
    println!("{opened} camera(s) streamed");
}

// ----------------------------------------------------------------------------------------------
// Command line

fn envlight(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .expect("run envlight")
}

/// Writes an 8-bit sRGB PNG of linear RGB pixels scaled by `k`.
fn write_png(path: &Path, w: u32, h: u32, pixels: &[[f32; 3]], k: f64) {
    let bytes: Vec<u8> = pixels
        .iter()
        .flat_map(|p| {
            p.map(|v| (srgb_encode((f64::from(v) * k).clamp(0.0, 1.0)) * 255.0).round() as u8)
        })
        .collect();
    image::RgbImage::from_raw(w, h, bytes)
        .expect("size")
        .save(path)
        .unwrap_or_else(|e| panic!("{e}"));
}

#[test]
fn calibrate_fisheye_prints_config_lines_for_the_detected_circle() {
    let img = read_hdr_image(&data("venice_sunset_1k.hdr")).unwrap_or_else(|e| panic!("{e}"));
    let truth = FisheyeCalibration {
        model: FisheyeModel::Equisolid,
        center: Some([131.6, 97.3]),
        radius: Some(84.2),
        ..Default::default()
    };
    let (w, h) = (256, 192);
    let frame = render_fisheye(&img.pixels, img.width, img.height, &truth, w, h, 4);
    let mut g: Vec<f32> = frame.iter().map(|p| p[1]).filter(|&v| v > 0.0).collect();
    g.sort_by(f32::total_cmp);
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("frame.png");
    write_png(&png, w, h, &frame, 0.3 / f64::from(g[g.len() / 2]));
    let o = envlight(&[
        "calibrate-fisheye",
        png.to_str().unwrap(),
        "--model",
        "equisolid",
    ]);
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(
        o.status.success(),
        "{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    // the printed lines are a valid [source.fisheye] table with the circle within a pixel
    let cfg = RawConfig::parse(
        &format!("[source]\nkind = \"v4l2\"\nprojection = \"fisheye\"\n{out}"),
        Path::new("out"),
    )
    .and_then(|r| r.validate())
    .unwrap_or_else(|e| panic!("{e}\n{out}"));
    let Projection::Fisheye(cal) = cfg.source.projection else {
        panic!("not fisheye: {out}");
    };
    assert_eq!(cal.model, FisheyeModel::Equisolid);
    let c = cal.center.unwrap_or_default();
    let r = cal.radius.unwrap_or_default();
    assert!(
        (c[0] - 131.6).abs() < 1.0 && (c[1] - 97.3).abs() < 1.0,
        "{out}"
    );
    assert!((r - 84.2).abs() < 1.0, "{out}");
    // an image without a circle is an error naming the file
    let flat = dir.path().join("flat.png");
    write_png(&flat, 64, 64, &vec![[0.5; 3]; 64 * 64], 1.0);
    let o = envlight(&["calibrate-fisheye", flat.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("flat.png"));
}

#[test]
fn calibrate_response_writes_a_curve_file_from_png_brackets() {
    let (w, h, e) = small_hdri("noon_grass_1k.hdr", 8);
    let mut g: Vec<f32> = e.iter().map(|p| p[1]).collect();
    g.sort_by(f32::total_cmp);
    let median = f64::from(g[g.len() / 2]);
    let dir = tempfile::tempdir().unwrap();
    let times: Vec<f64> = (-3..=1).map(|k| 0.3 / median * 4f64.powi(k)).collect();
    let mut args: Vec<String> = vec!["calibrate-response".into()];
    for (i, t) in times.iter().enumerate() {
        let p = dir.path().join(format!("b{i}.png"));
        write_png(&p, w, h, &e, *t);
        args.push(p.to_str().unwrap().into());
    }
    let curve_path = dir.path().join("curve.txt");
    let exposures: Vec<String> = times.iter().map(|t| t.to_string()).collect();
    args.extend([
        "--exposures".into(),
        exposures.join(","),
        "-o".into(),
        curve_path.to_str().unwrap().into(),
    ]);
    let argv: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = envlight(&argv);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let curve = ResponseCurve::read(&curve_path).unwrap();
    // the PNGs are sRGB-encoded: the recovered curve is sRGB's (relative to mid code)
    let s = |z: usize| {
        ResponseModel::Srgb
            .relative_exposure(1, z as f64 / 255.0, 255.0)
            .ln()
    };
    let worst = (40..=240)
        .map(|z| ((curve.values[1][z].ln() - curve.values[1][128].ln()) - (s(z) - s(128))).abs())
        .fold(0.0, f64::max);
    assert!(worst < 0.05, "worst ln difference to sRGB {worst}");
    // one exposure per image
    let unused = dir.path().join("unused.txt");
    let o = envlight(&[
        argv[0],
        argv[1],
        argv[2],
        "--exposures",
        "0.1",
        "-o",
        unused.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("2 images but 1"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    // -o on one of the brackets is refused before anything is read or written (it replaced
    // the image with the curve's text).
    let last = argv[times.len()];
    let before = std::fs::read(last).unwrap();
    let mut onto_input = argv.clone();
    *onto_input.last_mut().unwrap() = last;
    let o = envlight(&onto_input);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("is the input file") && err.contains("b4.png"),
        "{err}"
    );
    assert_eq!(std::fs::read(last).unwrap(), before);
    // Errors about a bracket name its file; exposures in reverse order are refused and no
    // curve is written.
    let mut reversed: Vec<&str> = argv.clone();
    let rev_exposures: Vec<String> = times.iter().rev().map(|t| t.to_string()).collect();
    let rev_exposures = rev_exposures.join(",");
    let n = times.len();
    reversed[n + 2] = &rev_exposures;
    reversed[n + 4] = unused.to_str().unwrap();
    let o = envlight(&reversed);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("darker than") && err.contains("1 = ") && err.contains("b0.png"),
        "{err}"
    );
    assert!(!unused.exists());
    // A floating-point image is no bracket: refused, named (values above 1 were clamped).
    let hdr = data("rooitou_park_1k.hdr");
    // A FIFO is refused, not waited on (nothing will write to it); so by calibrate-fisheye.
    let fifo = dir.path().join("pipe.png");
    let made = std::process::Command::new("mkfifo").arg(&fifo).status();
    assert!(made.unwrap().success());
    let fifo = fifo.to_str().unwrap();
    for (first, needles) in [
        (
            hdr.to_str().unwrap(),
            ["rooitou_park_1k.hdr", "floating-point"],
        ),
        (fifo, ["pipe.png", "not a regular file"]),
    ] {
        let o = envlight(&[
            "calibrate-response",
            first,
            argv[1],
            "--exposures",
            "0.1,0.4",
            "-o",
            unused.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(needles.iter().all(|n| err.contains(n)), "{err}");
    }
    let o = envlight(&["calibrate-fisheye", fifo]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("pipe.png") && err.contains("not a regular file"),
        "{err}"
    );
    // A solver setting out of range names its option, before any image is read (the FIFO
    // would be refused otherwise): it named the field and blamed the bracket files.
    for (option, value, needle) in [
        (
            "--levels",
            "65536",
            "invalid --levels 65536: must be in 4..=4096",
        ),
        ("--lambda", "0", "invalid --lambda 0: must be in (0, 1e6]"),
        ("--samples", "1", "invalid --samples 1: must be in 2..=5000"),
    ] {
        let o = envlight(&[
            "calibrate-response",
            fifo,
            argv[1],
            "--exposures",
            "0.1,0.4",
            option,
            value,
            "-o",
            unused.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(needle) && !err.contains("pipe.png"), "{err}");
    }
    assert!(!unused.exists());
}

#[test]
fn devices_lists_or_says_there_are_none() {
    let o = envlight(&["devices"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    if envlight::capture::v4l2::device_nodes().is_empty() {
        assert!(String::from_utf8_lossy(&o.stderr).contains("no /dev/video* devices"));
    } else {
        assert!(String::from_utf8_lossy(&o.stdout).contains("/dev/video"));
    }
    // a camera name that matches nothing is a settings error before the first open: it fails
    // at once, naming it, instead of being retried
    let o = envlight(&[
        "decompose",
        "--device",
        "no-such-camera-xyz",
        "--frames",
        "1",
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("no-such-camera-xyz"), "{err}");
}

#[test]
fn logarithmic_hdr_camera_path_recovers_radiance_within_quantisation() {
    use envlight::capture::pixel_format::{decode, PixelFormat, RawFrame, YuvMatrix};
    use envlight::capture::response::Linearizer;
    // An HDRC-style 10-bit logarithmic camera looking at a shared HDRI: D = a ln(L·k) + b.
    let (w, h, e) = small_hdri("noon_grass_1k.hdr", 8);
    let (a, b) = (40.0f64, 512.0f64);
    let radiometry = Radiometry {
        exposure_s: 1.0,
        gain: 1.0,
        white_balance: [1.0; 3],
        scale: 2.0, // L = 2·X
    };
    let mut data = Vec::new();
    let mut expected = Vec::new();
    for p in &e {
        let l = f64::from(envlight::frame::luminance(*p));
        let x = l / radiometry.scale;
        let dn = (a * x.max(1e-30).ln() + b).round().clamp(0.0, 1023.0);
        data.extend_from_slice(&(dn as u16).to_le_bytes());
        expected.push((l, dn));
    }
    let raw = RawFrame {
        data: &data,
        format: PixelFormat::Grey { bits: 10 },
        width: w,
        height: h,
        stride: 0,
    };
    let codes = decode(&raw, YuvMatrix::Auto).unwrap();
    let lin = Linearizer::new(&ResponseModel::Logarithmic { a, b }, 1023.0, &radiometry);
    let radiance = lin.linearize(&codes);
    let mut worst: f64 = 0.0;
    let mut in_range = 0;
    for (r, &(l, dn)) in radiance.iter().zip(&expected) {
        if dn <= 0.0 || dn >= 1023.0 {
            continue; // outside the sensor's range
        }
        in_range += 1;
        let rel = (f64::from(r[1]) - l).abs() / l;
        worst = worst.max(rel);
        assert_eq!(r[0], r[2], "grey");
    }
    // rounding D to an integer is an error of at most ½ DN = 1/(2a) neper
    let bound = (0.5 / a).exp() - 1.0;
    eprintln!(
        "log camera: {in_range} of {} pixels in range, worst relative error {:.3}% (bound {:.3}%)",
        expected.len(),
        worst * 100.0,
        bound * 100.0
    );
    assert!(in_range * 100 >= expected.len() * 99, "{in_range}");
    assert!(worst <= bound * 1.01 + 1e-4, "{worst} > {bound}");
}
