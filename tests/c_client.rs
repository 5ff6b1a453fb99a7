//! The C client (examples/c/envlight_client.h and examples/c/subscribe.c), built with the
//! system's C compiler (`cc`, or `$CC`; the socket layer's harness also as C++, `c++` or
//! `$CXX`): its decoder gives the same answer as envlight's own on thousands of valid, damaged
//! and random messages of every type and representation; its socket layer reassembles streams
//! served in pieces of any size and ends them as envlight would; and the example reads a
//! running daemon's lights, ASG sets, wavelet sets and spherical-harmonic (SH) sets bit for bit
//! as a Rust client does.

mod common;
mod splitmix;

use common::{config, spawn, TIMEOUT};
use envlight::daemon::{Daemon, DaemonOptions};
use envlight::stream::client::{Client, Endpoint};
use envlight::stream::protocol::decode_message;
use envlight::stream::{Format, Message, ProtocolError, Representation, Request};
use splitmix::SplitMix64;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// The language a C file is built as: the header is meant for both.
#[derive(Clone, Copy, Debug)]
enum Language {
    C,
    Cpp,
}

/// Compiles one C file (strict C99, or C++11 for [`Language::Cpp`]; every warning an error)
/// into the tests' scratch directory, with `$CC` or `cc` (`$CXX` or `c++`). A missing
/// compiler fails the test: it is part of what is tested.
fn compile_as(source: &str, name: &str, language: Language) -> PathBuf {
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let (variable, default, flags): (_, _, &[&str]) = match language {
        Language::C => ("CC", "cc", &["-std=c99"]),
        Language::Cpp => ("CXX", "c++", &["-x", "c++", "-std=c++11"]),
    };
    let cc = std::env::var(variable).unwrap_or_else(|_| default.to_owned());
    let result = Command::new(&cc)
        .args(flags)
        .args([
            "-Wall",
            "-Wextra",
            "-pedantic",
            "-Wshadow",
            "-Werror",
            "-O2",
        ])
        .arg("-o")
        .arg(&out)
        .arg(source)
        .arg("-lm")
        .output()
        .unwrap_or_else(|e| panic!("cannot run the compiler {cc:?}: {e}"));
    assert!(
        result.status.success(),
        "{cc} {source}:\n{}",
        String::from_utf8_lossy(&result.stderr)
    );
    out
}

fn compile(source: &str, name: &str) -> PathBuf {
    compile_as(source, name, Language::C)
}

