//! A Rust client of the envlight daemon: connect, subscribe for the brightest N lights (or ASG
//! lobes, or wavelet coefficients), and print each frame's strongest one — or, for
//! spherical harmonics, the irradiance of surfaces facing up and sideways.
//!
//! ```sh
//! cargo run --release -- run &                       # the daemon on the built-in sky
//! cargo run --release --example subscribe -- tcp:127.0.0.1:7878 16
//! cargo run --release --example subscribe -- tcp:127.0.0.1:7878 16 asg   # needs [asg] enabled
//! cargo run --release --example subscribe -- tcp:127.0.0.1:7878 256 wavelet   # [wavelet] enabled
//! cargo run --release --example subscribe -- tcp:127.0.0.1:7878 9 sh   # [sh] enabled, degree 2
//! ```

use envlight::stream::client::{Client, Endpoint};
use envlight::stream::{Format, Message, Representation, Request};
use std::io::Write;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let endpoint: Endpoint = args
        .next()
        .unwrap_or_else(|| "unix:/run/envlight/envlight.sock".to_owned())
        .parse()?;
    let max_lights: u32 = args.next().map_or(Ok(16), |n| n.parse())?;
    let representation = match args.next().as_deref() {
        None | Some("lights") => Representation::Lights,
        Some("asg") => Representation::Asg,
        Some("wavelet") => Representation::Wavelet,
        Some("sh") => Representation::Sh,
        Some(other) => {
            return Err(
                format!("unknown representation {other:?}: lights, asg, wavelet or sh").into(),
            )
        }
    };
    let request = Request {
        max_lights,
        format: Format::Binary,
        representation,
    };
    let mut client = Client::connect(&endpoint, &request, None)?;
    let mut out = std::io::stdout().lock();
    while let Some(message) = client.next_message()? {
        match message {
            Message::Frame(frame) => {
                let brightest = frame
                    .lights
                    .iter()
                    .max_by(|a, b| a.luminance().total_cmp(&b.luminance()));
                let written = match brightest {
                    Some(light) => writeln!(
                        out,
                        "seq {:>5}: {} lights; brightest id {} from {:?} carrying {:?} W/m²",
                        frame.seq,
                        frame.lights.len(),
                        light.id,
                        light.dir,
                        light.rgb
                    ),
                    None => writeln!(out, "seq {:>5}: no lights", frame.seq),
                };
                // The reader of our output went away (`| head`): stop quietly.
                if written.is_err() {
                    break;
                }
                // The next light list is decoded into this one's allocation.
                client.recycle(frame.lights);
            }
            Message::Asg(frame) => {
                let brightest = frame
                    .lobes
                    .iter()
                    .max_by(|a, b| a.luminance().total_cmp(&b.luminance()));
                let written = match brightest {
                    Some(lobe) => writeln!(
                        out,
                        "seq {:>5}: {} lobes; brightest id {} along {:?}, λ {} μ {}, energy {:?} W/m²",
                        frame.seq,
                        frame.lobes.len(),
                        lobe.id,
                        lobe.axis,
                        lobe.lambda,
                        lobe.mu,
                        lobe.rgb.map(|c| c * lobe.integral)
                    ),
                    None => writeln!(out, "seq {:>5}: no lobes", frame.seq),
                };
                if written.is_err() {
                    break;
                }
            }
            Message::Wavelet(frame) => {
                let frame = frame.into_wavelet_frame();
                let set = &frame.set;
                let norm = |rgb: &[f32; 3]| rgb.iter().map(|c| c * c).sum::<f32>().sqrt();
                let largest = set
                    .coefficients
                    .iter()
                    .max_by(|a, b| norm(&a.1).total_cmp(&norm(&b.1)));
                let written = match largest {
                    Some((index, rgb)) => writeln!(
                        out,
                        "seq {:>5}: {} {} coefficients on {}²; largest index {} = {:?}; ∫L dω {:?} W/m²",
                        frame.seq,
                        set.coefficients.len(),
                        set.basis,
                        set.side,
                        index,
                        rgb,
                        frame.integral().map(|c| c as f32)
                    ),
                    None => writeln!(out, "seq {:>5}: no coefficients", frame.seq),
                };
                if written.is_err() {
                    break;
                }
            }
            Message::Sh(frame) => {
                let frame = frame.into_sh_frame();
                // The decoder accepts only (degree + 1)² coefficients, so this is a set.
                let Some(set) = frame.to_coefficients() else {
                    return Err("an SH frame that is no set".into());
                };
                let facing = |x, y, z| set.irradiance(glam::DVec3::new(x, y, z)).map(|c| c as f32);
                let written = writeln!(
                    out,
                    "seq {:>5}: SH degree {}; irradiance up {:?}, towards +X {:?}, down {:?} W/m²",
                    frame.seq,
                    set.degree(),
                    facing(0.0, 1.0, 0.0),
                    facing(1.0, 0.0, 0.0),
                    facing(0.0, -1.0, 0.0)
                );
                if written.is_err() {
                    break;
                }
            }
            Message::Goodbye { message } => {
                eprintln!("goodbye: {message}");
                break;
            }
            Message::Error { code, message } => {
                return Err(format!("error {code}: {message}").into())
            }
            Message::Subscribe(_) => return Err("unexpected subscribe from the daemon".into()),
        }
    }
    Ok(())
}
