//! Camera response curves (`--response-curve FILE`, `[camera] response_curve`): arbitrary text
//! parsed as a curve file; an accepted curve must keep its documented invariants and read back
//! unchanged from the text `to_text` writes for it; it is turned into the linearizer's tables,
//! with and without a white balance and exposure, and every code from 0 to 1 (and past both ends) must
//! come out as a finite radiance ≥ 0.
#![no_main]

use std::path::Path;
use std::sync::Arc;

use envlight::capture::response::{Linearizer, Radiometry, ResponseCurve, ResponseModel};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(curve) = ResponseCurve::parse(text, Path::new("fuzz.curve")) else {
        return;
    };
    // An accepted curve keeps the documented invariants …
    let n = curve.codes.len();
    assert!(n >= 2 && curve.values.iter().all(|v| v.len() == n));
    assert!(curve.codes.windows(2).all(|w| w[0] < w[1]));
    assert!(curve.codes[0] >= 0.0 && curve.codes[n - 1] <= 1.0);
    assert!(curve
        .values
        .iter()
        .flatten()
        .all(|x| x.is_finite() && *x >= 0.0));
    // … and the file `calibrate-response` would write for it reads back to the same curve.
    let written = curve.to_text("fuzz");
    match ResponseCurve::parse(&written, Path::new("written.curve")) {
        Ok(back) => assert_eq!(back, curve, "{written}"),
        Err(e) => panic!("{e}\n{written}"),
    }
    let model = ResponseModel::Curve(Arc::new(curve));
    for radiometry in [
        Radiometry::default(),
        Radiometry {
            exposure_s: 1.0 / 8000.0,
            gain: 0.5,
            white_balance: [2.5, 1.0, 1.7],
            scale: 3.0,
        },
    ] {
        for code_max in [255.0, 65535.0] {
            let linearizer = Linearizer::new(&model, code_max, &radiometry);
            for i in -2..=1026 {
                let v = i as f32 / 1024.0;
                for channel in 0..3 {
                    let radiance = linearizer.apply(channel, v);
                    assert!(
                        radiance.is_finite() && radiance >= 0.0,
                        "channel {channel} code {v}: {radiance}"
                    );
                }
            }
        }
    }
});
