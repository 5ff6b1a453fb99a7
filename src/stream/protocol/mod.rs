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
//!
//! Files: this one has the constants, the message types, the errors and the selection of the
//! records a cap keeps; `encode.rs` the binary encoders, `decode.rs` the decoding of one
//! message and the validity checks, `decoder.rs` the [`Decoder`], `json.rs` the JSON form.

use bytemuck::Zeroable;
use std::borrow::Cow;

use serde::{Deserialize, Serialize};

use crate::light::{AsgLobe, AsgSet, Light, LightFrame};
use crate::sh::ShCoefficients;
use crate::wavelet::{Basis, WaveletSet};

mod decode;
mod decoder;
mod encode;
mod json;

pub use decode::{decode_message, validate_lobe, validate_sh_set, validate_wavelet_set};
pub use decoder::{Decoder, Messages};
pub use encode::{
    encode_asg_frame, encode_error, encode_frame, encode_goodbye, encode_request, encode_sh_frame,
    encode_wavelet_frame,
};
pub use json::{
    asg_frame_to_json, error_to_json, frame_to_json, goodbye_to_json, parse_json_message,
    parse_json_request, request_to_json, sh_frame_to_json, wavelet_frame_to_json,
};

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
/// The longest JSON message a server sends (one text message or JSON line), and so the longest
/// a client accepts: 8 MiB. JSON spends about four times the bytes of the binary form, so a
/// frame of [`MAX_FRAME_LIGHTS`] lights, [`MAX_FRAME_LOBES`] lobes or
/// [`MAX_FRAME_COEFFICIENTS`] coefficients, at their longest numbers, takes 3.9–4.6 MB (tested);
/// under 1 MiB (what a client may send) a daemon of more than about 8,000 lights sent JSON
/// frames its own client refused.
pub const MAX_JSON_MESSAGE_LEN: usize = 8 << 20;
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
/// Bytes of an SH frame's prefix: degree, basis, two reserved.
pub const SH_PREFIX_LEN: usize = 4;
/// Bytes of an SH coefficient record: r, g, b as f32.
pub const SH_RECORD_LEN: usize = 12;
/// Basis code of an SH frame: envlight's real orthonormal basis without the Condon–Shortley
/// phase, in its +Y-up axes ([`crate::sh`]; the only one in version 1).
pub const SH_BASIS_REAL: u8 = 0;
/// The highest degree an SH frame may carry in version 1 (256 coefficients).
pub const MAX_SH_DEGREE: usize = crate::sh::MAX_DEGREE;
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

/// What kind of lighting a frame carries: lights (0), ASG sets (1), wavelet coefficient sets
/// (2) and spherical-harmonic sets (3) all have frame layouts in version 1.
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
    /// Spherical-harmonic coefficients of the radiance (code 3).
    Sh,
}

impl Representation {
    /// The wire code.
    pub fn code(self) -> u8 {
        match self {
            Representation::Lights => 0,
            Representation::Asg => 1,
            Representation::Wavelet => 2,
            Representation::Sh => 3,
        }
    }

    /// The representation with this wire code.
    pub fn from_code(code: u8) -> Result<Self, ProtocolError> {
        match code {
            0 => Ok(Representation::Lights),
            1 => Ok(Representation::Asg),
            2 => Ok(Representation::Wavelet),
            3 => Ok(Representation::Sh),
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
            Representation::Sh => Some(FrameLayout {
                prefix_len: SH_PREFIX_LEN,
                record_len: SH_RECORD_LEN,
            }),
        }
    }

