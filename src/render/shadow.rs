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
    // The grid cells of unit normals, (n · 64).round() + 64 in 0..=128 per axis, as a bit
    // set (a hash set took 8 of the 12 ms that posing a 263,000-vertex animated scene cost).
    const SIDE: usize = 129;
    let mut seen = vec![0u64; (SIDE * SIDE * SIDE).div_ceil(64)];
    let mut facing: Vec<Vec3> = Vec::new();
    // Facing: n · (towards the viewer) > 0, whose sign needs no normalising.
    let viewer = scene.camera.viewer();
    for v in &scene.vertices {
        let p = Vec3::from_array(v.position);
        let n = Vec3::from_array(v.normal);
        if n.dot(viewer.truncate() - viewer.w * p) > 0.0 {
            let cell = (n * 64.0).round().as_ivec3() + 64;
            let inside = cell.cmpge(glam::IVec3::ZERO).all()
                && cell.cmplt(glam::IVec3::splat(SIDE as i32)).all();
            if !inside {
                // Not a unit normal: kept without deduplication.
                facing.push(n);
                continue;
            }
            let [x, y, z] = cell.to_array().map(|c| c as usize);
            let bit = (x * SIDE + y) * SIDE + z;
            let (word, mask) = (bit / 64, 1u64 << (bit % 64));
            if seen[word] & mask == 0 {
                seen[word] |= mask;
                facing.push(n);
            }
        }
    }
    facing
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
