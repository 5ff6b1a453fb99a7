//! Binary decoding of one message: the header checks, the bodies of every message type and
//! representation, and the validity checks shared with the encoders (docs/protocol.md).

use super::*;

pub(super) fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}

pub(super) fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

pub(super) fn u64_at(b: &[u8], at: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(a)
}

pub(super) fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_bits(u32_at(b, at))
}

pub(super) fn kind_name(message_type: u16) -> &'static str {
    match message_type {
        TYPE_FRAME => "frame",
        TYPE_ERROR => "error",
        TYPE_GOODBYE => "goodbye",
        TYPE_SUBSCRIBE => "subscribe",
        _ => "unknown",
    }
}

/// Checks whatever part of the 12-byte header `b` already holds (it may hold less). Returns the
/// length prefix once it is known.
pub(super) fn check_header(b: &[u8]) -> Result<Option<usize>, ProtocolError> {
    // Nothing is judged before the magic has arrived: bytes that are no envlight stream (an
    // HTTP request on the TCP port) are named as such, not as an absurd length, however the
    // first bytes were split.
    if b.len() < 8 {
        return Ok(None);
    }
    let found = [b[4], b[5], b[6], b[7]];
    if found != MAGIC {
        return Err(ProtocolError::BadMagic { found });
    }
    let len = u32_at(b, 0) as usize;
    if len > MAX_MESSAGE_LEN {
        return Err(ProtocolError::Oversized { len: len as u64 });
    }
    if b.len() >= 10 {
        let version = u16_at(b, 8);
        if version != VERSION {
            return Err(ProtocolError::UnsupportedVersion { version });
        }
    }
    if len < 8 {
        return Err(ProtocolError::Inconsistent {
            kind: "binary",
            reason: format!("length prefix {len} is shorter than the 8-byte header after it"),
        });
    }
    if b.len() >= 12 {
        let message_type = u16_at(b, 10);
        let body = len - 8;
        let ok = match message_type {
            // The record size depends on the representation, in the body: checked there.
            TYPE_FRAME => body >= FRAME_FIXED_LEN,
            TYPE_ERROR | TYPE_GOODBYE => body >= 6,
            TYPE_SUBSCRIBE => body == SUBSCRIBE_BODY_LEN,
            _ => return Err(ProtocolError::UnknownType { message_type }),
        };
        if !ok {
            return Err(ProtocolError::Inconsistent {
                kind: kind_name(message_type),
                reason: format!("length prefix {len} does not fit the message layout"),
            });
        }
    }
    Ok(Some(len))
}

pub(super) fn finite(v: f32, field: impl FnOnce() -> String) -> Result<f32, ProtocolError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(ProtocolError::NonFinite { field: field() })
    }
}

/// Decodes a body (the bytes after the 12-byte header) whose type and length `check_header`
/// accepted. A light list's records go into `spare` (cleared first), which the message then
/// owns: a client that hands its lists back ([`Decoder::recycle`]) decodes without allocating.
pub(super) fn decode_body(
    message_type: u16,
    body: &[u8],
    spare: &mut Vec<Light>,
) -> Result<Message, ProtocolError> {
    match message_type {
        TYPE_FRAME => {
            let seq = u64_at(body, 0);
            let time = f64::from_le_bytes(body[8..16].try_into().unwrap_or([0; 8]));
            if !time.is_finite() {
                return Err(ProtocolError::NonFinite {
                    field: "frame time".into(),
                });
            }
            let representation = Representation::from_code(body[16])?;
            let Some(layout) = representation.frame_layout() else {
                return Err(ProtocolError::UnsupportedRepresentation { representation });
            };
            let stale = body[17] & FLAG_STALE != 0;
            let count = u32_at(body, 20) as usize;
            let rest = &body[FRAME_FIXED_LEN..];
            let expected = count
                .checked_mul(layout.record_len)
                .and_then(|n| n.checked_add(layout.prefix_len));
            if expected != Some(rest.len()) {
                return Err(ProtocolError::Inconsistent {
                    kind: "frame",
                    reason: format!(
                        "count {count} × {} bytes per {} record{} ≠ {} bytes after the count",
                        layout.record_len,
                        representation.name(),
                        if layout.prefix_len > 0 {
                            format!(" + {} bytes of prefix", layout.prefix_len)
                        } else {
                            String::new()
                        },
                        rest.len()
                    ),
                });
            }
            let records = &rest[layout.prefix_len..];
            if representation == Representation::Wavelet {
                let set = decode_wavelet(&rest[..layout.prefix_len], records)?;
                return Ok(Message::Wavelet(WaveletFrameMessage {
                    seq,
                    time,
                    stale,
                    set,
                }));
            }
            if representation == Representation::Sh {
                return Ok(Message::Sh(ShFrameMessage {
                    seq,
                    time,
                    stale,
                    coefficients: decode_sh(&rest[..layout.prefix_len], records)?,
                }));
            }
            if representation == Representation::Asg {
                return Ok(Message::Asg(AsgFrameMessage {
                    seq,
                    time,
                    stale,
                    lobes: decode_lobes(records)?,
                }));
            }
            let mut lights = std::mem::take(spare);
            decode_lights(records, count, &mut lights)?;
            Ok(Message::Frame(FrameMessage {
                seq,
                time,
                representation,
                stale,
                lights,
            }))
        }
        TYPE_ERROR | TYPE_GOODBYE => {
            let kind = kind_name(message_type);
            let code = u16_at(body, 0);
            let text_len = u32_at(body, 2) as usize;
            let text = &body[6..];
            if text.len() != text_len {
                return Err(ProtocolError::Inconsistent {
                    kind,
                    reason: format!(
                        "text length {text_len} ≠ {} bytes left in the message",
                        text.len()
                    ),
                });
            }
            let message = std::str::from_utf8(text)
                .map_err(|e| ProtocolError::InvalidUtf8 {
                    kind,
                    detail: e.to_string(),
                })?
                .to_owned();
            Ok(if message_type == TYPE_ERROR {
                Message::Error { code, message }
            } else {
                Message::Goodbye { message }
            })
        }
        TYPE_SUBSCRIBE => Ok(Message::Subscribe(Request {
            max_lights: u32_at(body, 0),
            representation: Representation::from_code(body[4])?,
            format: Format::from_code(body[5])?,
        })),
        message_type => Err(ProtocolError::UnknownType { message_type }),
    }
}