/// Runs a compiled test program to its end; fails the test (with its stderr) unless it exits
/// successfully; returns its stdout.
fn run_ok(command: &mut Command, what: &str) -> String {
    let out = command.output().unwrap();
    assert!(
        out.status.success(),
        "{what}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// The sequence number of a frame of any representation.
fn frame_seq(message: &Message) -> u64 {
    match message {
        Message::Frame(f) => f.seq,
        Message::Asg(a) => a.seq,
        Message::Wavelet(w) => w.seq,
        Message::Sh(h) => h.seq,
        other => panic!("not a frame: {other:?}"),
    }
}

type Rng = SplitMix64;

/// A float: usually an ordinary value; with probability `dirty` a special one (±0, subnormal,
/// the largest, ±∞, NaN) or random bits.
fn random_float(rng: &mut Rng, dirty: f64) -> f32 {
    if !rng.chance(dirty) {
        return rng.uniform_f32(-100.0, 100.0);
    }
    let specials = [
        0.0,
        -0.0,
        f32::from_bits(1),
        f32::MAX,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::NAN,
    ];
    if rng.chance(0.5) {
        specials[rng.below(specials.len() as u64) as usize]
    } else {
        f32::from_bits(rng.next_u64() as u32)
    }
}

fn push_f32s(out: &mut Vec<u8>, values: &[f32]) {
    for v in values {
        out.extend(v.to_le_bytes());
    }
}

/// A whole message: length prefix, magic, version 1, `kind`, `body`.
fn message(kind: u16, body: &[u8]) -> Vec<u8> {
    let mut m = Vec::with_capacity(12 + body.len());
    m.extend((8 + body.len() as u32).to_le_bytes());
    m.extend(b"ENVL");
    m.extend(1u16.to_le_bytes());
    m.extend(kind.to_le_bytes());
    m.extend(body);
    m
}

/// The 24 fixed bytes of a frame body.
fn frame_head(rng: &mut Rng, representation: u8, count: usize) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend(rng.next_u64().to_le_bytes());
    let time = if rng.chance(0.03) {
        f64::from_bits(rng.next_u64())
    } else {
        f64::from(rng.uniform_f32(0.0, 1e4))
    };
    b.extend(time.to_le_bytes());
    b.push(representation);
    b.push(rng.next_u64() as u8); // flags: only bit 0 means something
    b.extend((rng.next_u64() as u16).to_le_bytes()); // reserved: ignored
    let count = if rng.chance(0.05) {
        (count as u32)
            .wrapping_add(rng.below(3) as u32)
            .wrapping_sub(1)
    } else {
        count as u32
    };
    b.extend(count.to_le_bytes());
    b
}

fn lights_frame(rng: &mut Rng) -> Vec<u8> {
    let count = if rng.chance(0.02) {
        1000
    } else {
        rng.below(12) as usize
    };
    let dirty = if rng.chance(0.8) { 0.0 } else { 0.05 };
    let mut b = frame_head(rng, 0, count);
    for _ in 0..count {
        b.extend((rng.next_u64() as u32).to_le_bytes());
        let floats: Vec<f32> = (0..7).map(|_| random_float(rng, dirty)).collect();
        push_f32s(&mut b, &floats);
    }
    message(1, &b)
}

fn normalized(v: [f32; 3]) -> [f32; 3] {
    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    v.map(|x| x / len)
}

fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// A lobe record: an orthonormal frame, sometimes bent or stretched around the 10⁻³
/// tolerance, and bandwidths and integral that are sometimes not positive.
fn lobe_record(rng: &mut Rng, out: &mut Vec<u8>) {
    let mut random_vector = || [0; 3].map(|_: i32| rng.uniform_f32(-1.0, 1.0));
    let axis = normalized(random_vector());
    let mut tangent = normalized(cross(axis, random_vector()));
    let mut axis = axis;
    if rng.chance(0.3) {
        let stretch = 1.0 + rng.uniform_f32(-2e-3, 2e-3);
        if rng.chance(0.5) {
            axis = axis.map(|x| x * stretch);
        } else {
            tangent = tangent.map(|x| x * stretch);
        }
    }
    if rng.chance(0.2) {
        let bend = rng.uniform_f32(-2e-3, 2e-3);
        tangent = [0, 1, 2].map(|k| tangent[k] + bend * axis[k]);
    }
    let mut positive = || {
        if rng.chance(0.05) {
            [0.0, -1.0, f32::from_bits(1), -0.0][rng.below(4) as usize]
        } else {
            rng.uniform_f32(0.01, 50.0)
        }
    };
    let (lambda, mu, integral) = (positive(), positive(), positive());
    let rgb = [
        random_float(rng, 0.02),
        random_float(rng, 0.02),
        random_float(rng, 0.02),
    ];
    out.extend((rng.next_u64() as u32).to_le_bytes());
    push_f32s(out, &axis);
    push_f32s(out, &tangent);
    push_f32s(out, &[lambda, mu]);
    push_f32s(out, &rgb);
    push_f32s(out, &[integral]);
}

fn asg_frame(rng: &mut Rng) -> Vec<u8> {
    let count = rng.below(6) as usize;
    let mut b = frame_head(rng, 1, count);
    for _ in 0..count {
        lobe_record(rng, &mut b);
    }
    message(1, &b)
}

fn wavelet_frame(rng: &mut Rng) -> Vec<u8> {
    let count = rng.below(10) as usize;
    let mut b = frame_head(rng, 2, count);
    let bases = [1u8, 2, 3, 4, 5, 6, 7, 8, 9, 10, 17, 18, 19, 20, 21];
    let basis = if rng.chance(0.9) {
        bases[rng.below(bases.len() as u64) as usize]
    } else {
        rng.next_u64() as u8
    };
    let log_side = 1 + rng.below(15) as u32;
    let side: u32 = match rng.below(20) {
        0 => [0, 1, 3, 48, 1 << 16, u32::MAX][rng.below(6) as usize],
        _ => 1 << log_side,
    };
    let levels = match rng.below(20) {
        0 => log_side + 1,
        1 => rng.next_u64() as u8 as u32,
        _ => rng.below(u64::from(log_side) + 1) as u32,
    };
    let map = if rng.chance(0.95) {
        0
    } else {
        rng.next_u64() as u8
    };
    b.extend([basis, levels as u8, map, rng.next_u64() as u8]);
    b.extend(side.to_le_bytes());
    let cells = u64::from(side).pow(2).max(1);
    let mut index = rng.below(cells.min(8)) as u32;
    let dirty = if rng.chance(0.85) { 0.0 } else { 0.05 };
    for _ in 0..count {
        let written = match rng.below(40) {
            0 => index.saturating_sub(1),
            1 => side.saturating_mul(side),
            _ => index,
        };
        b.extend(written.to_le_bytes());
        let rgb = [
            random_float(rng, dirty),
            random_float(rng, dirty),
            random_float(rng, dirty),
        ];
        push_f32s(&mut b, &rgb);
        index = index.saturating_add(1 + rng.below(cells / 16 + 1) as u32);
    }
    message(1, &b)
}

/// An SH frame: usually a valid set of a small degree, up to 15 now and then; sometimes a
/// basis code other than 0, a degree above 15, a count other than (degree + 1)² (the length
/// still that of the count) or non-finite values.
fn sh_frame(rng: &mut Rng) -> Vec<u8> {
    let degree = match rng.below(20) {
        0 => 16 + rng.below(240) as u32,
        1..=3 => rng.below(16) as u32,
        _ => rng.below(4) as u32,
    };
    let count = match rng.below(20) {
        0 => ((degree + 1) * (degree + 1))
            .wrapping_add(rng.below(3) as u32)
            .wrapping_sub(1),
        1 if degree > 15 => rng.below(8) as u32,
        _ => (degree + 1) * (degree + 1),
    }
    .min(1000) as usize;
    let mut b = frame_head(rng, 3, count);
    let basis = if rng.chance(0.95) {
        0
    } else {
        rng.next_u64() as u8
    };
    b.extend([degree as u8, basis]);
    b.extend((rng.next_u64() as u16).to_le_bytes()); // reserved: ignored
    let dirty = if rng.chance(0.85) { 0.0 } else { 0.02 };
    for _ in 0..count {
        let rgb = [
            random_float(rng, dirty),
            random_float(rng, dirty),
            random_float(rng, dirty),
        ];
        push_f32s(&mut b, &rgb);
    }
    message(1, &b)
}

/// Text of an error or goodbye: ASCII, valid multi-byte characters, and now and then a byte
/// sequence that is not UTF-8 (overlong forms, surrogates, beyond U+10FFFF, cut short).
fn text(rng: &mut Rng) -> Vec<u8> {
    let pieces: [&[u8]; 12] = [
        b"a",
        b"envlight ",
        "é".as_bytes(),
        "€".as_bytes(),
        "\u{fffd}".as_bytes(),
        "😀".as_bytes(),
        &[0xc0, 0x80],
        &[0xed, 0xa0, 0x80],
        &[0xf4, 0x90, 0x80, 0x80],
        &[0xe0, 0x80, 0x80],
        &[0xe2, 0x82],
        &[0xff],
    ];
    let mut t = Vec::new();
    for _ in 0..rng.below(8) {
        let piece = if rng.chance(0.85) {
            pieces[rng.below(6) as usize]
        } else {
            pieces[6 + rng.below(6) as usize]
        };
        t.extend(piece);
    }
    if rng.chance(0.05) {
        t.push(rng.next_u64() as u8);
    }
    t
}

fn closing(rng: &mut Rng) -> Vec<u8> {
    let text = text(rng);
    let mut b = Vec::new();
    b.extend((rng.below(8) as u16).to_le_bytes());
    let len = if rng.chance(0.05) {
        (text.len() as u32)
            .wrapping_add(rng.below(3) as u32)
            .wrapping_sub(1)
    } else {
        text.len() as u32
    };
    b.extend(len.to_le_bytes());
    b.extend(text);
    message(if rng.chance(0.5) { 2 } else { 3 }, &b)
}

fn subscribe(rng: &mut Rng) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend((rng.next_u64() as u32).to_le_bytes());
    b.push(rng.below(5) as u8);
    b.push(rng.below(3) as u8);
    b.extend((rng.next_u64() as u16).to_le_bytes());
    if rng.chance(0.05) {
        b.pop();
    }
    message(16, &b)
}

