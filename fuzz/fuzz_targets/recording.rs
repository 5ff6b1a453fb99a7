//! Recordings: a `session.json` and a `frames.jsonl` of arbitrary text opened by
//! `ReplaySource::open`, as `envlight run --replay DIR` does, then every frame replayed (as fast
//! as possible) and decomposed with the session's settings. The frames themselves are three
//! fixed small files the index may name (`frames/000000.exr` 16×8, `frames/000001.exr` 32×16,
//! `frames/000002.hdr` 16×16: lat-long, fisheye or angular-map sized); the damaged image files
//! are the `hdr_image` target's work.
//!
//! Input: two bytes (little-endian) giving the length of the session text, the session text,
//! then the index text. To keep an execution short, a session asking for more than 256 lights,
//! a working map wider than 64 or more than one resampling thread is decomposed with those
//! limits (the validation still sees the values as given).
//!
//! Every light of every frame must be finite, with a non-negative power and solid angle and a
//! unit direction: the wire form carries finite floats only.
#![no_main]

use std::path::PathBuf;
use std::sync::OnceLock;

use envlight::capture::FrameSource;
use envlight::decompose::Decomposer;
use envlight::record::{Pacing, ReplaySource};
use libfuzzer_sys::fuzz_target;

/// The recording directory, made once per process: the three frames in place.
fn recording_dir() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir =
            std::env::temp_dir().join(format!("envlight-fuzz-recording-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("frames")).unwrap();
        write_exr(&dir.join("frames/000000.exr"), 16, 8);
        write_exr(&dir.join("frames/000001.exr"), 32, 16);
        std::fs::write(dir.join("frames/000002.hdr"), flat_hdr(16, 16)).unwrap();
        dir
    })
}

/// A sky with a sun 10⁴ times brighter, so concentrated-source paths run.
fn pixel(x: usize, y: usize, width: usize) -> [f32; 3] {
    if x == width / 3 && y == 1 {
        [2.0e4, 1.8e4, 1.5e4]
    } else {
        let v = 0.5 + 0.1 * (x as f32) + 0.05 * (y as f32);
        [v, 0.9 * v, 1.2 * v]
    }
}

fn write_exr(path: &std::path::Path, width: usize, height: usize) {
    use exr::prelude::{Image, SpecificChannels, Vec2, WritableImage};
    let channels = SpecificChannels::rgb(|Vec2(x, y)| {
        let [r, g, b] = pixel(x, y, width);
        (r, g, b)
    });
    Image::from_channels((width, height), channels)
        .write()
        .to_file(path)
        .unwrap();
}

/// A flat (not run-length encoded) Radiance RGBE file.
fn flat_hdr(width: usize, height: usize) -> Vec<u8> {
    let mut bytes =
        format!("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {height} +X {width}\n").into_bytes();
    for y in 0..height {
        for x in 0..width {
            let [r, g, b] = pixel(x, y, width);
            let m = r.max(g).max(b);
            let e = m.log2().floor() as i32 + 1;
            let scale = 256.0 / 2f32.powi(e);
            bytes.extend([
                (r * scale) as u8,
                (g * scale) as u8,
                (b * scale) as u8,
                (e + 128) as u8,
            ]);
        }
    }
    bytes
}

fuzz_target!(|data: &[u8]| {
    let Some((length, rest)) = data.split_first_chunk::<2>() else {
        return;
    };
    let length = usize::from(u16::from_le_bytes(*length)).min(rest.len());
    let (session, index) = rest.split_at(length);
    let dir = recording_dir();
    std::fs::write(dir.join("session.json"), session).unwrap();
    std::fs::write(dir.join("frames.jsonl"), index).unwrap();
    let Ok(mut replay) = ReplaySource::open(dir, Pacing::AsFastAsPossible) else {
        return;
    };
    let mut settings = replay.session().decompose.clone();
    settings.lights = settings.lights.min(256);
    settings.working_width = settings.working_width.min(64);
    settings.resample_threads = 1;
    let Ok(mut decomposer) = Decomposer::new(settings) else {
        return;
    };
    for _ in 0..8 {
        let Ok(Some(frame)) = replay.next_frame() else {
            break;
        };
        let lights = decomposer.decompose(&frame);
        for light in &lights.lights {
            assert!(
                light.rgb.iter().all(|c| c.is_finite() && *c >= 0.0)
                    && light.solid_angle.is_finite()
                    && light.solid_angle >= 0.0,
                "light {light:?}"
            );
            let norm: f32 = light.dir.iter().map(|c| c * c).sum();
            assert!((norm - 1.0).abs() < 1e-3, "light {light:?}");
        }
    }
});
