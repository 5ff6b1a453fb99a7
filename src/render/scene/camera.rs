//! The scene camera: its view and projection matrices, the camera a glTF file places, the
//! user's override and the camera fitted to a scene's bounds.

use super::*;
use glam::Vec4;

/// How a camera projects the scene onto the image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// A pinhole camera of this vertical field of view, in radians.
    Perspective { fov_y: f32 },
    /// Parallel rays along the view: half the view's height in world units (glTF's `ymag`);
    /// its width follows the image's aspect ratio.
    Orthographic { half_height: f32 },
}

/// The camera: where it is, where it looks, which way is up in the image, and its projection.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub eye: Vec3,
    pub target: Vec3,
    /// The world direction drawn upwards in the image (any length; only its part across the
    /// view counts): +Y for a level camera, a glTF camera's own +Y for a rolled one. Where it
    /// lies along the view, the camera is drawn level (+Y up, or +Z looking straight up or
    /// down).
    pub up: Vec3,
    pub projection: Projection,
}

impl Camera {
    /// A level perspective camera of vertical field of view `fov_y` (radians).
    pub fn perspective(eye: Vec3, target: Vec3, fov_y: f32) -> Self {
        Self {
            eye,
            target,
            up: Vec3::Y,
            projection: Projection::Perspective { fov_y },
        }
    }

    /// A level orthographic camera showing `half_height` world units above and below the
    /// point it looks at.
    pub fn orthographic(eye: Vec3, target: Vec3, half_height: f32) -> Self {
        Self {
            eye,
            target,
            up: Vec3::Y,
            projection: Projection::Orthographic { half_height },
        }
    }

    /// The unit direction the camera looks along.
    pub fn forward(&self) -> Vec3 {
        (self.target - self.eye).normalize_or(Vec3::NEG_Z)
    }

    /// The up direction the view uses: [`Camera::up`] unless it lies within 2.6° of the view
    /// direction ([`MIN_UP_SINE`]), then +Y, or +Z where that does too.
    fn view_up(&self) -> Vec3 {
        let forward = self.forward();
        [self.up, Vec3::Y, Vec3::Z]
            .into_iter()
            .map(Vec3::normalize_or_zero)
            .find(|up| up.is_finite() && forward.cross(*up).length() > MIN_UP_SINE)
            .unwrap_or(Vec3::X)
    }

    pub fn view(&self) -> Mat4 {
        look_along_rh(self.eye, self.forward(), self.view_up())
    }

    /// The camera in words, for the log: eye, look-at point, up direction where not +Y, and
    /// the projection.
    pub fn describe(&self) -> String {
        let p = |v: Vec3| format!("({:.3}, {:.3}, {:.3})", v.x, v.y, v.z);
        let up = self.view_up();
        let up = if up == Vec3::Y {
            String::new()
        } else {
            format!(", up {}", p(up))
        };
        let projection = match self.projection {
            Projection::Perspective { fov_y } => {
                format!("vertical field of view {:.1}°", fov_y.to_degrees())
            }
            Projection::Orthographic { half_height } => {
                format!("orthographic, {:.3} units high", 2.0 * half_height)
            }
        };
        format!(
            "eye {}, looking at {}{up}, {projection}",
            p(self.eye),
            p(self.target)
        )
    }

    /// View-projection with wgpu's [0, 1] depth range.
    pub fn view_proj(&self, aspect: f32, near: f32, far: f32) -> Mat4 {
        let projection = match self.projection {
            Projection::Perspective { fov_y } => perspective_rh(fov_y, aspect, near, far),
            Projection::Orthographic { half_height: h } => {
                orthographic_rh(-h * aspect, h * aspect, -h, h, near, far)
            }
        };
        projection * self.view()
    }

    /// The viewer in homogeneous coordinates, as the shaders take it: the eye (w = 1) for a
    /// perspective camera, the direction towards the viewer (w = 0, a point at infinity) for
    /// an orthographic one. The view vector at a point p is normalize(xyz − w·p) either way.
    pub fn viewer(&self) -> Vec4 {
        match self.projection {
            Projection::Perspective { .. } => self.eye.extend(1.0),
            Projection::Orthographic { .. } => (-self.forward()).extend(0.0),
        }
    }

    /// The unit direction from `p` towards the viewer.
    pub fn toward_viewer(&self, p: Vec3) -> Vec3 {
        let viewer = self.viewer();
        (viewer.truncate() - viewer.w * p).normalize_or_zero()
    }

    /// How far from the viewer `p` lies, to draw back to front: the distance from the eye for
    /// a perspective camera, the depth along the view for an orthographic one.
    pub fn sort_depth(&self, p: Vec3) -> f32 {
        match self.projection {
            Projection::Perspective { .. } => self.eye.distance(p),
            Projection::Orthographic { .. } => (p - self.eye).dot(self.forward()),
        }
    }
}

