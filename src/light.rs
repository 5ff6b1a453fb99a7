//! Directional lights and the per-frame light list: the contract with every consumer.
//!
//! Units and JSON form follow DESIGN.md: `rgb` is the environment radiance integrated over the
//! light's region of the sphere (W/m² at normal incidence, per channel), so the lights of a frame
//! sum to ∫L dω; `dir` is a unit vector in envlight's right-handed, +Y-up frame; `id` is the
//! light's index in the progressive point set and is stable across frames; `solid_angle` is the
//! size of the light's region (or of a merged source) in steradians.
//!
//! The second representation, anisotropic spherical Gaussians ([`crate::asg`]), travels as an
//! [`AsgSet`] of [`AsgLobe`]s: the fitted lobes in f32 with a stable id (the lobe's index in
//! the fit, kept by warm-started refits) and the lobe's exact integral, so a consumer knows each
//! lobe's energy without re-deriving it.

use serde::{Deserialize, Serialize};

/// One directional light.
///
/// `repr(C)`: eight 4-byte fields, 32 bytes without padding, in the order of the binary
/// protocol's light record (docs/protocol.md), so on a little-endian machine a light list is
/// its records byte for byte and the stream encodes and decodes it with one copy.
#[derive(
    Clone, Copy, Debug, PartialEq, Serialize, Deserialize, bytemuck::Pod, bytemuck::Zeroable,
)]
#[repr(C)]
pub struct Light {
    /// Index in the progressive point set; stable from frame to frame.
    pub id: u32,
    /// Unit direction towards the light (world frame, +Y up).
    pub dir: [f32; 3],
    /// Radiance integrated over the light's region, per channel (W/m² at normal incidence).
    pub rgb: [f32; 3],
    /// Solid angle of the light's region or of the merged source, in steradians.
    pub solid_angle: f32,
}

/// `v` as f32, saturating at ±`f32::MAX` instead of overflowing to ±∞: a light's power (or a
/// wavelet coefficient) summed in f64 beyond f32's range stays finite (the wire and JSON forms
/// carry finite floats only). NaN stays NaN, so a bug that makes one is not hidden.
pub fn saturating_f32(v: f64) -> f32 {
    let x = v as f32;
    if x.is_infinite() {
        f32::MAX.copysign(x)
    } else {
        x
    }
}

impl Light {
    /// Rec. 709 luminance of the light's power.
    pub fn luminance(&self) -> f32 {
        crate::frame::luminance(self.rgb)
    }
}

/// The lights decomposed from one environment-map frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LightFrame {
    /// Sequence number of the source frame.
    pub seq: u64,
    /// Capture time of the source frame, in seconds since the source started.
    pub time: f64,
    /// The lights, ordered by id.
    pub lights: Vec<Light>,
}

impl LightFrame {
    /// Sum of all lights' rgb in f64: the integral of the radiance they represent.
    pub fn total_rgb(&self) -> [f64; 3] {
        let mut sum = [0.0f64; 3];
        for light in &self.lights {
            for (s, c) in sum.iter_mut().zip(light.rgb) {
                *s += f64::from(c);
            }
        }
        sum
    }
}

/// One anisotropic spherical Gaussian lobe as streamed (docs/protocol.md):
/// G(v) = rgb · max(v·z, 0) · exp(−λ (v·x)² − μ (v·y)²) with z = `axis`, x = `tangent` and
/// y = z × x.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AsgLobe {
    /// The lobe's index in the fit; stable from frame to frame (warm-started fits keep it).
    pub id: u32,
    /// Lobe axis z (unit).
    pub axis: [f32; 3],
    /// Tangent x (unit, ⟂ axis): the direction of bandwidth λ.
    pub tangent: [f32; 3],
    /// Bandwidth λ along the tangent (> 0).
    pub lambda: f32,
    /// Bandwidth μ along the bitangent y = z × x (> 0).
    pub mu: f32,
    /// Amplitude c, linear RGB radiance, W/(m²·sr).
    pub rgb: [f32; 3],
    /// ∫ max(v·z,0)·exp(−λ(v·x)² − μ(v·y)²) dω of the unit-amplitude lobe, steradians
    /// ([`crate::asg::integral`], exact); `rgb · integral` is the lobe's energy in W/m².
    pub integral: f32,
}

