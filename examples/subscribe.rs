//! A Rust client of the envlight daemon: connect, subscribe for the brightest N lights, and
//! print each frame's strongest light.
//!
//! ```sh
//! cargo run --release -- run &                       # the daemon on the built-in sky
//! cargo run --release --example subscribe -- tcp:127.0.0.1:7878 16
//! ```

use envlight::stream::client::{Client, Endpoint};
use envlight::stream::{Format, Message, Request};
use std::io::Write;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let endpoint: Endpoint = args
        .next()
        .unwrap_or_else(|| "unix:/run/envlight/envlight.sock".to_owned())
        .parse()?;
    let max_lights: u32 = args.next().map_or(Ok(16), |n| n.parse())?;
    let request = Request {
        max_lights,
        format: Format::Binary,
        ..Request::default()
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