    /// The name used in JSON and messages: `lights`, `asg`, `wavelet`, `sh`.
    pub fn name(self) -> &'static str {
        match self {
            Representation::Lights => "lights",
            Representation::Asg => "asg",
            Representation::Wavelet => "wavelet",
            Representation::Sh => "sh",
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
    /// The name used in JSON and messages: `binary`, `json`.
    pub fn name(self) -> &'static str {
        match self {
            Format::Binary => "binary",
            Format::Json => "json",
        }
    }

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

/// The spherical-harmonic coefficients of one source frame, as the daemon's SH stage publishes
/// them and the wire carries them (representation 3): (degree + 1)² rgb triples, coefficient
/// `l² + l + m` for Y_l^m of [`crate::sh`]'s basis, radiance in W/(m²·sr).
#[derive(Clone, Debug, PartialEq)]
pub struct ShFrame {
    /// Sequence number of the source frame.
    pub seq: u64,
    /// Capture time of the source frame, seconds since the source started.
    pub time: f64,
    /// The coefficients; their number is a square (degree + 1)².
    pub coefficients: Vec<[f32; 3]>,
}

impl ShFrame {
    /// The frame of a projected set (coefficients rounded to f32, saturating).
    pub fn new(seq: u64, time: f64, set: &ShCoefficients) -> Self {
        Self {
            seq,
            time,
            coefficients: set
                .rgb()
                .iter()
                .map(|rgb| rgb.map(crate::light::saturating_f32))
                .collect(),
        }
    }

    /// The degree L, `None` if the number of coefficients is not (L + 1)² for an L up to
    /// [`MAX_SH_DEGREE`].
    pub fn degree(&self) -> Option<usize> {
        crate::sh::degree_of(self.coefficients.len())
    }

