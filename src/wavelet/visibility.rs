//! Per-vertex visibility by CPU ray casting against the mesh itself.
//!
//! Steps:
//! 1. A [`Mesh`] (positions, normals, triangles) comes from a render [`Scene`] (its casters and
//!    ground) or from a procedural generator: [`Mesh::sphere_on_plane`] (a sphere resting on a
//!    finely subdivided ground, whose vertices see its shadow) and [`Mesh::bumpy_blob`] (a sphere
//!    with bumps that shadow each other).
//! 2. A [`Bvh`] over the triangles: median split of the centroid bounds on the longest axis,
//!    flattened depth-first into an array, up to [`LEAF_SIZE`] triangles per leaf.
//! 3. For every vertex and every texel direction `d` of the sphere map, a shadow ray leaves
//!    `p + ε n` along `d` ([`Bvh::occluded`]: any-hit, slab test for boxes, Möller–Trumbore for
//!    triangles). Directions below the vertex's tangent plane are not traced (the cosine factor
//!    of the transport is zero there). Vertices are processed in parallel (rayon).
//!
//! The result is visibility in the pixel domain of the map (one bit per texel per vertex); the
//! transport and the triple product turn it into wavelet coefficients.

use crate::render::scene::Scene;
use glam::Vec3;
use rayon::prelude::*;
use thiserror::Error;

/// Why a mesh cannot be used for visibility.
#[derive(Debug, Error, PartialEq)]
pub enum MeshError {
    #[error("mesh has no triangles")]
    Empty,
    #[error("mesh has {positions} positions but {normals} normals")]
    NormalCount { positions: usize, normals: usize },
    #[error("triangle {triangle} refers to vertex {index}, but the mesh has {vertices} vertices")]
    IndexOutOfRange {
        triangle: usize,
        index: u32,
        vertices: usize,
    },
    #[error("vertex {0} has a non-finite position or normal")]
    NonFinite(usize),
}

/// A triangle mesh in world space with per-vertex unit normals.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
}

/// Triangles per BVH leaf (at most).
pub const LEAF_SIZE: usize = 4;

impl Mesh {
    /// Checks counts, indices and finiteness.
    pub fn validate(&self) -> Result<(), MeshError> {
        if self.triangles.is_empty() {
            return Err(MeshError::Empty);
        }
        if self.positions.len() != self.normals.len() {
            return Err(MeshError::NormalCount {
                positions: self.positions.len(),
                normals: self.normals.len(),
            });
        }
        for (i, (p, n)) in self.positions.iter().zip(&self.normals).enumerate() {
            if !p.is_finite() || !n.is_finite() {
                return Err(MeshError::NonFinite(i));
            }
        }
        for (t, tri) in self.triangles.iter().enumerate() {
            for &index in tri {
                if index as usize >= self.positions.len() {
                    return Err(MeshError::IndexOutOfRange {
                        triangle: t,
                        index,
                        vertices: self.positions.len(),
                    });
                }
            }
        }
        Ok(())
    }

    /// The scene's triangles (casters and ground) with its vertex normals.
    pub fn from_scene(scene: &Scene) -> Result<Self, MeshError> {
        let mesh = Self {
            positions: scene
                .vertices
                .iter()
                .map(|v| Vec3::from_array(v.position))
                .collect(),
            normals: scene
                .vertices
                .iter()
                .map(|v| Vec3::from_array(v.normal).normalize_or(Vec3::Y))
                .collect(),
            triangles: scene
                .indices
                .chunks_exact(3)
                .map(|t| [t[0], t[1], t[2]])
                .collect(),
        };
        mesh.validate()?;
        Ok(mesh)
    }

