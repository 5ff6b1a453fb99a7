//! The envlight wire protocol, version 1: light lists, ASG sets and wavelet coefficient sets as
//! length-prefixed binary
//! messages, and the JSON form of the same for WebSocket and scripts. `docs/protocol.md` is the
//! byte-exact contract; this module implements it and its tests pin it.
//!
//! Every binary message is
//!
//! ```text
//! u32 length (bytes that follow) | "ENVL" | u16 version | u16 type | body
//! ```
//!
//! all little-endian. Server → client: [`TYPE_FRAME`] (a light list, an ASG set or a wavelet
//! set), [`TYPE_ERROR`] (the
//! connection is about to close because of the error), [`TYPE_GOODBYE`] (the daemon is shutting
//! down). Client → server: [`TYPE_SUBSCRIBE`] (a [`Request`]: light cap, representation, binary or
//! JSON). The JSON forms are [`frame_to_json`], [`asg_frame_to_json`],
//! [`wavelet_frame_to_json`], [`error_to_json`],
//! [`goodbye_to_json`], [`request_to_json`], and the parsers [`parse_json_request`] and
//! [`parse_json_message`].
//!
//! A frame's records depend on its representation ([`Representation::frame_layout`]): 32-byte
//! light records (code 0, [`encode_frame`]), 52-byte ASG lobe records (code 1,
//! [`encode_asg_frame`]), or an 8-byte prefix (basis, levels, map, side) and 16-byte wavelet
//! coefficient records (code 2, [`encode_wavelet_frame`], checked by [`validate_wavelet_set`]).
//! The decoder takes the prefix and record sizes from the representation byte, so a
//! representation is added by giving it a layout, an encoder and a record decoder.
//!
//! [`Decoder`] reads messages from a byte stream fed in arbitrary pieces. It never panics on any
//! input, rejects an oversized length prefix as soon as the 12-byte header has arrived (before any
//! of the body is stored, so a peer cannot make it allocate more than [`MAX_MESSAGE_LEN`]), and
//! after an error stays failed: once framing is lost the connection must be closed, and
//! [`ProtocolError::code`] gives the error code to send in the closing [`encode_error`] message.

use bytemuck::Zeroable;
use std::borrow::Cow;

use serde::{Deserialize, Serialize};

use crate::light::{AsgLobe, AsgSet, Light, LightFrame};
use crate::wavelet::{Basis, WaveletSet};

/// The four bytes after the length prefix of every message.
pub const MAGIC: [u8; 4] = *b"ENVL";
/// The protocol version this build writes and reads.
pub const VERSION: u16 = 1;

/// Message type: a light list (server → client).
pub const TYPE_FRAME: u16 = 1;
/// Message type: an error; the sender closes the connection after it.
pub const TYPE_ERROR: u16 = 2;
/// Message type: goodbye; the daemon is shutting down and closes the connection after it.
pub const TYPE_GOODBYE: u16 = 3;
/// Message type: subscribe (client → server), carrying a [`Request`].
pub const TYPE_SUBSCRIBE: u16 = 16;

/// Size of the common header including the length prefix: length, magic, version, type.
pub const HEADER_LEN: usize = 12;
/// Size of a frame message's fixed part after the common header: seq, time, representation,
/// flags, reserved, count.
pub const FRAME_FIXED_LEN: usize = 24;
/// Size of one light record: u32 id, 3×f32 dir, 3×f32 rgb, f32 solid angle.
pub const LIGHT_RECORD_LEN: usize = 32;
/// Size of one ASG lobe record: u32 id, 3×f32 axis, 3×f32 tangent, f32 λ, f32 μ, 3×f32 rgb,
/// f32 integral.
pub const ASG_RECORD_LEN: usize = 52;
/// Size of a subscribe message's body after the common header.
pub const SUBSCRIBE_BODY_LEN: usize = 8;
/// The largest accepted value of the length prefix (bytes after it): 1 MiB.
pub const MAX_MESSAGE_LEN: usize = 1 << 20;
/// The most lights one frame message can carry within [`MAX_MESSAGE_LEN`] (32767).
pub const MAX_FRAME_LIGHTS: usize = (MAX_MESSAGE_LEN - 8 - FRAME_FIXED_LEN) / LIGHT_RECORD_LEN;
// The largest frame fits in a message, one more light would not.
const _: () = assert!(8 + FRAME_FIXED_LEN + MAX_FRAME_LIGHTS * LIGHT_RECORD_LEN <= MAX_MESSAGE_LEN);
const _: () =
    assert!(8 + FRAME_FIXED_LEN + (MAX_FRAME_LIGHTS + 1) * LIGHT_RECORD_LEN > MAX_MESSAGE_LEN);
/// The most lobes one ASG frame message can carry within [`MAX_MESSAGE_LEN`] (20164).
pub const MAX_FRAME_LOBES: usize = (MAX_MESSAGE_LEN - 8 - FRAME_FIXED_LEN) / ASG_RECORD_LEN;
/// Size of the wavelet prefix after `count`: u8 basis, u8 levels, u8 map, u8 reserved, u32 side.
pub const WAVELET_PREFIX_LEN: usize = 8;
/// Size of one wavelet coefficient record: u32 index, 3×f32 rgb.
pub const WAVELET_RECORD_LEN: usize = 16;
/// The most coefficients one wavelet frame message can carry within [`MAX_MESSAGE_LEN`] (65533).
pub const MAX_FRAME_COEFFICIENTS: usize =
    (MAX_MESSAGE_LEN - 8 - FRAME_FIXED_LEN - WAVELET_PREFIX_LEN) / WAVELET_RECORD_LEN;
/// The largest wavelet map side a frame may declare (2^15: side² indices fit a u32 easily).
pub const MAX_WAVELET_SIDE: u32 = 1 << 15;
/// Wavelet map code: the equal-area octahedral map of [`crate::wavelet::sphere`] (the only one
/// in version 1).
pub const WAVELET_MAP_OCTAHEDRAL: u8 = 0;
/// Tolerance of an ASG record's frame: |axis|, |tangent| within this of 1 and |axis·tangent|
/// at most this (f32 rounding of a unit frame is about 10⁻⁷).
pub const ASG_FRAME_TOLERANCE: f32 = 1e-3;
/// Longest text (UTF-8 bytes) written in an error or goodbye message; longer text is cut at a
/// character boundary.
pub const MAX_TEXT_LEN: usize = 4096;

/// Frame flag bit 0: the lights are the last known ones; the source is lost.
pub const FLAG_STALE: u8 = 1;

/// Error codes carried by [`TYPE_ERROR`] messages (and by [`ProtocolError::code`]).
pub mod code {
    /// Malformed bytes: bad magic, inconsistent lengths, non-finite floats, invalid UTF-8, a
    /// stream that ended inside a message.
    pub const MALFORMED: u16 = 1;
    /// The message's protocol version is not spoken here.
    pub const UNSUPPORTED_VERSION: u16 = 2;
    /// The message type is unknown.
    pub const UNKNOWN_TYPE: u16 = 3;
    /// The length prefix exceeds the maximum message size.
    pub const TOO_LARGE: u16 = 4;
    /// The request is well formed but invalid: bad JSON, unknown field, unknown
    /// representation or format code.
    pub const BAD_REQUEST: u16 = 5;
    /// The representation is valid but not produced by this daemon (or has no v1 layout).
    pub const UNSUPPORTED_REPRESENTATION: u16 = 6;
    /// A valid message that the receiver does not accept in this direction (e.g. a client
    /// sending a frame).
    pub const UNEXPECTED_MESSAGE: u16 = 7;
    /// The server failed for a reason that is not the client's fault.
    pub const INTERNAL: u16 = 100;
    /// Goodbye code: the daemon is shutting down.
    pub const SHUTDOWN: u16 = 0;
}

/// What kind of lighting a frame carries: lights (0), ASG sets (1) and wavelet coefficient sets
/// (2) all have frame layouts in version 1.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Representation {
    /// Directional lights (code 0).
    #[default]
    Lights,
    /// Anisotropic spherical Gaussians (code 1).
    Asg,
    /// Sparse wavelet coefficients (code 2).
    Wavelet,
}