    /// The coefficients in f64, to evaluate radiance or irradiance
    /// ([`ShCoefficients::irradiance`]); `None` if their number is not a square.
    pub fn to_coefficients(&self) -> Option<ShCoefficients> {
        ShCoefficients::from_rgb(
            self.coefficients
                .iter()
                .map(|rgb| rgb.map(f64::from))
                .collect(),
        )
    }
}

/// A decoded SH-set message (representation 3).
#[derive(Clone, Debug, PartialEq)]
pub struct ShFrameMessage {
    /// Sequence number of the source frame.
    pub seq: u64,
    /// Capture time of the source frame, seconds since the source started.
    pub time: f64,
    /// The set is the last known one; the source is lost.
    pub stale: bool,
    /// The (degree + 1)² coefficients as sent.
    pub coefficients: Vec<[f32; 3]>,
}

impl ShFrameMessage {
    /// The SH frame without the transport fields.
    pub fn into_sh_frame(self) -> ShFrame {
        ShFrame {
            seq: self.seq,
            time: self.time,
            coefficients: self.coefficients,
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
    /// A spherical-harmonic coefficient set.
    Sh(ShFrameMessage),
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
    /// JSON text longer than its limit ([`MAX_MESSAGE_LEN`] from a client,
    /// [`MAX_JSON_MESSAGE_LEN`] from a server).
    #[error("JSON message of {len} bytes or more exceeds the maximum of {limit} bytes")]
    OversizedJson {
        /// The length found (at least).
        len: u64,
        /// The limit.
        limit: usize,
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
    /// An SH frame that is not a valid set (unknown basis code, a degree above
    /// [`MAX_SH_DEGREE`], a count that is not (degree + 1)²).
    #[error("invalid SH set: {reason}")]
    InvalidShSet {
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
    #[error("unknown representation code {code} (0 = lights, 1 = asg, 2 = wavelet, 3 = sh)")]
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
            | ProtocolError::InvalidShSet { .. }
            | ProtocolError::InvalidUtf8 { .. }
            | ProtocolError::Truncated { .. } => code::MALFORMED,
            ProtocolError::UnsupportedVersion { .. } => code::UNSUPPORTED_VERSION,
            ProtocolError::UnknownType { .. } => code::UNKNOWN_TYPE,
            ProtocolError::Oversized { .. } | ProtocolError::OversizedJson { .. } => {
                code::TOO_LARGE
            }
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

/// The coefficients of an SH set to send for a cap: those of the highest complete degree that
/// fits, ⌊√cap⌋ − 1 (a cap of 4 sends degrees 0 and 1), so a capped set is the same
/// environment band-limited further; all of them without a cap or below it. A prefix of the
/// list, so never copied.
fn select_sh(coefficients: &[[f32; 3]], max: Option<usize>) -> &[[f32; 3]] {
    let Some(cap) = max else {
        return coefficients;
    };
    let mut keep = 1usize;
    while (keep + 1) * (keep + 1) <= cap {
        keep += 1;
    }
    &coefficients[..coefficients.len().min(keep * keep)]
}

/// The degree an SH frame of `count` coefficients declares: the smallest that holds them
/// (exact for a valid set, whose count is (L + 1)²; decoders reject any other count).
fn sh_degree_field(count: usize) -> u8 {
    (0..=u8::MAX)
        .find(|&l| crate::sh::coefficient_count(usize::from(l)) >= count)
        .unwrap_or(u8::MAX)
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

#[cfg(test)]
mod tests {
    use super::decode::{decode_lights, decode_lights_one_by_one, u32_at};
    use super::encode::put_light_records;
    use super::*;

    fn light(id: u32, power: f32) -> Light {
        Light {
            id,
            dir: [0.0, 1.0, 0.0],
            rgb: [power, power * 0.5, power * 0.25],
            solid_angle: 0.01,
        }
    }

    /// The largest frames a server may send, at their longest numbers (f32's longest
    /// shortest-round-trip forms, the largest ids, seq and time), fit [`MAX_JSON_MESSAGE_LEN`]
    /// in JSON, and parse back: a client accepts whatever a server sends.
    #[test]
    fn the_largest_frames_fit_the_json_limit() {
        let long = -1.175_494_4e-38_f32; // "-1.1754944e-38"
                                         // unit vectors with two such components
        let (axis, tangent) = ([long, long, -1.0], [-1.0, long, -long]);
        let longest = |text: String| {
            assert!(text.len() <= MAX_JSON_MESSAGE_LEN, "{} bytes", text.len());
            if let Err(e) = parse_json_message(&text) {
                panic!("{e}");
            }
            text.len()
        };
        let lights = LightFrame {
            seq: u64::MAX,
            time: f64::MAX,
            lights: (0..MAX_FRAME_LIGHTS as u32)
                .map(|i| Light {
                    id: u32::MAX - i,
                    dir: axis,
                    rgb: [f32::MAX / 3.0; 3],
                    solid_angle: long.abs(),
                })
                .rev()
                .collect(),
        };
        let lobes = AsgSet {
            seq: u64::MAX,
            time: f64::MAX,
            lobes: (0..MAX_FRAME_LOBES as u32)
                .map(|i| AsgLobe {
                    id: u32::MAX - i,
                    axis,
                    tangent,
                    lambda: long.abs(),
                    mu: long.abs(),
                    rgb: [long.abs(); 3],
                    integral: long.abs(),
                })
                .rev()
                .collect(),
        };
        let coefficients = WaveletFrame {
            seq: u64::MAX,
            time: f64::MAX,
            set: WaveletSet {
                basis: Basis::Daubechies(4),
                side: 1 << 15,
                levels: 15,
                coefficients: (0..MAX_FRAME_COEFFICIENTS as u32)
                    .map(|i| ((1 << 30) - 1 - i, [long; 3]))
                    .rev()
                    .collect(),
            },
        };
        let sizes = [
            longest(frame_to_json(&lights, None, false)),
            longest(asg_frame_to_json(&lobes, None, false)),
            longest(wavelet_frame_to_json(&coefficients, None, false)),
        ];
        eprintln!("largest JSON frames (lights, ASG, wavelet): {sizes:?} bytes");
        // Well past what a client may send (1 MiB), so the limit is needed.
        assert!(sizes.iter().all(|&n| n > 2 * MAX_MESSAGE_LEN), "{sizes:?}");
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
        // However the first bytes are split: an HTTP request whose first four bytes arrive
        // alone is no absurd length prefix ("GET " is 542393671) but a bad magic.
        let request = b"GET / HTTP/1.1\r\nHost: rig\r\n\r\n";
        for first in 1..8 {
            let mut split = Decoder::new();
            split.push(&request[..first]);
            assert_eq!(split.next_message(), Ok(None), "after {first} bytes");
            split.push(&request[first..]);
            assert!(
                matches!(
                    split.next_message(),
                    Err(ProtocolError::BadMagic { found }) if &found == b"/ HT"
                ),
                "split after {first} bytes"
            );
        }
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
        d.push(&[3, 0, 0, 0, b'E', b'N', b'V', b'L']);
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
            r#"{"subscribe":{"representation":"spherical"}}"#,
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
