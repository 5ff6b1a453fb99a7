//! Camera buffers: arbitrary bytes as a frame of any pixel format envlight negotiates, at a
//! small size and row stride taken from the first bytes, kept and turned into radiance.
#![no_main]

use envlight::capture::convert::{Calibration, FrameConverter, StreamFormat};
use envlight::capture::pixel_format::{YuvMatrix, DEFAULT_PREFERENCE};
use envlight::capture::response::ResponseModel;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let [format, width, height, stride, flags, rest @ ..] = data else {
        return;
    };
    let format = DEFAULT_PREFERENCE[usize::from(*format) % DEFAULT_PREFERENCE.len()];
    let stream = StreamFormat {
        format,
        width: u32::from(*width % 64),
        height: u32::from(*height % 64),
        stride: usize::from(*stride) * 4,
    };
    let response = match flags % 4 {
        0 => ResponseModel::Linear,
        1 => ResponseModel::Srgb,
        2 => ResponseModel::Pq,
        _ => ResponseModel::Gamma(2.2),
    };
    let calibration = Calibration {
        response,
        yuv_matrix: YuvMatrix::Auto,
        white_balance: [1.0, 1.0, 1.0],
        scale: 1.0,
    };
    let mut converter = FrameConverter::new(stream, calibration, flags & 0x10 != 0, None);
    if converter.keep(rest).is_ok() {
        let _ = converter.radiance(0.01, 1.0);
        let _ = converter.codes();
    }
});