    /// Appends another mesh.
    pub fn append(&mut self, other: &Mesh) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&other.positions);
        self.normals.extend_from_slice(&other.normals);
        self.triangles.extend(
            other
                .triangles
                .iter()
                .map(|t| [t[0] + base, t[1] + base, t[2] + base]),
        );
    }

    /// A UV sphere whose radius is `radius · (1 + bump(n))` for unit direction `n`; normals are
    /// computed from the displaced surface.
    fn displaced_sphere(
        center: Vec3,
        radius: f32,
        segments: u32,
        bump: impl Fn(Vec3) -> f32,
    ) -> Self {
        let segments = segments.max(4);
        let rings = segments / 2;
        let mut positions = Vec::new();
        for r in 0..=rings {
            let theta = std::f32::consts::PI * r as f32 / rings as f32;
            for s in 0..=segments {
                let phi = std::f32::consts::TAU * s as f32 / segments as f32;
                let n = Vec3::new(
                    theta.sin() * phi.sin(),
                    theta.cos(),
                    theta.sin() * phi.cos(),
                );
                positions.push(center + radius * (1.0 + bump(n)) * n);
            }
        }
        let row = segments + 1;
        let mut triangles = Vec::new();
        for r in 0..rings {
            for s in 0..segments {
                let a = r * row + s;
                let b = a + row;
                if r != 0 {
                    triangles.push([a, b, a + 1]);
                }
                if r + 1 != rings {
                    triangles.push([a + 1, b, b + 1]);
                }
            }
        }
        let normals = smooth_normals(&positions, &triangles)
            .into_iter()
            .zip(&positions)
            .map(|(n, p)| {
                n.try_normalize()
                    .unwrap_or((*p - center).normalize_or(Vec3::Y))
            })
            .collect();
        Self {
            positions,
            normals,
            triangles,
        }
    }

    /// A square ground grid at height `y` with `cells × cells` quads, normals +Y.
    pub fn ground_grid(y: f32, half_size: f32, cells: u32) -> Self {
        let cells = cells.max(1);
        let mut positions = Vec::new();
        for i in 0..=cells {
            for j in 0..=cells {
                let x = -half_size + 2.0 * half_size * j as f32 / cells as f32;
                let z = -half_size + 2.0 * half_size * i as f32 / cells as f32;
                positions.push(Vec3::new(x, y, z));
            }
        }
        let row = cells + 1;
        let mut triangles = Vec::new();
        for i in 0..cells {
            for j in 0..cells {
                let a = i * row + j;
                let b = a + row;
                // Counter-clockwise seen from above (+Y).
                triangles.push([a, b, a + 1]);
                triangles.push([a + 1, b, b + 1]);
            }
        }
        Self {
            normals: vec![Vec3::Y; positions.len()],
            positions,
            triangles,
        }
    }

    /// A unit-diameter sphere resting on a ground grid of `ground_cells²` quads (half size 2):
    /// the ground vertices see the sphere's shadow, the sphere's lower half sees the ground.
    pub fn sphere_on_plane(segments: u32, ground_cells: u32) -> Self {
        let mut mesh = Self::displaced_sphere(Vec3::new(0.0, 0.5, 0.0), 0.5, segments, |_| 0.0);
        mesh.append(&Self::ground_grid(0.0, 2.0, ground_cells));
        mesh
    }

    /// A sphere of radius 1 at the origin with large smooth bumps (relative height up to about
    /// `amplitude`) that cast shadows on each other.
    pub fn bumpy_blob(segments: u32, amplitude: f32) -> Self {
        Self::displaced_sphere(Vec3::ZERO, 1.0, segments, |n| {
            amplitude
                * ((5.0 * n.x).sin() * (4.0 * n.y + 1.0).sin() * (5.0 * n.z + 0.5).sin()).powi(2)
        })
    }
}

/// Area-weighted face normals summed at the vertices (not normalised).
fn smooth_normals(positions: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
    let mut n = vec![Vec3::ZERO; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| i as usize);
        let f = (positions[b] - positions[a]).cross(positions[c] - positions[a]);
        n[a] += f;
        n[b] += f;
        n[c] += f;
    }
    n
}

#[derive(Clone, Copy, Debug)]
struct Node {
    lo: Vec3,
    hi: Vec3,
    /// Leaf: first triangle; inner: index of the right child (the left child follows the node).
    start_or_right: u32,
    /// Leaf: triangle count (> 0); inner: 0.
    count: u32,
}

