//! The wire format (src/stream/protocol/, docs/protocol.md): round trips through the
//! incremental decoder in any chunking, light caps, hostile input, the golden byte layout.

use envlight::stream::protocol::{
    self, code, decode_message, encode_error, encode_frame, encode_goodbye, encode_request,
    frame_to_json, parse_json_message, parse_json_request, request_to_json, Decoder, Format,
    FrameMessage, Message, ProtocolError, Representation, Request, MAX_MESSAGE_LEN,
};
use envlight::{Light, LightFrame};
use proptest::prelude::*;

/// Small deterministic generator (xorshift64*), so failures reproduce.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
}

fn random_frame(n: usize, seed: u64) -> LightFrame {
    let mut rng = Rng(seed | 1);
    let lights = (0..n)
        .map(|i| {
            let z = 2.0 * rng.unit() - 1.0;
            let phi = std::f32::consts::TAU * rng.unit();
            let r = (1.0 - z * z).max(0.0).sqrt();
            let p = 1000.0 * rng.unit().powi(4);
            Light {
                id: i as u32 * 3 + 1,
                dir: [r * phi.cos(), z, r * phi.sin()],
                rgb: [p, p * rng.unit(), p * rng.unit()],
                solid_angle: 4.0 * std::f32::consts::PI / n as f32 * (0.5 + rng.unit()),
            }
        })
        .collect();
    LightFrame {
        seq: seed.wrapping_mul(7919),
        time: seed as f64 / 60.0,
        lights,
    }
}

fn as_frame(message: Message) -> FrameMessage {
    match message {
        Message::Frame(f) => f,
        other => panic!("expected a frame, got {other:?}"),
    }
}

/// Feeds `bytes` to a decoder in the given chunk sizes (cycled) and collects every message;
/// checks that nothing is returned before its last byte arrived.
fn decode_chunked(bytes: &[u8], mut chunk: impl FnMut() -> usize) -> Vec<Message> {
    let mut d = Decoder::new();
    let mut out = Vec::new();
    let mut at = 0;
    while at < bytes.len() {
        let n = chunk().clamp(1, bytes.len() - at);
        d.push(&bytes[at..at + n]);
        at += n;
        while let Some(m) = d.next_message().expect("valid stream") {
            out.push(m);
        }
    }
    d.finish().expect("stream ends on a message boundary");
    out
}

fn check_frame(decoded: &FrameMessage, frame: &LightFrame, stale: bool) {
    assert_eq!(decoded.seq, frame.seq);
    assert_eq!(decoded.time.to_bits(), frame.time.to_bits());
    assert_eq!(decoded.representation, Representation::Lights);
    assert_eq!(decoded.stale, stale);
    assert_eq!(decoded.lights.len(), frame.lights.len());
    for (a, b) in decoded.lights.iter().zip(&frame.lights) {
        assert_eq!(a.id, b.id);
        for (x, y) in a.dir.iter().chain(&a.rgb).zip(b.dir.iter().chain(&b.rgb)) {
            assert_eq!(x.to_bits(), y.to_bits());
        }
        assert_eq!(a.solid_angle.to_bits(), b.solid_angle.to_bits());
    }
}

#[test]
fn frames_round_trip_in_any_chunking() {
    for (k, n) in [0usize, 1, 256, 16384].into_iter().enumerate() {
        let frame = random_frame(n, 11 + k as u64);
        let mut bytes = Vec::new();
        encode_frame(&frame, None, k % 2 == 1, &mut bytes);
        assert_eq!(bytes.len(), 36 + 32 * n);

        let whole = decode_chunked(&bytes, || usize::MAX);
        let mut rng = Rng(99 + n as u64);
        let random = decode_chunked(&bytes, || 1 + (rng.next() % 97) as usize);
        let singles = if n <= 256 {
            decode_chunked(&bytes, || 1)
        } else {
            whole.clone()
        };
        for messages in [whole, random, singles] {
            assert_eq!(messages.len(), 1);
            check_frame(&as_frame(messages[0].clone()), &frame, k % 2 == 1);
        }
    }
}

#[test]
fn a_stream_of_mixed_messages_decodes_in_order() {
    let mut bytes = Vec::new();
    let frames: Vec<LightFrame> = (0..20).map(|i| random_frame(i * 7, i as u64 + 1)).collect();
    encode_request(
        &Request {
            max_lights: 64,
            representation: Representation::Lights,
            format: Format::Binary,
        },
        &mut bytes,
    );
    for f in &frames {
        encode_frame(f, None, false, &mut bytes);
    }
    encode_goodbye("bye", &mut bytes);
    let mut rng = Rng(5);
    let messages = decode_chunked(&bytes, || 1 + (rng.next() % 300) as usize);
    assert_eq!(messages.len(), 22);
    assert!(matches!(messages[0], Message::Subscribe(r) if r.max_lights == 64));
    for (m, f) in messages[1..21].iter().zip(&frames) {
        check_frame(&as_frame(m.clone()), f, false);
    }
    assert_eq!(
        messages[21],
        Message::Goodbye {
            message: "bye".into()
        }
    );
}

#[test]
fn truncated_stream_waits_until_complete() {
    let frame = random_frame(10, 3);
    let mut bytes = Vec::new();
    encode_frame(&frame, None, false, &mut bytes);
    let mut d = Decoder::new();
    for (i, b) in bytes.iter().enumerate() {
        assert_eq!(d.next_message(), Ok(None), "message before byte {i}");
        d.push(std::slice::from_ref(b));
    }
    check_frame(&as_frame(d.next_message().unwrap().unwrap()), &frame, false);
    assert_eq!(d.next_message(), Ok(None));

    // A stream that ends mid-message is reported by finish().
    let mut d = Decoder::new();
    d.push(&bytes[..bytes.len() - 1]);
    assert_eq!(d.next_message(), Ok(None));
    assert_eq!(
        d.finish(),
        Err(ProtocolError::Truncated {
            buffered: bytes.len() - 1
        })
    );
    assert!(matches!(
        decode_message(&bytes[..20]),
        Err(ProtocolError::Truncated { .. })
    ));
}

#[test]
fn cap_keeps_the_brightest_lights_exactly() {
    let frame = random_frame(300, 8);
    for cap in [0usize, 1, 16, 299, 300, 1000] {
        let mut bytes = Vec::new();
        encode_frame(&frame, Some(cap), false, &mut bytes);
        let decoded = as_frame(decode_message(&bytes).unwrap());
        let kept = cap.min(300);
        assert_eq!(decoded.lights.len(), kept);

        // The kept lights are the `kept` largest luminances, bit for bit, in id order.
        let mut lum: Vec<f32> = frame.lights.iter().map(Light::luminance).collect();
        lum.sort_by(|a, b| b.total_cmp(a));
        let threshold = if kept == 0 {
            f32::INFINITY
        } else {
            lum[kept - 1]
        };
        for l in &decoded.lights {
            let original = frame.lights.iter().find(|o| o.id == l.id).unwrap();
            assert_eq!(l, original);
            assert!(l.luminance() >= threshold);
        }
        assert!(decoded.lights.windows(2).all(|w| w[0].id < w[1].id));

        // The JSON form selects the same lights.
        let json = as_frame(parse_json_message(&frame_to_json(&frame, Some(cap), false)).unwrap());
        assert_eq!(json.lights, decoded.lights);
    }
}

