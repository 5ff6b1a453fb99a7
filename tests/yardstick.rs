//! Yardsticks and median cut on the real HDRIs in tests/data.

mod test_data;

use envlight::envmap::Projection;
use envlight::yardstick::{diffuse_irradiance_error, evaluate, median_cut, ReferenceMap};
use envlight::HdrFrame;
use std::path::Path;
use test_data::{data, HDRIS};

/// Reads a Radiance .hdr lat-long map with the image crate (test-only reader).
fn read_hdr(path: &Path) -> HdrFrame {
    let image = image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_rgb32f();
    let (w, h) = image.dimensions();
    let pixels = image.pixels().map(|p| p.0).collect();
    let mut frame = HdrFrame::new(w, h, pixels, Projection::LatLong).unwrap();
    frame.sanitize();
    frame
}

fn integral(frame: &HdrFrame) -> [f64; 3] {
    let omega = Projection::LatLong.solid_angles(frame.width, frame.height);
    let mut sum = [0.0; 3];
    for (p, om) in frame.pixels.iter().zip(omega) {
        for c in 0..3 {
            sum[c] += f64::from(p[c]) * om;
        }
    }
    sum
}

#[test]
fn median_cut_lights_sum_to_the_integral_of_a_real_map() {
    let frame = read_hdr(&data("rooitou_park_1k.hdr"));
    let expected = integral(&frame);
    for n in [16, 100, 256] {
        let total = median_cut(&frame, n).unwrap().total_rgb();
        for c in 0..3 {
            let rel = (total[c] - expected[c]).abs() / expected[c];
            assert!(rel < 1e-6, "n={n} channel {c}: {rel}");
        }
    }
}

#[test]
fn more_median_cut_lights_are_better_on_real_maps() {
    for name in HDRIS {
        let frame = read_hdr(&data(name));
        let map = ReferenceMap::new(&frame, 256).unwrap();
        let coarse = median_cut(&frame, 16).unwrap();
        let fine = median_cut(&frame, 256).unwrap();
        let (e16, e256) = (
            diffuse_irradiance_error(&map, &coarse.lights),
            diffuse_irradiance_error(&map, &fine.lights),
        );
        assert!(e256 < e16, "{name}: 256 lights {e256} vs 16 lights {e16}");
        let report = evaluate(&map, &fine.lights);
        assert!(report.energy < 1e-5, "{name}: {report:?}");
        assert!(report.diffuse < 0.05, "{name}: {report:?}");
    }
}
