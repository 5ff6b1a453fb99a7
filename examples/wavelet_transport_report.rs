//! The figures of docs/wavelets.md's transport sections (issue 7 part B): triple-product tensor
//! sizes, relighting and triple-product error against coefficient counts, and lighting recovery
//! error against observations and noise. Everything is computed here; nothing is hard-coded.
//!
//! Run: `cargo run --release --example wavelet_transport_report [-- tensor|relight|triple|inverse|speed]`
//! (no argument: all five; the whole report takes a few minutes on two cores).

use envlight::capture::image_file::read_hdr_image;
use envlight::envmap::Projection;
use envlight::wavelet::approx::Coefficients;
use envlight::wavelet::inverse::{
    prediction_error, refine, synthesize, transport_rows, upper_hemisphere_error, ObservationSetup,
    RefineOptions,
};
use envlight::wavelet::relight::{
    brute_force, visibility_texels, Brdf, DenseLighting, Grid, Transport, View,
};
use envlight::wavelet::triple::{sparse_largest, TripleTensor, DEFAULT_PRUNE};
use envlight::wavelet::visibility::{vertex_visibility, Bvh, Mesh};
use envlight::wavelet::{Basis, OctahedralMap};
use envlight::HdrFrame;
use glam::Vec3;
use std::path::Path;
use std::time::Instant;

fn frame(name: &str) -> HdrFrame {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name);
    let image = read_hdr_image(&path).unwrap_or_else(|e| panic!("{e}"));
    let mut f = HdrFrame::new(image.width, image.height, image.pixels, Projection::LatLong)
        .expect("valid size");
    f.sanitize();
    f
}

fn bases() -> [Basis; 5] {
    [
        Basis::Haar,
        Basis::Daubechies(2),
        Basis::Daubechies(4),
        Basis::Coiflet(1),
        Basis::Coiflet(2),
    ]
}

fn tensor() {
    println!("## tensor");
    println!("| basis | side | 1-D functions | 1-D triples (f≤g≤h) | supports overlap | kept (1e-12) | kept (1e-6) | 2-D nonzeros C_ijk | 2-D nonzeros per (i,j) pair | build ms |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for side in [16usize, 32] {
        for basis in bases() {
            let grid = Grid::new(side, basis, None).expect("grid");
            let t0 = Instant::now();
            let t = TripleTensor::new(&grid, DEFAULT_PRUNE).expect("tensor");
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            let loose = TripleTensor::new(&grid, 1e-6).expect("tensor");
            let nz = t.count_nonzero_2d();
            let n2 = (side * side) as f64;
            println!(
                "| {basis} | {side} | {} | {} | {} | {} | {} | {nz} | {:.1} | {ms:.1} |",
                t.stats.functions,
                t.stats.triples_total,
                t.stats.triples_overlapping,
                t.stats.triples_kept,
                loose.stats.triples_kept,
                nz as f64 / (n2 * n2)
            );
        }
    }
}

struct Scene {
    mesh: Mesh,
    vis_grid: Grid,
    vis: envlight::wavelet::visibility::Visibility,
}

fn scene(grid: &Grid) -> Scene {
    let mesh = Mesh::sphere_on_plane(32, 16);
    let bvh = Bvh::build(&mesh).expect("mesh");
    let vis = vertex_visibility(&mesh, &bvh, &grid.dirs);
    Scene {
        mesh,
        vis_grid: grid.clone(),
        vis,
    }
}

/// Two relative errors of the RGB radiance against brute force: the RMS over vertices of each
/// vertex's own relative error (weighs a dark vertex like a bright one), and the error relative
/// to the whole set, ‖got − want‖ / ‖want‖ over all vertices (what an image shows).
fn rms_rel(got: &[[f64; 3]], want: &[[f64; 3]]) -> (f64, f64) {
    let mut sq = 0.0;
    let mut n = 0;
    let (mut num, mut den) = (0.0, 0.0);
    for (g, w) in got.iter().zip(want) {
        let norm = w.iter().map(|x| x * x).sum::<f64>().sqrt();
        let err2 = (0..3).map(|c| (g[c] - w[c]).powi(2)).sum::<f64>();
        num += err2;
        den += norm * norm;
        if norm > 0.0 {
            sq += err2 / (norm * norm);
            n += 1;
        }
    }
    let image = if den > 0.0 { (num / den).sqrt() } else { 0.0 };
    ((sq / n.max(1) as f64).sqrt(), image)
}