#[test]
fn oversized_length_prefix_fails_before_buffering() {
    let mut d = Decoder::new();
    let len = (MAX_MESSAGE_LEN as u32 + 1).to_le_bytes();
    d.push(&len);
    assert_eq!(d.next_message(), Ok(None), "judged before the magic");
    d.push(b"ENVL");
    assert_eq!(
        d.next_message(),
        Err(ProtocolError::Oversized {
            len: MAX_MESSAGE_LEN as u64 + 1
        })
    );
    // Whatever follows is not stored.
    d.push(&vec![0u8; 4 << 20]);
    assert_eq!(d.buffered(), 0);
    assert!(d.next_message().is_err());

    // u32::MAX in the same push as a valid magic: rejected at the header, body never stored.
    let mut d = Decoder::new();
    let mut bytes = u32::MAX.to_le_bytes().to_vec();
    bytes.extend_from_slice(b"ENVL\x01\x00\x01\x00");
    bytes.extend_from_slice(&vec![0u8; 1 << 20]);
    d.push(&bytes);
    assert_eq!(d.buffered(), 0);
    let e = d.next_message().unwrap_err();
    assert_eq!(e.code(), code::TOO_LARGE);
    assert!(e.to_string().contains("4294967295"), "{e}");

    // The largest allowed message still decodes.
    let frame = random_frame(protocol::MAX_FRAME_LIGHTS, 2);
    let mut bytes = Vec::new();
    encode_frame(&frame, None, false, &mut bytes);
    assert!(bytes.len() - 4 <= MAX_MESSAGE_LEN);
    check_frame(&as_frame(decode_message(&bytes).unwrap()), &frame, false);
    // A longer light list is capped to what fits.
    let frame = random_frame(protocol::MAX_FRAME_LIGHTS + 5, 2);
    let mut bytes = Vec::new();
    encode_frame(&frame, None, false, &mut bytes);
    assert_eq!(
        as_frame(decode_message(&bytes).unwrap()).lights.len(),
        protocol::MAX_FRAME_LIGHTS
    );
}

#[test]
fn wrong_magic_version_type_and_inconsistent_bodies() {
    let mut good = Vec::new();
    encode_frame(&random_frame(2, 4), None, false, &mut good);

    let mut bad = good.clone();
    bad[4..8].copy_from_slice(b"GET ");
    let e = decode_message(&bad).unwrap_err();
    assert!(matches!(e, ProtocolError::BadMagic { .. }));
    assert!(e.to_string().contains("bad magic"), "{e}");

    let mut bad = good.clone();
    bad[8] = 2;
    assert_eq!(
        decode_message(&bad),
        Err(ProtocolError::UnsupportedVersion { version: 2 })
    );

    let mut bad = good.clone();
    bad[10] = 4;
    assert_eq!(
        decode_message(&bad),
        Err(ProtocolError::UnknownType { message_type: 4 })
    );

    // count disagrees with the length.
    let mut bad = good.clone();
    bad[32] = 3;
    let e = decode_message(&bad).unwrap_err();
    assert!(matches!(e, ProtocolError::Inconsistent { .. }), "{e}");
    assert!(e.to_string().contains("count 3"), "{e}");

    // Length not a whole number of light records.
    let mut bad = good.clone();
    bad[0] += 1;
    bad.push(0);
    assert!(matches!(
        decode_message(&bad),
        Err(ProtocolError::Inconsistent { .. })
    ));

    // Non-finite light values.
    let mut bad = good.clone();
    bad[36 + 16..36 + 20].copy_from_slice(&f32::NAN.to_le_bytes());
    let e = decode_message(&bad).unwrap_err();
    assert!(matches!(e, ProtocolError::NonFinite { .. }));
    assert!(e.to_string().contains("light 0 rgb"), "{e}");
    let mut bad = good.clone();
    bad[20..28].copy_from_slice(&f64::INFINITY.to_le_bytes());
    assert!(matches!(
        decode_message(&bad),
        Err(ProtocolError::NonFinite { .. })
    ));

    // Invalid UTF-8 in an error message.
    let mut bytes = Vec::new();
    encode_error(code::INTERNAL, "ab", &mut bytes);
    let n = bytes.len();
    bytes[n - 1] = 0xff;
    assert!(matches!(
        decode_message(&bytes),
        Err(ProtocolError::InvalidUtf8 { .. })
    ));

    // Text length disagreeing with the message length.
    let mut bytes = Vec::new();
    encode_goodbye("abc", &mut bytes);
    bytes[14] = 2;
    assert!(matches!(
        decode_message(&bytes),
        Err(ProtocolError::Inconsistent { .. })
    ));

    // Trailing bytes after a single message.
    let mut bytes = good.clone();
    bytes.push(0);
    assert!(decode_message(&bytes).is_err());
}

#[test]
fn garbage_is_an_error_not_a_panic() {
    let mut rng = Rng(1234);
    for _ in 0..2000 {
        let n = (rng.next() % 200) as usize;
        let bytes: Vec<u8> = (0..n).map(|_| rng.next() as u8).collect();
        let mut d = Decoder::new();
        d.push(&bytes);
        while let Ok(Some(_)) = d.next_message() {}
    }
    let mut d = Decoder::new();
    d.push(b"GET / HTTP/1.1\r\nHost: envlight\r\n\r\n");
    let e = d.next_message().unwrap_err();
    // The magic is checked before the length ("GET " read as one is absurd): an HTTP request
    // is named as no envlight stream.
    assert_eq!(e.code(), code::MALFORMED, "{e}");
    assert!(e.to_string().contains("not an envlight stream"), "{e}");
    // Only the length has arrived: nothing is judged before the magic, so the request's
    // first four bytes alone are no absurd length but wait for the rest.
    let mut d = Decoder::new();
    d.push(b"GET ");
    assert_eq!(d.next_message(), Ok(None));
    d.push(b"/ HTTP/1.1\r\n");
    assert_eq!(d.next_message().unwrap_err().code(), code::MALFORMED);
    let mut d = Decoder::new();
    d.push(b"\x10\x00\x00\x00HTTP/1.1 200 OK");
    assert_eq!(d.next_message().unwrap_err().code(), code::MALFORMED);
}

#[test]
fn request_round_trips_binary_and_json() {
    for request in [
        Request::default(),
        Request {
            max_lights: 64,
            representation: Representation::Lights,
            format: Format::Json,
        },
        Request {
            max_lights: u32::MAX,
            representation: Representation::Wavelet,
            format: Format::Binary,
        },
        Request {
            max_lights: 15,
            representation: Representation::Asg,
            format: Format::Binary,
        },
    ] {
        let mut bytes = Vec::new();
        encode_request(&request, &mut bytes);
        assert_eq!(bytes.len(), 20);
        assert_eq!(decode_message(&bytes), Ok(Message::Subscribe(request)));
        let json = request_to_json(&request);
        assert_eq!(parse_json_request(&json), Ok(request), "{json}");
        assert_eq!(parse_json_message(&json), Ok(Message::Subscribe(request)));
    }
    assert_eq!(
        parse_json_request(
            r#"{"subscribe": {"max_lights": 64, "representation": "lights", "format": "json"}}"#
        ),
        Ok(Request {
            max_lights: 64,
            representation: Representation::Lights,
            format: Format::Json
        })
    );
    assert_eq!(Request::default().cap(), None);
    assert_eq!(
        Request {
            max_lights: 5,
            ..Request::default()
        }
        .cap(),
        Some(5)
    );
}

