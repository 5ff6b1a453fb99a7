//! Shadow maps: one layer of a depth texture array per light that needs one.
//!
//! 1. Which lights need a map: a light needs one only if it reaches a visible surface, i.e. some
//!    vertex normal that faces the camera also faces the light (n·v > 0 and n·l > 0). Lights
//!    from below the ground whose only lit surfaces are hidden render no map. (The test ignores
//!    occlusion, so it is conservative: it never drops a map that a visible pixel reads.)
//! 2. Projection: orthographic, looking along −d, fitted to the shadow casters' bounding sphere
//!    (centre c, radius R): the eye at c + 2R·d, a 2R × 2R window, depth from R to 3R. Receivers
//!    outside the window or beyond the far plane read as lit unless a caster lies in front.
//! 3. Filtering: percentage-closer filtering with a Poisson disk whose radius grows with the
//!    light's spread. A merged light of solid angle Ω has an angular radius ρ = acos(1 − Ω/2π);
//!    its penumbra at occluder-receiver distance t is t·tan ρ. Without a blocker search the
//!    kernel assumes t = R/2, half the casters' radius, so radius = R/2 · tan ρ world units,
//!    plus a base of 1.5 texels (the filter footprint of a point light).

use super::scene::{look_at_rh, orthographic_rh, Scene, Sphere};
use glam::{Mat4, Vec3};

/// Base PCF radius in shadow-map texels (point lights).
pub const BASE_PCF_TEXELS: f32 = 1.5;

/// View-projection of the light-space orthographic camera for direction `dir` (towards the
/// light), fitted to `bounds`; depth in [0, 1] (wgpu).
pub fn light_view_proj(dir: Vec3, bounds: Sphere) -> Mat4 {
    let d = dir.normalize_or(Vec3::Y);
    let r = bounds.radius.max(1e-3);
    let eye = bounds.center + d * (2.0 * r);
    let up = if d.y.abs() > 0.99 { Vec3::Z } else { Vec3::Y };
    let view = look_at_rh(eye, bounds.center, up);
    let proj = orthographic_rh(-r, r, -r, r, r, 3.0 * r);
    proj * view
}

/// Angular radius of a source of solid angle `omega` (a spherical cap), in radians.
pub fn angular_radius(omega: f32) -> f32 {
    let c = 1.0 - (omega.max(0.0) / std::f32::consts::TAU);
    c.clamp(-1.0, 1.0).acos()
}

/// PCF kernel radius in shadow-map uv units (the map spans 2R) for a light of solid angle
/// `omega`, casters of radius `r`, and a map `resolution` texels wide.
pub fn pcf_radius_uv(omega: f32, resolution: u32) -> f32 {
    let rho = angular_radius(omega).min(1.2);
    // Penumbra of R/2 · tan ρ world units over a 2R window: tan ρ / 4 in uv.
    BASE_PCF_TEXELS / resolution.max(1) as f32 + 0.25 * rho.tan()
}

/// The normals of the camera-facing vertices, deduplicated on a coarse grid to bound the work
/// of [`reaches_visible`].
pub fn facing_normals(scene: &Scene) -> Vec<Vec3> {
    let mut facing = FacingSet::default();
    facing.add(&scene.vertices, scene.camera.viewer());
    facing.normals
}

/// Camera-facing normals deduplicated on a grid: the grid cells of unit normals,
/// (n · 64).round() + 64 in 0..=128 per axis, as a bit set (a hash set took 8 of the 12 ms
/// that posing a 263,000-vertex animated scene cost), and the first normal of each cell (those
/// off the unit grid all).
#[derive(Clone, Debug)]
pub struct FacingSet {
    seen: Vec<u64>,
    pub normals: Vec<Vec3>,
}

/// Grid cells along each axis of a [`FacingSet`].
const FACING_SIDE: usize = 129;

impl Default for FacingSet {
    fn default() -> Self {
        Self {
            seen: vec![0u64; (FACING_SIDE * FACING_SIDE * FACING_SIDE).div_ceil(64)],
            normals: Vec::new(),
        }
    }
}