impl Representation {
    /// The wire code.
    pub fn code(self) -> u8 {
        match self {
            Representation::Lights => 0,
            Representation::Asg => 1,
            Representation::Wavelet => 2,
        }
    }

    /// The representation with this wire code.
    pub fn from_code(code: u8) -> Result<Self, ProtocolError> {
        match code {
            0 => Ok(Representation::Lights),
            1 => Ok(Representation::Asg),
            2 => Ok(Representation::Wavelet),
            _ => Err(ProtocolError::UnknownRepresentation { code }),
        }
    }

    /// The layout of this representation's frame records, `None` if it had none in this
    /// build (every representation of version 1 has one now; the decoder keeps the check for
    /// codes added later).
    pub fn frame_layout(self) -> Option<FrameLayout> {
        match self {
            Representation::Lights => Some(FrameLayout {
                prefix_len: 0,
                record_len: LIGHT_RECORD_LEN,
            }),
            Representation::Asg => Some(FrameLayout {
                prefix_len: 0,
                record_len: ASG_RECORD_LEN,
            }),
            Representation::Wavelet => Some(FrameLayout {
                prefix_len: WAVELET_PREFIX_LEN,
                record_len: WAVELET_RECORD_LEN,
            }),
        }
    }

    /// The name used in JSON and messages: `lights`, `asg`, `wavelet`.
    pub fn name(self) -> &'static str {
        match self {
            Representation::Lights => "lights",
            Representation::Asg => "asg",
            Representation::Wavelet => "wavelet",
        }
    }
}

/// How a frame's body continues after the 24 fixed bytes (seq … count): `prefix_len` bytes of
/// representation-specific fields, then `count` records of `record_len` bytes each.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameLayout {
    /// Bytes between `count` and the first record.
    pub prefix_len: usize,
    /// Bytes per record.
    pub record_len: usize,
}

/// How the server encodes the frames it sends to a client.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// Binary frame messages (code 0).
    Binary,
    /// JSON text, one object per frame (code 1).
    #[default]
    Json,
}

impl Format {
    /// The wire code.
    pub fn code(self) -> u8 {
        match self {
            Format::Binary => 0,
            Format::Json => 1,
        }
    }

    /// The format with this wire code.
    pub fn from_code(code: u8) -> Result<Self, ProtocolError> {
        match code {
            0 => Ok(Format::Binary),
            1 => Ok(Format::Json),
            _ => Err(ProtocolError::UnknownFormat { code }),
        }
    }
}

/// A client's subscription: what it wants to receive.
///
/// JSON form: `{"subscribe": {"max_lights": 64, "representation": "lights", "format": "json"}}`;
/// every field is optional (defaults: all lights, `"lights"`, `"json"`). `max_lights` caps
/// whatever the representation's records are: lights, or lobes of an ASG set.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Request {
    /// At most this many lights (or ASG lobes) per frame; 0 = all.
    pub max_lights: u32,
    /// The representation wanted.
    pub representation: Representation,
    /// Binary or JSON frames.
    pub format: Format,
}

impl Request {
    /// The light cap as [`encode_frame`] takes it: `None` for all lights.
    pub fn cap(&self) -> Option<usize> {
        (self.max_lights != 0).then_some(self.max_lights as usize)
    }
}

/// A decoded light-list message.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameMessage {
    /// Sequence number of the source frame.
    pub seq: u64,
    /// Capture time of the source frame, seconds since the source started.
    pub time: f64,
    /// Always [`Representation::Lights`] in version 1.
    pub representation: Representation,
    /// The lights are the last known ones; the source is lost.
    pub stale: bool,
    /// The lights, in the order they were sent (by id, as in [`LightFrame`]).
    pub lights: Vec<Light>,
}

impl FrameMessage {
    /// The light list without the transport fields.
    pub fn into_light_frame(self) -> LightFrame {
        LightFrame {
            seq: self.seq,
            time: self.time,
            lights: self.lights,
        }
    }
}

/// A decoded ASG-set message (representation 1).
#[derive(Clone, Debug, PartialEq)]
pub struct AsgFrameMessage {
    /// Sequence number of the source frame.
    pub seq: u64,
    /// Capture time of the source frame, seconds since the source started.
    pub time: f64,
    /// The lobes are the last known ones; the source is lost.
    pub stale: bool,
    /// The lobes, in the order they were sent (by id).
    pub lobes: Vec<AsgLobe>,
}

impl AsgFrameMessage {
    /// The ASG set without the transport fields.
    pub fn into_asg_set(self) -> AsgSet {
        AsgSet {
            seq: self.seq,
            time: self.time,
            lobes: self.lobes,
        }
    }
}

/// A wavelet coefficient set of one source frame, as the daemon's wavelet stage publishes it
/// and the wire carries it (representation 2).
#[derive(Clone, Debug, PartialEq)]
pub struct WaveletFrame {
    /// Sequence number of the source frame.
    pub seq: u64,
    /// Capture time of the source frame, seconds since the source started.
    pub time: f64,
    /// The kept coefficients, with basis, side and levels.
    pub set: WaveletSet,
}

impl WaveletFrame {
    /// ∫L dω (W/m² per channel, the counterpart of the sum of a light list's `rgb`) from the
    /// scaling coefficients the set holds: the top-left (side/2^levels)² block of the layout
    /// (a capped frame keeps them first).
    /// Every orthonormal analysis step halves the sum of a 2-D signal, so Σ texels =
    /// 2^levels · Σ scaling coefficients, and a texel has solid angle 4π/side². Exact when all
    /// scaling coefficients are kept (with the full pyramid there is one, index 0).
    pub fn integral(&self) -> [f64; 3] {
        let set = &self.set;
        let side = u64::from(set.side.max(1));
        let block = side >> set.levels.min(31);
        let mut sum = [0.0f64; 3];
        for (index, rgb) in &set.coefficients {
            let (row, col) = (u64::from(*index) / side, u64::from(*index) % side);
            if row < block && col < block {
                for c in 0..3 {
                    sum[c] += f64::from(rgb[c]);
                }
            }
        }
        let scale = 2f64.powi(set.levels.min(31) as i32) * 4.0 * std::f64::consts::PI
            / (side * side) as f64;
        sum.map(|v| v * scale)
    }
}

/// A decoded wavelet-set message (representation 2).
#[derive(Clone, Debug, PartialEq)]
pub struct WaveletFrameMessage {
    /// Sequence number of the source frame.
    pub seq: u64,
    /// Capture time of the source frame, seconds since the source started.
    pub time: f64,
    /// The set is the last known one; the source is lost.
    pub stale: bool,
    /// The coefficients as sent (by increasing index).
    pub set: WaveletSet,
}

impl WaveletFrameMessage {
    /// The wavelet frame without the transport fields.
    pub fn into_wavelet_frame(self) -> WaveletFrame {
        WaveletFrame {
            seq: self.seq,
            time: self.time,
            set: self.set,
        }
    }
}

/// One decoded message.
#[derive(Clone, Debug, PartialEq)]
pub enum Message {
    /// A light list.
    Frame(FrameMessage),
    /// An ASG set.
    Asg(AsgFrameMessage),
    /// A wavelet coefficient set.
    Wavelet(WaveletFrameMessage),
    /// An error; the sender closes the connection after it.
    Error {
        /// One of [`code`].
        code: u16,
        /// Human-readable text.
        message: String,
    },
    /// The daemon is shutting down.
    Goodbye {
        /// Human-readable text.
        message: String,
    },
    /// A client's subscription.
    Subscribe(Request),
}