impl AsgLobe {
    /// The lobe's twelve floats in the order of its binary record after the id (docs/protocol.md):
    /// axis, tangent, λ, μ, rgb, integral.
    pub fn record_floats(&self) -> impl Iterator<Item = f32> + '_ {
        self.axis
            .iter()
            .chain(&self.tangent)
            .chain([&self.lambda, &self.mu])
            .chain(&self.rgb)
            .chain([&self.integral])
            .copied()
    }

    /// The streamed form of a fitted lobe (f64 → f32, rounded to nearest).
    pub fn from_asg(id: u32, asg: &crate::asg::Asg) -> Self {
        let f = |v: [f64; 3]| v.map(|c| c as f32);
        Self {
            id,
            axis: f(asg.axis),
            tangent: f(asg.tangent),
            lambda: asg.lambda as f32,
            mu: asg.mu as f32,
            rgb: f(asg.rgb),
            integral: crate::asg::integral(asg.lambda, asg.mu) as f32,
        }
    }

    /// The lobe for shading (frame re-orthonormalised in f64); `None` if it is degenerate
    /// (zero or non-finite axis, non-positive or non-finite bandwidths or amplitude).
    pub fn to_asg(&self) -> Option<crate::asg::Asg> {
        let d = |v: [f32; 3]| glam::DVec3::from_array(v.map(f64::from));
        crate::asg::Asg::new(
            d(self.axis),
            d(self.tangent),
            f64::from(self.lambda),
            f64::from(self.mu),
            self.rgb.map(f64::from),
        )
    }

    /// The bitangent y = z × x.
    pub fn bitangent(&self) -> [f32; 3] {
        let (z, x) = (self.axis, self.tangent);
        [
            z[1] * x[2] - z[2] * x[1],
            z[2] * x[0] - z[0] * x[2],
            z[0] * x[1] - z[1] * x[0],
        ]
    }

    /// Rec. 709 luminance of the lobe's energy (`rgb · integral`): what a lobe cap ranks by.
    pub fn luminance(&self) -> f32 {
        crate::frame::luminance(self.rgb) * self.integral
    }
}

/// The ASG lobes fitted to one environment-map frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AsgSet {
    /// Sequence number of the source frame.
    pub seq: u64,
    /// Capture time of the source frame, in seconds since the source started.
    pub time: f64,
    /// The lobes, ordered by id.
    pub lobes: Vec<AsgLobe>,
}

impl AsgSet {
    /// The streamed form of a fit's lobes (ids 0, 1, …, in fit order).
    pub fn from_fit(seq: u64, time: f64, lobes: &[crate::asg::Asg]) -> Self {
        Self {
            seq,
            time,
            lobes: lobes
                .iter()
                .enumerate()
                .map(|(i, a)| AsgLobe::from_asg(u32::try_from(i).unwrap_or(u32::MAX), a))
                .collect(),
        }
    }
}

/// Why a JSON Lines light list could not be read.
#[derive(Debug, thiserror::Error)]
pub enum LightListError {
    #[error("cannot read light list {path}: {source}")]
    Io {
        path: std::path::PathBuf,
        source: std::io::Error,
    },
    #[error("light list {path}, line {line}: {message}")]
    Parse {
        path: std::path::PathBuf,
        line: usize,
        message: String,
    },
}

/// Reads the JSON Lines written by `envlight decompose` (one [`LightFrame`] per non-empty line).
pub fn read_json_lines(path: &std::path::Path) -> Result<Vec<LightFrame>, LightListError> {
    JsonLinesReader::open(path)?.collect()
}

/// Longest line [`JsonLinesReader`] accepts: 64 MiB (a frame of the most lights the
/// decomposition makes, 16,384, is about 2.5 MB of JSON).
pub const MAX_JSON_LINE_BYTES: usize = 64 << 20;

/// The frames of a JSON Lines light list, read one line at a time (a session of hours is
/// gigabytes of JSON; only one frame is in memory at a time). Each item is a frame or the error
/// of its line (I/O, not UTF-8, longer than [`MAX_JSON_LINE_BYTES`], or what
/// [`parse_json_lines`] refuses); blank lines are skipped.
pub struct JsonLinesReader {
    path: std::path::PathBuf,
    reader: std::io::BufReader<std::fs::File>,
    line: usize,
    buffer: Vec<u8>,
    failed: bool,
    max_line: usize,
}

