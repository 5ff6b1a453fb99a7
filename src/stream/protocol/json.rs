//! The JSON form of every message (DESIGN.md's frame object plus `representation` and
//! `stale`), for WebSocket clients and scripts, and its parsers.

use super::encode::clip_text;
use super::*;

#[derive(Serialize, Deserialize)]
pub(super) struct JsonFrame<'a> {
    seq: u64,
    time: f64,
    #[serde(default)]
    representation: Representation,
    #[serde(default)]
    stale: bool,
    lights: Cow<'a, [Light]>,
}

#[derive(Serialize, Deserialize)]
pub(super) struct JsonAsgFrame<'a> {
    seq: u64,
    time: f64,
    representation: Representation,
    #[serde(default)]
    stale: bool,
    lobes: Cow<'a, [AsgLobe]>,
}

#[derive(Serialize, Deserialize)]
pub(super) struct JsonWaveletFrame<'a> {
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
pub(super) struct JsonShFrame<'a> {
    seq: u64,
    time: f64,
    representation: Representation,
    #[serde(default)]
    stale: bool,
    degree: u32,
    sh: Cow<'a, [[f32; 3]]>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct JsonText<'a> {
    code: u16,
    message: Cow<'a, str>,
}

#[derive(Serialize)]
#[serde(rename_all = "lowercase")]
pub(super) enum JsonEnvelope<'a> {
    Error(JsonText<'a>),
    Goodbye(JsonText<'a>),
    Subscribe(&'a Request),
}

#[derive(Deserialize)]
#[serde(rename_all = "lowercase", deny_unknown_fields)]
pub(super) enum JsonRequest {
    Subscribe(Request),
}

#[derive(Deserialize)]
#[serde(rename_all = "lowercase", deny_unknown_fields)]
pub(super) enum JsonControl<'a> {
    Error(JsonText<'a>),
    Goodbye(JsonText<'a>),
    Subscribe(Request),
}

pub(super) fn to_json<T: Serialize>(value: &T) -> String {
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

/// The JSON form of an SH frame, with the same selection as [`encode_sh_frame`]; `sh` lists
/// the (degree + 1)² coefficients as `[r, g, b]`, coefficient `l² + l + m` for Y_l^m:
///
/// ```json
/// {"seq":17,"time":0.5,"representation":"sh","stale":false,"degree":1,"sh":[[1.0,0.9,0.8],[0.1,0.1,0.1],[0.0,0.0,0.0],[-0.05,0.0,0.02]]}
/// ```
pub fn sh_frame_to_json(frame: &ShFrame, max_coefficients: Option<usize>, stale: bool) -> String {
    let coefficients = select_sh(&frame.coefficients, max_coefficients);
    let degree = u32::from(sh_degree_field(coefficients.len()));
    to_json(&JsonShFrame {
        seq: frame.seq,
        time: frame.time,
        representation: Representation::Sh,
        stale,
        degree,
        sh: Cow::Borrowed(coefficients),
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

pub(super) fn check_json_len(text: &str, limit: usize) -> Result<(), ProtocolError> {
    if text.len() > limit {
        return Err(ProtocolError::OversizedJson {
            len: text.len() as u64,
            limit,
        });
    }
    Ok(())
}

/// Parses a client's JSON request, `{"subscribe": {...}}`. Unknown fields, unknown
/// representation or format names, and text longer than [`MAX_MESSAGE_LEN`] are errors.
pub fn parse_json_request(text: &str) -> Result<Request, ProtocolError> {
    check_json_len(text, MAX_MESSAGE_LEN)?;
    match serde_json::from_str::<JsonRequest>(text) {
        Ok(JsonRequest::Subscribe(request)) => Ok(request),
        Err(e) => Err(ProtocolError::Json(
            request_problem(text).unwrap_or(e.to_string()),
        )),
    }
}

/// What is wrong with a JSON object that is no request, in words serde's message for the
/// tagged enum lacks ("expected value at line 1 column 15" for an extra key): a missing
/// `subscribe`, or keys beside it. `None` when the text is no object (serde's message stands).
fn request_problem(text: &str) -> Option<String> {
    let serde_json::Value::Object(object) = serde_json::from_str(text).ok()? else {
        return None;
    };
    let others: Vec<&str> = object
        .keys()
        .map(String::as_str)
        .filter(|k| *k != "subscribe")
        .collect();
    if !object.contains_key("subscribe") {
        return Some(format!(
            "expected {{\"subscribe\": {{…}}}}, found {}",
            if others.is_empty() {
                "an empty object".to_owned()
            } else {
                format!("the keys {}", others.join(", "))
            }
        ));
    }
    (!others.is_empty()).then(|| {
        format!(
            "unknown keys beside \"subscribe\": {} (a request is {{\"subscribe\": {{…}}}} alone)",
            others.join(", ")
        )
    })
}

/// Parses any JSON message (what a JSON client receives, or a request): a light frame (has
/// `lights`), an ASG frame (has `lobes`), a wavelet frame (has `coefficients`), an SH frame
/// (has `sh`), `{"error":…}`, `{"goodbye":…}` or
/// `{"subscribe":…}`. Frame values must be finite (and lobes valid, as in binary frames).
pub fn parse_json_message(text: &str) -> Result<Message, ProtocolError> {
    check_json_len(text, MAX_JSON_MESSAGE_LEN)?;
    let value: serde_json::Value =
        serde_json::from_str(text).map_err(|e| ProtocolError::Json(e.to_string()))?;
    let json_err = |e: serde_json::Error| ProtocolError::Json(e.to_string());
    if value.get("sh").is_some() {
        let frame: JsonShFrame<'static> = serde_json::from_value(value).map_err(json_err)?;
        if frame.representation != Representation::Sh {
            return Err(ProtocolError::Json(format!(
                "a frame with sh coefficients must have representation \"sh\", not {:?}",
                frame.representation.name()
            )));
        }
        if !frame.time.is_finite() {
            return Err(ProtocolError::NonFinite {
                field: "frame time".into(),
            });
        }
        let coefficients = frame.sh.into_owned();
        let degree = validate_sh_set(&coefficients)?;
        if degree as u32 != frame.degree {
            return Err(ProtocolError::InvalidShSet {
                reason: format!(
                    "degree {} with {} coefficients (degree {degree})",
                    frame.degree,
                    coefficients.len()
                ),
            });
        }
        return Ok(Message::Sh(ShFrameMessage {
            seq: frame.seq,
            time: frame.time,
            stale: frame.stale,
            coefficients,
        }));
    }
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
            // A bad request (5), as for lobes or coefficients under another representation.
            return Err(ProtocolError::Json(format!(
                "a frame with lights must have representation \"lights\", not {:?}",
                frame.representation.name()
            )));
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