/// Light records (whose total length, `count` records, the caller checked).
///
/// Every client decodes every frame (256 lights: 8 KiB, 60 times a second), so this is the
/// tight loop of a client's CPU time. On a little-endian machine the records are copied into
/// the lights as they are ([`Light`] is `repr(C)` in record order) and then the seven floats
/// of every light are checked for finiteness in one pass over the words; only when one fails
/// are the lights looked at one by one, to name the first bad field. Elsewhere each record
/// is read as one fixed 32-byte array and its seven floats checked together. (With a
/// bounds-checked read and a `Result` per float, decoding took about half of the stream
/// bench's client CPU time; docs/performance.md "Streaming".)
///
/// The lights go into `lights`, cleared first (its allocation is reused when large enough);
/// after an error they are unspecified.
pub(super) fn decode_lights(
    records: &[u8],
    count: usize,
    lights: &mut Vec<Light>,
) -> Result<(), ProtocolError> {
    lights.clear();
    if cfg!(target_endian = "little") && records.len() == count * LIGHT_RECORD_LEN {
        lights.resize(count, Light::zeroed());
        bytemuck::cast_slice_mut::<Light, u8>(lights).copy_from_slice(records);
        // A float is finite iff its exponent bits are not all ones; the id (word 0) is not a
        // float. One flag per word of the record, OR-ed over all lights: a branch-free pass
        // that compiles to vector compares.
        let exponent = 0x7f80_0000u32;
        let words: &[u32] = bytemuck::cast_slice(lights);
        let mut not_finite = [0u32; 8];
        for w in words.chunks_exact(8) {
            for (flag, &x) in not_finite.iter_mut().zip(w) {
                *flag |= u32::from(x & exponent == exponent);
            }
        }
        let all_finite = not_finite[1..].iter().all(|&flag| flag == 0);
        if all_finite {
            return Ok(());
        }
        lights.clear();
    }
    decode_lights_one_by_one(records, count, lights)
}

/// [`decode_lights`] record by record: the portable path, and the one that names the first
/// non-finite field.
pub(super) fn decode_lights_one_by_one(
    records: &[u8],
    count: usize,
    lights: &mut Vec<Light>,
) -> Result<(), ProtocolError> {
    lights.reserve(count);
    for (i, r) in records.chunks_exact(LIGHT_RECORD_LEN).enumerate() {
        let Ok(r) = <&[u8; LIGHT_RECORD_LEN]>::try_from(r) else {
            continue; // chunks_exact: never shorter
        };
        let word =
            |k: usize| u32::from_le_bytes([r[4 * k], r[4 * k + 1], r[4 * k + 2], r[4 * k + 3]]);
        let float = |k: usize| f32::from_bits(word(k));
        // A float is finite iff its exponent bits are not all ones.
        let exponent = 0x7f80_0000;
        let all_finite = (1..8).all(|k| word(k) & exponent != exponent);
        if !all_finite {
            let names = ["dir", "dir", "dir", "rgb", "rgb", "rgb", "solid_angle"];
            for (k, name) in (1..8).zip(names) {
                finite(float(k), || format!("light {i} {name}"))?;
            }
        }
        lights.push(Light {
            id: word(0),
            dir: [float(1), float(2), float(3)],
            rgb: [float(4), float(5), float(6)],
            solid_angle: float(7),
        });
    }
    Ok(())
}