/// Damages a message: a changed byte, a cut, bytes after it, or a new length prefix,
/// version or type.
fn damage(rng: &mut Rng, m: &mut Vec<u8>) {
    match rng.below(6) {
        0 if !m.is_empty() => {
            let at = rng.below(m.len() as u64) as usize;
            m[at] = rng.next_u64() as u8;
        }
        1 => m.truncate(rng.below(m.len() as u64 + 1) as usize),
        2 => m.extend((0..1 + rng.below(8)).map(|_| rng.next_u64() as u8)),
        3 if m.len() >= 4 => {
            let len = match rng.below(3) {
                0 => rng.next_u64() as u32,
                1 => rng.below(16) as u32,
                _ => (1 << 20) + 1,
            };
            m[..4].copy_from_slice(&len.to_le_bytes());
        }
        4 if m.len() >= 10 => m[8..10].copy_from_slice(&(rng.below(4) as u16).to_le_bytes()),
        _ if m.len() >= 12 => {
            let kinds = [0u16, 1, 2, 3, 4, 15, 16, 17, 0xffff];
            let kind = kinds[rng.below(kinds.len() as u64) as usize];
            m[10..12].copy_from_slice(&kind.to_le_bytes());
        }
        _ => {}
    }
}

fn cases(seed: u64, n: usize) -> Vec<Vec<u8>> {
    let mut rng = SplitMix64(seed);
    (0..n)
        .map(|_| {
            let mut m = match rng.below(15) {
                0..=2 => lights_frame(&mut rng),
                3..=5 => asg_frame(&mut rng),
                6..=8 => wavelet_frame(&mut rng),
                9..=11 => sh_frame(&mut rng),
                12 => closing(&mut rng),
                13 => subscribe(&mut rng),
                _ => (0..rng.below(48)).map(|_| rng.next_u64() as u8).collect(),
            };
            if rng.chance(0.25) {
                damage(&mut rng, &mut m);
            }
            m
        })
        .collect()
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().fold(String::new(), |mut s, b| {
        let _ = write!(s, "{b:02x}");
        s
    })
}