/// A bounding-volume hierarchy over a mesh's triangles for shadow rays.
#[derive(Clone, Debug)]
pub struct Bvh {
    nodes: Vec<Node>,
    /// Triangle vertices in leaf order.
    tris: Vec<[Vec3; 3]>,
}

impl Bvh {
    /// Builds the hierarchy (median split on the longest axis of the centroid bounds).
    pub fn build(mesh: &Mesh) -> Result<Self, MeshError> {
        mesh.validate()?;
        let tris: Vec<[Vec3; 3]> = mesh
            .triangles
            .iter()
            .map(|t| t.map(|i| mesh.positions[i as usize]))
            .collect();
        let centroids: Vec<Vec3> = tris.iter().map(|t| (t[0] + t[1] + t[2]) / 3.0).collect();
        let mut order: Vec<u32> = (0..tris.len() as u32).collect();
        let mut nodes = Vec::with_capacity(2 * tris.len() / LEAF_SIZE + 1);
        build_node(&tris, &centroids, &mut order, 0, &mut nodes);
        let tris = order.iter().map(|&i| tris[i as usize]).collect();
        Ok(Self { nodes, tris })
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// Whether the ray `origin + t·dir`, `0 < t < t_max`, hits any triangle.
    pub fn occluded(&self, origin: Vec3, dir: Vec3, t_max: f32) -> bool {
        let inv = dir.recip();
        let mut stack = [0u32; 64];
        let mut top = 1usize;
        while top > 0 {
            top -= 1;
            let index = stack[top];
            let node = &self.nodes[index as usize];
            if !slab_hit(node.lo, node.hi, origin, inv, t_max) {
                continue;
            }
            if node.count > 0 {
                let start = node.start_or_right as usize;
                for tri in &self.tris[start..start + node.count as usize] {
                    if triangle_hit(tri, origin, dir, t_max) {
                        return true;
                    }
                }
            } else if top + 2 <= stack.len() {
                stack[top] = node.start_or_right;
                // The left child directly follows its parent.
                stack[top + 1] = index + 1;
                top += 2;
            }
        }
        false
    }
}

fn build_node(
    tris: &[[Vec3; 3]],
    centroids: &[Vec3],
    order: &mut [u32],
    offset: u32,
    nodes: &mut Vec<Node>,
) {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    let mut clo = Vec3::splat(f32::INFINITY);
    let mut chi = Vec3::splat(f32::NEG_INFINITY);
    for &i in order.iter() {
        for v in tris[i as usize] {
            lo = lo.min(v);
            hi = hi.max(v);
        }
        clo = clo.min(centroids[i as usize]);
        chi = chi.max(centroids[i as usize]);
    }
    let index = nodes.len();
    nodes.push(Node {
        lo,
        hi,
        start_or_right: offset,
        count: order.len() as u32,
    });
    if order.len() <= LEAF_SIZE {
        return;
    }
    // Split at the median centroid along their widest axis. Where the centroids coincide
    // (triangles {a, b, −(a+b)} all have centroid 0) the centres of the triangles' bounds
    // are used instead: one leaf of every triangle made each ray test them all (5,000 such
    // triangles took 79 s to relight against 3.8 s; found by an audit). Only where those
    // coincide too, all the triangles' bounds are one box and a leaf is the best there is.
    let bounds_centre = |i: u32| {
        let [a, b, c] = tris[i as usize];
        (a.min(b).min(c) + a.max(b).max(c)) * 0.5
    };
    let mut extent = chi - clo;
    let by_bounds = extent.max_element() <= 0.0;
    if by_bounds {
        let (mut blo, mut bhi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for &i in order.iter() {
            blo = blo.min(bounds_centre(i));
            bhi = bhi.max(bounds_centre(i));
        }
        extent = bhi - blo;
        if extent.max_element().partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return;
        }
    }
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    let key = |i: u32| {
        if by_bounds {
            bounds_centre(i)[axis]
        } else {
            centroids[i as usize][axis]
        }
    };
    let mid = order.len() / 2;
    order.select_nth_unstable_by(mid, |&a, &b| key(a).total_cmp(&key(b)));
    let (left, right) = order.split_at_mut(mid);
    build_node(tris, centroids, left, offset, nodes);
    let right_index = nodes.len() as u32;
    build_node(tris, centroids, right, offset + mid as u32, nodes);
    nodes[index].start_or_right = right_index;
    nodes[index].count = 0;
}

fn slab_hit(lo: Vec3, hi: Vec3, origin: Vec3, inv: Vec3, t_max: f32) -> bool {
    let t0 = (lo - origin) * inv;
    let t1 = (hi - origin) * inv;
    let tmin = t0.min(t1).max_element().max(0.0);
    let tmax = t0.max(t1).min_element().min(t_max);
    // NaN (0 · ∞ for a ray in a slab's plane) is incomparable: treated as a hit.
    !matches!(tmin.partial_cmp(&tmax), Some(std::cmp::Ordering::Greater))
}

fn triangle_hit(tri: &[Vec3; 3], origin: Vec3, dir: Vec3, t_max: f32) -> bool {
    let e1 = tri[1] - tri[0];
    let e2 = tri[2] - tri[0];
    let p = dir.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-12 {
        return false;
    }
    let inv_det = 1.0 / det;
    let s = origin - tri[0];
    let u = s.dot(p) * inv_det;
    if !(0.0..=1.0).contains(&u) {
        return false;
    }
    let q = s.cross(e1);
    let v = dir.dot(q) * inv_det;
    if v < 0.0 || u + v > 1.0 {
        return false;
    }
    let t = e2.dot(q) * inv_det;
    t > 0.0 && t < t_max
}

/// Visibility of every direction from every vertex: bit `t` of row `v` is set when texel
/// direction `dirs[t]` is above vertex `v`'s tangent plane and unoccluded.
#[derive(Clone, Debug)]
pub struct Visibility {
    pub texels: usize,
    words_per_vertex: usize,
    bits: Vec<u64>,
}

impl Visibility {
    /// Whether direction `t` is visible from vertex `v`.
    pub fn get(&self, v: usize, t: usize) -> bool {
        self.bits[v * self.words_per_vertex + t / 64] >> (t % 64) & 1 == 1
    }