fn relight() {
    println!("## relight (side 32, sphere on plane, rooitou_park; error vs brute force: per-vertex relative RMS / relative to all vertices)");
    let side = 32;
    let env = frame("rooitou_park_1k.hdr");
    let eye = Vec3::new(0.0, 1.5, 4.0);
    for (name, brdf) in [
        ("Lambert", Brdf::Lambert),
        ("Phong 32", Brdf::Phong { exponent: 32.0 }),
        ("GGX α = 0.3", Brdf::Ggx { alpha: 0.3 }),
    ] {
        println!("### {name}");
        println!("| basis | light K | transport 32 | transport 64 | transport 128 | transport 256 | all 1024 |");
        println!("|---|---|---|---|---|---|---|");
        for basis in bases() {
            let grid = Grid::new(side, basis, None).expect("grid");
            let sc = scene(&grid);
            let map = OctahedralMap::from_frame(&env, side).expect("map");
            let texels: Vec<[f64; 3]> = map.texels().iter().map(|t| t.map(f64::from)).collect();
            let want: Vec<[f64; 3]> = (0..sc.mesh.positions.len())
                .map(|v| {
                    let slice = sc.vis_grid.brdf_slice(
                        brdf,
                        sc.mesh.normals[v],
                        View::Eye(eye).at(sc.mesh.positions[v]),
                    );
                    brute_force(&grid, &sc.vis, v, &slice, &texels)
                })
                .collect();
            let coeffs =
                Coefficients::analyze(map.texels(), side, basis, grid.levels).expect("analyze");
            let transports: Vec<Transport> = [32usize, 64, 128, 256, 1024]
                .iter()
                .map(|&k| {
                    Transport::precompute(
                        &grid,
                        &sc.mesh.positions,
                        &sc.mesh.normals,
                        &sc.vis,
                        brdf,
                        View::Eye(eye),
                        k,
                    )
                    .expect("transport")
                })
                .collect();
            for light_k in [32usize, 128, 512, 1024] {
                let mut light = DenseLighting::new(&grid);
                light
                    .set(&grid, &coeffs.truncate(light_k))
                    .expect("lighting");
                let mut row = format!("| {basis} | {light_k} |");
                for t in &transports {
                    let mut out = vec![[0.0f32; 3]; t.vertices()];
                    t.relight(&light, &mut out).expect("relight");
                    let got: Vec<[f64; 3]> = out.iter().map(|o| o.map(f64::from)).collect();
                    let (per_vertex, image) = rms_rel(&got, &want);
                    row += &format!(" {per_vertex:.4} / {image:.1e} |");
                }
                println!("{row}");
            }
        }
    }
}

