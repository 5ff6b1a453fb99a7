//! Environment-map projections: pixel ↔ direction maps and exact per-pixel solid angles.
//!
//! Conventions (DESIGN.md): right-handed, +Y up. Pixel coordinates are continuous: pixel (x, y)
//! covers [x, x+1) × [y, y+1) and its centre is (x + 0.5, y + 0.5); row 0 is the top row.
//!
//! - [`Projection::LatLong`]: u = x/W, v = y/H, θ = πv, φ = 2πu,
//!   d = (sin θ sin φ, cos θ, −sin θ cos φ). Row 0 is the zenith, u = 0 looks along −Z.
//! - [`Projection::Fisheye`]: the upper hemisphere seen by a camera looking at the zenith, with a
//!   radial lens model ([`FisheyeModel`]) and a calibration ([`FisheyeCalibration`]).
//! - [`Projection::AngularMap`]: Debevec's angular map of the full sphere.

mod fisheye;
pub mod fisheye_detect;
mod latlong;

pub use fisheye::{FisheyeCalibration, FisheyeModel, MAX_RADIUS_PX, MIN_FOV_DEG};
pub(crate) use latlong::interval_overlaps;

use glam::DVec3;

/// How the pixels of an environment-map image map to directions.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Projection {
    /// Equirectangular map of the full sphere (DESIGN.md's convention).
    #[default]
    LatLong,
    /// Upper hemisphere through a fisheye lens looking at the zenith.
    Fisheye(FisheyeCalibration),
    /// Debevec's angular map: the full sphere in the image's inscribed disc.
    AngularMap,
}

impl Projection {
    /// Direction (unit vector) seen at continuous pixel position (x, y) of a `width`×`height`
    /// image, or `None` where the image holds no direction (outside a fisheye's image circle).
    pub fn pixel_to_direction(&self, width: u32, height: u32, x: f64, y: f64) -> Option<DVec3> {
        match self {
            Projection::LatLong => Some(latlong::pixel_to_direction(width, height, x, y)),
            Projection::Fisheye(cal) => cal.pixel_to_direction(width, height, x, y),
            Projection::AngularMap => fisheye::angular_pixel_to_direction(width, height, x, y),
        }
    }

    /// Continuous pixel position at which direction `d` (need not be normalised) appears, or
    /// `None` where the image does not see it (below a fisheye's field of view).
    pub fn direction_to_pixel(&self, width: u32, height: u32, d: DVec3) -> Option<(f64, f64)> {
        match self {
            Projection::LatLong => latlong::direction_to_pixel(width, height, d),
            Projection::Fisheye(cal) => cal.direction_to_pixel(width, height, d),
            Projection::AngularMap => fisheye::angular_direction_to_pixel(width, height, d),
        }
    }

    /// Exact solid angle (steradians) of every pixel, row-major; 0 for pixels that see nothing.
    /// They sum to the solid angle the image covers (4π for lat-long and angular maps).
    pub fn solid_angles(&self, width: u32, height: u32) -> Vec<f64> {
        match self {
            Projection::LatLong => latlong::solid_angles(width, height),
            Projection::Fisheye(cal) => cal.solid_angles(width, height),
            Projection::AngularMap => fisheye::angular_solid_angles(width, height),
        }
    }

    /// The same projection for the image magnified `n` times in each direction (its sub-pixel
    /// grid): a fisheye calibration's centre and radius, given in pixels, scale with it; the
    /// lat-long and angular maps depend on no pixel size.
    pub fn magnified(&self, n: u32) -> Projection {
        match self {
            Projection::Fisheye(cal) => Projection::Fisheye(FisheyeCalibration {
                center: cal
                    .center
                    .map(|[x, y]| [x * f64::from(n), y * f64::from(n)]),
                radius: cal.radius.map(|r| r * f64::from(n)),
                ..*cal
            }),
            other => *other,
        }
    }

    /// Short name used in logs and on the command line.
    pub fn name(&self) -> &'static str {
        match self {
            Projection::LatLong => "latlong",
            Projection::Fisheye(_) => "fisheye",
            Projection::AngularMap => "angular",
        }
    }
}