impl FacingSet {
    /// Adds the normals of those `vertices` that face `viewer` ([`Camera::viewer`]: n · (towards
    /// the viewer) > 0, whose sign needs no normalising).
    ///
    /// [`Camera::viewer`]: super::scene::Camera::viewer
    pub fn add(&mut self, vertices: &[super::scene::Vertex], viewer: glam::Vec4) {
        const SIDE: usize = FACING_SIDE;
        for v in vertices {
            let p = Vec3::from_array(v.position);
            let n = Vec3::from_array(v.normal);
            if n.dot(viewer.truncate() - viewer.w * p) > 0.0 {
                let cell = (n * 64.0).round().as_ivec3() + 64;
                let inside = cell.cmpge(glam::IVec3::ZERO).all()
                    && cell.cmplt(glam::IVec3::splat(SIDE as i32)).all();
                if !inside {
                    // Not a unit normal: kept without deduplication.
                    self.normals.push(n);
                    continue;
                }
                let [x, y, z] = cell.to_array().map(|c| c as usize);
                let bit = (x * SIDE + y) * SIDE + z;
                let (word, mask) = (bit / 64, 1u64 << (bit % 64));
                if self.seen[word] & mask == 0 {
                    self.seen[word] |= mask;
                    self.normals.push(n);
                }
            }
        }
    }
}

/// The facing set of the vertices of an animated scene that no clip moves, read once so that
/// a pose reads only the moved ones ([`posed_facing_normals`]); `None` where nothing is
/// gained: a scene without animation, or one whose camera a clip moves (every vertex may turn
/// towards or away from it).
pub fn still_facing(scene: &Scene) -> Option<FacingSet> {
    let animation = scene.animation.as_ref().filter(|a| a.camera.is_none())?;
    let mut still = FacingSet::default();
    let viewer = scene.camera.viewer();
    // The runs between the moved ranges, and after the last.
    let mut next = 0;
    for range in animation.moved_runs() {
        if let Some(between) = scene.vertices.get(next..range.start) {
            still.add(between, viewer);
        }
        next = range.end;
    }
    if let Some(rest) = scene.vertices.get(next..) {
        still.add(rest, viewer);
    }
    Some(still)
}

/// The facing normals of an animated scene as posed: `still`'s ([`still_facing`]) and those
/// of the moved vertices; every vertex's ([`facing_normals`]) without `still`.
pub fn posed_facing_normals(scene: &Scene, still: Option<&FacingSet>) -> Vec<Vec3> {
    let (Some(still), Some(animation)) = (still, scene.animation.as_ref()) else {
        return facing_normals(scene);
    };
    let mut facing = still.clone();
    let viewer = scene.camera.viewer();
    for range in animation.moved_vertices() {
        if let Some(moved) = scene.vertices.get(range) {
            facing.add(moved, viewer);
        }
    }
    facing.normals
}

/// Whether a light from `dir` reaches any of the `facing` normals (see the module doc).
pub fn reaches_visible(facing: &[Vec3], dir: Vec3) -> bool {
    facing.iter().any(|n| n.dot(dir) > 0.0)
}

