//! Directional lights and the per-frame light list: the contract with every consumer.
//!
//! Units and JSON form follow DESIGN.md: `rgb` is the environment radiance integrated over the
//! light's region of the sphere (W/m² at normal incidence, per channel), so the lights of a frame
//! sum to ∫L dω; `dir` is a unit vector in envlight's right-handed, +Y-up frame; `id` is the
//! light's index in the progressive point set and is stable across frames; `solid_angle` is the
//! size of the light's region (or of a merged source) in steradians.

use serde::{Deserialize, Serialize};

/// One directional light.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
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
    let text = std::fs::read_to_string(path).map_err(|source| LightListError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_json_lines(&text).map_err(|(line, message)| LightListError::Parse {
        path: path.to_path_buf(),
        line,
        message,
    })
}

/// Parses JSON Lines text; the error gives the 1-based line number and the problem.
pub fn parse_json_lines(text: &str) -> Result<Vec<LightFrame>, (usize, String)> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| serde_json::from_str(l).map_err(|e| (i + 1, e.to_string())))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