/// ASG lobe records (whose total length the caller checked).
pub(super) fn decode_lobes(records: &[u8]) -> Result<Vec<AsgLobe>, ProtocolError> {
    let mut lobes = Vec::with_capacity(records.len() / ASG_RECORD_LEN);
    for (i, r) in records.chunks_exact(ASG_RECORD_LEN).enumerate() {
        let f = |at: usize, name: &str| finite(f32_at(r, at), || format!("lobe {i} {name}"));
        let lobe = AsgLobe {
            id: u32_at(r, 0),
            axis: [f(4, "axis")?, f(8, "axis")?, f(12, "axis")?],
            tangent: [f(16, "tangent")?, f(20, "tangent")?, f(24, "tangent")?],
            lambda: f(28, "lambda")?,
            mu: f(32, "mu")?,
            rgb: [f(36, "rgb")?, f(40, "rgb")?, f(44, "rgb")?],
            integral: f(48, "integral")?,
        };
        validate_lobe(i, &lobe)?;
        lobes.push(lobe);
    }
    Ok(lobes)
}

/// A wavelet set from its 8-byte prefix and its records (whose total length the caller checked).
pub(super) fn decode_wavelet(prefix: &[u8], records: &[u8]) -> Result<WaveletSet, ProtocolError> {
    let bad = |reason: String| ProtocolError::InvalidWaveletSet { reason };
    let basis = Basis::from_code(prefix[0]).ok_or_else(|| {
        bad(format!(
            "unknown basis code {} (1 = haar, 2..=10 = db2..db10, 17..=21 = coif1..coif5)",
            prefix[0]
        ))
    })?;
    if prefix[2] != WAVELET_MAP_OCTAHEDRAL {
        return Err(bad(format!(
            "unknown map code {} (0 = equal-area octahedral)",
            prefix[2]
        )));
    }
    let mut coefficients = Vec::with_capacity(records.len() / WAVELET_RECORD_LEN);
    for (i, r) in records.chunks_exact(WAVELET_RECORD_LEN).enumerate() {
        let f = |at: usize| finite(f32_at(r, at), || format!("coefficient {i} rgb"));
        coefficients.push((u32_at(r, 0), [f(4)?, f(8)?, f(12)?]));
    }
    let set = WaveletSet {
        basis,
        side: u32_at(prefix, 4),
        levels: u32::from(prefix[1]),
        coefficients,
    };
    validate_wavelet_set(&set)?;
    Ok(set)
}

/// An SH set from its 4-byte prefix and its records (whose total length the caller checked).
pub(super) fn decode_sh(prefix: &[u8], records: &[u8]) -> Result<Vec<[f32; 3]>, ProtocolError> {
    let bad = |reason: String| ProtocolError::InvalidShSet { reason };
    if prefix[1] != SH_BASIS_REAL {
        return Err(bad(format!(
            "unknown basis code {} (0 = real orthonormal, envlight's axes)",
            prefix[1]
        )));
    }
    let degree = usize::from(prefix[0]);
    if degree > MAX_SH_DEGREE {
        return Err(bad(format!("degree {degree} (at most {MAX_SH_DEGREE})")));
    }
    let count = records.len() / SH_RECORD_LEN;
    if count != crate::sh::coefficient_count(degree) {
        return Err(bad(format!(
            "{count} coefficients for degree {degree} (it has {})",
            crate::sh::coefficient_count(degree)
        )));
    }
    let mut coefficients = Vec::with_capacity(count);
    for (i, r) in records.chunks_exact(SH_RECORD_LEN).enumerate() {
        let f = |at: usize| finite(f32_at(r, at), || format!("SH coefficient {i}"));
        coefficients.push([f(0)?, f(4)?, f(8)?]);
    }
    Ok(coefficients)
}

/// Whether an SH set may be sent: (L + 1)² coefficients for an L up to [`MAX_SH_DEGREE`],
/// every value finite. Returns L. Decoders of JSON frames apply it; the daemon's SH stage
/// applies it before publishing.
pub fn validate_sh_set(coefficients: &[[f32; 3]]) -> Result<usize, ProtocolError> {
    let degree =
        crate::sh::degree_of(coefficients.len()).ok_or_else(|| ProtocolError::InvalidShSet {
            reason: format!(
                "{} coefficients: not (degree + 1)² for a degree up to {MAX_SH_DEGREE}",
                coefficients.len()
            ),
        })?;
    if let Some(i) = coefficients
        .iter()
        .position(|rgb| !rgb.iter().all(|v| v.is_finite()))
    {
        return Err(ProtocolError::NonFinite {
            field: format!("SH coefficient {i}"),
        });
    }
    Ok(degree)
}

