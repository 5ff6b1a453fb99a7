//! `envlight subscribe`: a client of a running daemon that prints its stream (lights, ASG,
//! wavelet or SH sets) as summary lines or JSON.

use anyhow::{anyhow, bail, Context, Result};
use clap::{Args, ValueEnum};
use std::io::Write;

pub(crate) const LONG_ABOUT: &str = "\
Connect to a running envlight daemon and print the light lists it streams, until the daemon
says goodbye (or --frames have arrived).

ADDR is unix:PATH (or a path: one with a `/`, or an existing file), tcp:HOST:PORT (or
HOST:PORT), or ws://HOST:PORT/.
With --json every frame is printed as one JSON line (docs/protocol.md's JSON form); otherwise
one summary line per frame. --representation asg prints the ASG sets of a daemon whose [asg]
stage is enabled (--max-lights then caps the lobes); --representation wavelet the wavelet
coefficient sets of a daemon whose [wavelet] stage is enabled (--max-lights then caps the
coefficients: the scaling coefficient first, then the largest; the summary line's total rgb is
∫L dω from the scaling coefficient); --representation sh the spherical-harmonic coefficients of
a daemon whose [sh] stage is enabled (--max-lights N then keeps the bands that fit in N
coefficients: 4 = degrees 0 and 1; the summary line gives ∫L dω and the irradiance of an
upward-facing surface).";

#[derive(Args, Debug)]
pub(crate) struct SubscribeArgs {
    /// Where the daemon listens: unix:PATH, tcp:HOST:PORT, HOST:PORT or ws://HOST:PORT/.
    #[arg(value_name = "ADDR")]
    address: envlight::stream::client::Endpoint,
    /// Print every frame as a JSON line.
    #[arg(long)]
    json: bool,
    /// Ask for at most N lights per frame (the brightest); 0 = all.
    #[arg(long, value_name = "N", default_value_t = 0)]
    max_lights: u32,
    /// Stop after N frames (0: no limit, as without it).
    #[arg(long, value_name = "N")]
    frames: Option<u64>,
    /// Fail when the daemon sends nothing for this many seconds (the connection and its
    /// upgrade included). [default: wait for ever: a daemon paced slowly, replaying a pause or
    /// waiting for its camera may be silent for long]
    #[arg(long, value_name = "SECONDS", value_parser = parse_timeout)]
    timeout: Option<f64>,
    /// What to receive: directional lights, ASG sets (the daemon needs [asg] enabled),
    /// wavelet coefficient sets (needs [wavelet] enabled) or spherical-harmonic sets (needs
    /// [sh] enabled); --max-lights then caps the lobes or the coefficients (the largest
    /// wavelet coefficients, the lowest SH bands).
    #[arg(long, value_enum, default_value = "lights")]
    representation: RepresentationArg,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum RepresentationArg {
    /// Directional lights.
    Lights,
    /// Anisotropic spherical Gaussians.
    Asg,
    /// Sparse wavelet coefficients of the environment (equal-area octahedral map).
    Wavelet,
    /// Spherical-harmonic coefficients of the environment's radiance.
    Sh,
}

/// `--timeout SECONDS` of `subscribe`: from a millisecond to a day.
fn parse_timeout(text: &str) -> Result<f64, String> {
    let seconds: f64 = text
        .parse()
        .map_err(|_| format!("{text:?} is not a number of seconds"))?;
    if (0.001..=86_400.0).contains(&seconds) {
        Ok(seconds)
    } else {
        Err(format!("{text} s: must be in 0.001..=86400"))
    }
}

pub(crate) fn run(args: &SubscribeArgs) -> Result<()> {
    use envlight::stream::client::Client;
    use envlight::stream::{Format, Message, Representation, Request};
    let request = Request {
        max_lights: args.max_lights,
        format: if args.json {
            Format::Json
        } else {
            Format::Binary
        },
        representation: match args.representation {
            RepresentationArg::Lights => Representation::Lights,
            RepresentationArg::Asg => Representation::Asg,
            RepresentationArg::Wavelet => Representation::Wavelet,
            RepresentationArg::Sh => Representation::Sh,
        },
    };
    let timeout = args.timeout.map(std::time::Duration::from_secs_f64);
    let timed_out = |e: envlight::stream::client::ClientError| {
        if e.is_timeout() {
            anyhow!(
                "{}: no message within {} s (--timeout)",
                args.address,
                args.timeout.unwrap_or_default()
            )
        } else {
            anyhow!(e)
        }
    };
    let mut client = Client::connect(&args.address, &request, timeout).map_err(|e| {
        use envlight::stream::client::ClientError;
        use std::io::ErrorKind;
        match &e {
            ClientError::Io { source, .. }
                if matches!(
                    source.kind(),
                    ErrorKind::ConnectionRefused | ErrorKind::NotFound
                ) =>
            {
                anyhow!(
                    "{e}; is `envlight run` serving there? (by default it listens on \
                     unix:/run/envlight/envlight.sock, tcp:127.0.0.1:7878 and \
                     ws://127.0.0.1:7879/)"
                )
            }
            _ => timed_out(e),
        }
    })?;
    let mut stdout = std::io::stdout().lock();
    let mut frames = 0u64;
    // --frames 0 is no limit, as for every command (it stopped at once, printing nothing).
    let limit = args.frames.filter(|&n| n > 0);
    while limit.is_none_or(|n| frames < n) {
        let Some(message) = client.next_message().map_err(timed_out)? else {
            bail!("{}: the daemon closed the connection", args.address);
        };
        // A frame of another representation than the one asked for is the server's fault, and
        // printing it as if it were asked for would mislead (it was printed; an audit).
        let sent = match &message {
            Message::Frame(_) => Some(Representation::Lights),
            Message::Asg(_) => Some(Representation::Asg),
            Message::Wavelet(_) => Some(Representation::Wavelet),
            Message::Sh(_) => Some(Representation::Sh),
            _ => None,
        };
        if let Some(sent) = sent.filter(|&sent| sent != request.representation) {
            bail!(
                "{}: the server sent a frame of representation {sent:?} on a subscription to \
                 {:?}; it does not follow the protocol (docs/protocol.md)",
                args.address,
                request.representation
            );
        }
        let line = match message {
            Message::Frame(frame) => {
                frames += 1;
                if args.json {
                    let stale = frame.stale;
                    envlight::stream::protocol::frame_to_json(
                        &frame.into_light_frame(),
                        None,
                        stale,
                    )
                } else {
                    let total = frame.lights.iter().fold([0.0f64; 3], |s, l| {
                        [0, 1, 2].map(|c| s[c] + f64::from(l.rgb[c]))
                    });
                    format!(
                        "seq {} time {:.3} s: {} lights, total rgb [{:.4}, {:.4}, {:.4}]{}",
                        frame.seq,
                        frame.time,
                        frame.lights.len(),
                        total[0],
                        total[1],
                        total[2],
                        if frame.stale { " (stale)" } else { "" }
                    )
                }
            }
            Message::Asg(frame) => {
                frames += 1;
                if args.json {
                    let stale = frame.stale;
                    envlight::stream::protocol::asg_frame_to_json(
                        &frame.into_asg_set(),
                        None,
                        stale,
                    )
                } else {
                    let total = frame.lobes.iter().fold([0.0f64; 3], |s, l| {
                        [0, 1, 2].map(|c| s[c] + f64::from(l.rgb[c]) * f64::from(l.integral))
                    });
                    format!(
                        "seq {} time {:.3} s: {} ASG lobes, total rgb [{:.4}, {:.4}, {:.4}]{}",
                        frame.seq,
                        frame.time,
                        frame.lobes.len(),
                        total[0],
                        total[1],
                        total[2],
                        if frame.stale { " (stale)" } else { "" }
                    )
                }
            }
            Message::Wavelet(frame) => {
                frames += 1;
                let stale = frame.stale;
                let frame = frame.into_wavelet_frame();
                if args.json {
                    envlight::stream::protocol::wavelet_frame_to_json(&frame, None, stale)
                } else {
                    let total = frame.integral();
                    let set = &frame.set;
                    format!(
                        "seq {} time {:.3} s: {} wavelet coefficients ({} on {}², {} levels), \
                         total rgb [{:.4}, {:.4}, {:.4}]{}",
                        frame.seq,
                        frame.time,
                        set.coefficients.len(),
                        set.basis,
                        set.side,
                        set.levels,
                        total[0],
                        total[1],
                        total[2],
                        if stale { " (stale)" } else { "" }
                    )
                }
            }
            Message::Sh(frame) => {
                frames += 1;
                let stale = frame.stale;
                let frame = frame.into_sh_frame();
                if args.json {
                    envlight::stream::protocol::sh_frame_to_json(&frame, None, stale)
                } else {
                    // The decoder accepts only (degree + 1)² coefficients.
                    let set = frame
                        .to_coefficients()
                        .ok_or_else(|| anyhow!("{}: an SH frame that is no set", args.address))?;
                    let total = set.integral();
                    let up = set.irradiance(glam::DVec3::Y);
                    format!(
                        "seq {} time {:.3} s: SH degree {} ({} coefficients), total rgb \
                         [{:.4}, {:.4}, {:.4}], irradiance up [{:.4}, {:.4}, {:.4}]{}",
                        frame.seq,
                        frame.time,
                        set.degree(),
                        frame.coefficients.len(),
                        total[0],
                        total[1],
                        total[2],
                        up[0],
                        up[1],
                        up[2],
                        if stale { " (stale)" } else { "" }
                    )
                }
            }
            Message::Goodbye { message } => {
                tracing::info!("the daemon said goodbye: {message}");
                return Ok(());
            }
            Message::Error { code, message } => {
                bail!(
                    "{}: the daemon reported error {code}: {message}",
                    args.address
                )
            }
            Message::Subscribe(_) => {
                bail!("{}: unexpected subscribe from the daemon", args.address)
            }
        };
        let written = writeln!(stdout, "{line}").and_then(|()| stdout.flush());
        match written {
            Err(e) if crate::cli::output::is_broken_pipe(&e) => return Ok(()),
            r => r.context("cannot write to stdout")?,
        }
    }
    Ok(())
}