fn triple() {
    let side = 16;
    println!("## triple (side {side}, 24 vertices of the sphere on plane, Lambert slice kept whole, V and L truncated to K; relative RMS error vs brute force)");
    println!("| basis | K = 16 | K = 32 | K = 64 | K = 128 | all 256 | ms per vertex (all) |");
    println!("|---|---|---|---|---|---|---|");
    let env = frame("rooitou_park_1k.hdr");
    for basis in bases() {
        let grid = Grid::new(side, basis, None).expect("grid");
        let t = TripleTensor::new(&grid, DEFAULT_PRUNE).expect("tensor");
        let sc = scene(&grid);
        let map = OctahedralMap::from_frame(&env, side).expect("map");
        let texels: Vec<[f64; 3]> = map.texels().iter().map(|t| t.map(f64::from)).collect();
        let planes: Vec<Vec<f64>> = (0..3)
            .map(|c| {
                grid.project(&texels.iter().map(|p| p[c]).collect::<Vec<_>>())
                    .expect("project")
            })
            .collect();
        let n = sc.mesh.positions.len();
        let verts: Vec<usize> = (0..24).map(|i| i * n / 24).collect();
        let want: Vec<[f64; 3]> = verts
            .iter()
            .map(|&v| {
                let slice = Brdf::Lambert.slice(sc.mesh.normals[v], Vec3::Y, &grid.dirs);
                brute_force(&grid, &sc.vis, v, &slice, &texels)
            })
            .collect();
        let mut row = format!("| {basis} |");
        let mut ms = 0.0;
        for k in [16usize, 32, 64, 128, 256] {
            let t0 = Instant::now();
            let got: Vec<[f64; 3]> = verts
                .iter()
                .map(|&v| {
                    let vc = grid
                        .project(&visibility_texels(&sc.vis, v))
                        .expect("project");
                    let rho = grid
                        .project(&Brdf::Lambert.slice(sc.mesh.normals[v], Vec3::Y, &grid.dirs))
                        .expect("project");
                    let vs = sparse_largest(&vc, k);
                    std::array::from_fn(|c| {
                        t.triple(&vs, &sparse_largest(&planes[c], k), &rho)
                            .expect("triple")
                    })
                })
                .collect();
            ms = t0.elapsed().as_secs_f64() * 1e3 / verts.len() as f64;
            row += &format!(" {:.4} |", rms_rel(&got, &want).0);
        }
        println!("{row} {ms:.1} |");
    }
}

fn inverse() {
    let side = 16;
    println!("## inverse (side {side}, sphere on plane: Lambertian ground + Phong-32 sphere from 4 views; truth: rooitou_park and a synthetic smooth sky; relative L2 errors of the recovered map above the horizon — the ground hides the lower hemisphere from every view — and of the radiance it predicts)");
    let mesh = Mesh::sphere_on_plane(32, 24);
    let bvh = Bvh::build(&mesh).expect("mesh");
    let (sphere, ground): (Vec<usize>, Vec<usize>) =
        (0..mesh.positions.len()).partition(|&v| mesh.positions[v].y > 1e-3);
    let mut setups = vec![ObservationSetup {
        brdf: Brdf::Lambert,
        view: View::Direction(Vec3::Y),
        vertices: ground,
    }];
    for i in 0..4 {
        let a = std::f32::consts::TAU * i as f32 / 4.0;
        setups.push(ObservationSetup {
            brdf: Brdf::Phong { exponent: 32.0 },
            view: View::Eye(Vec3::new(4.0 * a.sin(), 1.5, 4.0 * a.cos())),
            vertices: sphere.clone(),
        });
    }
    let env = frame("rooitou_park_1k.hdr");
    for basis in [Basis::Haar, Basis::Daubechies(4), Basis::Coiflet(1)] {
        let grid = Grid::new(side, basis, None).expect("grid");
        let vis = vertex_visibility(&mesh, &bvh, &grid.dirs);
        let all_rows = transport_rows(&grid, &mesh, &vis, &setups).expect("rows");
        let map = OctahedralMap::from_frame(&env, side).expect("map");
        let s = grid.d_omega().sqrt();
        let park: [Vec<f64>; 3] = Coefficients::analyze(map.texels(), side, basis, grid.levels)
            .expect("analyze")
            .planes
            .map(|p| p.into_iter().map(|v| v * s).collect());
        let sky: [Vec<f64>; 3] = std::array::from_fn(|c| {
            let f: Vec<f64> = grid
                .dirs
                .iter()
                .map(|d| {
                    let sun = f64::from(d.dot(Vec3::new(0.6, 0.6, -0.5).normalize())).max(0.0);
                    1.0 + 0.5 * f64::from(d.y) + 8.0 * sun.powi(8) * (1.0 + 0.1 * c as f64)
                })
                .collect();
            grid.project(&f).expect("project")
        });
        for (truth_name, truth) in [("smooth sky", &sky), ("rooitou_park", &park)] {
            println!(
                "### {basis}, {truth_name} (upper-hemisphere error / prediction error on all {} observations / active nodes)",
                all_rows.len()
            );
            println!("| observations | noise 0 | noise 0.01 | noise 0.05 | noise 0.2 |");
            println!("|---|---|---|---|---|");
            for m in [250usize, 500, 1000, 2000, all_rows.len()] {
                let n = all_rows.len();
                let rows: Vec<Vec<f64>> = (0..m).map(|i| all_rows[i * n / m].clone()).collect();
                let mut row = format!("| {m} |");
                for noise in [0.0, 0.01, 0.05, 0.2] {
                    let obs = synthesize(&rows, truth, noise, 3).expect("synth");
                    let rec = refine(&grid, &obs, RefineOptions::default()).expect("refine");
                    let upper = upper_hemisphere_error(&grid, &rec.planes, truth)
                        .expect("upper error")
                        .expect("texels above the horizon");
                    let predicted = prediction_error(&all_rows, &rec.planes, truth);
                    row += &format!(" {upper:.3} / {predicted:.4} / {} |", rec.active.len());
                }
                println!("{row}");
            }
        }
    }
}