/// The sine of the smallest angle (2.6°) between a camera's up direction and its view for the
/// up direction to set the image's: nearer, the image's up is ill-defined.
const MIN_UP_SINE: f32 = 0.0447;

/// Right-handed view matrix (camera looks along −Z).
pub fn look_at_rh(eye: Vec3, center: Vec3, up: Vec3) -> Mat4 {
    look_along_rh(eye, (center - eye).normalize(), up)
}

/// Right-handed view matrix of a camera at `eye` looking along the unit direction `f`.
pub fn look_along_rh(eye: Vec3, f: Vec3, up: Vec3) -> Mat4 {
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

/// A glTF camera placed by its node's world transform `world`: the eye at the node's origin,
/// looking along its −Z (the target one unit ahead) with its +Y up in the image, so a rolled
/// camera is drawn rolled. A perspective camera keeps its vertical field of view `yfov`
/// (radians), an orthographic one its half-height `ymag` (world units; its `xmag` gives way to
/// the image's aspect ratio). glTF's aspect ratio and clip planes are the renderer's own (the
/// image's, and the scene's bounds).
pub(super) fn gltf_camera(world: Mat4, projection: Projection) -> Result<Camera, String> {
    match projection {
        Projection::Perspective { fov_y } => {
            // Below 10⁻⁶ rad the projection's 1/tan(fov/2) leaves f32.
            if !(1e-6..std::f32::consts::PI).contains(&fov_y) {
                return Err(format!("yfov {fov_y} is not an angle in [10⁻⁶, π) radians"));
            }
        }
        Projection::Orthographic { half_height } => {
            if !CameraOverride::ORTHO_HEIGHT.contains(&(2.0 * half_height)) {
                return Err(format!(
                    "ymag {half_height} is not a positive height (a view {}..={:e} units high)",
                    CameraOverride::ORTHO_HEIGHT.start(),
                    CameraOverride::ORTHO_HEIGHT.end()
                ));
            }
        }
    }
    let eye = world.transform_point3(Vec3::ZERO);
    let forward = world.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
    let up = world.transform_vector3(Vec3::Y).normalize_or_zero();
    if !eye.is_finite() || forward == Vec3::ZERO || !forward.is_finite() || !up.is_finite() {
        return Err("its transform does not place it (not finite, or degenerate)".into());
    }
    if forward.cross(up).length() <= MIN_UP_SINE {
        return Err("its transform turns its up direction (+Y) along its view (−Z)".into());
    }
    // The target ahead by a step the eye's coordinates can tell from it (one unit, more far from
    // the origin: 10⁻³ of the eye's largest coordinate).
    let step = (eye.abs().max_element() * 1e-3).max(1.0);
    Ok(Camera {
        eye,
        target: eye + forward * step,
        up,
        projection,
    })
}

/// A camera set by the user over a scene's own (`envlight render --eye`, `--look-at`, `--fov`;
/// the daemon's `[render] eye`, `look_at`, `fov_deg`): each given part replaces the camera's.
/// The camera keeps its up direction (drawn level where the new view runs along it); a field
/// of view makes the camera a perspective one, an orthographic height an orthographic one.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CameraOverride {
    pub eye: Option<Vec3>,
    pub look_at: Option<Vec3>,
    /// Vertical field of view, degrees: a perspective camera.
    pub fov_deg: Option<f32>,
    /// The view's height in world units: an orthographic camera (not with a field of view).
    pub ortho_height: Option<f32>,
}

impl CameraOverride {
    /// The range of [`CameraOverride::fov_deg`].
    pub const FOV_DEG: std::ops::RangeInclusive<f32> = 1.0..=179.0;

    /// The range of [`CameraOverride::ortho_height`], scene units: smaller views' projection
    /// leaves f32, larger ones than a scene may be ([`MAX_SCENE_RADIUS`]).
    pub const ORTHO_HEIGHT: std::ops::RangeInclusive<f32> = 1e-6..=MAX_SCENE_RADIUS;

    /// `camera` with the given parts replaced; an error where a part is not finite, the field
    /// of view is outside [`CameraOverride::FOV_DEG`], the orthographic height is not
    /// positive (or comes with a field of view) or the eye is at the point it looks at.
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
            c.projection = Projection::Perspective {
                fov_y: fov.to_radians(),
            };
        }
        if let Some(height) = self.ortho_height {
            if self.fov_deg.is_some() {
                return Err(
                    "a field of view (perspective) and an orthographic height exclude each other"
                        .into(),
                );
            }
            if !Self::ORTHO_HEIGHT.contains(&height) {
                return Err(format!(
                    "orthographic height {height} is not a positive number of scene units \
                     ({}..={:e})",
                    Self::ORTHO_HEIGHT.start(),
                    Self::ORTHO_HEIGHT.end()
                ));
            }
            c.projection = Projection::Orthographic {
                half_height: 0.5 * height,
            };
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
    Camera::perspective(bounds.center + dir * dist, bounds.center, fov_y)
}
