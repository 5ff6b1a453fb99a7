//! Binary encoding: frames (light lists, ASG sets, wavelet and SH sets), errors, goodbyes and
//! requests as length-prefixed messages (docs/protocol.md).

use super::*;

pub(super) fn put_header(out: &mut Vec<u8>, body_len: usize, message_type: u16) {
    // Callers keep body_len ≤ MAX_MESSAGE_LEN - 8, so the prefix fits a u32.
    out.extend_from_slice(&((body_len + 8) as u32).to_le_bytes());
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&message_type.to_le_bytes());
}

/// Appends one binary frame message for `frame` to `out`.
///
/// With `max_lights = Some(n)` and more than `n` lights, only the `n` lights of largest
/// luminance ([`Light::luminance`], Rec. 709) are sent — the ones that matter most for shading —
/// in their original order (by id); ties go to the earlier light. Capping selects, it never
/// merges or rescales: every kept light is sent bit for bit as it is in `frame` (so the energy of
/// the dropped lights is missing, not redistributed). A message carries at most
/// [`MAX_FRAME_LIGHTS`] lights; a longer list is capped to that. `stale` sets [`FLAG_STALE`].
///
/// Lights and time should be finite (the decomposition guarantees it); decoders reject
/// non-finite values.
pub fn encode_frame(frame: &LightFrame, max_lights: Option<usize>, stale: bool, out: &mut Vec<u8>) {
    let lights = select_lights(&frame.lights, max_lights);
    put_frame_head(
        out,
        frame.seq,
        frame.time,
        Representation::Lights,
        stale,
        lights.len(),
    );
    put_light_records(&lights, out);
}

// The light record is `Light`'s `repr(C)` layout: id, dir, rgb, solid angle, 4 bytes each.
const _: () = assert!(std::mem::size_of::<Light>() == LIGHT_RECORD_LEN);

/// Appends the records of `lights`. On a little-endian machine the records are the lights'
/// bytes ([`Light`] is `repr(C)` in record order), so this is one copy.
pub(super) fn put_light_records(lights: &[Light], out: &mut Vec<u8>) {
    if cfg!(target_endian = "little") {
        out.extend_from_slice(bytemuck::cast_slice(lights));
        return;
    }
    for light in lights {
        out.extend_from_slice(&light.id.to_le_bytes());
        for v in light.dir.iter().chain(&light.rgb) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&light.solid_angle.to_le_bytes());
    }
}

/// The header and the 24 fixed bytes of a frame with `count` records of `representation`
/// (whose layout must exist; callers pass lights or ASG, and keep `count` within the limit).
pub(super) fn put_frame_head(
    out: &mut Vec<u8>,
    seq: u64,
    time: f64,
    representation: Representation,
    stale: bool,
    count: usize,
) {
    let layout = representation.frame_layout().unwrap_or(FrameLayout {
        prefix_len: 0,
        record_len: 0,
    });
    let body_len = FRAME_FIXED_LEN + layout.prefix_len + count * layout.record_len;
    out.reserve(4 + 8 + body_len);
    put_header(out, body_len, TYPE_FRAME);
    out.extend_from_slice(&seq.to_le_bytes());
    out.extend_from_slice(&time.to_le_bytes());
    out.push(representation.code());
    out.push(if stale { FLAG_STALE } else { 0 });
    out.extend_from_slice(&0u16.to_le_bytes());
    out.extend_from_slice(&(count as u32).to_le_bytes());
}