/// For each light direction, whether it reaches a surface the camera sees.
pub fn lights_needing_maps(scene: &Scene, dirs: &[Vec3]) -> Vec<bool> {
    let facing = facing_normals(scene);
    dirs.iter().map(|d| reaches_visible(&facing, *d)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::scene::{Camera, Ground, Material};

    /// The bit-set deduplication keeps the normals a hash set of the grid cells kept (the
    /// first of each cell), in their order; normals off the unit grid are all kept.
    #[test]
    fn facing_normals_are_the_first_of_each_grid_cell() {
        let mut scene = Scene::default_scene();
        // A few off the grid (not unit length), twice each.
        for (i, n) in [[3.0, 0.0, 0.0], [0.0, 0.0, 2.5], [3.0, 0.0, 0.0]]
            .into_iter()
            .enumerate()
        {
            scene.vertices[i].normal = n;
        }
        let mut reference = Vec::new();
        let mut seen = std::collections::HashSet::new();
        for v in &scene.vertices {
            let (p, n) = (Vec3::from(v.position), Vec3::from(v.normal));
            if n.dot(scene.camera.toward_viewer(p)) > 0.0 {
                let cell = (n * 64.0).round().as_ivec3();
                if n.length() > 1.01 || seen.insert(cell) {
                    reference.push(n);
                }
            }
        }
        assert!(reference.len() > 100, "{}", reference.len());
        assert_eq!(facing_normals(&scene), reference);
    }

    /// A pose's facing normals, read from the moved vertices over the still ones' set made
    /// once, fall in the grid cells that reading every vertex gives (the first normal of a
    /// cell may be another one: the vertices come in another order).
    #[test]
    fn posed_facing_normals_read_only_the_moved_vertices_to_the_same_cells() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/animated/turning_boxes.gltf");
        let mut scene = Scene::load(&path, true).unwrap();
        let still = still_facing(&scene).expect("a still camera");
        let animation = scene.animation.as_ref().unwrap();
        let moved: usize = animation.moved_vertices().map(|r| r.len()).sum();
        // The ground's 4 vertices are not moved; the boxes' are.
        assert_eq!(moved + 4, scene.vertices.len());
        let cells = |normals: &[Vec3]| {
            let mut cells: Vec<[i32; 3]> = normals
                .iter()
                .map(|n| (*n * 64.0).round().as_ivec3().to_array())
                .collect();
            cells.sort();
            cells
        };
        let mut compared = 0;
        for t in [0.0, 0.3, 1.0, 1.7] {
            scene.animate(t);
            let every = facing_normals(&scene);
            let posed = posed_facing_normals(&scene, Some(&still));
            assert_eq!(cells(&every), cells(&posed), "at {t} s");
            compared += every.len();
        }
        // (19 here: a few faces of two boxes and the ground each pose.)
        assert!(compared >= 16, "{compared}");
        // Without the still set (or animation), every vertex is read.
        assert_eq!(posed_facing_normals(&scene, None), facing_normals(&scene));
    }

    #[test]
    fn projection_keeps_the_bounds_inside_the_unit_cube() {
        let b = Sphere {
            center: Vec3::new(1.0, 2.0, -3.0),
            radius: 2.5,
        };
        for d in [
            Vec3::Y,
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(-0.3, 0.2, 0.9),
            Vec3::NEG_Y,
        ] {
            let m = light_view_proj(d, b);
            for k in 0..200 {
                let t = k as f32 * 0.7;
                let off = Vec3::new(t.sin() * t.cos(), t.cos(), (2.0 * t).sin()).normalize();
                let p = m.project_point3(b.center + off * b.radius * 0.999);
                assert!(p.x.abs() <= 1.0 && p.y.abs() <= 1.0, "{p}");
                assert!(p.z >= 0.0 && p.z <= 1.0, "{p}");
            }
            // Nearer the light is smaller depth.
            let near = m
                .project_point3(b.center + d.normalize() * b.radius * 0.5)
                .z;
            let far = m
                .project_point3(b.center - d.normalize() * b.radius * 0.5)
                .z;
            assert!(near < far);
        }
    }

    #[test]
    fn spread_widens_the_kernel() {
        assert!(angular_radius(0.0).abs() < 1e-6);
        // A hemisphere has angular radius π/2.
        assert!((angular_radius(std::f32::consts::TAU) - std::f32::consts::FRAC_PI_2).abs() < 1e-5);
        let point = pcf_radius_uv(0.0, 512);
        let sun = pcf_radius_uv(6.8e-5, 512);
        let merged = pcf_radius_uv(0.05, 512);
        assert!((point - 1.5 / 512.0).abs() < 1e-7);
        assert!(point < sun && sun < merged);
    }

    #[test]
    fn lights_below_the_visible_surfaces_need_no_map() {
        // A camera straight above sees the ground and the sphere's upper half only.
        let cam = Camera::perspective(Vec3::new(0.0, 6.0, 0.01), Vec3::ZERO, 0.7);
        let scene = Scene::sphere(
            Vec3::new(0.0, 0.5, 0.0),
            0.5,
            16,
            Material::default(),
            Some(Ground {
                height: 0.0,
                half_size: 4.0,
                material: Material::default(),
            }),
            cam,
        );
        let dirs = [Vec3::Y, Vec3::new(1.0, -0.05, 0.0).normalize(), Vec3::NEG_Y];
        let need = lights_needing_maps(&scene, &dirs);
        assert_eq!(need, vec![true, true, false]);
    }
}
