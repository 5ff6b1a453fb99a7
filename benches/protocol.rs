//! The wire codec of light lists (src/stream/protocol/), one frame at a time.
//!
//! - `protocol/encode_binary/{256,4096}`: [`encode_frame`] of a light list of that many lights
//!   into a reused buffer: what the daemon does once per publication and per cap.
//! - `protocol/decode_binary/{256,4096}`: [`Decoder::next_from`] of that frame, the list
//!   handed back with [`Decoder::recycle`] as a client that keeps up does: what every client
//!   does for every frame.
//! - `protocol/encode_json/256`: [`frame_to_json`], the WebSocket and script form.
//!
//! Run with `cargo bench --bench protocol`; quote the medians.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use envlight::stream::protocol::{encode_frame, frame_to_json, Decoder, Message};
use envlight::{Light, LightFrame};
use std::hint::black_box;
use std::time::Duration;

/// A light list like the decomposition's: ids in order, unit directions spread over the
/// sphere, powers spanning several orders of magnitude.
fn frame(lights: u32) -> LightFrame {
    let lights = (0..lights)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / lights as f32;
            let phi = i as f32 * 2.399_963;
            let r = (1.0 - z * z).sqrt();
            let power = 10f32.powf((i % 7) as f32 - 2.0);
            Light {
                id: i,
                dir: [r * phi.cos(), z, r * phi.sin()],
                rgb: [power, 0.9 * power, 0.8 * power],
                solid_angle: 4.0 * std::f32::consts::PI / lights as f32,
            }
        })
        .collect();
    LightFrame {
        seq: 1,
        time: 0.5,
        lights,
    }
}

fn codec(c: &mut Criterion) {
    let mut group = c.benchmark_group("protocol");
    group.measurement_time(Duration::from_secs(3));
    for n in [256u32, 4096] {
        let frame = frame(n);
        let mut scratch = Vec::new();
        group.bench_with_input(BenchmarkId::new("encode_binary", n), &frame, |b, frame| {
            b.iter(|| {
                scratch.clear();
                encode_frame(black_box(frame), None, false, &mut scratch);
            })
        });
        // Encoded here, not by the bench above, which a filter may skip.
        let mut bytes = Vec::new();
        encode_frame(&frame, None, false, &mut bytes);
        let mut decoder = Decoder::new();
        group.bench_with_input(BenchmarkId::new("decode_binary", n), &bytes, |b, bytes| {
            b.iter(|| {
                let mut input = black_box(&bytes[..]);
                let mut decoded = 0;
                while let Ok(Some(message)) = decoder.next_from(&mut input) {
                    if let Message::Frame(frame) = message {
                        decoded += frame.lights.len();
                        decoder.recycle(black_box(frame.lights));
                    }
                }
                assert_eq!(decoded, n as usize, "the frame did not decode");
            })
        });
    }
    let frame = frame(256);
    group.bench_function("encode_json/256", |b| {
        b.iter(|| frame_to_json(black_box(&frame), None, false))
    });
    group.finish();
}

criterion_group!(benches, codec);
criterion_main!(benches);