    /// Number of vertices.
    pub fn vertices(&self) -> usize {
        self.bits.len() / self.words_per_vertex.max(1)
    }

    /// Fraction of the vertex's upper-hemisphere texels that are visible.
    pub fn open_fraction(&self, v: usize, normal: Vec3, dirs: &[Vec3]) -> f64 {
        let mut up = 0usize;
        let mut open = 0usize;
        for (t, d) in dirs.iter().enumerate() {
            if normal.dot(*d) > 0.0 {
                up += 1;
                open += self.get(v, t) as usize;
            }
        }
        if up == 0 {
            0.0
        } else {
            open as f64 / up as f64
        }
    }
}

/// Ray origin offset along the normal, relative to the mesh's bounding-box diagonal.
pub const RAY_OFFSET: f32 = 1e-4;

/// How far (in radians) the cell of one of `n` directions spread evenly over the sphere
/// (solid angle 4π/n, a texel of an equal-area map) reaches from its centre, generously: a
/// square cell's corner lies 0.71 of its side away, and the octahedral map's texels are up to
/// about twice as long as wide.
fn cell_reach(n: usize) -> f32 {
    1.5 * (4.0 * std::f32::consts::PI / n.max(1) as f32).sqrt()
}

/// The ray that stands for direction `d`'s cell where its centre lies below the tangent plane
/// of `normal` (`n·d ≤ 0`) but the cell reaches above it: `d` turned up onto the plane and
/// `lift` radians above it, into the part of the cell that is above the horizon. `None` where
/// `d` is (anti)parallel to the normal.
fn horizon_ray(normal: Vec3, d: Vec3, lift: f32) -> Option<Vec3> {
    let along = (d - normal.dot(d) * normal).try_normalize()?;
    Some(along * lift.cos() + normal * lift.sin())
}

/// Casts one shadow ray per vertex and texel direction, in parallel. A direction's bit stands
/// for its texel: a texel above the tangent plane is tested along its centre direction; one
/// whose centre is below the plane but which reaches above it (within `cell_reach` of
/// `dirs.len()` texels) along its direction turned up to just above the horizon (it was left
/// unset: a narrow glossy lobe seen at a grazing angle, whose reflection lies in such a texel,
/// was lost: 0.33 of a mirror-like quad's albedo at side 32, 0.003 nearer grazing; an audit);
/// texels wholly below stay unset. The BRDF slices are 0 wherever no direction of a texel is
/// above the plane, so a texel set needlessly changes nothing.
pub fn vertex_visibility(mesh: &Mesh, bvh: &Bvh, dirs: &[Vec3]) -> Visibility {
    let (lo, hi) = mesh.positions.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(l, h), p| (l.min(*p), h.max(*p)),
    );
    let diag = (hi - lo).length().max(1e-6);
    let eps = RAY_OFFSET * diag;
    let words = dirs.len().div_ceil(64).max(1);
    let reach = cell_reach(dirs.len()).min(std::f32::consts::FRAC_PI_2);
    let (below, lift) = (-reach.sin(), 0.1 * reach);
    let mut bits = vec![0u64; words * mesh.positions.len()];
    bits.par_chunks_mut(words)
        .zip(mesh.positions.par_iter().zip(mesh.normals.par_iter()))
        .for_each(|(row, (p, n))| {
            let origin = *p + eps * *n;
            for (t, d) in dirs.iter().enumerate() {
                let n_d = n.dot(*d);
                let ray = if n_d > 0.0 {
                    Some(*d)
                } else if n_d > below {
                    horizon_ray(*n, *d, lift)
                } else {
                    None
                };
                if ray.is_some_and(|r| !bvh.occluded(origin, r, f32::INFINITY)) {
                    row[t / 64] |= 1 << (t % 64);
                }
            }
        });
    Visibility {
        texels: dirs.len(),
        words_per_vertex: words,
        bits,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fibonacci_dirs(n: usize) -> Vec<Vec3> {
        (0..n)
            .map(|i| {
                let y = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
                let r = (1.0 - y * y).max(0.0).sqrt();
                let phi = i as f32 * 2.399_963;
                Vec3::new(r * phi.cos(), y, r * phi.sin())
            })
            .collect()
    }

    #[test]
    fn bvh_agrees_with_brute_force() {
        let mesh = Mesh::bumpy_blob(24, 0.3);
        let bvh = Bvh::build(&mesh).unwrap();
        let dirs = fibonacci_dirs(200);
        let tris: Vec<[Vec3; 3]> = mesh
            .triangles
            .iter()
            .map(|t| t.map(|i| mesh.positions[i as usize]))
            .collect();
        let mut hits = 0;
        for (k, origin) in [Vec3::new(0.0, 0.0, 0.0), Vec3::new(2.0, 0.3, 0.1)]
            .into_iter()
            .enumerate()
        {
            for d in &dirs {
                let brute = tris.iter().any(|t| triangle_hit(t, origin, *d, 10.0));
                assert_eq!(bvh.occluded(origin, *d, 10.0), brute, "origin {k} dir {d}");
                hits += brute as usize;
            }
        }
        // From inside every ray hits; from outside some do and some do not.
        assert!(hits > 200 && hits < 400, "{hits}");
    }

    /// Triangles whose centroids all coincide ({a, b, −(a+b)}: centroid 0) are still split
    /// into small leaves (by the centres of their bounds; they were one leaf, so every ray
    /// tested every triangle), and rays agree with the brute force.
    #[test]
    fn coincident_centroids_still_make_a_tree() {
        let mut unit = {
            let mut state = 0x2545_f491_4f6c_dd1du64;
            move || {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 11) as f32 / (1u64 << 53) as f32 * 2.0 - 1.0
            }
        };
        let mut mesh = Mesh {
            positions: Vec::new(),
            normals: Vec::new(),
            triangles: Vec::new(),
        };
        for t in 0..400u32 {
            let a = Vec3::new(unit(), unit(), unit()) * 3.0;
            let b = Vec3::new(unit(), unit(), unit()) * 3.0;
            mesh.positions.extend([a, b, -(a + b)]);
            mesh.normals.extend([Vec3::Y; 3]);
            mesh.triangles.push([3 * t, 3 * t + 1, 3 * t + 2]);
        }
        let bvh = Bvh::build(&mesh).unwrap();
        let largest_leaf = bvh.nodes.iter().map(|n| n.count).max().unwrap();
        assert!(
            largest_leaf as usize <= LEAF_SIZE,
            "a leaf of {largest_leaf}"
        );
        let tris: Vec<[Vec3; 3]> = mesh
            .triangles
            .iter()
            .map(|t| t.map(|i| mesh.positions[i as usize]))
            .collect();
        for d in fibonacci_dirs(100) {
            for origin in [Vec3::ZERO, Vec3::new(8.0, 0.5, -0.2)] {
                let brute = tris.iter().any(|t| triangle_hit(t, origin, d, 20.0));
                assert_eq!(bvh.occluded(origin, d, 20.0), brute, "{origin} {d}");
            }
        }
    }

