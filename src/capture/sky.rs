//! The built-in analytic sky: envlight's default frame source (no files, no camera).
//!
//! Every frame is a lat-long map ([`Projection::LatLong`], DESIGN.md's convention) of a clear or
//! partly cloudy daylight sky with a moving sun, rendered procedurally and deterministically from
//! [`SkyOptions`] and the frame time ([`render_sky`]). [`SkySource`] is the [`FrameSource`].
//!
//! # Model
//!
//! 1. **Sky dome** (directions above the horizon): the Preetham model — A. J. Preetham,
//!    P. Shirley, B. Smits, "A practical analytic model for daylight", SIGGRAPH 1999. The Perez
//!    distribution `F(θ, γ) = (1 + A e^{B/cos θ})(1 + C e^{Dγ} + E cos²γ)` with the paper's
//!    turbidity-dependent coefficients A..E for the luminance Y and the chromaticities x, y
//!    (θ: zenith angle of the view direction, γ: angle between view and sun). Each quantity is
//!    its zenith value times `F(θ, γ) / F(0, θs)`; the zenith luminance
//!    `Yz = (4.0453 T − 4.9710) tan χ − 0.2155 T + 2.4192` kcd/m², `χ = (4/9 − T/120)(π − 2θs)`,
//!    and the zenith chromaticities are the paper's cubic polynomials in θs and T. xyY → XYZ →
//!    linear sRGB (Rec. 709 primaries, D65); negative channels (out of gamut) clamp to 0.
//!    The model breaks down near and below the horizon, so the sun elevation it sees is clamped to
//!    ≥ 1°; below 1° the whole sky fades smoothly (smoothstep) to a faint night floor at −8°.
//! 2. **Sun**: a uniform disc of angular radius 0.2665° (solid angle ≈ 6.80e-5 sr). Its
//!    direct-normal irradiance is the extraterrestrial solar illuminance (128 klx, a slightly warm
//!    white) times a per-channel transmittance `exp(−m (τ_R(λ) + τ_a(λ)))`: Kasten–Young air mass
//!    m, Rayleigh depth `τ_R = 0.008735 λ^−4.08`, Ångström aerosol depth `τ_a = β λ^−1.3` with
//!    Preetham's `β = 0.04608 T − 0.04586`, at λ = 680, 550, 440 nm for R, G, B. At T = 3 and the
//!    sun at the zenith that is ≈ 95 klx (≈ 140 W/m² in our units). The disc is rasterised by
//!    splatting: a stratified set of points on the disc, each carrying an equal share of the sun's
//!    irradiance, adds `energy / pixel solid angle` to the pixel it falls in, so Σ radiance × solid
//!    angle over the pixels equals the sun's irradiance exactly at every resolution. Disc points
//!    below the horizon are hidden by the ground.
//! 3. **Sun motion**: the azimuth advances at `sun_speed_deg_per_s`; the elevation follows a day
//!    arc `e(ψ) = e_min + (e_max − e_min)(1 + cos ψ)/2` with `ψ` advancing at the same rate,
//!    `e_min = min(−5°, start)`, `e_max = max(60°, start)`, starting at `sun_start_elevation_deg`
//!    and rising. One "day" (360° of ψ) takes `360 / sun_speed` seconds (180 s by default), part of
//!    it with the sun below the horizon.
//! 4. **Clouds** (optional): a flat layer 1500 m up, textured by five octaves of hash-based value
//!    noise (fBm, features ~1 km) seeded by `seed`, drifting with the wind (`wind_speed` m/s, in a
//!    direction derived from the seed). `cloud_cover` sets the threshold (≈ the covered fraction of
//!    the sky). Clouds are grey-white: lit by the clear sky and the sun (diffuse
//!    `(E_sky + E_sun,h)/π` scaled, plus Henyey–Greenstein forward scattering, so brighter near
//!    the sun), blended over the sky by their opacity, fading out toward the horizon. The sun disc
//!    is attenuated by the cloud opacity in its direction, so its power changes as clouds pass.
//!    Octaves finer than a pixel's footprint on the layer fade to their mean (anti-aliasing, so
//!    the clouds near the horizon do not flicker as they drift).
//! 5. **Ground** (below the horizon): uniform Lambertian ground of `ground_albedo`, radiance
//!    `albedo · E_ground / π`, with `E_ground` = the sun's direct irradiance × sin(elevation) ×
//!    cloud transmittance + the sky's irradiance on a horizontal plane (summed from the rendered
//!    sky pixels, clouds included).
//!
//! # Cost
//!
//! [`SkySource`] computes the per-pixel directions and solid angles once; a frame then costs one
//! pass per stage. The Perez gradation term is evaluated per row and the scattering term comes
//! from a per-frame table over sin(γ/2). 512×256 with clouds renders in about 8 ms in the test
//! profile (opt-level 2) on a loaded 2-core machine; without clouds about 3 ms.
//!
//! # Units
//!
//! Pixels are radiance in W/(m²·sr) per channel, assuming 683 lm/W: a luminance of L cd/m² becomes
//! L / 683. (So the Rec. 709 luminance of a pixel × 683 is its photometric luminance.)

use super::{CaptureError, FrameSource};
use crate::envmap::Projection;
use crate::frame::HdrFrame;
use glam::{DVec2, DVec3};
use std::f64::consts::PI;
use std::time::Instant;

/// Luminous efficacy used to turn photometric into radiometric-ish units (lm/W).
pub const LUMENS_PER_WATT: f64 = 683.0;
/// Angular radius of the sun disc (radians): 0.2665°.
pub const SUN_ANGULAR_RADIUS: f64 = 0.2665 * PI / 180.0;
/// Extraterrestrial solar illuminance (lux).
const SOLAR_ILLUMINANCE_LUX: f64 = 128_000.0;
/// Colour of the extraterrestrial sun in linear sRGB (normalised to luminance 1 below).
const SUN_COLOUR: [f64; 3] = [1.06, 0.99, 0.93];
/// Wavelengths (µm) standing for the R, G, B channels in the transmittance.
const CHANNEL_WAVELENGTHS_UM: [f64; 3] = [0.680, 0.550, 0.440];
/// Largest accepted image side.
pub const MAX_SIDE: u32 = 16384;
/// Fastest sun, degrees per second either way: a day in a tenth of a second.
pub const MAX_SUN_SPEED_DEG_PER_S: f64 = 3600.0;
/// Below this sun elevation (degrees) the Preetham model is evaluated at this elevation and the
/// sky fades out.
const MODEL_MIN_ELEVATION_DEG: f64 = 1.0;
/// Sun elevation (degrees) at which the twilight fade reaches the night floor.
const NIGHT_ELEVATION_DEG: f64 = -8.0;
/// Night-sky luminance floor (cd/m²), so a frame is never entirely black.
const NIGHT_LUMINANCE: f64 = 1e-3;
/// Height of the cloud layer (m) and the size of the lowest noise octave (m).
const CLOUD_HEIGHT_M: f64 = 1500.0;
const CLOUD_FEATURE_M: f64 = 1000.0;
/// Frame rate assumed for frame times when the source is not paced.
pub const UNPACED_FRAME_RATE: f64 = 30.0;

/// Settings of the built-in sky. See the module doc for the model.
#[derive(Clone, Debug, PartialEq)]
pub struct SkyOptions {
    /// Image width in pixels (lat-long map), 1..=16384.
    pub width: u32,
    /// Image height in pixels, 1..=16384.
    pub height: u32,
    /// Atmospheric turbidity T of the Preetham model, 1.7..=10 (2 = very clear, 10 = hazy).
    pub turbidity: f64,
    /// Sun elevation at time 0 (degrees above the horizon), −90..=90.
    pub sun_start_elevation_deg: f64,
    /// Sun azimuth at time 0 (degrees, as the lat-long u: 0 = −Z, 90 = +X).
    pub sun_start_azimuth_deg: f64,
    /// How fast the sun moves along its arc (degrees per second; negative runs backwards).
    pub sun_speed_deg_per_s: f64,
    /// Whether to draw the cloud layer.
    pub clouds: bool,
    /// Cloud cover 0..=1 (≈ fraction of the sky covered).
    pub cloud_cover: f64,
    /// Cloud drift speed at the cloud layer (m/s), ≥ 0.
    pub wind_speed: f64,
    /// Albedo of the Lambertian ground, 0..=1.
    pub ground_albedo: f64,
    /// Seed of the cloud noise and wind direction. The default, 2, is chosen so that the sun is
    /// clear of clouds at the start (for the first 6 s with the other defaults); a cloud then
    /// passes over it (about 6–15 s).
    pub seed: u64,
    /// Pacing in frames per second (> 0); `None` = as fast as possible.
    pub fps: Option<f64>,
    /// Number of frames to produce; `None` = endless.
    pub frames: Option<u64>,
}