fn floats(out: &mut String, values: &[f32]) {
    for v in values {
        let _ = write!(out, ":{:08x}", v.to_bits());
    }
}

/// envlight's decoding of one message, in the line format of tests/c/decode_cases.c.
fn canonical(result: Result<Message, ProtocolError>) -> String {
    let frame = |seq: u64, time: f64, representation: u8, stale: bool, count: usize| {
        format!(
            "frame {seq} {:016x} {representation} {} {count}",
            time.to_bits(),
            u8::from(stale)
        )
    };
    match result {
        Err(e) => format!("err {}", e.code()),
        Ok(Message::Frame(f)) => {
            let mut s = frame(f.seq, f.time, 0, f.stale, f.lights.len());
            for l in &f.lights {
                let _ = write!(s, " {}", l.id);
                floats(&mut s, &l.dir);
                floats(&mut s, &l.rgb);
                floats(&mut s, &[l.solid_angle]);
            }
            s
        }
        Ok(Message::Sh(h)) => {
            let mut s = frame(h.seq, h.time, 3, h.stale, h.coefficients.len());
            for rgb in &h.coefficients {
                floats(&mut s, rgb);
            }
            s
        }
        Ok(Message::Asg(a)) => {
            let mut s = frame(a.seq, a.time, 1, a.stale, a.lobes.len());
            for g in &a.lobes {
                let _ = write!(s, " {}", g.id);
                floats(&mut s, &g.axis);
                floats(&mut s, &g.tangent);
                floats(&mut s, &[g.lambda, g.mu]);
                floats(&mut s, &g.rgb);
                floats(&mut s, &[g.integral]);
            }
            s
        }
        Ok(Message::Wavelet(w)) => {
            let set = &w.set;
            let mut s = frame(w.seq, w.time, 2, w.stale, set.coefficients.len());
            let _ = write!(s, " {} {} 0 {}", set.basis.code(), set.levels, set.side);
            for (index, rgb) in &set.coefficients {
                let _ = write!(s, " {index}");
                floats(&mut s, rgb);
            }
            s
        }
        Ok(Message::Error { code, message }) => format!("error {code} {}", hex(message.as_bytes())),
        Ok(Message::Goodbye { message }) => format!("goodbye {}", hex(message.as_bytes())),
        Ok(Message::Subscribe(r)) => format!(
            "subscribe {} {} {}",
            r.max_lights,
            r.representation.code(),
            r.format.code()
        ),
    }
}