/// The frame of docs/protocol.md's worked example.
fn golden_frame() -> LightFrame {
    LightFrame {
        seq: 17,
        time: 0.5,
        lights: vec![Light {
            id: 3,
            dir: [0.0, 1.0, 0.0],
            rgb: [1.0, 0.5, 0.25],
            solid_angle: 0.0625,
        }],
    }
}

fn hex(s: &str) -> Vec<u8> {
    let digits: Vec<u8> = s.bytes().filter(|b| b.is_ascii_hexdigit()).collect();
    digits
        .chunks(2)
        .map(|p| u8::from_str_radix(std::str::from_utf8(p).unwrap(), 16).unwrap())
        .collect()
}

#[test]
fn golden_frame_bytes() {
    // Pinned layout: see docs/protocol.md, "Worked example".
    let expected = hex("40 00 00 00  45 4e 56 4c  01 00  01 00
         11 00 00 00 00 00 00 00
         00 00 00 00 00 00 e0 3f
         00  01  00 00
         01 00 00 00
         03 00 00 00
         00 00 00 00  00 00 80 3f  00 00 00 00
         00 00 80 3f  00 00 00 3f  00 00 80 3e
         00 00 80 3d");
    let mut bytes = Vec::new();
    encode_frame(&golden_frame(), None, true, &mut bytes);
    assert_eq!(bytes, expected);
    assert_eq!(bytes.len(), 68);
    check_frame(
        &as_frame(decode_message(&bytes).unwrap()),
        &golden_frame(),
        true,
    );
}

#[test]
fn golden_control_bytes() {
    let mut bytes = Vec::new();
    encode_request(
        &Request {
            max_lights: 64,
            representation: Representation::Lights,
            format: Format::Binary,
        },
        &mut bytes,
    );
    assert_eq!(
        bytes,
        hex("10 00 00 00  45 4e 56 4c  01 00  10 00  40 00 00 00  00  00  00 00")
    );
    let mut bytes = Vec::new();
    encode_goodbye("bye", &mut bytes);
    assert_eq!(
        bytes,
        hex("11 00 00 00  45 4e 56 4c  01 00  03 00  00 00  03 00 00 00  62 79 65")
    );
    let mut bytes = Vec::new();
    encode_error(code::UNKNOWN_TYPE, "x", &mut bytes);
    assert_eq!(
        bytes,
        hex("0f 00 00 00  45 4e 56 4c  01 00  02 00  03 00  01 00 00 00  78")
    );
}

#[test]
fn golden_json() {
    assert_eq!(
        frame_to_json(&golden_frame(), None, false),
        r#"{"seq":17,"time":0.5,"representation":"lights","stale":false,"lights":[{"id":3,"dir":[0.0,1.0,0.0],"rgb":[1.0,0.5,0.25],"solid_angle":0.0625}]}"#
    );
    assert_eq!(
        protocol::error_to_json(code::BAD_REQUEST, "bad"),
        r#"{"error":{"code":5,"message":"bad"}}"#
    );
    assert_eq!(
        protocol::goodbye_to_json("bye"),
        r#"{"goodbye":{"code":0,"message":"bye"}}"#
    );
    // DESIGN.md's object (no representation/stale) and extra fields are accepted.
    let design = r#"{"seq": 17, "time": 0.5667, "extra": 1, "lights": [{"id": 3, "dir": [0.71, 0.60, -0.35], "rgb": [812.1, 790.4, 701.9], "solid_angle": 0.0021}]}"#;
    let f = as_frame(parse_json_message(design).unwrap());
    assert_eq!((f.seq, f.stale, f.lights.len()), (17, false, 1));
    assert!(matches!(
        parse_json_message(
            r#"{"seq":1,"time":0,"lights":[{"id":0,"dir":[1e300,0,0],"rgb":[0,0,0],"solid_angle":0}]}"#
        ),
        Err(ProtocolError::NonFinite { .. })
    ));
}

fn arb_light() -> impl Strategy<Value = Light> {
    let f = || -1e30f32..1e30f32;
    (any::<u32>(), [f(), f(), f()], [f(), f(), f()], f()).prop_map(|(id, dir, rgb, solid_angle)| {
        Light {
            id,
            dir,
            rgb,
            solid_angle,
        }
    })
}

proptest! {
    #[test]
    fn arbitrary_bytes_never_panic(
        bytes in proptest::collection::vec(any::<u8>(), 0..512),
        chunk in 1usize..64,
    ) {
        let mut d = Decoder::new();
        for piece in bytes.chunks(chunk) {
            d.push(piece);
            while let Ok(Some(_)) = d.next_message() {}
        }
        let _ = d.finish();
        let _ = decode_message(&bytes);
        let _ = parse_json_message(&String::from_utf8_lossy(&bytes));
    }

    #[test]
    fn arbitrary_valid_headers_with_random_bodies_never_panic(
        message_type in prop_oneof![Just(1u16), Just(2), Just(3), Just(16), any::<u16>()],
        body in proptest::collection::vec(any::<u8>(), 0..200),
    ) {
        let mut bytes = ((body.len() + 8) as u32).to_le_bytes().to_vec();
        bytes.extend_from_slice(b"ENVL\x01\x00");
        bytes.extend_from_slice(&message_type.to_le_bytes());
        bytes.extend_from_slice(&body);
        let _ = decode_message(&bytes);
    }

    #[test]
    fn arbitrary_valid_frames_round_trip(
        seq in any::<u64>(),
        time in -1e12f64..1e12,
        lights in proptest::collection::vec(arb_light(), 0..64),
        stale in any::<bool>(),
        chunk in 1usize..100,
    ) {
        let frame = LightFrame { seq, time, lights };
        let mut bytes = Vec::new();
        encode_frame(&frame, None, stale, &mut bytes);
        let messages = decode_chunked(&bytes, || chunk);
        prop_assert_eq!(messages.len(), 1);
        let decoded = as_frame(messages[0].clone());
        prop_assert_eq!(decoded.stale, stale);
        prop_assert_eq!(&decoded.clone().into_light_frame(), &frame);
        let json = as_frame(parse_json_message(&frame_to_json(&frame, None, stale)).unwrap());
        prop_assert_eq!(json, decoded);
    }
}

// -------------------------------------------------------------------------------------------
// Decoding straight from the read buffer (`Decoder::next_from`, `Decoder::feed`)

/// What `push` + `next_message` give for `bytes` cut at `cuts`: the messages, then the error
/// that ended the stream (if any) or what `finish` says.
fn decode_buffered(bytes: &[u8], cuts: &[usize]) -> (Vec<Message>, Result<(), ProtocolError>) {
    let mut d = Decoder::new();
    let mut out = Vec::new();
    let mut start = 0;
    for &end in cuts.iter().chain([&bytes.len()]) {
        d.push(&bytes[start..end]);
        start = end;
        loop {
            match d.next_message() {
                Ok(Some(m)) => out.push(m),
                Ok(None) => break,
                Err(e) => return (out, Err(e)),
            }
        }
    }
    (out, d.finish())
}

/// The same through `feed`, handing every light list back (`recycle`) as a client would.
fn decode_fed(bytes: &[u8], cuts: &[usize]) -> (Vec<Message>, Result<(), ProtocolError>) {
    let mut d = Decoder::new();
    let mut out = Vec::new();
    let mut start = 0;
    for &end in cuts.iter().chain([&bytes.len()]) {
        let piece = &bytes[start..end];
        start = end;
        // The decoder is borrowed by the iterator: the lists go back after it.
        let mut used = Vec::new();
        for m in d.feed(piece) {
            match m {
                Ok(Message::Frame(f)) => {
                    out.push(Message::Frame(f.clone()));
                    used.push(f.lights);
                }
                Ok(m) => out.push(m),
                Err(e) => return (out, Err(e)),
            }
        }
        for lights in used {
            d.recycle(lights);
        }
    }
    (out, d.finish())
}

/// The same through `next_from`, one message at a time, as `stream::client` reads.
fn decode_next_from(bytes: &[u8], cuts: &[usize]) -> (Vec<Message>, Result<(), ProtocolError>) {
    let mut d = Decoder::new();
    let mut out = Vec::new();
    let mut start = 0;
    for &end in cuts.iter().chain([&bytes.len()]) {
        let mut input = &bytes[start..end];
        start = end;
        loop {
            let before = input.len();
            match d.next_from(&mut input) {
                Ok(Some(Message::Frame(f))) => {
                    out.push(Message::Frame(f.clone()));
                    d.recycle(f.lights);
                }
                Ok(Some(m)) => out.push(m),
                Ok(None) => {
                    assert!(input.is_empty(), "Ok(None) with {} bytes left", input.len());
                    break;
                }
                Err(e) => return (out, Err(e)),
            }
            assert!(input.len() < before, "a message from no bytes");
        }
    }
    (out, d.finish())
}

/// A stream of frames of several sizes (one with a cap), an error and a goodbye.
fn mixed_stream(seed: u64) -> Vec<u8> {
    let mut bytes = Vec::new();
    for (i, n) in [256usize, 0, 3, 256, 64].into_iter().enumerate() {
        let frame = random_frame(n, seed + i as u64);
        encode_frame(&frame, (i == 3).then_some(17), i == 2, &mut bytes);
    }
    encode_error(code::BAD_REQUEST, "bad request: whatever", &mut bytes);
    encode_frame(&random_frame(5, seed + 9), None, false, &mut bytes);
    encode_goodbye("bye", &mut bytes);
    bytes
}

#[test]
fn a_message_whole_in_the_read_is_decoded_in_place_and_a_split_one_is_stored() {
    let mut bytes = Vec::new();
    encode_frame(&random_frame(256, 1), None, false, &mut bytes);
    let one = bytes.len();
    encode_frame(&random_frame(256, 2), None, false, &mut bytes);
    let mut d = Decoder::new();
    // The first message and 100 bytes of the second in one read.
    let mut input = &bytes[..one + 100];
    let first = as_frame(d.next_from(&mut input).unwrap().unwrap());
    assert_eq!(input.len(), 100, "only the first message is taken");
    assert_eq!(
        d.buffered(),
        0,
        "a whole message is not copied into the decoder"
    );
    check_frame(&first, &random_frame(256, 1), false);
    assert!(d.next_from(&mut input).unwrap().is_none());
    assert!(input.is_empty());
    assert_eq!(d.buffered(), 100, "the split message is stored");
    // The rest of the second, and a third message's first bytes, in the next read.
    let mut tail = bytes[one + 100..].to_vec();
    tail.extend_from_slice(&bytes[..5]);
    let mut input = &tail[..];
    let second = as_frame(d.next_from(&mut input).unwrap().unwrap());
    check_frame(&second, &random_frame(256, 2), false);
    assert_eq!(
        input.len(),
        5,
        "exactly the split message's bytes are taken"
    );
    assert_eq!(d.buffered(), 0);
}

#[test]
fn recycled_light_lists_are_decoded_into_without_allocating() {
    let mut bytes = Vec::new();
    encode_frame(&random_frame(256, 3), None, false, &mut bytes);
    let mut d = Decoder::new();
    let first = as_frame(d.feed(&bytes).next().unwrap().unwrap());
    let ptr = first.lights.as_ptr();
    d.recycle(first.lights);
    let second = as_frame(d.feed(&bytes).next().unwrap().unwrap());
    assert_eq!(
        second.lights.as_ptr(),
        ptr,
        "the recycled allocation is reused"
    );
    check_frame(&second, &random_frame(256, 3), false);
    // A smaller list handed back does not replace a larger spare.
    d.recycle(second.lights);
    d.recycle(Vec::with_capacity(1));
    let third = as_frame(d.feed(&bytes).next().unwrap().unwrap());
    assert_eq!(third.lights.as_ptr(), ptr);
}

#[test]
fn a_feed_dropped_early_keeps_the_rest_of_the_bytes() {
    let bytes = mixed_stream(11);
    let (all, end) = decode_buffered(&bytes, &[]);
    end.unwrap();
    let mut d = Decoder::new();
    let first = d.feed(&bytes).next().unwrap().unwrap();
    assert_eq!(first, all[0]);
    let rest: Vec<Message> = d.feed(&[]).map(Result::unwrap).collect();
    assert_eq!(rest, all[1..]);
    d.finish().unwrap();
}

#[test]
fn errors_in_place_match_the_buffered_decoder() {
    let good = mixed_stream(5);
    let mut oversized = good.clone();
    oversized.extend_from_slice(&(MAX_MESSAGE_LEN as u32 + 1).to_le_bytes());
    let mut bad_magic = good.clone();
    bad_magic.extend_from_slice(b"\x20\0\0\0ENVX");
    let mut nan = Vec::new();
    let mut frame = random_frame(4, 8);
    frame.lights[2].rgb[1] = f32::NAN;
    encode_frame(&frame, None, false, &mut nan);
    let mut bad_body = good.clone();
    bad_body.extend_from_slice(&nan);
    for (name, bytes) in [
        ("oversized", oversized),
        ("magic", bad_magic),
        ("nan", bad_body),
    ] {
        for cuts in [
            vec![],
            vec![good.len() - 3],
            vec![good.len() + 2],
            vec![1, 2, 3],
        ] {
            let buffered = decode_buffered(&bytes, &cuts);
            assert!(buffered.1.is_err(), "{name}");
            assert_eq!(decode_fed(&bytes, &cuts), buffered, "{name} {cuts:?}");
            assert_eq!(decode_next_from(&bytes, &cuts), buffered, "{name} {cuts:?}");
        }
    }
}

proptest! {
    #[test]
    fn in_place_decoding_equals_buffered_decoding_at_any_split_points(
        seed in any::<u64>(),
        cuts in proptest::collection::vec(any::<prop::sample::Index>(), 0..12),
        truncate in any::<prop::sample::Index>(),
        truncated in any::<bool>(),
    ) {
        let mut bytes = mixed_stream(seed);
        if truncated {
            // The stream may also end inside a message.
            bytes.truncate(truncate.index(bytes.len()));
        }
        let mut cuts: Vec<usize> = cuts.iter().map(|i| i.index(bytes.len() + 1)).collect();
        cuts.sort_unstable();
        let buffered = decode_buffered(&bytes, &cuts);
        if !truncated {
            prop_assert_eq!(buffered.0.len(), 8);
        }
        prop_assert_eq!(&decode_fed(&bytes, &cuts), &buffered);
        prop_assert_eq!(&decode_next_from(&bytes, &cuts), &buffered);
    }

    #[test]
    fn arbitrary_bytes_decode_alike_in_place_and_buffered(
        bytes in proptest::collection::vec(any::<u8>(), 0..512),
        cuts in proptest::collection::vec(any::<prop::sample::Index>(), 0..6),
    ) {
        let mut cuts: Vec<usize> = cuts.iter().map(|i| i.index(bytes.len() + 1)).collect();
        cuts.sort_unstable();
        let buffered = decode_buffered(&bytes, &cuts);
        prop_assert_eq!(&decode_fed(&bytes, &cuts), &buffered);
        prop_assert_eq!(&decode_next_from(&bytes, &cuts), &buffered);
    }
}

// -------------------------------------------------------------------------------------------
// ASG sets (representation 1)

use envlight::asg::Asg;
use envlight::light::{AsgLobe, AsgSet};
use envlight::stream::protocol::{
    asg_frame_to_json, encode_asg_frame, AsgFrameMessage, ASG_RECORD_LEN, FRAME_FIXED_LEN,
    HEADER_LEN,
};
use glam::DVec3;

fn as_asg(message: Message) -> AsgFrameMessage {
    match message {
        Message::Asg(f) => f,
        other => panic!("expected an ASG frame, got {other:?}"),
    }
}

/// `n` fitted-looking lobes: random frames, bandwidths over the fitter's range, HDR amplitudes.
fn random_set(n: usize, seed: u64) -> AsgSet {
    let mut rng = Rng(seed | 1);
    let mut unit = || f64::from(rng.unit());
    let lobes: Vec<Asg> = (0..n)
        .map(|_| {
            let axis = DVec3::new(unit() - 0.5, unit() - 0.5, unit() - 0.5 + 1e-3);
            let hint = DVec3::new(unit() - 0.5, unit() - 0.5, unit() - 0.5);
            let lambda = 0.25 * (4e5f64).powf(unit());
            let mu = 0.25 * (4e5f64).powf(unit());
            let p = 1e4 * unit().powi(4);
            Asg::new(axis, hint, lambda, mu, [p, p * unit(), p * unit()]).unwrap()
        })
        .collect();
    AsgSet::from_fit(seed.wrapping_mul(31), seed as f64 / 30.0, &lobes)
}

#[test]
fn asg_frames_round_trip_binary_and_json() {
    for (n, seed) in [(0usize, 1u64), (1, 2), (16, 3), (64, 4)] {
        let set = random_set(n, seed);
        for stale in [false, true] {
            let mut bytes = Vec::new();
            encode_asg_frame(&set, None, stale, &mut bytes);
            assert_eq!(
                bytes.len(),
                HEADER_LEN + FRAME_FIXED_LEN + n * ASG_RECORD_LEN
            );
            let mut k = 0usize;
            let messages = decode_chunked(&bytes, || {
                k += 1;
                k % 13
            });
            assert_eq!(messages.len(), 1);
            let decoded = as_asg(messages[0].clone());
            assert_eq!(decoded.stale, stale);
            assert_eq!(decoded.clone().into_asg_set(), set, "binary, {n} lobes");
            let json = asg_frame_to_json(&set, None, stale);
            assert!(json.contains("\"representation\":\"asg\""), "{json}");
            let from_json = as_asg(parse_json_message(&json).unwrap());
            // Bit for bit: shortest round-trip floats.
            assert_eq!(from_json, decoded, "JSON, {n} lobes");
        }
    }
}

#[test]
fn asg_lobes_survive_the_wire_as_lobes() {
    // What a renderer gets back is the fitted lobe up to f32 rounding.
    let set = random_set(8, 9);
    let mut bytes = Vec::new();
    encode_asg_frame(&set, None, false, &mut bytes);
    let decoded = as_asg(decode_message(&bytes).unwrap());
    for lobe in &decoded.lobes {
        let asg = lobe.to_asg().expect("a valid lobe");
        let rel = (asg.lambda - f64::from(lobe.lambda)).abs() / asg.lambda;
        assert!(rel < 1e-6);
        let integral = envlight::asg::integral(asg.lambda, asg.mu);
        assert!((integral - f64::from(lobe.integral)).abs() <= 1e-6 * integral);
        let y = lobe.bitangent();
        let z = DVec3::from_array(asg.bitangent);
        assert!((DVec3::new(y[0].into(), y[1].into(), y[2].into()) - z).length() < 1e-6);
    }
}

#[test]
fn asg_cap_keeps_the_most_energetic_lobes_in_id_order() {
    let set = random_set(20, 5);
    let mut by_energy: Vec<&AsgLobe> = set.lobes.iter().collect();
    by_energy.sort_by(|a, b| b.luminance().total_cmp(&a.luminance()));
    let mut want: Vec<u32> = by_energy[..6].iter().map(|l| l.id).collect();
    want.sort_unstable();
    let mut bytes = Vec::new();
    encode_asg_frame(&set, Some(6), false, &mut bytes);
    let decoded = as_asg(decode_message(&bytes).unwrap());
    let got: Vec<u32> = decoded.lobes.iter().map(|l| l.id).collect();
    assert_eq!(got, want);
    for l in &decoded.lobes {
        assert_eq!(*l, set.lobes[l.id as usize], "kept lobes are unchanged");
    }
    let json = as_asg(parse_json_message(&asg_frame_to_json(&set, Some(6), false)).unwrap());
    assert_eq!(json, decoded);
    let mut zero = Vec::new();
    encode_asg_frame(&set, Some(0), false, &mut zero);
    assert!(as_asg(decode_message(&zero).unwrap()).lobes.is_empty());
}

/// Offset of lobe `i`'s field at `at` (record-relative) in an encoded frame.
fn lobe_field(i: usize, at: usize) -> usize {
    HEADER_LEN + FRAME_FIXED_LEN + i * ASG_RECORD_LEN + at
}

#[test]
fn bad_asg_frames_are_errors_not_panics() {
    let set = random_set(3, 11);
    let mut good = Vec::new();
    encode_asg_frame(&set, None, false, &mut good);
    // Truncated: waits, then fails at the end of the stream.
    let mut d = Decoder::new();
    d.push(&good[..good.len() - 5]);
    assert_eq!(d.next_message(), Ok(None));
    assert!(matches!(d.finish(), Err(ProtocolError::Truncated { .. })));
    // Wrong sizes: a count that disagrees with the records, a record short by 4 bytes.
    let mut bad = good.clone();
    bad[HEADER_LEN + 20] = 4;
    assert!(matches!(
        decode_message(&bad),
        Err(ProtocolError::Inconsistent { kind: "frame", .. })
    ));
    let mut short = good[..good.len() - 4].to_vec();
    let len = (short.len() - 4) as u32;
    short[..4].copy_from_slice(&len.to_le_bytes());
    assert!(matches!(
        decode_message(&short),
        Err(ProtocolError::Inconsistent { kind: "frame", .. })
    ));
    // Values: NaN, infinity, non-positive bandwidths or integral, a frame that is not one.
    let put = |at: usize, v: f32| {
        let mut b = good.clone();
        b[at..at + 4].copy_from_slice(&v.to_le_bytes());
        decode_message(&b)
    };
    assert!(
        matches!(put(lobe_field(1, 28), f32::NAN), Err(ProtocolError::NonFinite { field }) if field == "lobe 1 lambda")
    );
    assert!(matches!(
        put(lobe_field(2, 40), f32::INFINITY),
        Err(ProtocolError::NonFinite { .. })
    ));
    for (at, v) in [(28, 0.0), (32, -1.0), (48, 0.0), (4, 2.0), (16, 0.5)] {
        let e = put(lobe_field(0, at), v).unwrap_err();
        assert!(
            matches!(e, ProtocolError::InvalidLobe { index: 0, .. }),
            "{at}: {e}"
        );
        assert_eq!(e.code(), code::MALFORMED);
    }
    // A tangent along the axis: not orthogonal.
    let mut b = good.clone();
    let axis: Vec<u8> = b[lobe_field(0, 4)..lobe_field(0, 16)].to_vec();
    b[lobe_field(0, 16)..lobe_field(0, 28)].copy_from_slice(&axis);
    assert!(matches!(
        decode_message(&b),
        Err(ProtocolError::InvalidLobe { index: 0, .. })
    ));
    // JSON: a number too large for f32, a missing or wrong representation, a bad lobe.
    let json = asg_frame_to_json(&set, None, false);
    let value: serde_json::Value = serde_json::from_str(&json).unwrap();
    let edit = |f: &dyn Fn(&mut serde_json::Value)| {
        let mut v = value.clone();
        f(&mut v);
        parse_json_message(&v.to_string())
    };
    assert!(matches!(
        edit(&|v| v["lobes"][0]["mu"] = serde_json::json!(1e300)),
        Err(ProtocolError::NonFinite { .. })
    ));
    assert!(matches!(
        edit(&|v| v["lobes"][1]["lambda"] = serde_json::json!(-3.0)),
        Err(ProtocolError::InvalidLobe { index: 1, .. })
    ));
    assert!(matches!(
        edit(&|v| v["representation"] = serde_json::json!("lights")),
        Err(ProtocolError::Json(_))
    ));
    assert!(matches!(
        edit(&|v| {
            v.as_object_mut().unwrap().remove("representation");
        }),
        Err(ProtocolError::Json(_))
    ));
    assert!(matches!(
        edit(&|v| v["lobes"][0]
            .as_object_mut()
            .unwrap()
            .remove("integral")
            .map(|_| ())
            .unwrap()),
        Err(ProtocolError::Json(_))
    ));
}

/// The golden ASG frame of docs/protocol.md: seq 17, time 0.5, one lobe with id 0, axis +Y,
/// tangent +X, λ 8, μ 2, rgb (3, 2.5, 2) and integral 0.75 (a value exact in binary; a real
/// frame carries `asg::integral(λ, μ)`).
fn golden_asg() -> AsgSet {
    AsgSet {
        seq: 17,
        time: 0.5,
        lobes: vec![AsgLobe {
            id: 0,
            axis: [0.0, 1.0, 0.0],
            tangent: [1.0, 0.0, 0.0],
            lambda: 8.0,
            mu: 2.0,
            rgb: [3.0, 2.5, 2.0],
            integral: 0.75,
        }],
    }
}

#[test]
fn golden_asg_frame_bytes_and_json() {
    let mut bytes = Vec::new();
    encode_asg_frame(&golden_asg(), None, false, &mut bytes);
    let want = hex(
        "54000000 454e564c 0100 0100 1100000000000000 000000000000e03f 01 00 0000 01000000 \
         00000000 00000000 0000803f 00000000 0000803f 00000000 00000000 00000041 00000040 \
         00004040 00002040 00000040 0000403f",
    );
    assert_eq!(bytes, want);
    assert_eq!(
        asg_frame_to_json(&golden_asg(), None, false),
        r#"{"seq":17,"time":0.5,"representation":"asg","stale":false,"lobes":[{"id":0,"axis":[0.0,1.0,0.0],"tangent":[1.0,0.0,0.0],"lambda":8.0,"mu":2.0,"rgb":[3.0,2.5,2.0],"integral":0.75}]}"#
    );
}

#[test]
fn asg_subscribe_round_trips() {
    let request = Request {
        max_lights: 8,
        representation: Representation::Asg,
        format: Format::Binary,
    };
    let mut bytes = Vec::new();
    encode_request(&request, &mut bytes);
    assert_eq!(bytes[16], 1);
    assert_eq!(decode_message(&bytes), Ok(Message::Subscribe(request)));
    assert_eq!(
        parse_json_request(
            r#"{"subscribe":{"representation":"asg","max_lights":8,"format":"binary"}}"#
        ),
        Ok(request)
    );
}

fn arb_asg() -> impl Strategy<Value = Asg> {
    let v = || -1.0f64..1.0;
    (
        [v(), v(), v()],
        [v(), v(), v()],
        0.25f64..1e5,
        0.25f64..1e5,
        [0.0f64..1e6, 0.0f64..1e6, 0.0f64..1e6],
    )
        .prop_filter_map("degenerate axis", |(axis, hint, l, m, rgb)| {
            Asg::new(DVec3::from_array(axis), DVec3::from_array(hint), l, m, rgb)
        })
}

proptest! {
    #[test]
    fn arbitrary_asg_sets_round_trip(
        seq in any::<u64>(),
        time in -1e12f64..1e12,
        lobes in proptest::collection::vec(arb_asg(), 0..64),
        stale in any::<bool>(),
        cap in proptest::option::of(0usize..70),
        chunk in 1usize..100,
    ) {
        let set = AsgSet::from_fit(seq, time, &lobes);
        let mut bytes = Vec::new();
        encode_asg_frame(&set, cap, stale, &mut bytes);
        let messages = decode_chunked(&bytes, || chunk);
        prop_assert_eq!(messages.len(), 1);
        let decoded = as_asg(messages[0].clone());
        prop_assert_eq!(decoded.lobes.len(), cap.unwrap_or(usize::MAX).min(lobes.len()));
        if cap.is_none() {
            prop_assert_eq!(&decoded.clone().into_asg_set(), &set);
        }
        let json = as_asg(parse_json_message(&asg_frame_to_json(&set, cap, stale)).unwrap());
        prop_assert_eq!(json, decoded);
    }
}

// -------------------------------------------------------------------------------------------
// Wavelet sets (representation 2)

use envlight::stream::protocol::{
    encode_wavelet_frame, wavelet_frame_to_json, WaveletFrame, WaveletFrameMessage,
    MAX_FRAME_COEFFICIENTS, WAVELET_PREFIX_LEN, WAVELET_RECORD_LEN,
};
use envlight::wavelet::{Basis, WaveletSet};

fn as_wavelet(message: Message) -> WaveletFrameMessage {
    match message {
        Message::Wavelet(m) => m,
        other => panic!("expected a wavelet frame, got {other:?}"),
    }
}

/// The golden wavelet frame of docs/protocol.md: seq 17, time 0.5, live, Haar on a 4 × 4 map
/// with 2 levels, two coefficients: index 0 (the scaling coefficient) = (4, 2, 1) and index 5
/// = (−0.5, 0.25, 0).
fn golden_wavelet() -> WaveletFrame {
    WaveletFrame {
        seq: 17,
        time: 0.5,
        set: WaveletSet {
            basis: Basis::Haar,
            side: 4,
            levels: 2,
            coefficients: vec![(0, [4.0, 2.0, 1.0]), (5, [-0.5, 0.25, 0.0])],
        },
    }
}

#[test]
fn golden_wavelet_frame_bytes_and_json() {
    let mut bytes = Vec::new();
    encode_wavelet_frame(&golden_wavelet(), None, false, &mut bytes);
    let want = hex(
        "48000000 454e564c 0100 0100 1100000000000000 000000000000e03f 02 00 0000 02000000 \
         01 02 00 00 04000000 \
         00000000 00008040 00000040 0000803f \
         05000000 000000bf 0000803e 00000000",
    );
    assert_eq!(bytes, want);
    assert_eq!(
        bytes.len(),
        HEADER_LEN + FRAME_FIXED_LEN + WAVELET_PREFIX_LEN + 2 * WAVELET_RECORD_LEN
    );
    let json = wavelet_frame_to_json(&golden_wavelet(), None, false);
    assert_eq!(
        json,
        r#"{"seq":17,"time":0.5,"representation":"wavelet","stale":false,"basis":"haar","side":4,"levels":2,"coefficients":[[0,[4.0,2.0,1.0]],[5,[-0.5,0.25,0.0]]]}"#
    );
    let decoded = as_wavelet(decode_message(&bytes).unwrap());
    assert_eq!(decoded, as_wavelet(parse_json_message(&json).unwrap()));
    assert_eq!(decoded.into_wavelet_frame(), golden_wavelet());
    // ∫L dω from the scaling coefficient: 2² · 4 · 4π / 4² for red.
    let red = golden_wavelet().integral()[0];
    assert!((red - 4.0 * std::f64::consts::PI).abs() < 1e-12, "{red}");
    // Readers ignore unknown fields of a frame.
    let extended = json.replacen('{', r#"{"future":[1,2],"#, 1);
    assert_eq!(
        parse_json_message(&extended).map(as_wavelet),
        parse_json_message(&json).map(as_wavelet)
    );
}

#[test]
fn wavelet_subscribe_round_trips() {
    let request = Request {
        max_lights: 256,
        representation: Representation::Wavelet,
        format: Format::Json,
    };
    let mut bytes = Vec::new();
    encode_request(&request, &mut bytes);
    assert_eq!(bytes[16], 2);
    assert_eq!(decode_message(&bytes), Ok(Message::Subscribe(request)));
    assert_eq!(
        parse_json_request(r#"{"subscribe":{"representation":"wavelet","max_lights":256}}"#),
        Ok(request)
    );
}

#[test]
fn hostile_wavelet_frames_are_errors_not_panics() {
    let mut bytes = Vec::new();
    encode_wavelet_frame(&golden_wavelet(), None, false, &mut bytes);
    // Every single-byte corruption of the prefix and the records decodes or fails cleanly, and
    // a frame that decodes is a valid set.
    for at in 36..bytes.len() {
        for value in [0u8, 1, 0x7f, 0x80, 0xff] {
            let mut b = bytes.clone();
            b[at] = value;
            if let Ok(Message::Wavelet(m)) = decode_message(&b) {
                protocol::validate_wavelet_set(&m.set).unwrap();
            }
        }
    }
    // A count that promises more records than there are: error 1 before any allocation.
    let mut b = bytes.clone();
    b[32..36].copy_from_slice(&u32::MAX.to_le_bytes());
    assert_eq!(decode_message(&b).unwrap_err().code(), code::MALFORMED);
    // A declared side of 2^15 with an index near the end is fine; 2^16 is not.
    let mut big = golden_wavelet();
    big.set.side = 1 << 15;
    big.set.levels = 15;
    big.set.coefficients = vec![(0, [1.0; 3]), ((1 << 30) - 1, [2.0; 3])];
    let mut b = Vec::new();
    encode_wavelet_frame(&big, None, false, &mut b);
    assert_eq!(as_wavelet(decode_message(&b).unwrap()).set, big.set);
    b[40..44].copy_from_slice(&(1u32 << 16).to_le_bytes());
    assert_eq!(decode_message(&b).unwrap_err().code(), code::MALFORMED);
    // A set larger than one message is capped to what fits.
    let mut huge = golden_wavelet();
    huge.set.side = 512;
    huge.set.levels = 9;
    huge.set.coefficients = (0..70_000u32).map(|i| (i, [1.0, 0.0, 0.0])).collect();
    let mut b = Vec::new();
    encode_wavelet_frame(&huge, None, false, &mut b);
    assert!(b.len() - 4 <= MAX_MESSAGE_LEN);
    let decoded = as_wavelet(decode_message(&b).unwrap());
    assert_eq!(decoded.set.coefficients.len(), MAX_FRAME_COEFFICIENTS);
}

fn arb_wavelet_frame() -> impl Strategy<Value = WaveletFrame> {
    let basis = prop_oneof![
        Just(Basis::Haar),
        (2usize..=10).prop_map(Basis::Daubechies),
        (1usize..=5).prop_map(Basis::Coiflet),
    ];
    (1u32..=8, basis, any::<u64>(), -1e9f64..1e9)
        .prop_flat_map(|(log_side, basis, seq, time)| {
            let side = 1u32 << log_side;
            let value = -1e6f32..1e6;
            (
                Just((side, basis, seq, time)),
                0..=log_side,
                proptest::collection::vec(
                    (0..side * side, [value.clone(), value.clone(), value]),
                    0..80,
                ),
            )
        })
        .prop_map(
            |((side, basis, seq, time), levels, coefficients)| WaveletFrame {
                seq,
                time,
                set: WaveletSet {
                    basis,
                    side,
                    levels,
                    // Sorted by index, unique (a later duplicate replaces an earlier one).
                    coefficients: coefficients
                        .into_iter()
                        .collect::<std::collections::BTreeMap<_, _>>()
                        .into_iter()
                        .collect(),
                },
            },
        )
}

proptest! {
    #[test]
    fn arbitrary_wavelet_sets_round_trip_and_caps_keep_scaling_then_largest(
        frame in arb_wavelet_frame(),
        stale in any::<bool>(),
        cap in proptest::option::of(0usize..90),
        chunk in 1usize..100,
    ) {
        let mut bytes = Vec::new();
        encode_wavelet_frame(&frame, cap, stale, &mut bytes);
        let messages = decode_chunked(&bytes, || chunk);
        prop_assert_eq!(messages.len(), 1);
        let decoded = as_wavelet(messages[0].clone());
        prop_assert_eq!(decoded.stale, stale);
        let all = &frame.set.coefficients;
        let kept = &decoded.set.coefficients;
        prop_assert_eq!(kept.len(), cap.unwrap_or(usize::MAX).min(all.len()));
        // Kept coefficients are unchanged, in index order, and none dropped outranks one kept:
        // scaling coefficients first, then by RGB norm.
        prop_assert!(kept.iter().all(|c| all.contains(c)));
        prop_assert!(kept.windows(2).all(|w| w[0].0 < w[1].0));
        let side = frame.set.side;
        let block = side >> frame.set.levels;
        let rank = |&(i, rgb): &(u32, [f32; 3])| {
            let scaling = i / side < block && i % side < block;
            let norm2: f64 = rgb.iter().map(|&c| f64::from(c).powi(2)).sum();
            (scaling, norm2)
        };
        if let Some(worst_kept) = kept.iter().map(rank).min_by(|a, b| a.partial_cmp(b).unwrap()) {
            for dropped in all.iter().filter(|c| !kept.contains(c)) {
                prop_assert!(rank(dropped) <= worst_kept);
            }
        }
        if cap.is_none() {
            prop_assert_eq!(&decoded.clone().into_wavelet_frame(), &frame);
        }
        let json = as_wavelet(parse_json_message(&wavelet_frame_to_json(&frame, cap, stale)).unwrap());
        prop_assert_eq!(json, decoded);
    }
}

// -------------------------------------------------------------------------------------------
// Spherical-harmonic sets (representation 3)

use envlight::stream::protocol::{
    encode_sh_frame, sh_frame_to_json, ShFrame, ShFrameMessage, MAX_SH_DEGREE, SH_PREFIX_LEN,
    SH_RECORD_LEN,
};

fn as_sh(message: Message) -> ShFrameMessage {
    match message {
        Message::Sh(m) => m,
        other => panic!("expected an SH frame, got {other:?}"),
    }
}

/// The SH frame of docs/protocol.md's JSON example: seq 17, time 0.5, live, degree 1.
fn golden_sh() -> ShFrame {
    ShFrame {
        seq: 17,
        time: 0.5,
        coefficients: vec![
            [1.0, 0.9, 0.8],
            [0.1, 0.1, 0.1],
            [0.0, 0.0, 0.0],
            [-0.05, 0.0, 0.02],
        ],
    }
}

#[test]
fn golden_sh_frame_bytes_and_json() {
    let mut bytes = Vec::new();
    encode_sh_frame(&golden_sh(), None, false, &mut bytes);
    let head = hex(
        "54000000 454e564c 0100 0100 1100000000000000 000000000000e03f 03 00 0000 04000000 \
         01 00 0000",
    );
    assert_eq!(bytes[..head.len()], head[..]);
    assert_eq!(
        bytes.len(),
        HEADER_LEN + FRAME_FIXED_LEN + SH_PREFIX_LEN + 4 * SH_RECORD_LEN
    );
    // The records are the coefficients' f32 in order, little-endian.
    let floats: Vec<f32> = bytes[head.len()..]
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect();
    assert_eq!(floats, golden_sh().coefficients.concat());
    let json = sh_frame_to_json(&golden_sh(), None, false);
    assert_eq!(
        json,
        r#"{"seq":17,"time":0.5,"representation":"sh","stale":false,"degree":1,"sh":[[1.0,0.9,0.8],[0.1,0.1,0.1],[0.0,0.0,0.0],[-0.05,0.0,0.02]]}"#
    );
    let decoded = as_sh(decode_message(&bytes).unwrap());
    assert_eq!(decoded, as_sh(parse_json_message(&json).unwrap()));
    assert_eq!(decoded.into_sh_frame(), golden_sh());
    assert_eq!(golden_sh().degree(), Some(1));
    // ∫L dω = √(4π) · L_00.
    let red = golden_sh().to_coefficients().unwrap().integral()[0];
    assert!(
        (red - (4.0 * std::f64::consts::PI).sqrt()).abs() < 1e-12,
        "{red}"
    );
    let extended = json.replacen('{', r#"{"future":[1,2],"#, 1);
    assert_eq!(
        parse_json_message(&extended).map(as_sh),
        parse_json_message(&json).map(as_sh)
    );
}

#[test]
fn sh_subscribe_round_trips_and_code_4_is_unknown() {
    let request = Request {
        max_lights: 9,
        representation: Representation::Sh,
        format: Format::Binary,
    };
    let mut bytes = Vec::new();
    encode_request(&request, &mut bytes);
    assert_eq!(bytes[16], 3);
    assert_eq!(decode_message(&bytes), Ok(Message::Subscribe(request)));
    assert_eq!(
        parse_json_request(
            r#"{"subscribe":{"representation":"sh","max_lights":9,"format":"binary"}}"#
        ),
        Ok(request)
    );
    bytes[16] = 4;
    assert_eq!(
        decode_message(&bytes).unwrap_err().code(),
        code::BAD_REQUEST
    );
}

#[test]
fn bad_sh_frames_are_errors_not_panics() {
    let mut good = Vec::new();
    encode_sh_frame(&golden_sh(), None, false, &mut good);
    let malformed = |b: &[u8], what: &str| {
        assert_eq!(
            decode_message(b).map(as_sh).unwrap_err().code(),
            code::MALFORMED,
            "{what}"
        )
    };
    let mut b = good.clone();
    b[37] = 1;
    malformed(&b, "basis 1");
    let mut b = good.clone();
    b[36] = 2;
    malformed(&b, "degree 2 with 4 coefficients");
    let mut b = good.clone();
    b[36] = MAX_SH_DEGREE as u8 + 1;
    malformed(&b, "degree 16");
    let mut b = good.clone();
    b[40..44].copy_from_slice(&f32::NAN.to_le_bytes());
    malformed(&b, "NaN");
    let mut b = good.clone();
    b[32..36].copy_from_slice(&u32::MAX.to_le_bytes());
    malformed(&b, "a count beyond the message");
    // Every single-byte corruption decodes or fails cleanly; what decodes is a valid set.
    for at in 28..good.len() {
        for value in [0u8, 1, 3, 0x7f, 0x80, 0xff] {
            let mut b = good.clone();
            b[at] = value;
            if let Ok(Message::Sh(m)) = decode_message(&b) {
                protocol::validate_sh_set(&m.coefficients).unwrap();
            }
        }
    }
    // JSON: a degree that disagrees with the coefficients, a count that is no square.
    for text in [
        r#"{"seq":1,"time":0,"representation":"sh","degree":2,"sh":[[1,1,1],[0,0,0],[0,0,0],[0,0,0]]}"#,
        r#"{"seq":1,"time":0,"representation":"sh","degree":1,"sh":[[1,1,1],[0,0,0]]}"#,
        r#"{"seq":1,"time":0,"representation":"lights","degree":0,"sh":[[1,1,1]]}"#,
        r#"{"seq":1,"time":0,"representation":"sh","degree":0,"sh":[[1e39,1,1]]}"#,
    ] {
        assert!(parse_json_message(text).is_err(), "{text}");
    }
}

fn arb_sh_frame() -> impl Strategy<Value = ShFrame> {
    (0usize..=MAX_SH_DEGREE, any::<u64>(), -1e9f64..1e9).prop_flat_map(|(degree, seq, time)| {
        let value = -1e6f32..1e6;
        proptest::collection::vec(
            [value.clone(), value.clone(), value],
            (degree + 1) * (degree + 1),
        )
        .prop_map(move |coefficients| ShFrame {
            seq,
            time,
            coefficients,
        })
    })
}

proptest! {
    #[test]
    fn arbitrary_sh_sets_round_trip_and_caps_keep_whole_bands(
        frame in arb_sh_frame(),
        stale in any::<bool>(),
        cap in proptest::option::of(1usize..300),
        chunk in 1usize..100,
    ) {
        let mut bytes = Vec::new();
        encode_sh_frame(&frame, cap, stale, &mut bytes);
        let messages = decode_chunked(&bytes, || chunk);
        prop_assert_eq!(messages.len(), 1);
        let decoded = as_sh(messages[0].clone());
        prop_assert_eq!(decoded.stale, stale);
        // The largest whole set of bands within the cap: a prefix of the coefficients.
        let all = frame.coefficients.len();
        let mut bands = 1;
        while (bands + 1) * (bands + 1) <= cap.unwrap_or(usize::MAX).min(all) {
            bands += 1;
        }
        let kept = if cap.is_none() { all } else { bands * bands };
        prop_assert_eq!(&decoded.coefficients[..], &frame.coefficients[..kept]);
        let json = as_sh(parse_json_message(&sh_frame_to_json(&frame, cap, stale)).unwrap());
        prop_assert_eq!(json, decoded);
    }
}