impl Default for SkyOptions {
    fn default() -> Self {
        Self {
            width: 512,
            height: 256,
            turbidity: 3.0,
            sun_start_elevation_deg: 35.0,
            sun_start_azimuth_deg: 0.0,
            sun_speed_deg_per_s: 2.0,
            clouds: true,
            cloud_cover: 0.35,
            wind_speed: 15.0,
            ground_albedo: 0.2,
            seed: 2,
            fps: None,
            frames: None,
        }
    }
}

/// A sky setting out of range: the field, its value and what is allowed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct InvalidSkyOption {
    /// Field name, as in [`SkyOptions`] and the config file's `[sky]` table.
    pub field: &'static str,
    pub value: String,
    /// What is allowed, e.g. "in 1.7..=10".
    pub expected: String,
}

impl std::fmt::Display for InvalidSkyOption {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "sky {} must be {}, got {}",
            self.field, self.expected, self.value
        )
    }
}

fn check_range(field: &'static str, value: f64, lo: f64, hi: f64) -> Result<(), InvalidSkyOption> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(())
    } else {
        Err(InvalidSkyOption {
            field,
            value: value.to_string(),
            expected: format!("in {lo}..={hi}"),
        })
    }
}

fn check_finite(field: &'static str, value: f64) -> Result<(), InvalidSkyOption> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(InvalidSkyOption {
            field,
            value: value.to_string(),
            expected: "finite".into(),
        })
    }
}

impl SkyOptions {
    /// Checks every setting; the error names the field and its value.
    pub fn check(&self) -> Result<(), InvalidSkyOption> {
        for (field, side) in [("width", self.width), ("height", self.height)] {
            if side == 0 || side > MAX_SIDE {
                return Err(InvalidSkyOption {
                    field,
                    value: side.to_string(),
                    expected: format!("in 1..={MAX_SIDE}"),
                });
            }
        }
        // As many pixels as a frame file may hold, so that a recording of the sky replays
        // (about 68 bytes a pixel: 9 GB at the limit).
        let pixels = u64::from(self.width) * u64::from(self.height);
        if pixels > super::image_file::MAX_PIXELS {
            return Err(InvalidSkyOption {
                field: "width",
                value: format!("{} (height {})", self.width, self.height),
                expected: format!(
                    "at most {} pixels in all (16384x8192)",
                    super::image_file::MAX_PIXELS
                ),
            });
        }
        check_range("turbidity", self.turbidity, 1.7, 10.0)?;
        check_range(
            "sun_start_elevation_deg",
            self.sun_start_elevation_deg,
            -90.0,
            90.0,
        )?;
        check_finite("sun_start_azimuth_deg", self.sun_start_azimuth_deg)?;
        // Finite is not enough: speed × time overflowed to infinity (1e308 after 2 s) and
        // every later frame was black.
        check_range(
            "sun_speed_deg_per_s",
            self.sun_speed_deg_per_s,
            -MAX_SUN_SPEED_DEG_PER_S,
            MAX_SUN_SPEED_DEG_PER_S,
        )?;
        check_range("cloud_cover", self.cloud_cover, 0.0, 1.0)?;
        check_range("wind_speed", self.wind_speed, 0.0, 1000.0)?;
        check_range("ground_albedo", self.ground_albedo, 0.0, 1.0)?;
        if let Some(fps) = self.fps {
            if super::check_fps(fps).is_err() {
                return Err(InvalidSkyOption {
                    field: "fps",
                    value: fps.to_string(),
                    expected: format!("a frame rate of at least {} frames/s", super::MIN_FPS),
                });
            }
        }
        Ok(())
    }

    /// [`SkyOptions::check`] as a frame-source error.
    pub fn validate(&self) -> Result<(), CaptureError> {
        self.check()
            .map_err(|e| CaptureError::InvalidSettings(e.to_string()))
    }
}

/// The sun at one instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SunState {
    /// Unit direction towards the sun's centre.
    pub direction: DVec3,
    /// Elevation above the horizon (degrees).
    pub elevation_deg: f64,
    /// Azimuth (degrees, as the lat-long u: 0 = −Z, 90 = +X), in [0, 360).
    pub azimuth_deg: f64,
    /// Direct-normal irradiance of the whole disc after the atmosphere, before clouds (W/m² per
    /// channel). Zero once the disc is below the horizon.
    pub clear_irradiance: [f64; 3],
    /// Fraction of the direct sunlight that passes the clouds (1 without clouds).
    pub cloud_transmittance: f64,
}

impl SunState {
    /// Direct-normal irradiance after atmosphere and clouds (W/m² per channel), before the
    /// horizon hides part of the disc.
    pub fn irradiance(&self) -> [f64; 3] {
        self.clear_irradiance.map(|c| c * self.cloud_transmittance)
    }
}

/// Solid angle of the sun disc (sr).
pub fn sun_solid_angle() -> f64 {
    2.0 * PI * (1.0 - SUN_ANGULAR_RADIUS.cos())
}

fn direction_from_elevation_azimuth(elevation_deg: f64, azimuth_deg: f64) -> DVec3 {
    let (sin_e, cos_e) = elevation_deg.to_radians().sin_cos();
    let (sin_a, cos_a) = azimuth_deg.to_radians().sin_cos();
    DVec3::new(cos_e * sin_a, sin_e, -cos_e * cos_a)
}

/// Sun elevation and azimuth (degrees) at `time_s` (module doc, "Sun motion").
fn sun_position(options: &SkyOptions, time_s: f64) -> (f64, f64) {
    let start = options.sun_start_elevation_deg.clamp(-90.0, 90.0);
    let e_min = start.min(-5.0);
    let e_max = start.max(60.0);
    let cos_psi0 = (2.0 * (start - e_min) / (e_max - e_min) - 1.0).clamp(-1.0, 1.0);
    let psi0 = -cos_psi0.acos().to_degrees();
    let travelled = options.sun_speed_deg_per_s * time_s;
    let psi = (psi0 + travelled).to_radians();
    let elevation = e_min + (e_max - e_min) * 0.5 * (1.0 + psi.cos());
    let azimuth = (options.sun_start_azimuth_deg + travelled).rem_euclid(360.0);
    let azimuth = if azimuth.is_finite() { azimuth } else { 0.0 };
    (elevation, azimuth)
}

/// Kasten–Young relative optical air mass for a sun elevation in degrees (clamped to ≥ 0).
fn air_mass(elevation_deg: f64) -> f64 {
    let zenith_deg = 90.0 - elevation_deg.clamp(0.0, 90.0);
    1.0 / (zenith_deg.to_radians().cos() + 0.50572 * (96.07995 - zenith_deg).powf(-1.6364))
}

/// Direct-normal irradiance of the sun through a clear atmosphere (W/m² per channel).
fn clear_sun_irradiance(turbidity: f64, elevation_deg: f64) -> [f64; 3] {
    if elevation_deg < -SUN_ANGULAR_RADIUS.to_degrees() {
        return [0.0; 3];
    }
    let m = air_mass(elevation_deg);
    let beta = 0.04608 * turbidity - 0.04586;
    let lum = crate::frame::luminance(SUN_COLOUR.map(|c| c as f32)) as f64;
    let e0 = SOLAR_ILLUMINANCE_LUX / LUMENS_PER_WATT / lum;
    let mut out = [0.0; 3];
    for (c, o) in out.iter_mut().enumerate() {
        let lambda = CHANNEL_WAVELENGTHS_UM[c];
        let tau = 0.008735 * lambda.powf(-4.08) + beta * lambda.powf(-1.3);
        *o = e0 * SUN_COLOUR[c] * (-m * tau).exp();
    }
    out
}

/// The sun at `time_s` for these options (cloud transmittance included).
pub fn sun_at(options: &SkyOptions, time_s: f64) -> SunState {
    let (elevation_deg, azimuth_deg) = sun_position(options, time_s);
    let direction = direction_from_elevation_azimuth(elevation_deg, azimuth_deg);
    let cloud_transmittance = if options.clouds {
        1.0 - Clouds::new(options, time_s).opacity(direction, 0.0)
    } else {
        1.0
    };
    SunState {
        direction,
        elevation_deg,
        azimuth_deg,
        clear_irradiance: clear_sun_irradiance(options.turbidity, elevation_deg),
        cloud_transmittance,
    }
}

