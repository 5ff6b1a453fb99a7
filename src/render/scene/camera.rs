//! The scene camera: its view and projection matrices, the camera a glTF file places, the
//! user's override and the camera fitted to a scene's bounds.

use super::*;

/// A perspective camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub eye: Vec3,
    pub target: Vec3,
    /// Vertical field of view in radians.
    pub fov_y: f32,
}

impl Camera {
    pub fn view(&self) -> Mat4 {
        let fwd = (self.target - self.eye).normalize_or(Vec3::NEG_Z);
        let up = if fwd.y.abs() > 0.999 {
            Vec3::Z
        } else {
            Vec3::Y
        };
        look_at_rh(self.eye, self.target, up)
    }

    /// The camera in words, for the log: eye, look-at point, vertical field of view.
    pub fn describe(&self) -> String {
        let p = |v: Vec3| format!("({:.3}, {:.3}, {:.3})", v.x, v.y, v.z);
        format!(
            "eye {}, looking at {}, vertical field of view {:.1}°",
            p(self.eye),
            p(self.target),
            self.fov_y.to_degrees()
        )
    }

    /// View-projection with wgpu's [0, 1] depth range.
    pub fn view_proj(&self, aspect: f32, near: f32, far: f32) -> Mat4 {
        perspective_rh(self.fov_y, aspect, near, far) * self.view()
    }
}

/// Right-handed view matrix (camera looks along −Z).
pub fn look_at_rh(eye: Vec3, center: Vec3, up: Vec3) -> Mat4 {
    let f = (center - eye).normalize();
    let s = f.cross(up).normalize();
    let u = s.cross(f);
    Mat4::from_cols(
        glam::Vec4::new(s.x, u.x, -f.x, 0.0),
        glam::Vec4::new(s.y, u.y, -f.y, 0.0),
        glam::Vec4::new(s.z, u.z, -f.z, 0.0),
        glam::Vec4::new(-s.dot(eye), -u.dot(eye), f.dot(eye), 1.0),
    )
}

/// Right-handed perspective projection with depth in [0, 1] (wgpu).
pub fn perspective_rh(fov_y: f32, aspect: f32, near: f32, far: f32) -> Mat4 {
    let h = 1.0 / (0.5 * fov_y).tan();
    let w = h / aspect;
    let r = far / (near - far);
    Mat4::from_cols(
        glam::Vec4::new(w, 0.0, 0.0, 0.0),
        glam::Vec4::new(0.0, h, 0.0, 0.0),
        glam::Vec4::new(0.0, 0.0, r, -1.0),
        glam::Vec4::new(0.0, 0.0, r * near, 0.0),
    )
}

/// Right-handed orthographic projection with depth in [0, 1] (wgpu).
pub fn orthographic_rh(left: f32, right: f32, bottom: f32, top: f32, near: f32, far: f32) -> Mat4 {
    let rw = 1.0 / (right - left);
    let rh = 1.0 / (top - bottom);
    let r = 1.0 / (near - far);
    Mat4::from_cols(
        glam::Vec4::new(2.0 * rw, 0.0, 0.0, 0.0),
        glam::Vec4::new(0.0, 2.0 * rh, 0.0, 0.0),
        glam::Vec4::new(0.0, 0.0, r, 0.0),
        glam::Vec4::new(-(left + right) * rw, -(top + bottom) * rh, r * near, 1.0),
    )
}

/// A glTF perspective camera placed by its node's world transform `world` (it looks along the
/// node's −Z with +Y up) with vertical field of view `yfov` (radians): the camera's eye and
/// target (one unit ahead). The renderer keeps the horizon level (+Y up), so a camera rolled
/// about its view direction is drawn unrolled, with a warning; glTF's aspect ratio and clip
/// planes are the renderer's own (the image's, and the scene's bounds).
pub(super) fn gltf_camera(world: Mat4, yfov: f32) -> Result<Camera, String> {
    if !(yfov.is_finite() && yfov > 0.0 && yfov < std::f32::consts::PI) {
        return Err(format!("yfov {yfov} is not an angle in (0, π) radians"));
    }
    let eye = world.transform_point3(Vec3::ZERO);
    let forward = world.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
    if !eye.is_finite() || forward == Vec3::ZERO || !forward.is_finite() {
        return Err("its transform does not place it (not finite, or degenerate)".into());
    }
    let up = world.transform_vector3(Vec3::Y).normalize_or_zero();
    if forward.y.abs() < 0.999 {
        let level = forward.cross(Vec3::Y).normalize().cross(forward);
        let roll = up.dot(level).clamp(-1.0, 1.0).acos().to_degrees();
        if roll > 1.0 {
            tracing::warn!(
                "a glTF camera rolled {roll:.0}° about its view direction is drawn level (+Y up)"
            );
        }
    }
    Ok(Camera {
        eye,
        target: eye + forward,
        fov_y: yfov,
    })
}

/// A camera set by the user over a scene's own (`envlight render --eye`, `--look-at`, `--fov`;
/// the daemon's `[render] eye`, `look_at`, `fov_deg`): each given part replaces the camera's.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CameraOverride {
    pub eye: Option<Vec3>,
    pub look_at: Option<Vec3>,
    /// Vertical field of view, degrees.
    pub fov_deg: Option<f32>,
}

impl CameraOverride {
    /// The range of [`CameraOverride::fov_deg`].
    pub const FOV_DEG: std::ops::RangeInclusive<f32> = 1.0..=179.0;

    /// `camera` with the given parts replaced; an error where a part is not finite, the field
    /// of view is outside [`CameraOverride::FOV_DEG`] or the eye is at the point it looks at.
    pub fn apply(&self, camera: Camera) -> Result<Camera, String> {
        let mut c = camera;
        if let Some(eye) = self.eye {
            if !eye.is_finite() {
                return Err(format!("camera eye {eye} is not finite"));
            }
            c.eye = eye;
        }
        if let Some(target) = self.look_at {
            if !target.is_finite() {
                return Err(format!("camera look-at point {target} is not finite"));
            }
            c.target = target;
        }
        if let Some(fov) = self.fov_deg {
            if !Self::FOV_DEG.contains(&fov) {
                return Err(format!(
                    "field of view {fov}° is outside {}..={}°",
                    Self::FOV_DEG.start(),
                    Self::FOV_DEG.end()
                ));
            }
            c.fov_y = fov.to_radians();
        }
        if c.eye.distance(c.target) < 1e-6 * (1.0 + c.eye.length()) {
            return Err(format!(
                "the camera's eye {} is where it looks ({}); give another --look-at or --eye",
                c.eye, c.target
            ));
        }
        Ok(c)
    }
}

/// A camera looking at the sphere from the front and a little above, framing it.
pub fn fit_camera(bounds: Sphere) -> Camera {
    let fov_y = 40f32.to_radians();
    let dist = bounds.radius / (fov_y * 0.5).sin() * 1.15;
    let dir = Vec3::new(0.0, 0.35, 1.0).normalize();
    Camera {
        eye: bounds.center + dir * dist,
        target: bounds.center,
        fov_y,
    }
}