impl JsonLinesReader {
    /// Opens `path`; the error names it.
    pub fn open(path: &std::path::Path) -> Result<Self, LightListError> {
        let file = std::fs::File::open(path).map_err(|source| LightListError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Ok(Self {
            path: path.to_path_buf(),
            reader: std::io::BufReader::new(file),
            line: 0,
            buffer: Vec::new(),
            failed: false,
            max_line: MAX_JSON_LINE_BYTES,
        })
    }

    /// The file's path.
    pub fn path(&self) -> &std::path::Path {
        &self.path
    }

    fn parse_error(&self, message: String) -> LightListError {
        LightListError::Parse {
            path: self.path.clone(),
            line: self.line,
            message,
        }
    }

    /// The next non-blank line's frame, `None` at the end of the file.
    fn next_frame(&mut self) -> Option<Result<LightFrame, LightListError>> {
        use std::io::{BufRead, Read};
        loop {
            self.buffer.clear();
            self.line += 1;
            let limit = self.max_line as u64 + 1;
            let read = (&mut self.reader)
                .take(limit)
                .read_until(b'\n', &mut self.buffer);
            match read {
                Err(source) => {
                    return Some(Err(LightListError::Io {
                        path: self.path.clone(),
                        source,
                    }))
                }
                Ok(0) => return None,
                Ok(_) => {}
            }
            if self.buffer.last() != Some(&b'\n') && self.buffer.len() > self.max_line {
                let message = format!("the line is longer than {} bytes", self.max_line);
                return Some(Err(self.parse_error(message)));
            }
            // A byte-order mark some editors write at the start of a file is not JSON.
            let bytes = match self.buffer.strip_prefix(b"\xef\xbb\xbf") {
                Some(rest) if self.line == 1 => rest,
                _ => &self.buffer[..],
            };
            let Ok(text) = std::str::from_utf8(bytes) else {
                return Some(Err(self.parse_error("the line is not UTF-8 text".into())));
            };
            if text.trim().is_empty() {
                continue;
            }
            return Some(parse_line(text).map_err(|message| self.parse_error(message)));
        }
    }
}

impl Iterator for JsonLinesReader {
    type Item = Result<LightFrame, LightListError>;

    /// After an error the reader yields nothing more.
    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        let item = self.next_frame();
        self.failed = matches!(item, Some(Err(_)));
        item
    }
}

/// Parses JSON Lines text; the error gives the 1-based line number and the problem. Every light
/// must be usable as it stands: a finite, non-zero direction (scaled to unit length here), finite
/// non-negative `rgb` and a finite non-negative `solid_angle`; a light that is not is an error
/// naming its id, not a light dropped or clamped later.
pub fn parse_json_lines(text: &str) -> Result<Vec<LightFrame>, (usize, String)> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| parse_line(l).map_err(|message| (i + 1, message)))
        .collect()
}

/// One line's frame (see [`parse_json_lines`]).
fn parse_line(line: &str) -> Result<LightFrame, String> {
    let mut frame: LightFrame = serde_json::from_str(line).map_err(|e| e.to_string())?;
    for light in &mut frame.lights {
        if let Some(problem) = light_problem(light) {
            return Err(format!("light {}: {problem}", light.id));
        }
        light.dir = unit(light.dir);
    }
    Ok(frame)
}

/// `dir` scaled to unit length, in f64 (squaring f32 components of 1e20 overflows).
fn unit(dir: [f32; 3]) -> [f32; 3] {
    let d = dir.map(f64::from);
    let length = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    d.map(|c| (c / length) as f32)
}