    #[test]
    fn ground_under_sphere_is_shadowed_from_above() {
        let mesh = Mesh::sphere_on_plane(32, 8);
        let bvh = Bvh::build(&mesh).unwrap();
        let dirs = fibonacci_dirs(400);
        let vis = vertex_visibility(&mesh, &bvh, &dirs);
        // The ground vertex at the origin (centre of the 8×8 grid) sits under the sphere.
        let centre = mesh
            .positions
            .iter()
            .position(|p| p.y == 0.0 && p.x == 0.0 && p.z == 0.0)
            .unwrap();
        let up = dirs
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.y.total_cmp(&b.1.y))
            .unwrap()
            .0;
        assert!(!vis.get(centre, up));
        // The sphere's top sees its whole upper hemisphere; a far ground corner nearly so.
        let top = mesh
            .positions
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.y.total_cmp(&b.1.y))
            .unwrap()
            .0;
        assert_eq!(vis.open_fraction(top, mesh.normals[top], &dirs), 1.0);
        let corner = mesh.positions.len() - 1;
        let f = vis.open_fraction(corner, mesh.normals[corner], &dirs);
        assert!(f > 0.9 && f < 1.0 + 1e-9, "{f}");
        // Directions whose cells lie wholly below the tangent plane are never set; those whose
        // cells reach above it are, where nothing blocks the horizon (a far ground corner).
        let reach = cell_reach(dirs.len()).sin();
        let mut straddling = 0;
        for (t, d) in dirs.iter().enumerate() {
            if d.y <= -reach {
                assert!(!vis.get(corner, t));
            } else if d.y <= 0.0 {
                straddling += 1;
                assert!(vis.get(corner, t) || d.x < 0.0 || d.z < 0.0, "{d}");
            }
        }
        assert!(straddling > 0);
    }

    #[test]
    fn bad_meshes_are_errors() {
        assert_eq!(Bvh::build(&Mesh::default()).unwrap_err(), MeshError::Empty);
        let mut m = Mesh::ground_grid(0.0, 1.0, 1);
        m.triangles.push([0, 1, 99]);
        assert!(matches!(
            Bvh::build(&m).unwrap_err(),
            MeshError::IndexOutOfRange { index: 99, .. }
        ));
        let mut m = Mesh::ground_grid(0.0, 1.0, 1);
        m.positions[0].x = f32::NAN;
        assert_eq!(m.validate().unwrap_err(), MeshError::NonFinite(0));
    }
}