#[test]
fn the_c_decoder_answers_every_message_as_envlight_does() {
    let program = compile("tests/c/decode_cases.c", "c_decode_cases");
    let cases = cases(0x00c0_ffee, 6000);
    let mut input = Vec::new();
    for case in &cases {
        input.extend((case.len() as u32).to_le_bytes());
        input.extend(case);
    }
    let dir = tempfile::tempdir().unwrap();
    let input_path = dir.path().join("cases.bin");
    std::fs::write(&input_path, &input).unwrap();
    let text = run_ok(
        Command::new(&program).stdin(std::fs::File::open(&input_path).unwrap()),
        "decode_cases",
    );
    let answers: Vec<&str> = text.lines().collect();
    assert_eq!(answers.len(), cases.len(), "one answer per case");

    // What the cases cover, from envlight's answers: every message type and representation
    // decoded, and every error code the bytes can earn.
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    for (i, (case, c_answer)) in cases.iter().zip(&answers).enumerate() {
        let expected = canonical(decode_message(case));
        assert_eq!(
            *c_answer,
            expected,
            "case {i}: the C decoder disagrees with envlight's on {}",
            hex(case)
        );
        let kind = match expected.split(' ').collect::<Vec<_>>().as_slice() {
            ["frame", _, _, representation, ..] => format!("frame {representation}"),
            [word, code] if *word == "err" => format!("err {code}"),
            [word, ..] => (*word).to_owned(),
            [] => String::new(),
        };
        *seen.entry(kind).or_default() += 1;
    }
    for (kind, at_least) in [
        ("frame 0", 300),
        ("frame 1", 300),
        ("frame 2", 200),
        ("frame 3", 300),
        ("error", 50),
        ("goodbye", 50),
        ("subscribe", 100),
        ("err 1", 500),
        ("err 2", 20),
        ("err 3", 20),
        ("err 4", 20),
        ("err 5", 20),
    ] {
        let n = seen.get(kind).copied().unwrap_or(0);
        assert!(n >= at_least, "only {n} cases of {kind}: {seen:?}");
    }
}