/// Appends one binary ASG frame message (representation 1) for `set` to `out`.
///
/// With `max_lobes = Some(n)` and more than `n` lobes, only the `n` lobes of largest energy
/// luminance ([`AsgLobe::luminance`]) are sent, in their original order (by id), each bit for
/// bit as in `set`; ties go to the earlier lobe. A message carries at most
/// [`MAX_FRAME_LOBES`] lobes. `stale` sets [`FLAG_STALE`]. Values should be finite with
/// positive bandwidths and integral and an orthonormal frame (what [`AsgLobe::from_asg`]
/// gives); decoders reject anything else.
pub fn encode_asg_frame(set: &AsgSet, max_lobes: Option<usize>, stale: bool, out: &mut Vec<u8>) {
    let lobes = select_lobes(&set.lobes, max_lobes);
    put_frame_head(
        out,
        set.seq,
        set.time,
        Representation::Asg,
        stale,
        lobes.len(),
    );
    for lobe in lobes.iter() {
        out.extend_from_slice(&lobe.id.to_le_bytes());
        for v in lobe.record_floats() {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
}

/// Appends one binary wavelet frame message (representation 2) for `frame` to `out`.
///
/// With `max_coefficients = Some(n)` and more than `n` coefficients, `n` are sent: the scaling
/// coefficients first, then the details of largest RGB norm (ties to the lower index), in
/// index order, each bit for bit as in the set (capping drops coefficients, it never alters
/// one; with the scaling coefficients kept, a capped set keeps the map's ∫L dω). A message carries at most
/// [`MAX_FRAME_COEFFICIENTS`]. The set should be valid ([`WaveletSet::validate`]: finite
/// values, indices below side², sorted and unique; the daemon's stage checks); decoders reject
/// anything else. `stale` sets [`FLAG_STALE`].
pub fn encode_wavelet_frame(
    frame: &WaveletFrame,
    max_coefficients: Option<usize>,
    stale: bool,
    out: &mut Vec<u8>,
) {
    let set = &frame.set;
    let coefficients = select_coefficients(set, max_coefficients);
    put_frame_head(
        out,
        frame.seq,
        frame.time,
        Representation::Wavelet,
        stale,
        coefficients.len(),
    );
    out.push(set.basis.code());
    out.push(u8::try_from(set.levels).unwrap_or(u8::MAX));
    out.push(WAVELET_MAP_OCTAHEDRAL);
    out.push(0);
    out.extend_from_slice(&set.side.to_le_bytes());
    for (index, rgb) in coefficients.iter() {
        out.extend_from_slice(&index.to_le_bytes());
        for v in rgb {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
}

/// Appends one binary SH frame message (representation 3) for `frame` to `out`.
///
/// With `max_coefficients = Some(n)`, the coefficients of the highest complete degree that
/// fits are sent: degree ⌊√n⌋ − 1 (at least degree 0), each bit for bit as in the frame — the
/// same environment band-limited further. The prefix carries the degree sent and
/// [`SH_BASIS_REAL`]. The frame should be valid ([`validate_sh_set`]: (L + 1)² finite
/// coefficients, L ≤ [`MAX_SH_DEGREE`]; the daemon's stage checks); decoders reject anything
/// else. `stale` sets [`FLAG_STALE`].
pub fn encode_sh_frame(
    frame: &ShFrame,
    max_coefficients: Option<usize>,
    stale: bool,
    out: &mut Vec<u8>,
) {
    let coefficients = select_sh(&frame.coefficients, max_coefficients);
    put_frame_head(
        out,
        frame.seq,
        frame.time,
        Representation::Sh,
        stale,
        coefficients.len(),
    );
    out.extend_from_slice(&[sh_degree_field(coefficients.len()), SH_BASIS_REAL, 0, 0]);
    for rgb in coefficients {
        for v in rgb {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
}

/// `text` cut to at most [`MAX_TEXT_LEN`] bytes at a character boundary.
pub(super) fn clip_text(text: &str) -> &str {
    if text.len() <= MAX_TEXT_LEN {
        return text;
    }
    let mut end = MAX_TEXT_LEN;
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    &text[..end]
}

pub(super) fn encode_text(message_type: u16, code: u16, text: &str, out: &mut Vec<u8>) {
    let text = clip_text(text);
    put_header(out, 6 + text.len(), message_type);
    out.extend_from_slice(&code.to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(text.as_bytes());
}

/// Appends an error message (`code` from [`code`], e.g. [`ProtocolError::code`]) to `out`.
/// Text longer than [`MAX_TEXT_LEN`] bytes is cut at a character boundary.
pub fn encode_error(code: u16, message: &str, out: &mut Vec<u8>) {
    encode_text(TYPE_ERROR, code, message, out);
}

/// Appends a goodbye message (code [`code::SHUTDOWN`]) to `out`. Text longer than
/// [`MAX_TEXT_LEN`] bytes is cut at a character boundary.
pub fn encode_goodbye(message: &str, out: &mut Vec<u8>) {
    encode_text(TYPE_GOODBYE, code::SHUTDOWN, message, out);
}

/// Appends a subscribe message carrying `request` to `out`.
pub fn encode_request(request: &Request, out: &mut Vec<u8>) {
    put_header(out, SUBSCRIBE_BODY_LEN, TYPE_SUBSCRIBE);
    out.extend_from_slice(&request.max_lights.to_le_bytes());
    out.push(request.representation.code());
    out.push(request.format.code());
    out.extend_from_slice(&0u16.to_le_bytes());
}
