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