/// Everything that can be wrong with bytes or text received from a peer.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ProtocolError {
    /// The four bytes after the length prefix are not `ENVL`.
    #[error("bad magic {found:02x?} (expected \"ENVL\" = [45, 4e, 56, 4c]): not an envlight stream, or the stream lost its framing")]
    BadMagic {
        /// The bytes found.
        found: [u8; 4],
    },
    /// A protocol version other than [`VERSION`].
    #[error("unsupported protocol version {version}; this side speaks version {VERSION}")]
    UnsupportedVersion {
        /// The version found.
        version: u16,
    },
    /// A message type this version does not define.
    #[error("unknown message type {message_type} (version 1 defines 1 = frame, 2 = error, 3 = goodbye, 16 = subscribe)")]
    UnknownType {
        /// The type found.
        message_type: u16,
    },
    /// The length prefix exceeds [`MAX_MESSAGE_LEN`].
    #[error("length prefix {len} exceeds the maximum message size of {MAX_MESSAGE_LEN} bytes")]
    Oversized {
        /// The length found.
        len: u64,
    },
    /// The lengths inside a message disagree with each other or with the message type.
    #[error("malformed {kind} message: {reason}")]
    Inconsistent {
        /// Which message.
        kind: &'static str,
        /// What disagrees.
        reason: String,
    },
    /// A float that must be finite is NaN or infinite.
    #[error("non-finite value in {field}")]
    NonFinite {
        /// Which field (with the light index for light fields).
        field: String,
    },
    /// An ASG lobe record that is not a valid lobe (bandwidths or integral not positive, a
    /// frame that is not orthonormal).
    #[error("ASG lobe {index} is invalid: {reason}")]
    InvalidLobe {
        /// Position of the record in the frame.
        index: usize,
        /// What is wrong.
        reason: String,
    },
    /// A wavelet frame whose header or coefficients are not a valid set (unknown basis or map
    /// code, a side that is not a power of two, too many levels, indices out of range or not
    /// strictly increasing).
    #[error("invalid wavelet set: {reason}")]
    InvalidWaveletSet {
        /// What is wrong.
        reason: String,
    },
    /// Text that is not valid UTF-8.
    #[error("{kind} message text is not valid UTF-8: {detail}")]
    InvalidUtf8 {
        /// Which message.
        kind: &'static str,
        /// Where it fails.
        detail: String,
    },
    /// A representation code that no version defines.
    #[error("unknown representation code {code} (0 = lights, 1 = asg, 2 = wavelet)")]
    UnknownRepresentation {
        /// The code found.
        code: u8,
    },
    /// A frame of a representation that has no frame layout in this build.
    #[error("frame of representation {} has no layout in this build of protocol version 1", .representation.name())]
    UnsupportedRepresentation {
        /// The representation found.
        representation: Representation,
    },
    /// A format code that no version defines.
    #[error("unknown format code {code} (0 = binary, 1 = json)")]
    UnknownFormat {
        /// The code found.
        code: u8,
    },
    /// JSON text that does not parse as the expected message.
    #[error("invalid JSON message: {0}")]
    Json(String),
    /// The stream ended inside a message.
    #[error("stream ended inside a message ({buffered} bytes of it received)")]
    Truncated {
        /// How many bytes of the unfinished message had arrived.
        buffered: usize,
    },
}

impl ProtocolError {
    /// The error code to send to the peer in the closing [`TYPE_ERROR`] message.
    pub fn code(&self) -> u16 {
        match self {
            ProtocolError::BadMagic { .. }
            | ProtocolError::Inconsistent { .. }
            | ProtocolError::NonFinite { .. }
            | ProtocolError::InvalidLobe { .. }
            | ProtocolError::InvalidWaveletSet { .. }
            | ProtocolError::InvalidUtf8 { .. }
            | ProtocolError::Truncated { .. } => code::MALFORMED,
            ProtocolError::UnsupportedVersion { .. } => code::UNSUPPORTED_VERSION,
            ProtocolError::UnknownType { .. } => code::UNKNOWN_TYPE,
            ProtocolError::Oversized { .. } => code::TOO_LARGE,
            ProtocolError::UnknownRepresentation { .. }
            | ProtocolError::UnknownFormat { .. }
            | ProtocolError::Json(_) => code::BAD_REQUEST,
            ProtocolError::UnsupportedRepresentation { .. } => code::UNSUPPORTED_REPRESENTATION,
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Light selection

/// The lights to send for a cap: all of them, or the `max` with the largest luminance
/// ([`Light::luminance`]), ties broken by position, kept in their original order (by id).
/// Never more than [`MAX_FRAME_LIGHTS`]. Kept lights are copied unchanged.
fn select_lights(lights: &[Light], max_lights: Option<usize>) -> Cow<'_, [Light]> {
    select_brightest(lights, max_lights, MAX_FRAME_LIGHTS, Light::luminance)
}

/// The lobes to send for a cap: as [`select_lights`], ranked by [`AsgLobe::luminance`] (the
/// lobe's energy), never more than [`MAX_FRAME_LOBES`].
fn select_lobes(lobes: &[AsgLobe], max_lobes: Option<usize>) -> Cow<'_, [AsgLobe]> {
    select_brightest(lobes, max_lobes, MAX_FRAME_LOBES, AsgLobe::luminance)
}

/// The coefficients of `set` to send for a cap: all of them, or `max` of them chosen
/// **scaling coefficients first** (the top-left (side/2^levels)² block of the layout: the
/// map's local means, with the full pyramid only index 0 = mean × side, which carries the whole
/// ∫L dω), then the details of largest RGB norm √(r² + g² + b²) (the ranking of
/// [`crate::wavelet::approx`], which by Parseval minimises the RGB L2 error of the
/// reconstruction); within each group ties go to the lower index. Kept in index order, never
/// more than [`MAX_FRAME_COEFFICIENTS`].
fn select_coefficients(set: &WaveletSet, max: Option<usize>) -> Cow<'_, [(u32, [f32; 3])]> {
    let items = &set.coefficients;
    let cap = max.unwrap_or(usize::MAX).min(MAX_FRAME_COEFFICIENTS);
    if items.len() <= cap {
        return Cow::Borrowed(items);
    }
    let side = u64::from(set.side);
    let block = side >> set.levels.min(63);
    let scaling = |i: u32| {
        let i = u64::from(i);
        side > 0 && i / side < block && i % side < block
    };
    let norm2 = |rgb: &[f32; 3]| -> f64 { rgb.iter().map(|&c| f64::from(c) * f64::from(c)).sum() };
    let mut order: Vec<usize> = (0..items.len()).collect();
    let first = |a: &usize, b: &usize| {
        let (ia, ra) = &items[*a];
        let (ib, rb) = &items[*b];
        scaling(*ib)
            .cmp(&scaling(*ia))
            .then(norm2(rb).total_cmp(&norm2(ra)))
            .then(a.cmp(b))
    };
    if cap > 0 {
        order.select_nth_unstable_by(cap - 1, first);
    }
    order.truncate(cap);
    order.sort_unstable();
    Cow::Owned(order.into_iter().map(|i| items[i]).collect())
}

/// The `cap` (at most `limit`) records of largest `luminance`, ties to the earlier one, kept in
/// their original order.
fn select_brightest<T: Copy>(
    items: &[T],
    cap: Option<usize>,
    limit: usize,
    luminance: impl Fn(&T) -> f32,
) -> Cow<'_, [T]> {
    let cap = cap.unwrap_or(usize::MAX).min(limit);
    if items.len() <= cap {
        return Cow::Borrowed(items);
    }
    let mut order: Vec<usize> = (0..items.len()).collect();
    let brighter = |a: &usize, b: &usize| {
        luminance(&items[*b])
            .total_cmp(&luminance(&items[*a]))
            .then(a.cmp(b))
    };
    if cap > 0 {
        order.select_nth_unstable_by(cap - 1, brighter);
    }
    order.truncate(cap);
    order.sort_unstable();
    Cow::Owned(order.into_iter().map(|i| items[i]).collect())
}

// ---------------------------------------------------------------------------------------------
// Binary encoding