/// One subscription's frames from the C example (`--json`, four frames, and `extra`
/// arguments) as canonical lines, and its sequence numbers.
fn c_frames(
    program: &Path,
    address: &str,
    representation: &str,
    cap: u32,
    extra: &[&str],
) -> Vec<(u64, String)> {
    let text = run_ok(
        Command::new(program)
            .args([address, "--json", "--frames", "4", "--representation"])
            .arg(representation)
            .args(["--max-lights", &cap.to_string()])
            .args(extra),
        &format!("subscribe {address} {representation}"),
    );
    text.lines()
        .map(|line| {
            let message = envlight::stream::protocol::parse_json_message(line)
                .unwrap_or_else(|e| panic!("not a frame ({e}): {line}"));
            (frame_seq(&message), canonical(Ok(message)))
        })
        .collect()
}

#[test]
fn the_c_example_reads_the_daemon_bit_for_bit() {
    let program = compile("examples/c/subscribe.c", "c_subscribe");
    let dir = tempfile::tempdir().unwrap();
    let extra = "[source]\nfps = 30.0\nframes = 0\n[sky]\nwidth = 32\nheight = 16\n\
                 [decompose]\nlights = 8\nworking_width = 16\n\
                 [asg]\nenabled = true\nlobes = 4\nfit_height = 8\niterations = 40\n\
                 warm_iterations = 8\ndiffuse_normals = 16\nthreads = 1\n\
                 [wavelet]\nenabled = true\nside = 16\ncoefficients = 40\n\
                 [sh]\nenabled = true\ndegree = 3\n";
    let daemon = Daemon::start(config(dir.path(), 2.0, extra), DaemonOptions::default()).unwrap();
    let stream = &daemon.addresses().stream;
    let unix = format!("unix:{}", stream.unix_socket.clone().unwrap().display());
    let tcp = stream.tcp.unwrap().to_string();
    // The last one is a render loop that takes the newest frame every 200 ms without waiting
    // (`--poll`, envlight_poll): at 30 frames/s it skips some.
    for (address, name, representation, cap, extra) in [
        (&unix, "lights", Representation::Lights, 0, &[][..]),
        (&tcp, "lights", Representation::Lights, 3, &[]),
        (&unix, "asg", Representation::Asg, 2, &[]),
        (&tcp, "wavelet", Representation::Wavelet, 5, &[]),
        // Degree 3 (16 coefficients) capped to the bands that fit in 4: degrees 0 and 1.
        (&unix, "sh", Representation::Sh, 4, &[]),
        (
            &unix,
            "lights",
            Representation::Lights,
            4,
            &["--poll", "200"],
        ),
    ] {
        // A Rust client with the same subscription reads alongside until it has passed the
        // last frame the C client printed.
        let endpoint: Endpoint = address.parse().unwrap();
        let request = Request {
            max_lights: cap,
            representation,
            format: Format::Binary,
        };
        let mut client = Client::connect(&endpoint, &request, Some(TIMEOUT)).unwrap();
        let stop_after = Arc::new(AtomicU64::new(u64::MAX));
        let stop = Arc::clone(&stop_after);
        let rust = spawn("rust-client", move || {
            let mut frames = BTreeMap::new();
            loop {
                let message = client.next_message().unwrap().expect("a frame");
                let seq = frame_seq(&message);
                frames.insert(seq, canonical(Ok(message)));
                if seq >= stop.load(Ordering::Acquire) {
                    return frames;
                }
            }
        });
        let c = c_frames(&program, address, name, cap, extra);
        stop_after.store(c.last().map_or(0, |f| f.0), Ordering::Release);
        let rust = rust.join().unwrap();
        assert_eq!(c.len(), 4, "{address} {name}: {c:?}");
        assert!(c.windows(2).all(|w| w[0].0 < w[1].0), "{c:?}");
        let mut compared = 0;
        for (seq, line) in &c {
            if let Some(expected) = rust.get(seq) {
                assert_eq!(line, expected, "{address} {name} seq {seq}");
                compared += 1;
            }
        }
        assert!(compared >= 1, "{address} {name}: no frame in common: {c:?}");
        // The cap holds (the sky's frames have more lights, lobes and coefficients). An SH
        // line's coefficients follow its count without a space.
        let counts: Vec<&str> = c
            .iter()
            .filter_map(|(_, l)| l.split(' ').nth(5)?.split(':').next())
            .collect();
        let expected = if cap == 0 {
            "8".to_owned()
        } else {
            cap.to_string()
        };
        assert!(
            counts.iter().all(|n| *n == expected),
            "{address} {name}: {counts:?}"
        );
        if !extra.is_empty() {
            assert!(
                c.windows(2).any(|w| w[1].0 > w[0].0 + 1),
                "nothing skipped: {c:?}"
            );
        }
    }
    daemon.shutdown().unwrap();
}