/// What makes a light unusable, if anything (see [`parse_json_lines`]).
fn light_problem(light: &Light) -> Option<String> {
    let [x, y, z] = light.dir.map(f64::from);
    if !(x.is_finite() && y.is_finite() && z.is_finite()) || x * x + y * y + z * z < 1e-12 {
        return Some(format!(
            "dir {:?} is not a direction (expected a unit vector)",
            light.dir
        ));
    }
    if light.rgb.iter().any(|c| !(c.is_finite() && *c >= 0.0)) {
        return Some(format!(
            "rgb {:?} must be finite and non-negative",
            light.rgb
        ));
    }
    if !(light.solid_angle.is_finite() && light.solid_angle >= 0.0) {
        return Some(format!(
            "solid_angle {} must be finite and non-negative",
            light.solid_angle
        ));
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn saturating_f32_keeps_sums_finite_and_nan_visible() {
        assert_eq!(saturating_f32(1e39), f32::MAX);
        assert_eq!(saturating_f32(-1e39), -f32::MAX);
        assert_eq!(saturating_f32(1.5), 1.5);
        assert!(saturating_f32(f64::NAN).is_nan());
    }

    #[test]
    fn json_lines_reader_streams_frames_and_names_bad_lines() {
        let dir = tempfile::tempdir().unwrap();
        let frame = |seq: u64| {
            format!(
                "{{\"seq\":{seq},\"time\":0.5,\"lights\":[{{\"id\":3,\"dir\":[0.0,2.0,0.0],\
                 \"rgb\":[1.0,0.5,0.25],\"solid_angle\":0.1}}]}}"
            )
        };
        let path = dir.path().join("lights.jsonl");
        let text = format!("{}\n\n  \r\n{}\r\n{}", frame(0), frame(1), frame(2));
        std::fs::write(&path, &text).unwrap();
        let read: Vec<LightFrame> = JsonLinesReader::open(&path)
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap();
        assert_eq!(read, parse_json_lines(&text).unwrap());
        assert_eq!(read.iter().map(|f| f.seq).collect::<Vec<_>>(), [0, 1, 2]);
        assert_eq!(read[0].lights[0].dir, [0.0, 1.0, 0.0]);
        // A byte-order mark at the start of the file is skipped.
        std::fs::write(&path, format!("\u{feff}{text}")).unwrap();
        let with_bom: Vec<LightFrame> = JsonLinesReader::open(&path)
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap();
        assert_eq!(with_bom, read);
        // A line that is not UTF-8, then a good one: the error names line 2 and the reader
        // stops there.
        let mut bytes = format!("{}\n", frame(0)).into_bytes();
        bytes.extend_from_slice(b"{\"seq\":\xff}\n");
        bytes.extend_from_slice(format!("{}\n", frame(1)).as_bytes());
        std::fs::write(&path, &bytes).unwrap();
        let items: Vec<_> = JsonLinesReader::open(&path).unwrap().collect();
        assert_eq!(items.len(), 2);
        let err = items[1].as_ref().unwrap_err().to_string();
        assert!(err.contains("line 2: the line is not UTF-8"), "{err}");
        // A line longer than the limit is refused without reading it whole.
        std::fs::write(&path, format!("{}\n{}\n", frame(0), frame(1))).unwrap();
        let mut reader = JsonLinesReader::open(&path).unwrap();
        reader.max_line = frame(0).len() + 1;
        assert!(reader.next().unwrap().is_ok());
        reader.max_line = 20;
        let err = reader.next().unwrap().unwrap_err().to_string();
        assert!(
            err.contains("line 2: the line is longer than 20 bytes"),
            "{err}"
        );
        assert!(reader.next().is_none());
        let missing = JsonLinesReader::open(&dir.path().join("missing.jsonl"));
        assert!(missing.is_err());
    }

    #[test]
    fn json_lines_round_trip_and_errors_name_the_line() {
        let frame = LightFrame {
            seq: 3,
            time: 0.1,
            lights: vec![Light {
                id: 7,
                dir: [0.0, 1.0, 0.0],
                rgb: [1.0, 2.0, 3.0],
                solid_angle: 0.01,
            }],
        };
        let line = serde_json::to_string(&frame).unwrap();
        let text = format!("{line}\n\n{line}\n");
        let frames = parse_json_lines(&text).unwrap();
        assert_eq!(frames, vec![frame.clone(), frame]);
        let err = parse_json_lines(&format!("{line}\n{{\"seq\":1}}\n")).unwrap_err();
        assert_eq!(err.0, 2);
        let e = read_json_lines(std::path::Path::new("/no/such/lights.jsonl")).unwrap_err();
        assert!(e.to_string().contains("lights.jsonl"));
    }

    #[test]
    fn unusable_lights_are_errors_naming_the_line_and_light() {
        let good = r#"{"id":1,"dir":[0.0,1.0,0.0],"rgb":[1.0,2.0,3.0],"solid_angle":0.01}"#;
        for (bad, needle) in [
            (
                r#"{"id":9,"dir":[0,0,0],"rgb":[1,1,1],"solid_angle":0}"#,
                "dir",
            ),
            (
                r#"{"id":9,"dir":[0,1,0],"rgb":[-5,1,1],"solid_angle":0}"#,
                "rgb",
            ),
            (
                r#"{"id":9,"dir":[0,1,0],"rgb":[1,1,1],"solid_angle":-1}"#,
                "solid_angle",
            ),
        ] {
            let text = format!(
                "{{\"seq\":0,\"time\":0,\"lights\":[{good}]}}\n{{\"seq\":1,\"time\":0,\"lights\":[{good},{bad}]}}\n"
            );
            let (line, message) = parse_json_lines(&text).unwrap_err();
            assert_eq!(line, 2, "{message}");
            assert!(
                message.starts_with("light 9: ") && message.contains(needle),
                "{message}"
            );
        }
        // Black lights and an unnormalised direction are fine; the direction comes back as a
        // unit vector, also from components whose squares overflow f32.
        for (dir, unit) in [
            ("[0,2,0]", [0.0, 1.0, 0.0]),
            ("[1e30,1e30,0]", [0.70710677, 0.70710677, 0.0]),
            ("[0,0,-1e-5]", [0.0, 0.0, -1.0]),
        ] {
            let ok = format!(
                r#"{{"seq":0,"time":0,"lights":[{{"id":0,"dir":{dir},"rgb":[0,0,0],"solid_angle":0}}]}}"#
            );
            let frames = parse_json_lines(&ok).unwrap();
            assert_eq!(frames[0].lights[0].dir, unit, "{dir}");
        }
    }
}