/// CPU time (user + system) of this process in seconds, from /proc/self/stat (Linux; 0 elsewhere).
fn cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return 0.0;
    };
    // Fields after the command name (which is in parentheses): utime is the 12th, stime the 13th.
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

/// The bench's setup (10,011-vertex blob at side 64, rows stored 10 times: 100,110 vertices),
/// timed by wall clock and by process CPU time, so that a loaded machine can be accounted for.
fn speed() {
    let grid = Grid::new(64, Basis::Coiflet(1), None).expect("grid");
    let mesh = Mesh::bumpy_blob(140, 0.25);
    let bvh = Bvh::build(&mesh).expect("mesh");
    let t0 = Instant::now();
    let c0 = cpu_seconds();
    let vis = vertex_visibility(&mesh, &bvh, &grid.dirs);
    println!(
        "## speed\nvisibility: {} vertices x {} directions: wall {:.1} s, CPU {:.1} s",
        mesh.positions.len(),
        grid.len(),
        t0.elapsed().as_secs_f64(),
        cpu_seconds() - c0
    );
    let env = frame("rooitou_park_1k.hdr");
    let map = OctahedralMap::from_frame(&env, 64).expect("map");
    let set = envlight::wavelet::approximate(map.texels(), 64, grid.basis, grid.levels, 1000)
        .expect("approx");
    let mut light = DenseLighting::new(&grid);
    println!("| transport per vertex | entries | wall ms/frame | CPU ms/frame | frames/s at 2 cores (CPU/2) |");
    println!("|---|---|---|---|---|");
    for keep in [64usize, 128, 256] {
        let base = Transport::precompute(
            &grid,
            &mesh.positions,
            &mesh.normals,
            &vis,
            Brdf::Lambert,
            View::Direction(Vec3::Y),
            keep,
        )
        .expect("transport");
        let rows = (0..10).flat_map(|_| {
            (0..base.vertices())
                .map(|v| base.row(v).map(|(k, c)| (k as u16, c)).collect::<Vec<_>>())
        });
        let t = Transport::from_rows(&grid, rows).expect("rows");
        let mut out = vec![[0.0f32; 3]; t.vertices()];
        let frames = 40;
        let w0 = Instant::now();
        let c0 = cpu_seconds();
        for _ in 0..frames {
            light.set(&grid, &set).expect("set");
            t.relight(&light, &mut out).expect("relight");
        }
        let wall = w0.elapsed().as_secs_f64() * 1e3 / frames as f64;
        let cpu = (cpu_seconds() - c0) * 1e3 / frames as f64;
        println!(
            "| {keep} | {} | {wall:.1} | {cpu:.1} | {:.0} |",
            t.entries(),
            2000.0 / cpu.max(1e-9)
        );
    }
}

fn main() {
    let what = std::env::args().nth(1);
    let all = what.is_none();
    let is = |s: &str| all || what.as_deref() == Some(s);
    if is("tensor") {
        tensor();
    }
    if is("relight") {
        relight();
    }
    if is("triple") {
        triple();
    }
    if is("inverse") {
        inverse();
    }
    if is("speed") {
        speed();
    }
}
