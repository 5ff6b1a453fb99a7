//! Fisheye projections of the upper hemisphere and Debevec's angular map. (Being written.)

use glam::DVec3;

/// Radial lens model: how the angle θ from the optical axis maps to the image radius r.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FisheyeModel {
    /// r = f·θ
    #[default]
    Equidistant,
    /// r = 2f·sin(θ/2)
    Equisolid,
    /// r = 2f·tan(θ/2)
    Stereographic,
    /// r = f·sin θ
    Orthographic,
}

/// Calibration of a zenith-looking fisheye camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FisheyeCalibration {
    pub model: FisheyeModel,
    /// Image-circle centre in pixels; `None` = the image centre.
    pub center: Option<[f64; 2]>,
    /// Image-circle radius in pixels; `None` = half the shorter image side.
    pub radius: Option<f64>,
    /// Full field of view across the image circle, degrees (180 = the hemisphere).
    pub fov_deg: f64,
    /// Rotation about the zenith, degrees.
    pub rotation_deg: f64,
}

impl Default for FisheyeCalibration {
    fn default() -> Self {
        Self {
            model: FisheyeModel::Equidistant,
            center: None,
            radius: None,
            fov_deg: 180.0,
            rotation_deg: 0.0,
        }
    }
}

impl FisheyeCalibration {
    pub fn pixel_to_direction(&self, _w: u32, _h: u32, _x: f64, _y: f64) -> Option<DVec3> {
        None
    }
    pub fn direction_to_pixel(&self, _w: u32, _h: u32, _d: DVec3) -> Option<(f64, f64)> {
        None
    }
    pub fn solid_angles(&self, w: u32, h: u32) -> Vec<f64> {
        vec![0.0; w as usize * h as usize]
    }
}

pub fn angular_pixel_to_direction(_w: u32, _h: u32, _x: f64, _y: f64) -> Option<DVec3> {
    None
}
pub fn angular_direction_to_pixel(_w: u32, _h: u32, _d: DVec3) -> Option<(f64, f64)> {
    None
}
pub fn angular_solid_angles(w: u32, h: u32) -> Vec<f64> {
    vec![0.0; w as usize * h as usize]
}