/// How a served stream ends.
#[derive(Clone, Copy, Debug)]
enum Ending {
    /// A goodbye with some text.
    Goodbye,
    /// The daemon's error message, code 5.
    Error,
    /// A message with a bad magic.
    Garbage,
    /// A frame whose light has a NaN direction (a body the decoder rejects).
    BadBody,
    /// The connection closes inside a message.
    Truncated,
    /// The connection closes between messages, without a goodbye.
    Closed,
}

/// A stream of valid frames of every representation (a few large ones: 8,000 and 32,000
/// lights, 256 KB and 1 MB), then `ending`. Returns the bytes, the canonical lines of the
/// frames, and the lines the C client must end with.
fn served_stream(seed: u64, ending: Ending) -> (Vec<u8>, Vec<String>, Vec<String>) {
    let mut rng = SplitMix64(seed);
    let mut bytes = Vec::new();
    let mut frames = Vec::new();
    while frames.len() < 60 {
        let m = match rng.below(5) {
            0 => lights_frame(&mut rng),
            1 => asg_frame(&mut rng),
            2 => wavelet_frame(&mut rng),
            3 => sh_frame(&mut rng),
            _ => {
                let count = if rng.chance(0.5) { 8000 } else { 32_000 };
                let mut b = Vec::new();
                b.extend(rng.next_u64().to_le_bytes());
                b.extend(1.5f64.to_le_bytes());
                b.extend([0, 0, 0, 0]);
                b.extend((count as u32).to_le_bytes());
                for i in 0..count {
                    b.extend((i as u32).to_le_bytes());
                    let floats: Vec<f32> = (0..7).map(|_| random_float(&mut rng, 0.0)).collect();
                    push_f32s(&mut b, &floats);
                }
                message(1, &b)
            }
        };
        match decode_message(&m) {
            Ok(
                decoded @ (Message::Frame(_)
                | Message::Asg(_)
                | Message::Wavelet(_)
                | Message::Sh(_)),
            ) => {
                frames.push(canonical(Ok(decoded)));
                bytes.extend(m);
            }
            _ => continue,
        }
    }
    let text = "envlight shutting down ✓";
    let end = match ending {
        Ending::Goodbye => {
            let mut b = Vec::new();
            envlight::stream::protocol::encode_goodbye(text, &mut b);
            bytes.extend(b);
            vec![
                "end 0".to_owned(),
                format!("goodbye {}", hex(text.as_bytes())),
            ]
        }
        Ending::Error => {
            let mut b = Vec::new();
            envlight::stream::protocol::encode_error(5, "bad request", &mut b);
            bytes.extend(b);
            vec!["end 5".to_owned()]
        }
        Ending::Garbage => {
            bytes.extend(b"\x10\x00\x00\x00ENVX\x01\x00\x01\x00 more bytes after it");
            vec!["end 1".to_owned()]
        }
        Ending::BadBody => {
            let mut b = Vec::new();
            b.extend(7u64.to_le_bytes());
            b.extend(0.5f64.to_le_bytes());
            b.extend([0, 0, 0, 0]);
            b.extend(1u32.to_le_bytes());
            b.extend(3u32.to_le_bytes());
            push_f32s(&mut b, &[f32::NAN, 1.0, 0.0, 1.0, 1.0, 1.0, 0.1]);
            bytes.extend(message(1, &b));
            vec!["end 1".to_owned()]
        }
        Ending::Truncated => {
            let last = lights_frame(&mut rng);
            bytes.extend(&last[..last.len() / 2]);
            vec!["end 1".to_owned()]
        }
        Ending::Closed => vec!["end 1000".to_owned()],
    };
    (bytes, frames, end)
}