/// Whether `set` may be sent: a supported basis, a power-of-two side in 2..=[`MAX_WAVELET_SIDE`],
/// levels at most log2(side), at most [`MAX_FRAME_COEFFICIENTS`] coefficients with finite
/// values and indices below side², strictly increasing. Decoders apply it to every received
/// set; the daemon's wavelet stage applies it before publishing. Allocates nothing, whatever
/// side a peer declares.
pub fn validate_wavelet_set(set: &WaveletSet) -> Result<(), ProtocolError> {
    let bad = |reason: String| Err(ProtocolError::InvalidWaveletSet { reason });
    if !set.basis.is_supported() {
        return bad(format!("unsupported basis {:?}", set.basis));
    }
    let side = set.side;
    if !(2..=MAX_WAVELET_SIDE).contains(&side) || !side.is_power_of_two() {
        return bad(format!(
            "side {side} is not a power of two in 2..={MAX_WAVELET_SIDE}"
        ));
    }
    let max_levels = side.trailing_zeros();
    if set.levels > max_levels {
        return bad(format!(
            "{} levels on side {side} (at most {max_levels})",
            set.levels
        ));
    }
    if set.coefficients.len() > MAX_FRAME_COEFFICIENTS {
        return bad(format!(
            "{} coefficients (at most {MAX_FRAME_COEFFICIENTS} per frame)",
            set.coefficients.len()
        ));
    }
    let n = u64::from(side) * u64::from(side);
    let mut previous: Option<u32> = None;
    for (i, (index, rgb)) in set.coefficients.iter().enumerate() {
        if u64::from(*index) >= n {
            return bad(format!(
                "coefficient {i} has index {index}, outside 0..{n} (side {side})"
            ));
        }
        if previous.is_some_and(|p| *index <= p) {
            return bad(format!(
                "coefficient {i} has index {index} after {}: indices must be strictly increasing",
                previous.unwrap_or_default()
            ));
        }
        if rgb.iter().any(|v| !v.is_finite()) {
            return Err(ProtocolError::NonFinite {
                field: format!("coefficient {i} rgb"),
            });
        }
        previous = Some(*index);
    }
    Ok(())
}

/// Whether `lobe` (at position `index` of its frame) may be sent: finite values, positive
/// bandwidths and integral, an orthonormal frame within [`ASG_FRAME_TOLERANCE`]. Decoders
/// apply it to every received lobe; the daemon's ASG stage applies it before publishing.
pub fn validate_lobe(index: usize, lobe: &AsgLobe) -> Result<(), ProtocolError> {
    if lobe.record_floats().any(|v| !v.is_finite()) {
        return Err(ProtocolError::NonFinite {
            field: format!("lobe {index}"),
        });
    }
    let bad = |reason: String| Err(ProtocolError::InvalidLobe { index, reason });
    for (name, v) in [
        ("lambda", lobe.lambda),
        ("mu", lobe.mu),
        ("integral", lobe.integral),
    ] {
        if v.is_nan() || v <= 0.0 {
            return bad(format!("{name} = {v} must be positive"));
        }
    }
    let dot = |a: [f32; 3], b: [f32; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    for (name, v) in [("axis", lobe.axis), ("tangent", lobe.tangent)] {
        let len = dot(v, v).sqrt();
        if (len - 1.0).abs() > ASG_FRAME_TOLERANCE || len.is_nan() {
            return bad(format!("{name} has length {len}, not 1"));
        }
    }
    let d = dot(lobe.axis, lobe.tangent);
    if d.abs() > ASG_FRAME_TOLERANCE || d.is_nan() {
        return bad(format!("axis·tangent = {d}, not 0"));
    }
    Ok(())
}

/// Decodes exactly one complete binary message from `bytes` (length prefix included); trailing
/// bytes are an error. For streams use [`Decoder`].
pub fn decode_message(bytes: &[u8]) -> Result<Message, ProtocolError> {
    let mut decoder = Decoder::new();
    let mut input = bytes;
    match decoder.next_from(&mut input)? {
        Some(_) if !input.is_empty() => Err(ProtocolError::Inconsistent {
            kind: "binary",
            reason: format!("{} bytes after the end of the message", input.len()),
        }),
        Some(message) => Ok(message),
        None => Err(ProtocolError::Truncated {
            buffered: bytes.len(),
        }),
    }
}
