//! The wire protocol's decoders on arbitrary bytes: one message at a time, a stream fed in
//! chunks (the first byte sets the chunk length), and the JSON forms of frames and requests;
//! and the same text as a light-list file (`envlight render --lights`, JSON Lines), whose
//! accepted lights must be usable as they stand: unit directions, finite rgb and solid angles
//! ≥ 0.
#![no_main]

use envlight::light::parse_json_lines;
use envlight::stream::protocol::{decode_message, parse_json_message, parse_json_request, Decoder};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = decode_message(data);

    if let Some((&chunk, stream)) = data.split_first() {
        let mut decoder = Decoder::new();
        for piece in stream.chunks(usize::from(chunk).max(1)) {
            decoder.push(piece);
            while let Ok(Some(_)) = decoder.next_message() {}
        }
        let _ = decoder.finish();
    }

    let text = String::from_utf8_lossy(data);
    let _ = parse_json_message(&text);
    let _ = parse_json_request(&text);

    if let Ok(frames) = parse_json_lines(&text) {
        for light in frames.iter().flat_map(|f| &f.lights) {
            let length = light
                .dir
                .iter()
                .map(|&c| f64::from(c).powi(2))
                .sum::<f64>()
                .sqrt();
            assert!((length - 1.0).abs() < 1e-6, "{light:?}");
            assert!(
                light.rgb.iter().all(|c| c.is_finite() && *c >= 0.0),
                "{light:?}"
            );
            assert!(
                light.solid_angle.is_finite() && light.solid_angle >= 0.0,
                "{light:?}"
            );
        }
    }
});