fn smoothstep(edge0: f64, edge1: f64, x: f64) -> f64 {
    let t = ((x - edge0) / (edge1 - edge0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

// ---------------------------------------------------------------------------------------------
// Preetham sky

/// Perez coefficients A..E of one quantity.
#[derive(Clone, Copy, Debug)]
struct Perez([f64; 5]);

impl Perez {
    fn gradation(&self, cos_theta: f64) -> f64 {
        let [a, b, ..] = self.0;
        1.0 + a * (b / cos_theta.max(1e-4)).exp()
    }

    fn scattering(&self, gamma: f64, cos_gamma: f64) -> f64 {
        let [_, _, c, d, e] = self.0;
        1.0 + c * (d * gamma).exp() + e * cos_gamma * cos_gamma
    }
}

/// Preetham sky for one sun position and turbidity.
#[derive(Clone, Debug)]
struct PreethamSky {
    sun: DVec3,
    perez: [Perez; 3],
    /// Zenith Y (cd/m²), x, y divided by F(0, θs) of each quantity.
    #[cfg_attr(not(test), allow(dead_code))]
    zenith_over_f0: [f64; 3],
    /// Twilight fade of the sky, 1 for a sun ≥ 1° high.
    fade: f64,
    /// `zenith_over_f0 · scattering(γ)` of Y, x, y tabulated over `sin(γ/2)` in [0, 1]
    /// (smooth in that variable, so linear interpolation is accurate).
    table: Vec<[f64; 3]>,
}

/// Intervals of the scattering table.
const SCATTER_TABLE_STEPS: usize = 1024;

/// Zenith luminance Yz (kcd/m²) of Preetham et al. for turbidity `t` and sun zenith angle
/// `theta_s` (radians).
fn zenith_luminance_kcd(t: f64, theta_s: f64) -> f64 {
    let chi = (4.0 / 9.0 - t / 120.0) * (PI - 2.0 * theta_s);
    (4.0453 * t - 4.9710) * chi.tan() - 0.2155 * t + 2.4192
}

fn zenith_chromaticity(t: f64, theta_s: f64) -> (f64, f64) {
    let th = [theta_s * theta_s * theta_s, theta_s * theta_s, theta_s, 1.0];
    let row = |m: [[f64; 4]; 3]| {
        let dot = |r: [f64; 4]| r.iter().zip(th).map(|(a, b)| a * b).sum::<f64>();
        t * t * dot(m[0]) + t * dot(m[1]) + dot(m[2])
    };
    let x = row([
        [0.00166, -0.00375, 0.00209, 0.0],
        [-0.02903, 0.06377, -0.03202, 0.00394],
        [0.11693, -0.21196, 0.06052, 0.25886],
    ]);
    let y = row([
        [0.00275, -0.00610, 0.00317, 0.0],
        [-0.04214, 0.08970, -0.04153, 0.00516],
        [0.15346, -0.26756, 0.06670, 0.26688],
    ]);
    (x, y)
}

/// CIE xyY → linear sRGB (Rec. 709 primaries, D65), negative channels clamped to 0.
#[inline]
fn xyy_to_linear_srgb(x: f64, y: f64, big_y: f64) -> [f64; 3] {
    if y.is_nan() || big_y.is_nan() || y <= 1e-6 || big_y <= 0.0 {
        return [0.0; 3];
    }
    let k = big_y / y;
    let big_x = x * k;
    let big_z = (1.0 - x - y) * k;
    let r = 3.2404542 * big_x - 1.5371385 * big_y - 0.4985314 * big_z;
    let g = -0.9692660 * big_x + 1.8760108 * big_y + 0.0415560 * big_z;
    let b = 0.0556434 * big_x - 0.2040259 * big_y + 1.0572252 * big_z;
    [r.max(0.0), g.max(0.0), b.max(0.0)]
}

impl PreethamSky {
    fn new(turbidity: f64, sun_elevation_deg: f64, sun: DVec3) -> Self {
        let t = turbidity;
        let model_elevation = sun_elevation_deg.max(MODEL_MIN_ELEVATION_DEG);
        let theta_s = (90.0 - model_elevation).to_radians();
        // The model's sun: the true azimuth at the clamped elevation.
        let horizontal = DVec2::new(sun.x, sun.z);
        let sun_model = if horizontal.length() > 1e-9 {
            let h = horizontal.normalize() * theta_s.sin();
            DVec3::new(h.x, theta_s.cos(), h.y)
        } else {
            DVec3::Y
        };
        let perez = [
            Perez([
                0.1787 * t - 1.4630,
                -0.3554 * t + 0.4275,
                -0.0227 * t + 5.3251,
                0.1206 * t - 2.5771,
                -0.0670 * t + 0.3703,
            ]),
            Perez([
                -0.0193 * t - 0.2592,
                -0.0665 * t + 0.0008,
                -0.0004 * t + 0.2125,
                -0.0641 * t - 0.8989,
                -0.0033 * t + 0.0452,
            ]),
            Perez([
                -0.0167 * t - 0.2608,
                -0.0950 * t + 0.0092,
                -0.0079 * t + 0.2102,
                -0.0441 * t - 1.6537,
                -0.0109 * t + 0.0529,
            ]),
        ];
        let yz = zenith_luminance_kcd(t, theta_s) * 1000.0;
        let (xz, yz_chroma) = zenith_chromaticity(t, theta_s);
        let cos_ts = theta_s.cos();
        let f0 = |p: &Perez| p.gradation(1.0) * p.scattering(theta_s, cos_ts);
        let zenith_over_f0 = [
            yz / f0(&perez[0]),
            xz / f0(&perez[1]),
            yz_chroma / f0(&perez[2]),
        ];
        let fade = if sun_elevation_deg >= MODEL_MIN_ELEVATION_DEG {
            1.0
        } else {
            smoothstep(
                NIGHT_ELEVATION_DEG,
                MODEL_MIN_ELEVATION_DEG,
                sun_elevation_deg,
            )
        };
        let table = (0..=SCATTER_TABLE_STEPS)
            .map(|i| {
                let half = (i as f64 / SCATTER_TABLE_STEPS as f64).min(1.0);
                let gamma = 2.0 * half.asin();
                let cos_gamma = 1.0 - 2.0 * half * half;
                std::array::from_fn(|q| zenith_over_f0[q] * perez[q].scattering(gamma, cos_gamma))
            })
            .collect();
        Self {
            sun: sun_model,
            perez,
            zenith_over_f0,
            fade,
            table,
        }
    }

    /// Radiance like [`Self::radiance`], with the scattering term from the table.
    #[inline]
    fn radiance_tabulated(&self, d: DVec3, gradations: [f64; 3]) -> [f64; 3] {
        let cos_gamma = d.dot(self.sun);
        let half = (0.5 * (1.0 - cos_gamma)).clamp(0.0, 1.0).sqrt();
        let x = half * SCATTER_TABLE_STEPS as f64;
        let i = (x as usize).min(SCATTER_TABLE_STEPS - 1);
        let t = x - i as f64;
        let (a, b) = (self.table[i], self.table[i + 1]);
        let q = |k: usize| gradations[k] * (a[k] + (b[k] - a[k]) * t);
        let big_y = (q(0) * self.fade + NIGHT_LUMINANCE) * (1.0 / LUMENS_PER_WATT);
        xyy_to_linear_srgb(q(1), q(2), big_y)
    }

    /// Gradation terms (Y, x, y) for a view zenith cosine; depends only on the pixel row.
    fn gradations(&self, cos_theta: f64) -> [f64; 3] {
        [
            self.perez[0].gradation(cos_theta),
            self.perez[1].gradation(cos_theta),
            self.perez[2].gradation(cos_theta),
        ]
    }

    /// Chromaticity x, y and luminance Y (cd/m²) before the twilight fade (exact, no table).
    #[cfg_attr(not(test), allow(dead_code))]
    fn xyy(&self, d: DVec3, gradations: [f64; 3]) -> (f64, f64, f64) {
        let cos_gamma = d.dot(self.sun).clamp(-1.0, 1.0);
        let gamma = cos_gamma.acos();
        let q = |i: usize| {
            self.zenith_over_f0[i] * gradations[i] * self.perez[i].scattering(gamma, cos_gamma)
        };
        (q(1), q(2), q(0))
    }

    /// Radiance (W/(m²·sr) per channel) towards direction `d` (above the horizon).
    #[cfg_attr(not(test), allow(dead_code))]
    fn radiance(&self, d: DVec3, gradations: [f64; 3]) -> [f64; 3] {
        let (x, y, big_y) = self.xyy(d, gradations);
        let big_y = big_y * self.fade + NIGHT_LUMINANCE;
        xyy_to_linear_srgb(x, y, big_y).map(|c| c / LUMENS_PER_WATT)
    }
}

// ---------------------------------------------------------------------------------------------
// Clouds

fn hash64(mut x: u64) -> u64 {
    // SplitMix64 finaliser.
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

#[inline]
fn lattice_value(ix: i64, iy: i64, seed: u64) -> f64 {
    // One multiply-xorshift round over the combined key is plenty for value noise.
    let mut h = (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ seed;
    h ^= h >> 32;
    h = h.wrapping_mul(0xD6E8_FEB8_6659_FD93);
    h ^= h >> 32;
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// `floor` without a libm call (x86-64 baseline has no rounding instruction); |x| < 2⁶³.
#[inline]
fn floor_i64(x: f64) -> i64 {
    let i = x as i64;
    if (i as f64) > x {
        i - 1
    } else {
        i
    }
}

/// Value noise in [0, 1] with quintic interpolation.
#[inline]
fn value_noise(p: DVec2, seed: u64) -> f64 {
    let (ix, iy) = (floor_i64(p.x), floor_i64(p.y));
    let (tx, ty) = (p.x - ix as f64, p.y - iy as f64);
    let fade = |t: f64| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
    let (sx, sy) = (fade(tx), fade(ty));
    let v00 = lattice_value(ix, iy, seed);
    let v10 = lattice_value(ix + 1, iy, seed);
    let v01 = lattice_value(ix, iy + 1, seed);
    let v11 = lattice_value(ix + 1, iy + 1, seed);
    let a = v00 + (v10 - v00) * sx;
    let b = v01 + (v11 - v01) * sx;
    a + (b - a) * sy
}

const CLOUD_OCTAVES: usize = 5;
const OCTAVE_GAIN: f64 = 0.5;

/// Amplitude of each octave, the sum of all and the sum of those after each octave.
const fn octave_amplitudes() -> ([f64; CLOUD_OCTAVES], f64, [f64; CLOUD_OCTAVES]) {
    let mut amp = [0.0; CLOUD_OCTAVES];
    let mut a = 1.0;
    let mut i = 0;
    while i < CLOUD_OCTAVES {
        amp[i] = a;
        a *= OCTAVE_GAIN;
        i += 1;
    }
    let mut rest = [0.0; CLOUD_OCTAVES];
    let mut total = 0.0;
    let mut i = CLOUD_OCTAVES;
    while i > 0 {
        i -= 1;
        rest[i] = total;
        total += amp[i];
    }
    (amp, total, rest)
}

const OCTAVES: ([f64; CLOUD_OCTAVES], f64, [f64; CLOUD_OCTAVES]) = octave_amplitudes();

/// Next octave's lattice position: ×2 with a rotation (hides the lattice) and an offset.
#[inline]
fn next_octave(q: DVec2) -> DVec2 {
    DVec2::new(1.6 * q.x - 1.2 * q.y, 1.2 * q.x + 1.6 * q.y) + DVec2::new(17.3, -9.1)
}

#[inline]
fn octave_seed(seed: u64, octave: usize) -> u64 {
    seed.wrapping_add(octave as u64 * 0x51ED_27F3)
}

/// Fractal sum of value noise (5 octaves), normalised to [0, 1].
#[cfg_attr(not(test), allow(dead_code))]
fn fbm(p: DVec2, seed: u64) -> f64 {
    let (amp, total, _) = OCTAVES;
    let mut sum = 0.0;
    let mut q = p;
    for (octave, a) in amp.iter().enumerate() {
        sum += a * value_noise(q, octave_seed(seed, octave));
        q = next_octave(q);
    }
    sum / total
}

/// `smoothstep(lo, hi, fbm(p, seed))`, stopping early once the remaining octaves cannot change
/// the result. `footprint` is the pixel's size in noise units: octaves whose lattice spacing
/// (2^−k) is below two footprints fade to their mean 0.5 (anti-aliasing: near the horizon the
/// fine octaves would only alias and flicker as the clouds drift). 0 keeps every octave.
fn fbm_step(p: DVec2, seed: u64, lo: f64, hi: f64, footprint: f64) -> f64 {
    let (amp, total, rest) = OCTAVES;
    let (lo, hi) = (lo * total, hi * total);
    let mut sum = 0.0;
    let mut q = p;
    let mut spacing = 1.0;
    for octave in 0..CLOUD_OCTAVES {
        let weight = if footprint > 0.0 {
            (spacing / footprint - 1.0).clamp(0.0, 1.0)
        } else {
            1.0
        };
        if weight <= 0.0 {
            // This and all finer octaves are at their mean.
            sum += 0.5 * (amp[octave] + rest[octave]);
            break;
        }
        let noise = value_noise(q, octave_seed(seed, octave));
        sum += amp[octave] * (0.5 + weight * (noise - 0.5));
        if sum + rest[octave] <= lo {
            return 0.0;
        }
        if sum >= hi {
            return 1.0;
        }
        q = next_octave(q);
        spacing *= 0.5;
    }
    smoothstep(lo, hi, sum)
}

/// Quantiles of [`fbm`] at 0, 5%, …, 100% (measured over many samples; ends set to 0 and 1),
/// so that `cloud_cover` is close to the covered fraction of the sky.
const FBM_QUANTILES: [f64; 21] = [
    0.0, 0.2802, 0.3230, 0.3542, 0.3803, 0.4034, 0.4245, 0.4440, 0.4627, 0.4808, 0.4987, 0.5169,
    0.5357, 0.5549, 0.5749, 0.5960, 0.6192, 0.6452, 0.6767, 0.7209, 1.0,
];

fn fbm_quantile(q: f64) -> f64 {
    let x = q.clamp(0.0, 1.0) * 20.0;
    let i = (x.floor() as usize).min(19);
    let t = x - i as f64;
    FBM_QUANTILES[i] + (FBM_QUANTILES[i + 1] - FBM_QUANTILES[i]) * t
}

/// The cloud layer at one instant.
struct Clouds {
    seed: u64,
    /// Noise-space offset from the wind drift.
    offset: DVec2,
    /// Noise value where opacity starts to rise, and the width of the soft edge.
    threshold: f64,
    edge: f64,
    enabled: bool,
}

impl Clouds {
    fn new(options: &SkyOptions, time_s: f64) -> Self {
        let seed = hash64(options.seed ^ 0xC10D_5EED);
        let angle = (hash64(seed) >> 11) as f64 / (1u64 << 53) as f64 * 2.0 * PI;
        let wind = DVec2::new(angle.cos(), angle.sin()) * options.wind_speed;
        let offset = wind * time_s / CLOUD_FEATURE_M;
        let offset = if offset.is_finite() {
            offset
        } else {
            DVec2::ZERO
        };
        // Threshold at the (1 − cover) quantile, shifted by the soft edge so that cover 0 gives
        // no cloud and cover 1 a fully opaque overcast.
        let edge = 0.12;
        let cover = options.cloud_cover.clamp(0.0, 1.0);
        let threshold = fbm_quantile(1.0 - cover) - edge * cover;
        Self {
            seed,
            offset,
            threshold,
            edge,
            enabled: options.clouds && options.cloud_cover > 0.0,
        }
    }

    /// Cloud opacity in [0, 1] towards direction `d` (0 below and near the horizon), for a pixel
    /// of angular size `pixel_angle` (radians; 0 = a single ray, all octaves).
    fn opacity(&self, d: DVec3, pixel_angle: f64) -> f64 {
        if !self.enabled || d.y <= 0.02 {
            return 0.0;
        }
        let horizon = smoothstep(0.02, 0.15, d.y);
        let scale = CLOUD_HEIGHT_M / CLOUD_FEATURE_M / d.y;
        let p = DVec2::new(d.x, d.z) * scale + self.offset;
        // Distance × angle, stretched by 1/sin(elevation) on the plane.
        let footprint = pixel_angle * scale / d.y;
        let lo = self.threshold;
        fbm_step(p, self.seed, lo, lo + self.edge, footprint) * horizon
    }
}

/// Henyey–Greenstein phase function (per steradian).
fn henyey_greenstein(g: f64, cos_gamma: f64) -> f64 {
    let denom = (1.0 + g * g - 2.0 * g * cos_gamma).max(1e-9);
    (1.0 - g * g) / (4.0 * PI * denom * denom.sqrt())
}

// ---------------------------------------------------------------------------------------------
// Rendering

/// Per-pixel directions and solid angles of a lat-long map, computed once per size.
#[derive(Clone, Debug)]
struct SkyGeometry {
    width: u32,
    height: u32,
    directions: Vec<DVec3>,
    solid_angles: Vec<f64>,
}

impl SkyGeometry {
    fn new(width: u32, height: u32) -> Self {
        let projection = Projection::LatLong;
        let mut directions = Vec::with_capacity(width as usize * height as usize);
        for y in 0..height {
            for x in 0..width {
                let d = projection
                    .pixel_to_direction(width, height, f64::from(x) + 0.5, f64::from(y) + 0.5)
                    .unwrap_or(DVec3::Y);
                directions.push(d);
            }
        }
        Self {
            width,
            height,
            directions,
            solid_angles: projection.solid_angles(width, height),
        }
    }
}

/// Orthonormal tangents of unit vector `n`.
fn tangents(n: DVec3) -> (DVec3, DVec3) {
    let helper = if n.y.abs() < 0.9 { DVec3::Y } else { DVec3::X };
    let t1 = n.cross(helper).normalize();
    (t1, n.cross(t1))
}

/// Adds the sun disc's irradiance `irradiance` (W/m² per channel) to the pixels it covers.
fn splat_sun(geometry: &SkyGeometry, pixels: &mut [[f64; 3]], sun: DVec3, irradiance: [f64; 3]) {
    if irradiance.iter().all(|&c| c <= 0.0) {
        return;
    }
    let (w, h) = (geometry.width, geometry.height);
    // Enough points that every covered pixel gets several, capped for huge maps.
    let pixel_angle = PI / f64::from(h.max(w / 2).max(1));
    let diameter_px = 2.0 * SUN_ANGULAR_RADIUS / pixel_angle;
    let n = ((3.0 * diameter_px).ceil() as usize).clamp(16, 128);
    let share = 1.0 / (n * n) as f64;
    let (t1, t2) = tangents(sun);
    let projection = Projection::LatLong;
    for i in 0..n {
        for j in 0..n {
            // Stratified square → concentric disc (Shirley–Chiu).
            let a = 2.0 * (i as f64 + 0.5) / n as f64 - 1.0;
            let b = 2.0 * (j as f64 + 0.5) / n as f64 - 1.0;
            let (r, phi) = if a.abs() > b.abs() {
                (a, PI / 4.0 * (b / a))
            } else {
                (b, PI / 2.0 - PI / 4.0 * (a / b))
            };
            // Uniform in solid angle on the small cap: offset angle ∝ radius is accurate here.
            let offset = r * SUN_ANGULAR_RADIUS;
            let d = sun * offset.cos() + (t1 * phi.cos() + t2 * phi.sin()) * offset.sin();
            if d.y <= 0.0 {
                continue; // hidden by the ground
            }
            let Some((px, py)) = projection.direction_to_pixel(w, h, d) else {
                continue;
            };
            let x = (px.floor().max(0.0) as u32).min(w - 1);
            let y = (py.floor().max(0.0) as u32).min(h - 1);
            let idx = y as usize * w as usize + x as usize;
            let omega = geometry.solid_angles[idx];
            if omega > 0.0 {
                for c in 0..3 {
                    pixels[idx][c] += irradiance[c] * share / omega;
                }
            }
        }
    }
}

/// Renders one frame with precomputed geometry. `with_sun = false` leaves out the disc (tests).
fn render_with_geometry(
    geometry: &SkyGeometry,
    options: &SkyOptions,
    time_s: f64,
    with_sun: bool,
) -> HdrFrame {
    let (w, h) = (geometry.width as usize, geometry.height as usize);
    let sun = sun_at(options, time_s);
    let sky = PreethamSky::new(options.turbidity, sun.elevation_deg, sun.direction);
    let mut pixels = vec![[0.0f64; 3]; w * h];

    // 1. Clear sky above the horizon, and its irradiance on a horizontal plane.
    let mut clear_sky_irradiance = [0.0; 3];
    for y in 0..h {
        let row = y * w;
        let cos_theta = geometry.directions[row].y;
        if cos_theta <= 0.0 {
            continue;
        }
        let gradations = sky.gradations(cos_theta);
        for x in 0..w {
            let d = geometry.directions[row + x];
            let l = sky.radiance_tabulated(d, gradations);
            let weight = d.y * geometry.solid_angles[row + x];
            for c in 0..3 {
                clear_sky_irradiance[c] += l[c] * weight;
            }
            pixels[row + x] = l;
        }
    }

    // 2. Clouds over the sky.
    let clear = sun.clear_irradiance;
    let sun_sin = sun.elevation_deg.to_radians().sin().max(0.0);
    if options.clouds && options.cloud_cover > 0.0 {
        let clouds = Clouds::new(options, time_s);
        let ambient: [f64; 3] =
            std::array::from_fn(|c| (clear_sky_irradiance[c] + clear[c] * sun_sin) / PI);
        let pixel_angle = PI / f64::from(geometry.height);
        for (d, p) in geometry.directions.iter().zip(pixels.iter_mut()) {
            if d.y <= 0.02 {
                continue;
            }
            let alpha = clouds.opacity(*d, pixel_angle);
            if alpha <= 0.0 {
                continue;
            }
            let forward = henyey_greenstein(0.6, d.dot(sun.direction));
            let diffuse = 0.55 * (1.0 - 0.35 * alpha);
            let silver = 0.25 * (1.0 - 0.5 * alpha);
            for c in 0..3 {
                let cloud = diffuse * ambient[c] + silver * clear[c] * forward;
                p[c] = p[c] * (1.0 - alpha) + cloud * alpha;
            }
        }
    }

    // 3. Ground: albedo · (direct + sky irradiance) / π.
    let mut sky_irradiance = [0.0; 3];
    for ((d, p), omega) in geometry
        .directions
        .iter()
        .zip(&pixels)
        .zip(&geometry.solid_angles)
    {
        if d.y > 0.0 {
            for c in 0..3 {
                sky_irradiance[c] += p[c] * d.y * omega;
            }
        }
    }
    let direct = sun.irradiance().map(|c| c * sun_sin);
    let ground: [f64; 3] =
        std::array::from_fn(|c| options.ground_albedo * (direct[c] + sky_irradiance[c]) / PI);
    for (d, p) in geometry.directions.iter().zip(pixels.iter_mut()) {
        if d.y <= 0.0 {
            *p = ground;
        }
    }

    // 4. The sun disc.
    if with_sun {
        splat_sun(geometry, &mut pixels, sun.direction, sun.irradiance());
    }

    let pixels = pixels
        .into_iter()
        .map(|p| {
            p.map(|c| {
                if c.is_finite() && c > 0.0 {
                    c as f32
                } else {
                    0.0
                }
            })
        })
        .collect();
    let mut frame = HdrFrame {
        width: geometry.width,
        height: geometry.height,
        pixels,
        projection: Projection::LatLong,
        time: time_s,
        seq: 0,
    };
    frame.sanitize();
    frame
}

/// Renders the sky at `time_s` seconds: a lat-long [`HdrFrame`] of `options.width` ×
/// `options.height` pixels with `frame.time = time_s` and `seq = 0`. Pure and deterministic.
/// Options are expected to be valid ([`SkyOptions::validate`]); invalid ones still give finite,
/// non-negative pixels (sizes are clamped to 1..=16384).
pub fn render_sky(options: &SkyOptions, time_s: f64) -> HdrFrame {
    let geometry = SkyGeometry::new(
        options.width.clamp(1, MAX_SIDE),
        options.height.clamp(1, MAX_SIDE),
    );
    render_with_geometry(&geometry, options, time_s, true)
}

// ---------------------------------------------------------------------------------------------
// Frame source

/// The built-in sky as a [`FrameSource`]. Frame `seq` shows time `seq / fps`, or
/// `seq / 30` s when unpaced ([`UNPACED_FRAME_RATE`]). With `fps` set, frame `seq` is delivered no
/// earlier than `start + seq / fps` (start = the first call), so pacing does not drift.
#[derive(Debug)]
pub struct SkySource {
    options: SkyOptions,
    geometry: SkyGeometry,
    seq: u64,
    start: Option<Instant>,
}

impl SkySource {
    /// A source for these options (validated).
    pub fn new(options: SkyOptions) -> Result<Self, CaptureError> {
        options.validate()?;
        let geometry = SkyGeometry::new(options.width, options.height);
        Ok(Self {
            options,
            geometry,
            seq: 0,
            start: None,
        })
    }

    /// The options this source renders with.
    pub fn options(&self) -> &SkyOptions {
        &self.options
    }
}

impl FrameSource for SkySource {
    fn next_frame(&mut self) -> Result<Option<HdrFrame>, CaptureError> {
        if self.options.frames.is_some_and(|n| self.seq >= n) {
            return Ok(None);
        }
        let rate = self.options.fps.unwrap_or(UNPACED_FRAME_RATE);
        let time_s = self.seq as f64 / rate;
        if self.options.fps.is_some() {
            let start = *self.start.get_or_insert_with(Instant::now);
            if !super::sleep_until(start, time_s) {
                return Ok(None);
            }
        }
        let mut frame = render_with_geometry(&self.geometry, &self.options, time_s, true);
        frame.seq = self.seq;
        self.seq += 1;
        Ok(Some(frame))
    }

    fn describe(&self) -> String {
        let o = &self.options;
        let clouds = if o.clouds && o.cloud_cover > 0.0 {
            format!("clouds {:.0}%", o.cloud_cover * 100.0)
        } else {
            "no clouds".to_string()
        };
        let pacing = match o.fps {
            Some(fps) => format!("{fps} frames/s"),
            None => "unpaced".to_string(),
        };
        format!(
            "built-in sky {}x{} (Preetham, turbidity {}, {clouds}, {pacing})",
            o.width, o.height, o.turbidity
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::luminance;

    fn clear(options: SkyOptions) -> SkyOptions {
        SkyOptions {
            clouds: false,
            ..options
        }
    }

    fn small(width: u32, height: u32) -> SkyOptions {
        SkyOptions {
            width,
            height,
            ..SkyOptions::default()
        }
    }

    fn assert_valid_pixels(frame: &HdrFrame, what: &str) {
        assert_eq!(
            frame.pixels.len(),
            frame.width as usize * frame.height as usize
        );
        for (i, p) in frame.pixels.iter().enumerate() {
            assert!(
                p.iter().all(|c| c.is_finite() && *c >= 0.0),
                "{what}: pixel {i} = {p:?}"
            );
        }
    }

    /// Σ radiance × solid angle per channel.
    fn energy(frame: &HdrFrame) -> [f64; 3] {
        let omega = Projection::LatLong.solid_angles(frame.width, frame.height);
        let mut e = [0.0; 3];
        for (p, o) in frame.pixels.iter().zip(&omega) {
            for c in 0..3 {
                e[c] += f64::from(p[c]) * o;
            }
        }
        e
    }

    fn geometry_of(options: &SkyOptions) -> SkyGeometry {
        SkyGeometry::new(options.width, options.height)
    }

    #[test]
    fn pixels_are_finite_and_non_negative_everywhere() {
        let sizes = [(4, 2), (1, 1), (5, 3), (7, 1), (33, 17), (64, 32)];
        let times = [0.0, 1.0 / 30.0, 7.3, 45.0, 100.0, 150.0, 1e5];
        for (i, &(w, h)) in sizes.iter().enumerate() {
            for (j, &t) in times.iter().enumerate() {
                let k = i * times.len() + j;
                let options = SkyOptions {
                    width: w,
                    height: h,
                    turbidity: [1.7, 3.0, 10.0][k % 3],
                    sun_start_elevation_deg: [-90.0, -5.0, 0.0, 0.5, 35.0, 90.0][k % 6],
                    sun_speed_deg_per_s: [2.0, -7.0, 0.0, 37.0][k % 4],
                    clouds: k % 5 != 0,
                    cloud_cover: [0.0, 0.35, 1.0, 0.8][k % 4],
                    ground_albedo: [0.0, 0.2, 1.0][k % 3],
                    seed: k as u64 * 977,
                    ..SkyOptions::default()
                };
                options.validate().unwrap();
                let frame = render_sky(&options, t);
                assert_eq!((frame.width, frame.height), (w, h));
                assert_eq!(frame.projection, Projection::LatLong);
                assert_eq!(frame.time, t);
                assert_valid_pixels(&frame, &format!("{options:?} t={t}"));
            }
        }
    }

    #[test]
    fn sun_below_horizon_fades_the_sky_without_nan() {
        let mut previous = f64::INFINITY;
        for elevation in [1.0, -1.0, -3.0, -6.0, -8.0, -20.0, -90.0] {
            let options = SkyOptions {
                sun_start_elevation_deg: elevation,
                sun_speed_deg_per_s: 0.0,
                ..small(64, 32)
            };
            let frame = render_sky(&options, 0.0);
            assert_valid_pixels(&frame, "below horizon");
            let total: f64 = energy(&frame).iter().sum();
            assert!(total > 0.0 && total <= previous, "{elevation}: {total}");
            previous = total;
            if elevation < -1.0 {
                let sun = sun_at(&options, 0.0);
                assert_eq!(sun.clear_irradiance, [0.0; 3]);
            }
        }
        // Night: only the faint floor and the ground it lights.
        assert!(previous < 1e-4, "night energy {previous}");
    }

    #[test]
    fn brightest_pixel_is_the_sun() {
        for (w, h) in [(64, 32), (256, 128), (31, 15)] {
            for t in [0.0, 10.0, 33.3, 60.0] {
                let options = clear(small(w, h));
                let sun = sun_at(&options, t);
                assert!(sun.elevation_deg > 5.0, "pick times with the sun up");
                let frame = render_sky(&options, t);
                let (mut best, mut best_lum) = (0, -1.0);
                for (i, p) in frame.pixels.iter().enumerate() {
                    if luminance(*p) > best_lum {
                        (best, best_lum) = (i, luminance(*p));
                    }
                }
                let (px, py) = Projection::LatLong
                    .direction_to_pixel(w, h, sun.direction)
                    .unwrap();
                let (sx, sy) = (
                    (px as usize).min(w as usize - 1),
                    (py as usize).min(h as usize - 1),
                );
                let (bx, by) = (best % w as usize, best / w as usize);
                // The disc may straddle a pixel border.
                assert!(
                    bx.abs_diff(sx) <= 1 && by.abs_diff(sy) <= 1,
                    "{w}x{h} t={t}: brightest ({bx},{by}), sun at ({sx},{sy})"
                );
            }
        }
    }

    #[test]
    fn sun_energy_is_exact_at_every_resolution() {
        for clouds in [false, true] {
            for t in [0.0, 20.0] {
                let mut totals = Vec::new();
                for (w, h) in [(64, 32), (1024, 512), (4, 2), (101, 49)] {
                    let options = SkyOptions {
                        clouds,
                        cloud_cover: 0.5,
                        ..small(w, h)
                    };
                    let sun = sun_at(&options, t);
                    assert!(sun.elevation_deg > 1.0);
                    let geometry = geometry_of(&options);
                    let with = render_with_geometry(&geometry, &options, t, true);
                    let without = render_with_geometry(&geometry, &options, t, false);
                    let omega = Projection::LatLong.solid_angles(w, h);
                    // Pixels whose centre lies within 2° + a pixel diagonal of the sun.
                    let reach = (2.0f64.to_radians() + 2.0 * PI / f64::from(h)).cos();
                    let mut sum = [0.0; 3];
                    let pixels = with.pixels.iter().zip(&without.pixels);
                    for ((p, q), (o, d)) in pixels.zip(omega.iter().zip(&geometry.directions)) {
                        for (c, s) in sum.iter_mut().enumerate() {
                            let delta = f64::from(p[c]) - f64::from(q[c]);
                            if d.dot(sun.direction) < reach {
                                assert!(delta.abs() < 1e-3, "sun energy far from the sun");
                            }
                            *s += delta * o;
                        }
                    }
                    let expected = sun.irradiance();
                    for c in 0..3 {
                        let err = (sum[c] - expected[c]).abs();
                        assert!(
                            err <= 0.01 * expected[c] + 1e-6,
                            "{w}x{h} clouds={clouds} t={t} channel {c}: {} vs {}",
                            sum[c],
                            expected[c]
                        );
                    }
                    totals.push(sum);
                }
                for s in &totals {
                    for c in 0..3 {
                        assert!((s[c] - totals[0][c]).abs() <= 0.01 * totals[0][c] + 1e-6);
                    }
                }
            }
        }
    }

    #[test]
    fn sun_irradiance_is_about_100_klx_at_high_sun() {
        let options = SkyOptions {
            sun_start_elevation_deg: 90.0,
            clouds: false,
            ..SkyOptions::default()
        };
        let sun = sun_at(&options, 0.0);
        let lux = f64::from(luminance(sun.irradiance().map(|c| c as f32))) * LUMENS_PER_WATT;
        assert!((85_000.0..115_000.0).contains(&lux), "{lux} lx");
        // Warmer (less blue) than the extraterrestrial sun, and hazier skies dim it.
        let [r, _, b] = sun.irradiance();
        assert!(r > b);
        let hazy = sun_at(
            &SkyOptions {
                turbidity: 10.0,
                ..options.clone()
            },
            0.0,
        );
        assert!(hazy.irradiance()[1] < 0.7 * sun.irradiance()[1]);
        assert!((sun_solid_angle() - 6.8e-5).abs() < 0.05e-5);
    }

    #[test]
    fn zenith_luminance_matches_preetham_formula() {
        // T = 3, θs = 30°: Yz = (4.0453 T − 4.9710) tan χ − 0.2155 T + 2.4192 (kcd/m²),
        // χ = (4/9 − T/120)(π − 2θs).
        let t: f64 = 3.0;
        let theta_s = 30f64.to_radians();
        let chi = (4.0 / 9.0 - t / 120.0) * (PI - 2.0 * theta_s);
        let expected = ((4.0453 * t - 4.9710) * chi.tan() - 0.2155 * t + 2.4192) * 1000.0;
        assert!((expected - 10_430.0).abs() < 20.0, "{expected}");
        let sun = direction_from_elevation_azimuth(60.0, 0.0);
        let sky = PreethamSky::new(t, 60.0, sun);
        let (x, y, big_y) = sky.xyy(DVec3::Y, sky.gradations(1.0));
        assert!((big_y - expected).abs() < 1e-6 * expected, "{big_y}");
        // Zenith chromaticity from the paper's polynomials (evaluated by hand): bluish white.
        assert!(
            (x - 0.2534).abs() < 1e-3 && (y - 0.2598).abs() < 1e-3,
            "{x} {y}"
        );
        // The RGB conversion keeps the luminance (in W/(m²·sr), 683 lm/W).
        let rgb = sky.radiance(DVec3::Y, sky.gradations(1.0));
        let lum = f64::from(luminance(rgb.map(|c| c as f32))) * LUMENS_PER_WATT;
        assert!((lum - expected).abs() < 0.002 * expected, "{lum}");
        assert!(rgb[2] > rgb[0], "zenith is blue: {rgb:?}");
        // The rendered top row (θ = 0.35°) agrees.
        let options = SkyOptions {
            turbidity: t,
            sun_start_elevation_deg: 60.0,
            sun_speed_deg_per_s: 0.0,
            clouds: false,
            ..SkyOptions::default()
        };
        let frame = render_sky(&options, 0.0);
        let top: f64 = (0..frame.width)
            .map(|x| f64::from(luminance(frame.pixel(x, 0))))
            .sum::<f64>()
            / f64::from(frame.width)
            * LUMENS_PER_WATT;
        assert!((top - expected).abs() < 0.01 * expected, "{top}");
    }

    #[test]
    fn sky_is_brighter_near_the_sun_than_far_from_it() {
        let options = SkyOptions {
            sun_speed_deg_per_s: 0.0,
            ..clear(small(256, 128))
        };
        let sun = sun_at(&options, 0.0);
        let geometry = geometry_of(&options);
        let frame = render_with_geometry(&geometry, &options, 0.0, false);
        let (mut near, mut n_near, mut far, mut n_far) = (0.0, 0, 0.0, 0);
        for (d, p) in geometry.directions.iter().zip(&frame.pixels) {
            let gamma = d.dot(sun.direction).clamp(-1.0, 1.0).acos().to_degrees();
            if d.y > 0.1 && gamma < 10.0 {
                near += f64::from(luminance(*p));
                n_near += 1;
            } else if d.y > 0.1 && (85.0..95.0).contains(&gamma) {
                far += f64::from(luminance(*p));
                n_far += 1;
            }
        }
        let (near, far) = (near / f64::from(n_near), far / f64::from(n_far));
        assert!(near > 2.0 * far, "near {near} far {far}");
    }

    #[test]
    fn horizon_brightening_at_equal_distance_from_the_sun() {
        // What the Perez gradation term really does (A < 0 for T < 8.2): at (about) the same
        // angle from the sun, the sky near the horizon is brighter than at the zenith.
        let sun = direction_from_elevation_azimuth(46.0, 0.0);
        let sky = PreethamSky::new(3.0, 46.0, sun);
        let zenith = sky.xyy(DVec3::Y, sky.gradations(1.0)).2; // γ = 44°
        let low = direction_from_elevation_azimuth(1.0, 0.0); // γ = 45°
        let horizon = sky.xyy(low, sky.gradations(low.y)).2;
        assert!(horizon > 1.5 * zenith, "horizon {horizon} zenith {zenith}");
    }

    #[test]
    fn frames_change_smoothly_in_time() {
        let options = small(128, 64);
        for t in [0.0, 12.0, 41.0, 90.0] {
            let a = energy(&render_sky(&options, t));
            let b = energy(&render_sky(&options, t + 1.0 / 30.0));
            let c = energy(&render_sky(&options, t + 60.0));
            for ch in 0..3 {
                let rel = (a[ch] - b[ch]).abs() / a[ch];
                assert!(rel < 0.03, "t={t} channel {ch}: {rel}");
            }
            let moved = sun_at(&options, t)
                .direction
                .dot(sun_at(&options, t + 60.0).direction);
            assert!(moved < 30f64.to_radians().cos());
            let diff: f64 = (0..3).map(|ch| (a[ch] - c[ch]).abs() / a[ch]).sum();
            let fa = render_sky(&options, t);
            let fc = render_sky(&options, t + 60.0);
            let changed = fa
                .pixels
                .iter()
                .zip(&fc.pixels)
                .filter(|(p, q)| {
                    let (lp, lq) = (luminance(**p), luminance(**q));
                    (lp - lq).abs() > 0.1 * lp.max(lq)
                })
                .count();
            assert!(
                changed > fa.pixels.len() / 10 || diff > 0.1,
                "t={t}: only {changed} pixels changed"
            );
        }
    }

    #[test]
    fn clouds_are_deterministic_seeded_and_drift() {
        let base = SkyOptions {
            sun_speed_deg_per_s: 0.0,
            cloud_cover: 0.5,
            ..small(128, 64)
        };
        let cloudy = render_sky(&base, 5.0);
        assert_eq!(cloudy, render_sky(&base, 5.0), "deterministic");
        assert_ne!(cloudy, render_sky(&clear(base.clone()), 5.0), "clouds show");
        let other_seed = SkyOptions {
            seed: 12345,
            ..base.clone()
        };
        assert_ne!(cloudy, render_sky(&other_seed, 5.0), "seed matters");
        // With the sun still, only the clouds move.
        let later = render_sky(&base, 125.0);
        let moved = cloudy
            .pixels
            .iter()
            .zip(&later.pixels)
            .filter(|(p, q)| (luminance(**p) - luminance(**q)).abs() > 0.05 * luminance(**p))
            .count();
        assert!(moved > cloudy.pixels.len() / 20, "{moved} pixels changed");
        // Cover 0 is the clear sky.
        let none = SkyOptions {
            cloud_cover: 0.0,
            ..base.clone()
        };
        assert_eq!(render_sky(&none, 5.0), render_sky(&clear(base), 5.0));
    }

    /// The default sky is the demo of a fresh install (`envlight decompose`, `envlight run`), so
    /// its sun must be in view at the start, and the default seed is chosen for that: clear for
    /// the first 6 s, then a cloud passes over the sun (about 6–15 s) and leaves it clear again.
    #[test]
    fn the_default_sky_starts_with_a_clear_sun_and_a_cloud_passes_it() {
        let options = SkyOptions::default();
        let transmittance = |t: f64| sun_at(&options, t).cloud_transmittance;
        let steps = |from: f64, to: f64| {
            (0..)
                .map(move |i| from + 0.25 * f64::from(i))
                .take_while(move |t| *t <= to)
        };
        for t in steps(0.0, 6.0) {
            assert!(transmittance(t) > 0.999, "sun covered at {t} s");
        }
        let darkest = steps(6.0, 15.0).map(transmittance).fold(1.0, f64::min);
        assert!(darkest < 0.2, "no cloud over the sun: {darkest}");
        assert!(transmittance(15.0) > 0.95, "{}", transmittance(15.0));
        assert!(sun_at(&options, 0.0).elevation_deg > 30.0);
    }

    #[test]
    fn passing_clouds_change_the_sun_power() {
        let options = SkyOptions {
            sun_speed_deg_per_s: 0.0,
            cloud_cover: 0.5,
            ..SkyOptions::default()
        };
        let transmittances: Vec<f64> = (0..400)
            .map(|i| sun_at(&options, f64::from(i) * 3.0).cloud_transmittance)
            .collect();
        let min = transmittances.iter().copied().fold(1.0, f64::min);
        let max = transmittances.iter().copied().fold(0.0, f64::max);
        assert!(min < 0.3 && max > 0.99, "{min}..{max}");
        // Smooth per frame (1/30 s).
        for t in [0.0, 100.0, 333.0] {
            let a = sun_at(&options, t).cloud_transmittance;
            let b = sun_at(&options, t + 1.0 / 30.0).cloud_transmittance;
            assert!((a - b).abs() < 0.02, "{a} {b}");
        }
    }

    #[test]
    fn cloud_cover_is_roughly_the_covered_fraction() {
        for cover in [0.2, 0.35, 0.5, 0.8] {
            let options = SkyOptions {
                cloud_cover: cover,
                ..SkyOptions::default()
            };
            let mut sum = 0.0;
            let mut n = 0.0;
            for seed in 0..4 {
                let clouds = Clouds::new(
                    &SkyOptions {
                        seed,
                        ..options.clone()
                    },
                    0.0,
                );
                for i in 0..100 {
                    for j in 0..100 {
                        let p = DVec2::new(f64::from(i) * 0.13, f64::from(j) * 0.13);
                        sum += fbm_step(
                            p,
                            clouds.seed,
                            clouds.threshold,
                            clouds.threshold + 0.12,
                            0.0,
                        );
                        n += 1.0;
                    }
                }
            }
            let fraction = sum / n;
            assert!((fraction - cover).abs() < 0.1, "cover {cover}: {fraction}");
        }
    }

    #[test]
    fn fbm_step_matches_smoothstep_of_fbm() {
        for i in 0..2000 {
            let p = DVec2::new(f64::from(i) * 0.377, f64::from(i % 37) * 0.91);
            let (lo, hi) = (0.55, 0.67);
            let exact = smoothstep(lo, hi, fbm(p, 99));
            assert!((fbm_step(p, 99, lo, hi, 0.0) - exact).abs() < 1e-12);
            // A footprint far above the coarsest lattice spacing leaves the mean.
            let mean = smoothstep(0.4, 0.6, 0.5);
            assert!((fbm_step(p, 99, 0.4, 0.6, 5.0) - mean).abs() < 1e-12);
            // Footprints below the finest spacing change nothing.
            assert!((fbm_step(p, 99, lo, hi, 0.01) - exact).abs() < 1e-12);
        }
    }

    #[test]
    fn ground_is_lambertian_under_sun_and_sky() {
        let options = SkyOptions {
            sun_speed_deg_per_s: 0.0,
            ..clear(small(64, 32))
        };
        let geometry = geometry_of(&options);
        // The sky's irradiance without the disc: the sun counts as direct light.
        let frame = render_with_geometry(&geometry, &options, 0.0, false);
        let sun = sun_at(&options, 0.0);
        let mut sky = [0.0; 3];
        for ((d, p), o) in geometry
            .directions
            .iter()
            .zip(&frame.pixels)
            .zip(&geometry.solid_angles)
        {
            if d.y > 0.0 {
                for c in 0..3 {
                    sky[c] += f64::from(p[c]) * d.y * o;
                }
            }
        }
        let sin_e = sun.elevation_deg.to_radians().sin();
        let ground = frame.pixel(10, 31);
        for c in 0..3 {
            let expected = 0.2 * (sun.irradiance()[c] * sin_e + sky[c]) / PI;
            let got = f64::from(ground[c]);
            assert!(
                (got - expected).abs() < 0.1 * expected,
                "{got} vs {expected}"
            );
        }
        let brighter = render_sky(
            &SkyOptions {
                ground_albedo: 0.4,
                ..options
            },
            0.0,
        );
        let ratio = brighter.pixel(3, 30)[1] / ground[1];
        assert!((ratio - 2.0).abs() < 1e-4, "{ratio}");
    }

    #[test]
    fn validate_names_the_bad_field() {
        let cases: Vec<(SkyOptions, &str)> = vec![
            (small(0, 32), "width"),
            (small(64, 0), "height"),
            (small(20_000, 32), "20000"),
            (
                SkyOptions {
                    turbidity: 1.0,
                    ..SkyOptions::default()
                },
                "turbidity",
            ),
            (
                SkyOptions {
                    turbidity: f64::NAN,
                    ..SkyOptions::default()
                },
                "turbidity must be in 1.7..=10, got NaN",
            ),
            (
                SkyOptions {
                    cloud_cover: 1.5,
                    ..SkyOptions::default()
                },
                "cloud_cover",
            ),
            (
                SkyOptions {
                    ground_albedo: -0.1,
                    ..SkyOptions::default()
                },
                "ground_albedo",
            ),
            (
                SkyOptions {
                    fps: Some(0.0),
                    ..SkyOptions::default()
                },
                "fps",
            ),
            (
                SkyOptions {
                    fps: Some(f64::NAN),
                    ..SkyOptions::default()
                },
                "fps",
            ),
            (
                SkyOptions {
                    fps: Some(1e-30),
                    ..SkyOptions::default()
                },
                "fps",
            ),
            (
                SkyOptions {
                    sun_start_elevation_deg: f64::NAN,
                    ..SkyOptions::default()
                },
                "sun_start_elevation_deg",
            ),
            (
                SkyOptions {
                    sun_speed_deg_per_s: f64::INFINITY,
                    ..SkyOptions::default()
                },
                "sun_speed_deg_per_s",
            ),
            (
                SkyOptions {
                    sun_speed_deg_per_s: 1e308,
                    ..SkyOptions::default()
                },
                "sun_speed_deg_per_s must be in -3600..=3600",
            ),
            (
                SkyOptions {
                    wind_speed: -1.0,
                    ..SkyOptions::default()
                },
                "wind_speed",
            ),
            (small(MAX_SIDE, MAX_SIDE), "at most 134217728 pixels"),
        ];
        for (options, needle) in cases {
            let err = options.validate().unwrap_err();
            assert!(matches!(err, CaptureError::InvalidSettings(_)));
            let message = err.to_string();
            assert!(message.contains(needle), "{message:?} lacks {needle:?}");
            assert!(SkySource::new(options).is_err());
        }
        SkyOptions::default().validate().unwrap();
        small(MAX_SIDE, 1).validate().unwrap();
        small(MAX_SIDE, MAX_SIDE / 2).validate().unwrap();
    }

    #[test]
    fn source_counts_frames_and_stops() {
        let mut source = SkySource::new(SkyOptions {
            frames: Some(3),
            ..small(16, 8)
        })
        .unwrap();
        assert_eq!(
            source.describe(),
            "built-in sky 16x8 (Preetham, turbidity 3, clouds 35%, unpaced)"
        );
        for seq in 0..3u64 {
            let frame = source.next_frame().unwrap().unwrap();
            assert_eq!(frame.seq, seq);
            assert!((frame.time - seq as f64 / UNPACED_FRAME_RATE).abs() < 1e-12);
            assert_eq!(frame, {
                let mut f = render_sky(source.options(), frame.time);
                f.seq = seq;
                f
            });
        }
        assert!(source.next_frame().unwrap().is_none());
        assert!(source.next_frame().unwrap().is_none());
    }

    #[test]
    fn paced_source_waits_for_each_frame() {
        let mut source = SkySource::new(SkyOptions {
            fps: Some(100.0),
            frames: Some(4),
            clouds: false,
            ..small(8, 4)
        })
        .unwrap();
        assert_eq!(
            source.describe(),
            "built-in sky 8x4 (Preetham, turbidity 3, no clouds, 100 frames/s)"
        );
        let start = Instant::now();
        let mut times = Vec::new();
        while let Some(frame) = source.next_frame().unwrap() {
            times.push(frame.time);
        }
        assert_eq!(times, vec![0.0, 0.01, 0.02, 0.03]);
        assert!(start.elapsed() >= std::time::Duration::from_millis(30));
    }
}