/// Serves `bytes` to one client on a loopback port, in pieces of 1 byte to 100 KB with short
/// pauses, after reading its 20-byte subscribe; then closes.
fn serve_in_pieces(
    bytes: Vec<u8>,
    seed: u64,
) -> (std::net::SocketAddr, std::thread::JoinHandle<()>) {
    use std::io::{Read, Write};
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let address = listener.local_addr().unwrap();
    let server = spawn("piece server", move || {
        let (mut socket, _) = listener.accept().unwrap();
        let mut subscribe = [0u8; 20];
        socket.read_exact(&mut subscribe).unwrap();
        assert_eq!(&subscribe[4..8], b"ENVL");
        let mut rng = SplitMix64(seed);
        let mut rest = &bytes[..];
        while !rest.is_empty() {
            let size = match rng.below(4) {
                0 => 1 + rng.below(16),
                1 => 1 + rng.below(2000),
                _ => 1 + rng.below(100_000),
            } as usize;
            let (piece, tail) = rest.split_at(size.min(rest.len()));
            socket.write_all(piece).unwrap();
            rest = tail;
            if rng.chance(0.2) {
                std::thread::sleep(std::time::Duration::from_millis(1));
            }
        }
    });
    (address, server)
}

#[test]
fn the_c_client_reassembles_streams_in_any_pieces() {
    let programs = [
        compile("tests/c/stream_cases.c", "c_stream_cases"),
        compile_as("tests/c/stream_cases.c", "cpp_stream_cases", Language::Cpp),
    ];
    let endings = [
        Ending::Goodbye,
        Ending::Error,
        Ending::Garbage,
        Ending::BadBody,
        Ending::Truncated,
        Ending::Closed,
    ];
    for (k, ending) in endings.into_iter().enumerate() {
        // The C build in both modes, the C++ build of the same file in one.
        for (program, mode) in [
            (&programs[0], "next"),
            (&programs[0], "poll"),
            (&programs[1], if k % 2 == 0 { "next" } else { "poll" }),
        ] {
            let seed = 100 + k as u64;
            let (bytes, frames, end) = served_stream(seed, ending);
            let (address, server) = serve_in_pieces(bytes, seed + 1000);
            let text = run_ok(
                Command::new(program).args([&address.to_string(), mode]),
                &format!("stream_cases {ending:?} {mode}"),
            );
            server.join().unwrap();
            let lines: Vec<&str> = text.lines().collect();
            let at_end = lines.iter().position(|l| l.starts_with("end ")).unwrap();
            let (got, tail) = lines.split_at(at_end);
            assert_eq!(tail, end, "{ending:?} {mode}");
            if mode == "next" {
                // Every frame, in order.
                assert_eq!(got.len(), frames.len(), "{ending:?} {mode}");
                for (i, (a, b)) in got.iter().zip(&frames).enumerate() {
                    assert_eq!(a, b, "{ending:?} {mode}: frame {i}");
                }
            } else {
                // The newest at each call: frames in order, some skipped, the last one never.
                let mut expected = frames.iter();
                for line in got {
                    assert!(
                        expected.any(|f| f == line),
                        "{ending:?} {mode}: a frame out of order or unknown"
                    );
                }
                assert_eq!(got.last().copied(), frames.last().map(String::as_str));
            }
        }
    }
}
