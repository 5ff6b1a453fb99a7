//! The built-in shapes and the camera matrices.

use super::*;

#[test]
fn camera_matrices_map_the_view_frustum_to_wgpu_clip_space() {
    let cam = Camera::perspective(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, 1.0);
    let m = cam.view_proj(2.0, 1.0, 10.0);
    // The target is at the centre; near and far map to depth 0 and 1.
    let c = m.project_point3(Vec3::ZERO);
    assert!(c.x.abs() < 1e-6 && c.y.abs() < 1e-6 && c.z > 0.0 && c.z < 1.0);
    assert!(m.project_point3(Vec3::new(0.0, 0.0, 4.0)).z.abs() < 1e-5);
    assert!((m.project_point3(Vec3::new(0.0, 0.0, -5.0)).z - 1.0).abs() < 1e-5);
    // +Y up on screen, +X right.
    assert!(m.project_point3(Vec3::new(0.0, 1.0, 0.0)).y > 0.0);
    assert!(m.project_point3(Vec3::new(1.0, 0.0, 0.0)).x > 0.0);
    // The top of the field of view maps to y = 1.
    let top = Vec3::new(0.0, 5.0 * (0.5f32).tan(), 0.0);
    assert!((m.project_point3(top).y - 1.0).abs() < 1e-5);
}

#[test]
fn default_scene_has_casters_and_ground() {
    let s = Scene::default_scene();
    assert!(s.caster_indices > 0 && s.caster_indices < s.indices.len() as u32);
    assert!(s.ground_material.is_some());
    assert!(s.indices.iter().all(|&i| (i as usize) < s.vertices.len()));
    // The casters sit on the ground; the bounds hold all three spheres.
    assert!(s.bounds.radius > 1.5 && s.bounds.radius < 3.0);
}

#[test]
fn cuboid_faces_point_outwards() {
    let mut b = Builder::default();
    let m = b.material(Material::default());
    b.cuboid(Vec3::ZERO, Vec3::ONE, m);
    for t in b.indices.chunks_exact(3) {
        let p = |i: u32| Vec3::from_array(b.vertices[i as usize].position);
        let face = (p(t[1]) - p(t[0])).cross(p(t[2]) - p(t[0]));
        let n = Vec3::from_array(b.vertices[t[0] as usize].normal);
        assert!(face.dot(n) > 0.0, "triangle {t:?} winds inwards");
    }
}

#[test]
fn sphere_triangles_wind_outwards() {
    let mut b = Builder::default();
    let m = b.material(Material::default());
    b.uv_sphere(Vec3::ZERO, 1.0, 16, m);
    let mut checked = 0;
    for t in b.indices.chunks_exact(3) {
        let p = |i: u32| Vec3::from_array(b.vertices[i as usize].position);
        let face = (p(t[1]) - p(t[0])).cross(p(t[2]) - p(t[0]));
        if face.length() > 1e-6 {
            assert!(face.dot(p(t[0])) > 0.0);
            checked += 1;
        }
    }
    assert!(checked > 100);
}