fn put_header(out: &mut Vec<u8>, body_len: usize, message_type: u16) {
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
fn put_light_records(lights: &[Light], out: &mut Vec<u8>) {
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
fn put_frame_head(
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
        let values = lobe
            .axis
            .iter()
            .chain(&lobe.tangent)
            .chain([&lobe.lambda, &lobe.mu])
            .chain(&lobe.rgb)
            .chain([&lobe.integral]);
        for v in values {
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

/// `text` cut to at most [`MAX_TEXT_LEN`] bytes at a character boundary.
fn clip_text(text: &str) -> &str {
    if text.len() <= MAX_TEXT_LEN {
        return text;
    }
    let mut end = MAX_TEXT_LEN;
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    &text[..end]
}

fn encode_text(message_type: u16, code: u16, text: &str, out: &mut Vec<u8>) {
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

// ---------------------------------------------------------------------------------------------
// Binary decoding

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(a)
}

fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_bits(u32_at(b, at))
}

fn kind_name(message_type: u16) -> &'static str {
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
fn check_header(b: &[u8]) -> Result<Option<usize>, ProtocolError> {
    if b.len() < 4 {
        return Ok(None);
    }
    let len = u32_at(b, 0) as usize;
    if len > MAX_MESSAGE_LEN {
        return Err(ProtocolError::Oversized { len: len as u64 });
    }
    if b.len() >= 8 {
        let found = [b[4], b[5], b[6], b[7]];
        if found != MAGIC {
            return Err(ProtocolError::BadMagic { found });
        }
    }
    if b.len() >= 10 {
        let version = u16_at(b, 8);
        if version != VERSION {
            return Err(ProtocolError::UnsupportedVersion { version });
        }
    }
    if len < 8 {
        return Err(ProtocolError::Inconsistent {
            kind: "any",
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

fn finite(v: f32, field: impl FnOnce() -> String) -> Result<f32, ProtocolError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(ProtocolError::NonFinite { field: field() })
    }
}

/// Decodes a body (the bytes after the 12-byte header) whose type and length `check_header`
/// accepted. A light list's records go into `spare` (cleared first), which the message then
/// owns: a client that hands its lists back ([`Decoder::recycle`]) decodes without allocating.
fn decode_body(
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
fn decode_lights(
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
fn decode_lights_one_by_one(
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
fn decode_lobes(records: &[u8]) -> Result<Vec<AsgLobe>, ProtocolError> {
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
fn decode_wavelet(prefix: &[u8], records: &[u8]) -> Result<WaveletSet, ProtocolError> {
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
    let values = lobe
        .axis
        .iter()
        .chain(&lobe.tangent)
        .chain([&lobe.lambda, &lobe.mu])
        .chain(&lobe.rgb)
        .chain([&lobe.integral]);
    if values.into_iter().any(|v| !v.is_finite()) {
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
            kind: "any",
            reason: format!("{} bytes after the end of the message", input.len()),
        }),
        Some(message) => Ok(message),
        None => Err(ProtocolError::Truncated {
            buffered: bytes.len(),
        }),
    }
}

/// Incremental decoder for a byte stream: [`push`](Decoder::push) bytes as they arrive, in any
/// pieces, and take complete messages with [`next_message`](Decoder::next_message); or, without
/// copying, hand it each read's bytes with [`next_from`](Decoder::next_from) (or the iterator
/// [`feed`](Decoder::feed)), which decodes a message straight from them when they hold all of it
/// and stores only the bytes of a message that is not complete yet.
///
/// Memory stays bounded: the header of the pending message (length prefix, magic, version,
/// type, and whether the length fits the type) is checked as soon as its 12 bytes arrive and
/// before any byte of its body is stored, so the decoder holds at most one message of at most
/// [`MAX_MESSAGE_LEN`] + 4 bytes plus the rest of the latest push. After an error the decoder
/// stays failed: it discards further input and returns the same error again.
///
/// A client that hands each decoded light list back with [`recycle`](Decoder::recycle) has the
/// next one decoded into the same allocation: at a steady light count, no allocation per
/// message.
#[derive(Debug, Default)]
pub struct Decoder {
    buf: Vec<u8>,
    /// Start of the first unconsumed byte in `buf`.
    pos: usize,
    error: Option<ProtocolError>,
    /// A light list handed back, decoded into next.
    spare: Vec<Light>,
}

impl Decoder {
    /// An empty decoder.
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends received bytes.
    pub fn push(&mut self, mut bytes: &[u8]) {
        if self.error.is_some() {
            return;
        }
        let pending = self.buf.len() - self.pos;
        if pending < HEADER_LEN {
            let take = (HEADER_LEN - pending).min(bytes.len());
            self.buf.extend_from_slice(&bytes[..take]);
            bytes = &bytes[take..];
            if let Err(e) = check_header(&self.buf[self.pos..]) {
                self.fail(e);
                return;
            }
        }
        self.buf.extend_from_slice(bytes);
    }

    /// The next complete message, `Ok(None)` if more bytes are needed, or the error that ends
    /// the stream (returned again on every later call).
    pub fn next_message(&mut self) -> Result<Option<Message>, ProtocolError> {
        if let Some(e) = &self.error {
            return Err(e.clone());
        }
        let pending = &self.buf[self.pos..];
        let len = match check_header(pending) {
            Err(e) => return Err(self.fail(e)),
            Ok(None) => return Ok(None),
            Ok(Some(len)) => len,
        };
        if pending.len() < 4 + len {
            return Ok(None);
        }
        let message_type = u16_at(pending, 10);
        match decode_body(message_type, &pending[HEADER_LEN..4 + len], &mut self.spare) {
            Err(e) => Err(self.fail(e)),
            Ok(message) => {
                self.pos += 4 + len;
                if self.pos == self.buf.len() {
                    self.buf.clear();
                    self.pos = 0;
                } else if self.pos >= self.buf.len() / 2 {
                    self.buf.drain(..self.pos);
                    self.pos = 0;
                }
                Ok(Some(message))
            }
        }
    }

    /// The next message from the bytes stored before and then from `input`, which is advanced
    /// past the bytes taken. Same result as [`push`](Decoder::push)ing `input` and calling
    /// [`next_message`](Decoder::next_message), without the copy: a message that lies whole in
    /// `input` is decoded from there, and only a message that `input` ends inside is stored
    /// (then `input` is left empty and the result is `Ok(None)`). Call it again until it
    /// returns `Ok(None)`: `input` may hold more messages. After an error `input` is left empty
    /// and the decoder is failed, as with `next_message`.
    pub fn next_from(&mut self, input: &mut &[u8]) -> Result<Option<Message>, ProtocolError> {
        if let Some(e) = &self.error {
            *input = &[];
            return Err(e.clone());
        }
        if self.buffered() > 0 {
            // Complete the stored message first: its header, then exactly its remaining bytes.
            let pending = self.buffered();
            if pending < HEADER_LEN {
                let take = (HEADER_LEN - pending).min(input.len());
                self.push(&input[..take]);
                *input = &input[take..];
                if let Some(e) = &self.error {
                    *input = &[];
                    return Err(e.clone());
                }
            }
            let len = match check_header(&self.buf[self.pos..]) {
                Err(e) => {
                    *input = &[];
                    return Err(self.fail(e));
                }
                Ok(None) => return Ok(None), // `input` is used up
                Ok(Some(len)) => len,
            };
            let missing = (4 + len).saturating_sub(self.buffered());
            let take = missing.min(input.len());
            self.push(&input[..take]);
            *input = &input[take..];
            let message = self.next_message();
            if message.is_err() {
                *input = &[];
            }
            return message;
        }
        let bytes = *input;
        let len = match check_header(bytes) {
            Err(e) => {
                *input = &[];
                return Err(self.fail(e));
            }
            Ok(Some(len)) if bytes.len() >= 4 + len => len,
            // Not a whole message: keep what there is (its header checked as it is stored).
            Ok(_) => {
                self.push(bytes);
                *input = &[];
                return match &self.error {
                    Some(e) => Err(e.clone()),
                    None => Ok(None),
                };
            }
        };
        // 4 + len ≥ 12 (check_header): the whole header is there and was checked.
        let message_type = u16_at(bytes, 10);
        match decode_body(message_type, &bytes[HEADER_LEN..4 + len], &mut self.spare) {
            Err(e) => {
                *input = &[];
                Err(self.fail(e))
            }
            Ok(message) => {
                *input = &bytes[4 + len..];
                Ok(Some(message))
            }
        }
    }

    /// The messages in `bytes` (after any stored bytes), decoded as by
    /// [`next_from`](Decoder::next_from): without copying the messages that lie whole in
    /// `bytes`. The iterator ends when `bytes` is used up or after the first error (which
    /// every later call returns again). Bytes left when it is dropped early are stored, as by
    /// [`push`](Decoder::push), so nothing is lost.
    pub fn feed<'b>(&mut self, bytes: &'b [u8]) -> Messages<'_, 'b> {
        Messages {
            decoder: self,
            rest: bytes,
            failed: false,
        }
    }

    /// Hands a decoded light list back: the next light list is decoded into its allocation
    /// (only the largest one handed back is kept).
    pub fn recycle(&mut self, lights: Vec<Light>) {
        if lights.capacity() > self.spare.capacity() {
            self.spare = lights;
        }
    }

    /// Bytes received and not yet returned as messages.
    pub fn buffered(&self) -> usize {
        self.buf.len() - self.pos
    }

    /// Call when the stream has ended: an error if it ended inside a message (or the decoder
    /// had failed).
    pub fn finish(&self) -> Result<(), ProtocolError> {
        match &self.error {
            Some(e) => Err(e.clone()),
            None if self.buffered() > 0 => Err(ProtocolError::Truncated {
                buffered: self.buffered(),
            }),
            None => Ok(()),
        }
    }

    fn fail(&mut self, e: ProtocolError) -> ProtocolError {
        self.buf = Vec::new();
        self.pos = 0;
        self.error = Some(e.clone());
        e
    }
}

/// The messages of one read's bytes: [`Decoder::feed`].
#[derive(Debug)]
pub struct Messages<'d, 'b> {
    decoder: &'d mut Decoder,
    rest: &'b [u8],
    failed: bool,
}

impl Iterator for Messages<'_, '_> {
    type Item = Result<Message, ProtocolError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        match self.decoder.next_from(&mut self.rest) {
            Ok(message) => message.map(Ok),
            Err(e) => {
                self.failed = true;
                Some(Err(e))
            }
        }
    }
}

impl Drop for Messages<'_, '_> {
    fn drop(&mut self) {
        if !self.rest.is_empty() {
            self.decoder.push(self.rest);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// JSON form

#[derive(Serialize, Deserialize)]
struct JsonFrame<'a> {
    seq: u64,
    time: f64,
    #[serde(default)]
    representation: Representation,
    #[serde(default)]
    stale: bool,
    lights: Cow<'a, [Light]>,
}

#[derive(Serialize, Deserialize)]
struct JsonAsgFrame<'a> {
    seq: u64,
    time: f64,
    representation: Representation,
    #[serde(default)]
    stale: bool,
    lobes: Cow<'a, [AsgLobe]>,
}

#[derive(Serialize, Deserialize)]
struct JsonWaveletFrame<'a> {
    seq: u64,
    time: f64,
    representation: Representation,
    #[serde(default)]
    stale: bool,
    basis: Basis,
    side: u32,
    levels: u32,
    coefficients: Cow<'a, [(u32, [f32; 3])]>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct JsonText<'a> {
    code: u16,
    message: Cow<'a, str>,
}

#[derive(Serialize)]
#[serde(rename_all = "lowercase")]
enum JsonEnvelope<'a> {
    Error(JsonText<'a>),
    Goodbye(JsonText<'a>),
    Subscribe(&'a Request),
}

#[derive(Deserialize)]
#[serde(rename_all = "lowercase", deny_unknown_fields)]
enum JsonRequest {
    Subscribe(Request),
}

#[derive(Deserialize)]
#[serde(rename_all = "lowercase", deny_unknown_fields)]
enum JsonControl<'a> {
    Error(JsonText<'a>),
    Goodbye(JsonText<'a>),
    Subscribe(Request),
}

fn to_json<T: Serialize>(value: &T) -> String {
    // Plain derived structs of numbers and strings: serialising to a String cannot fail
    // (non-finite floats become `null`).
    serde_json::to_string(value).unwrap_or_default()
}

/// The JSON form of a frame (DESIGN.md's object plus `representation` and `stale`), with the
/// same light selection as [`encode_frame`]:
///
/// ```json
/// {"seq":17,"time":0.5,"representation":"lights","stale":false,"lights":[{"id":3,"dir":[0.0,1.0,0.0],"rgb":[1.0,0.5,0.25],"solid_angle":0.0625}]}
/// ```
///
/// Floats are written in shortest round-trip form, so parsing them back as f32/f64 with a
/// correctly rounding parser (serde_json's `float_roundtrip` feature, Python's `json`) gives the
/// same values bit for bit.
pub fn frame_to_json(frame: &LightFrame, max_lights: Option<usize>, stale: bool) -> String {
    to_json(&JsonFrame {
        seq: frame.seq,
        time: frame.time,
        representation: Representation::Lights,
        stale,
        lights: select_lights(&frame.lights, max_lights),
    })
}

/// The JSON form of an ASG frame, with the same lobe selection as [`encode_asg_frame`]
/// (`bitangent` is not sent: y = axis × tangent):
///
/// ```json
/// {"seq":17,"time":0.5,"representation":"asg","stale":false,"lobes":[{"id":0,"axis":[0.0,1.0,0.0],"tangent":[1.0,0.0,0.0],"lambda":8.0,"mu":2.0,"rgb":[3.0,2.5,2.0],"integral":0.7853982}]}
/// ```
pub fn asg_frame_to_json(set: &AsgSet, max_lobes: Option<usize>, stale: bool) -> String {
    to_json(&JsonAsgFrame {
        seq: set.seq,
        time: set.time,
        representation: Representation::Asg,
        stale,
        lobes: select_lobes(&set.lobes, max_lobes),
    })
}

/// The JSON form of a wavelet frame, with the same coefficient selection as
/// [`encode_wavelet_frame`]; `coefficients` is a list of `[index, [r, g, b]]` (the form of
/// `envlight wavelet approx`):
///
/// ```json
/// {"seq":17,"time":0.5,"representation":"wavelet","stale":false,"basis":"haar","side":4,"levels":2,"coefficients":[[0,[4.0,2.0,1.0]],[5,[-0.5,0.25,0.0]]]}
/// ```
pub fn wavelet_frame_to_json(
    frame: &WaveletFrame,
    max_coefficients: Option<usize>,
    stale: bool,
) -> String {
    let set = &frame.set;
    to_json(&JsonWaveletFrame {
        seq: frame.seq,
        time: frame.time,
        representation: Representation::Wavelet,
        stale,
        basis: set.basis,
        side: set.side,
        levels: set.levels,
        coefficients: select_coefficients(set, max_coefficients),
    })
}

/// The JSON form of an error: `{"error":{"code":5,"message":"..."}}`.
pub fn error_to_json(code: u16, message: &str) -> String {
    to_json(&JsonEnvelope::Error(JsonText {
        code,
        message: Cow::Borrowed(clip_text(message)),
    }))
}

/// The JSON form of a goodbye: `{"goodbye":{"code":0,"message":"..."}}`.
pub fn goodbye_to_json(message: &str) -> String {
    to_json(&JsonEnvelope::Goodbye(JsonText {
        code: code::SHUTDOWN,
        message: Cow::Borrowed(clip_text(message)),
    }))
}

/// The JSON form of a request: `{"subscribe":{"max_lights":64,"representation":"lights","format":"json"}}`.
pub fn request_to_json(request: &Request) -> String {
    to_json(&JsonEnvelope::Subscribe(request))
}

fn check_json_len(text: &str) -> Result<(), ProtocolError> {
    if text.len() > MAX_MESSAGE_LEN {
        return Err(ProtocolError::Oversized {
            len: text.len() as u64,
        });
    }
    Ok(())
}

/// Parses a client's JSON request, `{"subscribe": {...}}`. Unknown fields, unknown
/// representation or format names, and text longer than [`MAX_MESSAGE_LEN`] are errors.
pub fn parse_json_request(text: &str) -> Result<Request, ProtocolError> {
    check_json_len(text)?;
    match serde_json::from_str::<JsonRequest>(text) {
        Ok(JsonRequest::Subscribe(request)) => Ok(request),
        Err(e) => Err(ProtocolError::Json(e.to_string())),
    }
}

/// Parses any JSON message (what a JSON client receives, or a request): a light frame (has
/// `lights`), an ASG frame (has `lobes`), `{"error":…}`, `{"goodbye":…}` or
/// `{"subscribe":…}`. Frame values must be finite (and lobes valid, as in binary frames).
pub fn parse_json_message(text: &str) -> Result<Message, ProtocolError> {
    check_json_len(text)?;
    let value: serde_json::Value =
        serde_json::from_str(text).map_err(|e| ProtocolError::Json(e.to_string()))?;
    let json_err = |e: serde_json::Error| ProtocolError::Json(e.to_string());
    if value.get("coefficients").is_some() {
        let frame: JsonWaveletFrame<'static> = serde_json::from_value(value).map_err(json_err)?;
        if frame.representation != Representation::Wavelet {
            return Err(ProtocolError::Json(format!(
                "a frame with coefficients must have representation \"wavelet\", not {:?}",
                frame.representation.name()
            )));
        }
        if !frame.time.is_finite() {
            return Err(ProtocolError::NonFinite {
                field: "frame time".into(),
            });
        }
        let set = WaveletSet {
            basis: frame.basis,
            side: frame.side,
            levels: frame.levels,
            coefficients: frame.coefficients.into_owned(),
        };
        validate_wavelet_set(&set)?;
        return Ok(Message::Wavelet(WaveletFrameMessage {
            seq: frame.seq,
            time: frame.time,
            stale: frame.stale,
            set,
        }));
    }
    if value.get("lobes").is_some() {
        let frame: JsonAsgFrame<'static> = serde_json::from_value(value).map_err(json_err)?;
        if frame.representation != Representation::Asg {
            return Err(ProtocolError::Json(format!(
                "a frame with lobes must have representation \"asg\", not {:?}",
                frame.representation.name()
            )));
        }
        if !frame.time.is_finite() {
            return Err(ProtocolError::NonFinite {
                field: "frame time".into(),
            });
        }
        let lobes = frame.lobes.into_owned();
        for (i, l) in lobes.iter().enumerate() {
            validate_lobe(i, l)?;
        }
        return Ok(Message::Asg(AsgFrameMessage {
            seq: frame.seq,
            time: frame.time,
            stale: frame.stale,
            lobes,
        }));
    }
    if value.get("lights").is_some() {
        let frame: JsonFrame<'static> = serde_json::from_value(value).map_err(json_err)?;
        if frame.representation != Representation::Lights {
            return Err(ProtocolError::UnsupportedRepresentation {
                representation: frame.representation,
            });
        }
        // JSON has no NaN, but a huge number parsed as f32 becomes infinite.
        let lights = frame.lights.into_owned();
        let finite_light = |l: &Light| {
            l.dir
                .iter()
                .chain(&l.rgb)
                .chain([&l.solid_angle])
                .all(|v| v.is_finite())
        };
        if !frame.time.is_finite() {
            return Err(ProtocolError::NonFinite {
                field: "frame time".into(),
            });
        }
        if let Some(i) = lights.iter().position(|l| !finite_light(l)) {
            return Err(ProtocolError::NonFinite {
                field: format!("light {i}"),
            });
        }
        return Ok(Message::Frame(FrameMessage {
            seq: frame.seq,
            time: frame.time,
            representation: frame.representation,
            stale: frame.stale,
            lights,
        }));
    }
    let control: JsonControl<'_> = serde_json::from_str(text).map_err(json_err)?;
    Ok(match control {
        JsonControl::Error(t) => Message::Error {
            code: t.code,
            message: t.message.into_owned(),
        },
        JsonControl::Goodbye(t) => Message::Goodbye {
            message: t.message.into_owned(),
        },
        JsonControl::Subscribe(request) => Message::Subscribe(request),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn light(id: u32, power: f32) -> Light {
        Light {
            id,
            dir: [0.0, 1.0, 0.0],
            rgb: [power, power * 0.5, power * 0.25],
            solid_angle: 0.01,
        }
    }

    fn decode_all(bytes: &[u8]) -> Vec<Message> {
        let mut d = Decoder::new();
        d.push(bytes);
        let mut out = Vec::new();
        while let Some(m) = d.next_message().unwrap() {
            out.push(m);
        }
        d.finish().unwrap();
        out
    }

    #[test]
    fn light_records_decode_exactly_and_a_non_finite_field_is_named() {
        // Edge values that are finite (zero signs, subnormals, the extremes) decode bit for bit.
        let edge = [0.0, -0.0, f32::MIN_POSITIVE / 2.0, f32::MAX, f32::MIN, 1.5];
        let frame = LightFrame {
            seq: 9,
            time: 0.25,
            lights: (0..6)
                .map(|i| Light {
                    id: 100 + i as u32,
                    dir: [edge[i], edge[(i + 1) % 6], edge[(i + 2) % 6]],
                    rgb: [edge[(i + 3) % 6], edge[(i + 4) % 6], edge[(i + 5) % 6]],
                    solid_angle: edge[i],
                })
                .collect(),
        };
        let mut out = Vec::new();
        encode_frame(&frame, None, false, &mut out);
        let Ok(Message::Frame(decoded)) = decode_message(&out) else {
            panic!("not a frame");
        };
        assert_eq!(decoded.lights.len(), 6);
        for (a, b) in decoded.lights.iter().zip(&frame.lights) {
            assert_eq!(a.id, b.id);
            let bits = |l: &Light| {
                let mut v: Vec<u32> = l.dir.iter().chain(&l.rgb).map(|x| x.to_bits()).collect();
                v.push(l.solid_angle.to_bits());
                v
            };
            assert_eq!(bits(a), bits(b));
        }
        // Each of the seven floats of light 4, made infinite or NaN, is named.
        let names = ["dir", "dir", "dir", "rgb", "rgb", "rgb", "solid_angle"];
        for (k, name) in names.iter().enumerate() {
            for bad in [f32::INFINITY, f32::NEG_INFINITY, f32::NAN] {
                let mut corrupt = out.clone();
                let at = HEADER_LEN + FRAME_FIXED_LEN + 4 * LIGHT_RECORD_LEN + 4 + 4 * k;
                corrupt[at..at + 4].copy_from_slice(&bad.to_le_bytes());
                match decode_message(&corrupt) {
                    Err(ProtocolError::NonFinite { field }) => {
                        assert_eq!(field, format!("light 4 {name}"))
                    }
                    other => panic!("{other:?}"),
                }
            }
        }
    }

    #[test]
    fn max_frame_lights_fits_the_limit() {
        assert_eq!(MAX_FRAME_LIGHTS, 32767);
    }

    #[test]
    fn frame_message_sizes() {
        let mut out = Vec::new();
        let frame = LightFrame {
            seq: 1,
            time: 0.0,
            lights: (0..3).map(|i| light(i, 1.0)).collect(),
        };
        encode_frame(&frame, None, false, &mut out);
        assert_eq!(
            out.len(),
            HEADER_LEN + FRAME_FIXED_LEN + 3 * LIGHT_RECORD_LEN
        );
        assert_eq!(u32_at(&out, 0) as usize, out.len() - 4);
    }

    #[test]
    fn selection_keeps_brightest_in_id_order() {
        let lights: Vec<Light> = [5.0, 1.0, 9.0, 3.0, 9.0, 0.5]
            .iter()
            .enumerate()
            .map(|(i, &p)| light(i as u32, p))
            .collect();
        let kept = select_lights(&lights, Some(3));
        let ids: Vec<u32> = kept.iter().map(|l| l.id).collect();
        assert_eq!(ids, vec![0, 2, 4]);
        assert!(select_lights(&lights, Some(0)).is_empty());
        assert_eq!(select_lights(&lights, Some(6)).len(), 6);
        assert_eq!(select_lights(&lights, None).len(), 6);
        // Ties go to the earlier light.
        let ids: Vec<u32> = select_lights(&lights, Some(1))
            .iter()
            .map(|l| l.id)
            .collect();
        assert_eq!(ids, vec![2]);
    }

    #[test]
    fn error_and_goodbye_round_trip() {
        let mut out = Vec::new();
        encode_error(code::BAD_REQUEST, "no such representation: ä", &mut out);
        encode_goodbye("daemon shutting down", &mut out);
        let messages = decode_all(&out);
        assert_eq!(
            messages,
            vec![
                Message::Error {
                    code: code::BAD_REQUEST,
                    message: "no such representation: ä".into()
                },
                Message::Goodbye {
                    message: "daemon shutting down".into()
                }
            ]
        );
    }

    #[test]
    fn long_text_is_clipped_at_a_char_boundary() {
        let text = "é".repeat(MAX_TEXT_LEN); // 2 bytes each
        let mut out = Vec::new();
        encode_error(code::INTERNAL, &text, &mut out);
        match decode_message(&out).unwrap() {
            Message::Error { message, .. } => {
                assert_eq!(message.len(), MAX_TEXT_LEN);
                assert!(message.chars().all(|c| c == 'é'));
            }
            other => panic!("unexpected {other:?}"),
        }
    }

    #[test]
    fn header_errors_are_detected_early() {
        // Bad magic as soon as 8 bytes are there.
        let mut d = Decoder::new();
        d.push(&[16, 0, 0, 0, b'H', b'T', b'T', b'P']);
        assert!(matches!(
            d.next_message(),
            Err(ProtocolError::BadMagic { found }) if &found == b"HTTP"
        ));
        // Sticky: later input is discarded and the error repeats.
        d.push(&[0; 100]);
        assert_eq!(d.buffered(), 0);
        assert!(matches!(
            d.next_message(),
            Err(ProtocolError::BadMagic { .. })
        ));

        let mut d = Decoder::new();
        d.push(&[8, 0, 0, 0, b'E', b'N', b'V', b'L', 2, 0]);
        assert_eq!(
            d.next_message(),
            Err(ProtocolError::UnsupportedVersion { version: 2 })
        );

        let mut d = Decoder::new();
        d.push(&[8, 0, 0, 0, b'E', b'N', b'V', b'L', 1, 0, 9, 0]);
        assert_eq!(
            d.next_message(),
            Err(ProtocolError::UnknownType { message_type: 9 })
        );

        let mut d = Decoder::new();
        d.push(&[3, 0, 0, 0]);
        assert!(matches!(
            d.next_message(),
            Err(ProtocolError::Inconsistent { .. })
        ));
    }

    #[test]
    fn error_codes_map() {
        assert_eq!(
            ProtocolError::Oversized { len: 1 << 30 }.code(),
            code::TOO_LARGE
        );
        assert_eq!(
            ProtocolError::BadMagic { found: [0; 4] }.code(),
            code::MALFORMED
        );
        assert_eq!(ProtocolError::Json("x".into()).code(), code::BAD_REQUEST);
    }

    #[test]
    fn subscribe_with_unknown_codes_is_rejected() {
        let mut out = Vec::new();
        encode_request(&Request::default(), &mut out);
        let mut bad = out.clone();
        bad[16] = 7;
        assert_eq!(
            decode_message(&bad),
            Err(ProtocolError::UnknownRepresentation { code: 7 })
        );
        let mut bad = out.clone();
        bad[17] = 2;
        assert_eq!(
            decode_message(&bad),
            Err(ProtocolError::UnknownFormat { code: 2 })
        );
    }

    #[test]
    fn a_light_frame_relabelled_as_wavelet_lacks_the_prefix() {
        let mut out = Vec::new();
        encode_frame(&LightFrame::default(), None, false, &mut out);
        out[28] = Representation::Wavelet.code();
        assert!(matches!(
            decode_message(&out),
            Err(ProtocolError::Inconsistent { kind: "frame", .. })
        ));
    }

    fn wavelet_frame(coefficients: Vec<(u32, [f32; 3])>) -> WaveletFrame {
        WaveletFrame {
            seq: 3,
            time: 0.25,
            set: WaveletSet {
                basis: Basis::Daubechies(4),
                side: 8,
                levels: 3,
                coefficients,
            },
        }
    }

    #[test]
    fn wavelet_frames_round_trip_binary_and_json() {
        let frame = wavelet_frame(vec![
            (0, [8.0, 4.0, 2.0]),
            (3, [-0.5, 0.25, 1e-30]),
            (63, [0.0, -3.5, 0.125]),
        ]);
        let mut out = Vec::new();
        encode_wavelet_frame(&frame, None, true, &mut out);
        assert_eq!(
            out.len(),
            HEADER_LEN + FRAME_FIXED_LEN + WAVELET_PREFIX_LEN + 3 * WAVELET_RECORD_LEN
        );
        assert_eq!(&out[36..44], &[4, 3, 0, 0, 8, 0, 0, 0]);
        let want = WaveletFrameMessage {
            seq: 3,
            time: 0.25,
            stale: true,
            set: frame.set.clone(),
        };
        assert_eq!(decode_message(&out), Ok(Message::Wavelet(want.clone())));
        let json = wavelet_frame_to_json(&frame, None, true);
        assert!(
            json.contains(r#""basis":"db4","side":8,"levels":3"#),
            "{json}"
        );
        assert_eq!(parse_json_message(&json), Ok(Message::Wavelet(want)));
        assert_eq!(MAX_FRAME_COEFFICIENTS, 65533);
    }

    fn kept(frame: &WaveletFrame, cap: usize) -> Vec<u32> {
        let mut out = Vec::new();
        encode_wavelet_frame(frame, Some(cap), false, &mut out);
        let json = parse_json_message(&wavelet_frame_to_json(frame, Some(cap), false));
        match (decode_message(&out), json) {
            (Ok(Message::Wavelet(m)), Ok(Message::Wavelet(j))) => {
                assert_eq!(m.set, j.set, "binary and JSON select the same");
                m.set.coefficients.iter().map(|c| c.0).collect()
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn wavelet_cap_keeps_scaling_then_the_largest_rgb_norms_in_index_order() {
        // Side 8, 3 levels: index 0 is the only scaling coefficient. Norms: 1 (scaling),
        // 3 (luminance ≈ 0: pure chroma), 4, 5, 3 (a tie with index 1).
        let frame = wavelet_frame(vec![
            (0, [1.0, 0.0, 0.0]),
            (1, [3.0, 0.0, 0.0]),
            (2, [0.0, 0.0, -4.0]),
            (9, [3.0, 4.0, 0.0]),
            (10, [0.0, -3.0, 0.0]),
        ]);
        assert_eq!(kept(&frame, 0), Vec::<u32>::new());
        assert_eq!(kept(&frame, 1), vec![0], "the scaling coefficient first");
        assert_eq!(kept(&frame, 2), vec![0, 9]);
        assert_eq!(kept(&frame, 3), vec![0, 2, 9]);
        assert_eq!(
            kept(&frame, 4),
            vec![0, 1, 2, 9],
            "ties go to the lower index"
        );
        assert_eq!(kept(&frame, 9), vec![0, 1, 2, 9, 10]);
        // One level on side 8: the scaling block is 4 × 4 (rows 0..4, columns 0..4).
        let mut shallow = frame.clone();
        shallow.set.levels = 1;
        shallow.set.coefficients = vec![
            (5, [0.5, 0.0, 0.0]),  // row 0, column 5: detail
            (11, [0.1, 0.0, 0.0]), // row 1, column 3: scaling
            (24, [0.2, 0.0, 0.0]), // row 3, column 0: scaling
            (32, [9.0, 0.0, 0.0]), // row 4, column 0: detail
        ];
        assert_eq!(kept(&shallow, 1), vec![24]);
        assert_eq!(kept(&shallow, 2), vec![11, 24]);
        assert_eq!(kept(&shallow, 3), vec![11, 24, 32]);
        let integral = |f: &WaveletFrame| f.integral();
        // ∫L dω = 2^levels · Σ scaling · 4π / side².
        let want = 2.0 * f64::from(0.1f32 + 0.2f32) * 4.0 * std::f64::consts::PI / 64.0;
        assert!((integral(&shallow)[0] - want).abs() < 1e-6);
    }

    #[test]
    fn bad_wavelet_frames_are_rejected() {
        let good = wavelet_frame(vec![(1, [1.0, 1.0, 1.0]), (2, [2.0, 2.0, 2.0])]);
        let mut bytes = Vec::new();
        encode_wavelet_frame(&good, None, false, &mut bytes);
        let patched = |at: usize, value: &[u8]| {
            let mut b = bytes.clone();
            b[at..at + value.len()].copy_from_slice(value);
            decode_message(&b)
        };
        let invalid = |r: Result<Message, ProtocolError>| {
            matches!(r, Err(ProtocolError::InvalidWaveletSet { .. }))
        };
        assert!(invalid(patched(36, &[0])), "basis code 0");
        assert!(invalid(patched(36, &[11])), "basis code 11");
        assert!(invalid(patched(37, &[4])), "4 levels on side 8");
        assert!(invalid(patched(38, &[1])), "map code 1");
        assert!(invalid(patched(40, &12u32.to_le_bytes())), "side 12");
        assert!(invalid(patched(40, &1u32.to_le_bytes())), "side 1");
        assert!(
            invalid(patched(40, &(1u32 << 31).to_le_bytes())),
            "huge side"
        );
        assert!(
            invalid(patched(44, &64u32.to_le_bytes())),
            "index 64 on side 8"
        );
        assert!(invalid(patched(44, &2u32.to_le_bytes())), "duplicate index");
        assert!(invalid(patched(60, &1u32.to_le_bytes())), "decreasing");
        assert!(matches!(
            patched(48, &f32::NAN.to_le_bytes()),
            Err(ProtocolError::NonFinite { .. })
        ));
        // A record short: the length does not fit the layout.
        let mut short = bytes.clone();
        short.truncate(short.len() - 4);
        let len = (short.len() - 4) as u32;
        short[0..4].copy_from_slice(&len.to_le_bytes());
        assert!(matches!(
            decode_message(&short),
            Err(ProtocolError::Inconsistent { kind: "frame", .. })
        ));
        // Every rejection is error 1 (malformed).
        assert_eq!(
            ProtocolError::InvalidWaveletSet { reason: "x".into() }.code(),
            code::MALFORMED
        );
        // JSON: the same checks.
        let json = wavelet_frame_to_json(&good, None, false);
        for (from, to) in [
            (r#""basis":"db4""#, r#""basis":"db42""#),
            (r#""side":8"#, r#""side":6"#),
            (r#""levels":3"#, r#""levels":9"#),
            ("[2,[2.0", "[1,[2.0"),
            ("[2,[2.0", "[64,[2.0"),
            (r#""representation":"wavelet""#, r#""representation":"asg""#),
            ("[2,[2.0", "[2,[1e39"),
        ] {
            let bad = json.replace(from, to);
            assert_ne!(bad, json, "{from} not in {json}");
            assert!(parse_json_message(&bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn record_size_follows_the_representation() {
        // One light record (32 bytes) relabelled as ASG: 32 is not a multiple of 52.
        let mut out = Vec::new();
        let frame = LightFrame {
            seq: 1,
            time: 0.0,
            lights: vec![light(0, 1.0)],
        };
        encode_frame(&frame, None, false, &mut out);
        out[28] = Representation::Asg.code();
        assert!(matches!(
            decode_message(&out),
            Err(ProtocolError::Inconsistent { kind: "frame", .. })
        ));
        // An empty ASG frame is 36 bytes, like an empty light frame.
        let mut out = Vec::new();
        encode_asg_frame(&AsgSet::default(), None, false, &mut out);
        assert_eq!(out.len(), HEADER_LEN + FRAME_FIXED_LEN);
        assert_eq!(
            decode_message(&out),
            Ok(Message::Asg(AsgFrameMessage {
                seq: 0,
                time: 0.0,
                stale: false,
                lobes: Vec::new()
            }))
        );
        assert_eq!(MAX_FRAME_LOBES, 20164);
    }

    #[test]
    fn json_request_defaults_and_errors() {
        assert_eq!(
            parse_json_request(r#"{"subscribe":{}}"#),
            Ok(Request::default())
        );
        assert_eq!(
            parse_json_request(r#"{"subscribe":{"max_lights":8,"format":"binary"}}"#),
            Ok(Request {
                max_lights: 8,
                representation: Representation::Lights,
                format: Format::Binary
            })
        );
        for bad in [
            "",
            "{",
            "{}",
            r#"{"subscribe":{"max_lights":-1}}"#,
            r#"{"subscribe":{"max_lights":1.5}}"#,
            r#"{"subscribe":{"max_lights":1e999}}"#,
            r#"{"subscribe":{"representation":"sh"}}"#,
            r#"{"subscribe":{"colour":"red"}}"#,
            r#"{"subscribe":{},"extra":1}"#,
            r#"{"unsubscribe":{}}"#,
        ] {
            let e = parse_json_request(bad).unwrap_err();
            assert_eq!(e.code(), code::BAD_REQUEST, "{bad}: {e}");
        }
    }

    /// The copying decode of light records gives what the record-by-record one gives, bit for
    /// bit, on records with every kind of float (normal, subnormal, ±0, the largest, ±∞ and
    /// NaN, in every field and light), the same error naming the first bad field, and the
    /// same lights when a reused list held more lights before.
    #[test]
    fn copying_light_decode_equals_record_by_record() {
        let specials = [
            0.5f32,
            -0.0,
            f32::MIN_POSITIVE / 4.0,
            f32::MAX,
            -3.0e-7,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
        ];
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let mut reused = vec![Light::zeroed(); 40];
        for case in 0..400 {
            let count = (next() % 33) as usize;
            let mut records = Vec::with_capacity(count * LIGHT_RECORD_LEN);
            for _ in 0..count {
                records.extend_from_slice(&(next() as u32).to_le_bytes());
                for _ in 0..7 {
                    // Mostly finite values, a special one in about one field in 40.
                    let r = next();
                    let v = if r % 40 == 0 {
                        specials[(r / 40 % 8) as usize]
                    } else {
                        (r >> 11) as f32 * 1e-10 - 3.0e5
                    };
                    records.extend_from_slice(&v.to_le_bytes());
                }
            }
            let mut expected = Vec::new();
            let expected =
                decode_lights_one_by_one(&records, count, &mut expected).map(|()| expected);
            let got = decode_lights(&records, count, &mut reused).map(|()| reused.clone());
            let bits = |lights: &Vec<Light>| -> Vec<u32> {
                bytemuck::cast_slice::<Light, u32>(lights).to_vec()
            };
            match (&expected, &got) {
                (Ok(a), Ok(b)) => assert_eq!(bits(a), bits(b), "case {case}"),
                (Err(a), Err(b)) => assert_eq!(a, b, "case {case}"),
                _ => panic!("case {case}: {expected:?} against {got:?}"),
            }
        }
    }

    /// Encoding writes the record layout of docs/protocol.md: id, then dir, rgb and solid
    /// angle as little-endian words.
    #[test]
    fn light_records_are_little_endian_words_in_protocol_order() {
        let light = Light {
            id: 0x0102_0304,
            dir: [1.0, -2.0, 0.25],
            rgb: [3.5, 4.5, 5.5],
            solid_angle: 1e-3,
        };
        let mut out = Vec::new();
        put_light_records(&[light, light], &mut out);
        let mut expected = Vec::new();
        for _ in 0..2 {
            expected.extend_from_slice(&light.id.to_le_bytes());
            for v in [1.0f32, -2.0, 0.25, 3.5, 4.5, 5.5, 1e-3] {
                expected.extend_from_slice(&v.to_le_bytes());
            }
        }
        assert_eq!(out, expected);
    }
}
