//! The working map: any input frame resampled to a small lat-long map of per-pixel energy, plus
//! the input pixels of concentrated sources at full resolution.
//!
//! The decomposition works on a lat-long grid of a few hundred pixels across, whatever the
//! input's projection and size; the working map's total equals the input's integral (to
//! rounding). Three paths, chosen once per input geometry:
//! - a lat-long input whose size is an integer multiple of the working size: a box filter (f32
//!   column sums, compiled for the CPU's widest vector unit by runtime detection; bound by
//!   memory bandwidth; with AVX2 the horizontal sums of a factor-4 filter take eight working
//!   pixels at a time);
//! - any other lat-long input (1000 × 500, 1920 × 960, a map narrower than the working one):
//!   exact area overlap. An input pixel's energy (radiance × solid angle) is shared among the
//!   working pixels it overlaps in proportion to the overlaps' solid angles, which separate
//!   into a φ extent and a cos θ extent: per working row its input rows weighted by their cos θ
//!   extents, then per working column its input columns weighted by their φ extents. A
//!   uniform map stays uniform;
//! - other projections (a camera's fisheye, the angular map): each input pixel's solid angle
//!   is shared among the working pixels it covers, through a table built once per input
//!   geometry (`Plan::Table`) and summed in f64 in bands of input rows that helper threads may
//!   share with the calling one (src/parallel.rs; the result does not depend on the number of
//!   threads: each working pixel is summed whole, over its runs in input order, by the one band
//!   that owns it). A pixel inside one working pixel goes to it whole; a pixel that straddles
//!   several (a corner in another) is cut along the working pixels' edges: its corners'
//!   working-map positions make two triangles, clipped to each working pixel, and the pieces
//!   share the pixel's solid angle in proportion to their own (exact for a lat-long input;
//!   pixels the projection bends, around a pole, are quartered first, `small_pixel_shares`);
//!   a pixel wider than half a working pixel (a frame coarser than the working map, the rim
//!   of a stereographic or orthographic lens) is cut into sub-pixels of their own exact solid
//!   angles (`SplitPixel`, [`RectangleSolidAngles`]), each shared the same way. A uniform
//!   frame stays uniform (within 0.2 % at a lens's zenith, 0.5 % at the angular map's
//!   singular rim, 1.7 % in its pole rows; docs/performance.md, "A camera's frames, by area").
//!
//! Working pixels that hold more than a given share of the energy (a sun, a lamp) are
//! *concentrated*: their input pixels are also kept as [`FineSample`]s with exact directions,
//! so the lights that share a sun keep its shape and full-resolution position (and so its
//! penumbra).

use crate::envmap::{Projection, RectangleSolidAngles};
use crate::frame::HdrFrame;
use glam::{DVec3, Vec3A, Vec4};
use rayon::prelude::*;
use std::f64::consts::PI;

/// One input pixel of a concentrated working pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FineSample {
    /// Index of the working pixel it falls in.
    pub pixel: u32,
    /// Exact direction of the input pixel's centre (of a piece of one that straddles working
    /// pixels: of the piece's centroid, inside this working pixel).
    pub dir: [f32; 3],
    /// rgb · solid angle of the input pixel (of its piece).
    pub energy: [f32; 3],
    pub solid_angle: f32,
}

/// Lat-long map of energy (rgb · solid angle) per working pixel.
#[derive(Clone, Debug)]
pub struct WorkingMap {
    pub width: usize,
    pub height: usize,
    /// Σ rgb·Ω of the input pixels that fall in each working pixel, row-major. Stored in f32,
    /// the input's precision (the box filter's sums are f32; the table path's f64 sums are
    /// rounded once): it halves the map's largest buffer, which the decomposition reads twice
    /// per frame, and every sum over pixels (regions, totals) is taken in f64.
    pub energy: Vec<[f32; 3]>,
    /// (sin θ, cos θ) of each row's centre: a working pixel's centre direction is
    /// (sin θ·sin φ, cos θ, −sin θ·cos φ).
    pub row_trig: Vec<(f32, f32)>,
    pub row_trig_f64: Vec<(f64, f64)>,
    /// (sin φ, cos φ) of each column's centre.
    pub column_trig: Vec<(f32, f32)>,
    pub column_trig_f64: Vec<(f64, f64)>,
    /// Exact solid angle of the working pixels of each row.
    pub row_solid_angle: Vec<f64>,
    /// Rec. 709 luminance of each working pixel's energy (f32: it ranks and weights pixels;
    /// sums of it are taken in f64).
    pub luminance: Vec<f32>,
    /// Whether each working pixel is concentrated (its energy is given by `fine` instead).
    pub concentrated: Vec<bool>,
    /// The input pixels of the concentrated working pixels.
    pub fine: Vec<FineSample>,
    /// The working pixels that the input does not see whole (below a fisheye's field of view)
    /// or sees with rounding: (pixel, its solid angle less the input's shares in it, of either
    /// sign), so that a light's region counts only the sphere its frame sees. Empty for a
    /// lat-long input (it sees the whole sphere). Fixed by the geometry.
    pub unseen: Vec<(u32, f64)>,
}

#[derive(Clone, Debug)]
enum Plan {
    /// Lat-long input, `factor`×`factor` input pixels per working pixel. Directions are
    /// separable: d = (sin θ·sin φ, cos θ, −sin θ·cos φ), so per row and column tables suffice.
    Box {
        factor: usize,
        /// Solid angle of each input row's pixels.
        row_solid_angle: Vec<f64>,
        /// (sin θ, cos θ) of each input row's centre.
        row_theta: Vec<(f32, f32)>,
        /// (sin φ, cos φ) of each input column's centre.
        column_phi: Vec<(f32, f32)>,
    },
    /// Lat-long input whose sides are not multiples of the working map's: each input pixel's
    /// energy is shared among the working pixels it overlaps in proportion to the solid angle
    /// of each overlap, which is separable (its φ extent times its cos θ extent). Exact: a
    /// uniform map stays uniform to rounding. Binning whole input pixels by their centres (the
    /// table) gave a working pixel 3 or 4 input columns by turns when the input is 3.9 working
    /// widths wide: stripes of ±13 % energy by longitude, and lights of a uniform 1000 × 500
    /// map with 0.89–1.05 of their regions' energy (an audit).
    Overlap {
        /// Per working column, its first overlapping input column and how many it overlaps.
        columns: Vec<(u32, u32)>,
        /// The φ extents of those overlaps, working column by working column (f32: a row's
        /// sums per working column are taken in f32, as the box filter's, and the rows are
        /// summed in f64).
        column_extents: Vec<f32>,
        /// Every (input row, working row) pair that overlaps, working row by working row: the
        /// cos θ extent of the overlap.
        rows: Vec<Overlap>,
        /// Input rows (the input's height) and working rows.
        input_rows: usize,
        working_rows: usize,
    },
    /// Arbitrary projection: each input pixel's solid angle shared among the working pixels
    /// it covers (*entries*: one per input pixel and working pixel; an input pixel inside one
    /// working pixel has one, a pixel that straddles several or is larger than one has one per
    /// working pixel, [`PixelPart`]), as runs of consecutive input pixels with one working
    /// pixel in bands of input rows; pixels outside the image circle are in none.
    Table {
        bands: Vec<TableBand>,
        /// Per entry, in the order of the runs (each run's entries are
        /// `weights[run.entries..][..run.end - run.start]`): the solid angle of its input
        /// pixel's share.
        weights: Vec<f32>,
        /// Per entry: a direction inside its working pixel (the input pixel's centre, or the
        /// centroid of its pieces there).
        directions: Vec<[f32; 3]>,
        /// Per working pixel, its first member (`members[member_offsets[i]..member_offsets[i +
        /// 1]]`).
        member_offsets: Vec<u32>,
        /// Per working pixel, its entries in input order: (input pixel, entry).
        members: Vec<(u32, u32)>,
    },
}

/// [`WorkingMap::unseen`] of a table plan: each working pixel's solid angle less the input
/// pixel shares it holds (the part the frame sees), for every pixel where they differ. Inside
/// the field of view the difference is the shares' rounding, of either sign (f32; and a
/// share goes to a working pixel by its centroid, so a pixel may hold a little more than its
/// own solid angle): counting only the deficits left a 64² stereographic 359° frame's lights
/// 5.7e-4 sr short of what it sees.
fn unseen_parts(
    map: &WorkingMap,
    weights: &[f32],
    member_offsets: &[u32],
    members: &[(u32, u32)],
) -> Vec<(u32, f64)> {
    let mut unseen = Vec::new();
    for p in 0..map.width * map.height {
        let range = member_offsets[p] as usize..member_offsets[p + 1] as usize;
        let seen: f64 = members[range]
            .iter()
            .map(|&(_, entry)| f64::from(weights[entry as usize]))
            .sum();
        let omega = map.row_solid_angle[p / map.width];
        if seen != omega {
            unseen.push((p as u32, omega - seen));
        }
    }
    unseen
}

/// The share of one input pixel that falls in one working pixel. An input pixel wider than a
/// working pixel (a tiny image, the rim of a stereographic or orthographic lens) would put all
/// its energy in the working pixel of its centre and leave its neighbours empty: the energy
/// lumps, lights that land in the empty ones get none, and a lump big enough to be concentrated
/// adds the input pixel's whole solid angle to a working pixel whose neighbours count theirs
/// again. So such a pixel is cut into sub-pixels (as many along each image axis as its angular
/// extent there needs, [`split_factor`]), each with its own exact solid angle, and each shared
/// among the working pixels it covers as a small pixel is. A small input pixel that straddles
/// working pixels is cut along their edges ([`small_pixel_shares`]): binned whole by its
/// centre it gave its neighbour nothing, and the working pixels got whole input pixels by
/// turns (lights of a uniform frame with 0.92–1.09 of their regions' energy; sub-pixels binned
/// by their centres gave a coarse 340 × 255 fisheye's 0.64–1.31).
#[derive(Clone, Copy, Debug, PartialEq)]
struct PixelPart {
    /// Row-major index of the input pixel.
    input: u32,
    /// The working pixel.
    target: u32,
    solid_angle: f32,
    /// A direction inside the working pixel: that of the centroid (on the working map) of
    /// the input pixel's pieces in it, or of its centre where it lies in one working pixel.
    direction: [f32; 3],
}

impl PixelPart {
    /// The share `solid_angle` of input pixel `input` in working pixel `target`, its direction
    /// that of the working-map position `centroid` (of its pieces there) on a `width` ×
    /// `height` working map.
    fn at_centroid(
        (input, target): (u32, u32),
        solid_angle: f64,
        centroid: [f64; 2],
        (width, height): (usize, usize),
    ) -> Self {
        let [a, b] = centroid;
        let direction = Projection::LatLong
            .pixel_to_direction(width as u32, height as u32, a, b)
            .unwrap_or(DVec3::Y);
        Self {
            input,
            target,
            solid_angle: solid_angle as f32,
            direction: direction.as_vec3().to_array(),
        }
    }
}

/// Largest number of sub-pixels across one input pixel (256² sub-pixels: only a pixel of a
/// tiny image, seeing much of the sphere, gets that many).
const MAX_SPLIT: usize = 256;

/// Input pixels `start..end` (row-major indices) all go to working pixel `target` (all of them,
/// or their shares `weights[entries..]`, [`Plan::Table`]). Neighbouring
/// input pixels mostly share a working pixel (a 1280×960 fisheye has about 44 input pixels per
/// working pixel of the upper hemisphere, runs of about 6), so the resampling sums a run in
/// registers and touches the working pixel's sum once per run, not once per input pixel (a
/// chain of loads and stores to the same address; docs/performance.md, "A camera's frames",
/// has the before and after).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Run {
    start: u32,
    end: u32,
    target: u32,
    /// The run's first entry in `Plan::Table`'s `weights`.
    entries: u32,
}

/// How many times an input pixel that straddles working pixels is quartered where its shares
/// cannot be had from its corners ([`straddle_pieces`]: around a pole of the working map, where
/// the projection bends it): down to squares of 1/256 of the pixel a side. Only the squares
/// that still fail are cut again, a few per level around a pole.
const STRADDLE_DEPTH: u32 = 8;

/// How far (in working pixels) a square's centre may lie from the mean of its corners for
/// [`straddle_pieces`]' affine view of it: where the projection bends the working map's lines
/// across a pixel (around the zenith of a fisheye, where a working column is a pixel wide),
/// the pixel is quartered instead (from 0.15 % off to 0.0x % off, a uniform frame's working pixels).
const AFFINE_TOLERANCE: f64 = 1e-3;

/// Working-map column `a` moved by whole turns to within half a turn of column `reference`:
/// the columns wrap at φ = 2π, and a pixel across the seam has corners at both ends.
fn column_near(a: f64, reference: f64, width: usize) -> f64 {
    let w = width as f64;
    a - ((a - reference) / w).round() * w
}

/// Whether the square with corners `corners` and centre `middle` (working-map positions) is
/// close enough to its affine view ([`AFFINE_TOLERANCE`]); not where a point is outside.
fn nearly_affine(corners: [[f64; 2]; 4], middle: [f64; 2], width: usize) -> bool {
    let mean = corners.iter().fold([0.0; 2], |m, c| {
        [
            m[0] + column_near(c[0], middle[0], width) / 4.0,
            m[1] + c[1] / 4.0,
        ]
    });
    let d = [mean[0] - middle[0], mean[1] - middle[1]];
    d[0].hypot(d[1]) <= AFFINE_TOLERANCE
}

/// The buffers of [`small_pixel_shares`], kept from pixel to pixel: the pieces (working pixel,
/// solid angle, solid angle × centroid) and the rectangles still to do ((left, top, width,
/// height), corners, share of the patch's area, levels left).
#[derive(Default)]
struct StraddleScratch {
    pieces: Vec<(u32, f64, [f64; 2])>,
    #[allow(clippy::type_complexity)]
    stack: Vec<((f64, f64, f64, f64), [[f64; 2]; 4], f64, u32)>,
}

/// The largest part of its working pixel's solid angle that a square of a straddling pixel
/// may hold and still go whole to the working pixel of its centre ([`small_pixel_shares`]).
const NEGLIGIBLE_SHARE: f64 = 1e-3;

/// How many times a square across the image's edge (a corner outside) is quartered: down to
/// squares of 1/8 of a pixel a side (where their centres take them).
const RIM_DEPTH: u32 = 3;

/// How long building the index table may take before it is logged ([`Resampler::table_plan`]).
const SLOW_TABLE_S: f64 = 2.0;

/// A rectangle of an input image (a pixel, or a sub-pixel of a large one) and its solid angle.
#[derive(Clone, Copy, Debug)]
struct ImagePatch {
    /// Top-left corner, in pixels.
    origin: (f64, f64),
    /// Width and height, in pixels.
    size: (f64, f64),
    solid_angle: f64,
}

/// The shares of a small patch of an input image (`patch`: a pixel, or a sub-pixel of a large
/// one; the geometry is `pixel`'s, its `at`, `solid_angle` and `split` are not used) among the
/// working pixels it covers, from the working-map positions of its corners (top-left,
/// top-right, bottom-left, bottom-right; NaN outside the image) and of its centre: (working
/// pixel, share, share × centroid), the shares summing to 1, the working pixels in no
/// particular order. The patch's corners give its pieces' solid angles where they can
/// ([`straddle_pieces`]); elsewhere (and where the projection bends the patch,
/// [`nearly_affine`]) it is quartered, and each quarter tried the same way, down
/// [`STRADDLE_DEPTH`] levels, where a rectangle's centre takes it, or where that is outside the
/// image a corner of it inside (with its own exact solid angle). Rectangles whose corners are
/// all outside the image are left out, and the shares of the rest scaled to sum to 1 (the
/// patch's solid angle is that of its part inside). Nothing where no part is inside.
fn small_pixel_shares(
    pixel: &SplitPixel,
    patch: ImagePatch,
    (corners, centre): ([[f64; 2]; 4], [f64; 2]),
    scratch: &mut StraddleScratch,
    out: &mut Vec<(u32, f64, [f64; 2])>,
) {
    let SplitPixel {
        projection,
        rectangles,
        working_row_solid_angles,
        source: (sw, sh),
        working: (width, height),
        ..
    } = *pixel;
    let omega = patch.solid_angle;
    let position = |u: f64, v: f64| {
        working_position(projection.pixel_to_direction(sw, sh, u, v), (width, height))
    };
    let StraddleScratch { pieces, stack } = scratch;
    pieces.clear();
    stack.clear();
    let ((u0, v0), (su, sv)) = (patch.origin, patch.size);
    stack.push(((u0, v0, su, sv), corners, 1.0, STRADDLE_DEPTH));
    while let Some(((u0, v0, su, sv), corners, weight, depth)) = stack.pop() {
        if corners.iter().all(|c| c[0].is_nan()) {
            continue;
        }
        let (hu, hv) = (su / 2.0, sv / 2.0);
        let middle = if depth == STRADDLE_DEPTH {
            centre
        } else {
            position(u0 + hu, v0 + hv)
        };
        if (depth == 0 || nearly_affine(corners, middle, width))
            && straddle_pieces(corners, (width, height), pieces)
        {
            continue;
        }
        // A square across the image's edge is cut only RIM_DEPTH levels deep: the edge crosses
        // twice as many squares at each level, and its pixels are a lens's horizon. A square
        // whose solid angle is a negligible part of its centre's working pixel is not cut
        // either: the slivers of a lens near 360° along the nadir span dozens of working rows
        // but hardly any solid angle, and quartering them down 8 levels took 20 squares per
        // straddling pixel (6.3 s for a 1280 × 960 equisolid frame at 359.9° instead of 0.9).
        let rim = corners.iter().any(|c| c[0].is_nan());
        let negligible = !rim
            && !middle[0].is_nan()
            && weight * omega
                <= NEGLIGIBLE_SHARE
                    * working_row_solid_angles[cell_of(middle, width, height) as usize / width];
        if depth == 0 || negligible || (rim && STRADDLE_DEPTH - depth >= RIM_DEPTH) {
            // Where its centre is outside the image, a corner inside stands for it: at an
            // orthographic lens's rim a sliver no centre reaches can hold a good part of a
            // pixel's solid angle (0.0018 sr, the whole of one, was lost; a property test).
            let at = if middle[0].is_nan() {
                corners.iter().copied().find(|c| !c[0].is_nan())
            } else {
                Some(middle)
            };
            if let Some(at) = at {
                // Its own solid angle: across the rim of an orthographic lens it is far from
                // its share of the patch's area (the solid angle per pixel area grows without
                // bound there).
                let solid_angle = rectangles.of((u0, v0), (u0 + su, v0 + sv));
                pieces.push((
                    cell_of(at, width, height),
                    solid_angle,
                    at.map(|c| c * solid_angle),
                ));
            }
            continue;
        }
        let [c00, c10, c01, c11] = corners;
        let top = position(u0 + hu, v0);
        let left = position(u0, v0 + hv);
        let right = position(u0 + su, v0 + hv);
        let bottom = position(u0 + hu, v0 + sv);
        for (origin, corners) in [
            ((u0, v0), [c00, top, left, middle]),
            ((u0 + hu, v0), [top, c10, middle, right]),
            ((u0, v0 + hv), [left, middle, c01, bottom]),
            ((u0 + hu, v0 + hv), [middle, right, bottom, c11]),
        ] {
            stack.push((
                (origin.0, origin.1, hu, hv),
                corners,
                weight / 4.0,
                depth - 1,
            ));
        }
    }
    let total: f64 = pieces.iter().map(|p| p.1).sum();
    let pieces = pieces.drain(..);
    if total.is_nan() || total <= 0.0 {
        return;
    }
    // One entry per working pixel. A piece's centroid is in unwrapped columns (beyond the
    // last column or before the first across the φ = 2π seam): wrapped before it is summed.
    for (target, share, weighted) in pieces {
        let (share, mut weighted) = (share / total, weighted.map(|c| c / total));
        let column = (target as usize % width) as f64;
        weighted[0] = share * column_near(weighted[0] / share, column, width);
        match out.iter_mut().find(|e| e.0 == target) {
            Some(e) => {
                e.1 += share;
                e.2 = [e.2[0] + weighted[0], e.2[1] + weighted[1]];
            }
            None => out.push((target, share, weighted)),
        }
    }
}

/// The working-map position (continuous column, row: [`Projection::direction_to_pixel`] of the
/// lat-long working map) of every pixel corner of a `sw`×`sh` input ((sw + 1)·(sh + 1),
/// row-major; NaN where the corner is outside the image), for finding the input pixels that
/// straddle working pixels and their shares. Rows in parallel.
fn corner_positions(
    projection: Projection,
    sw: u32,
    sh: u32,
    width: usize,
    height: usize,
) -> Vec<[f64; 2]> {
    let row = sw as usize + 1;
    let mut corners = vec![[f64::NAN; 2]; row * (sh as usize + 1)];
    corners
        .par_chunks_mut(row)
        .enumerate()
        .for_each(|(y, out)| {
            for (x, c) in out.iter_mut().enumerate() {
                let d = projection.pixel_to_direction(sw, sh, x as f64, y as f64);
                *c = working_position(d, (width, height));
            }
        });
    corners
}

/// The corners (top-left, top-right, bottom-left, bottom-right) of cell (x, y) of a grid of
/// corner positions `row` wide, row-major ([`corner_positions`]).
fn cell_corners(corners: &[[f64; 2]], row: usize, (x, y): (usize, usize)) -> [[f64; 2]; 4] {
    let corner = |cx: usize, cy: usize| corners[cy * row + cx];
    [
        corner(x, y),
        corner(x + 1, y),
        corner(x, y + 1),
        corner(x + 1, y + 1),
    ]
}

/// The working-map position (continuous column, row) of direction `d`: NaN where there is none
/// (outside the image).
fn working_position(d: Option<DVec3>, (width, height): (usize, usize)) -> [f64; 2] {
    d.and_then(|d| Projection::LatLong.direction_to_pixel(width as u32, height as u32, d))
        .map_or([f64::NAN; 2], |(a, b)| [a, b])
}

/// The working pixel at working-map position `p` (column, row; the last column and row take
/// their far edges).
fn cell_of(p: [f64; 2], width: usize, height: usize) -> u32 {
    let ix = (p[0].max(0.0) as usize).min(width - 1);
    let iy = (p[1].max(0.0) as usize).min(height - 1);
    (iy * width + ix) as u32
}

/// The most working columns or rows a pixel's corners may span for [`straddle_pieces`] (more
/// is a pixel around a pole, where the working map's columns meet).
const MAX_STRADDLE_SPAN: f64 = 16.0;

/// The pieces of a small input pixel in the working pixels it covers, from the working-map
/// positions of its corners (top-left, top-right, bottom-left, bottom-right): the pixel is
/// taken as two triangles, each mapped affinely onto the working map (exact for a lat-long
/// input; for a lens, to second order in the pixel's size), clipped to each working pixel's
/// square. Appends (working pixel, solid angle, solid angle × centroid) per working pixel
/// ([`solid_angle_of`] the pieces: the solid angle of a pixel near a pole of the working map
/// is far from even over its area). `false` (and nothing appended) where a corner is outside
/// the image, the corners spread over more than [`MAX_STRADDLE_SPAN`] columns or rows (around
/// a pole), or a triangle is degenerate: the caller quarters the square instead.
fn straddle_pieces(
    corners: [[f64; 2]; 4],
    (width, height): (usize, usize),
    out: &mut Vec<(u32, f64, [f64; 2])>,
) -> bool {
    if corners.iter().flatten().any(|c| !c.is_finite()) {
        return false;
    }
    // Columns wrap at φ = 2π: take them all on the first corner's side.
    let mut corners = corners;
    let a0 = corners[0][0];
    for c in &mut corners[1..] {
        c[0] = column_near(c[0], a0, width);
    }
    let span = |k: usize| {
        let (lo, hi) = corners.iter().fold((f64::MAX, f64::MIN), |(lo, hi), c| {
            (lo.min(c[k]), hi.max(c[k]))
        });
        hi - lo
    };
    if span(0) > MAX_STRADDLE_SPAN || span(1) > MAX_STRADDLE_SPAN {
        return false;
    }
    let [c00, c10, c01, c11] = corners;
    let triangles = [[c00, c10, c11], [c00, c11, c01]];
    let degenerate = |t: &[[f64; 2]; 3]| {
        let area = polygon_area_and_centroid(t).0;
        area.is_nan() || area <= 1e-12
    };
    if triangles.iter().any(degenerate) {
        return false;
    }
    let first = out.len();
    for triangle in &triangles {
        let (lo, hi) = triangle
            .iter()
            .fold(([f64::MAX; 2], [f64::MIN; 2]), |(lo, hi), p| {
                (
                    [lo[0].min(p[0]), lo[1].min(p[1])],
                    [hi[0].max(p[0]), hi[1].max(p[1])],
                )
            });
        let rows = (lo[1].floor().max(0.0) as usize)..=(hi[1].floor() as usize).min(height - 1);
        for row in rows {
            // The last row takes θ = π itself (a corner on the nadir).
            let bottom = if row + 1 == height {
                f64::INFINITY
            } else {
                (row + 1) as f64
            };
            for column in (lo[0].floor() as i64)..=(hi[0].floor() as i64) {
                let cell = ([column as f64, row as f64], [(column + 1) as f64, bottom]);
                let piece = clip_to_box(triangle, cell);
                let (piece_area, centroid) = polygon_area_and_centroid(piece.points());
                if piece_area.is_nan() || piece_area <= 0.0 {
                    continue;
                }
                let share = solid_angle_of(piece.points(), (width, height));
                let target = (row * width + column.rem_euclid(width as i64) as usize) as u32;
                match out[first..].iter_mut().find(|e| e.0 == target) {
                    Some(e) => {
                        e.1 += share;
                        e.2 = [e.2[0] + share * centroid[0], e.2[1] + share * centroid[1]];
                    }
                    None => out.push((target, share, centroid.map(|c| share * c))),
                }
            }
        }
    }
    true
}

/// The edges of a polygon: each point with the next, the last with the first (without a
/// integer division per point, as `(i + 1) % len` took).
fn polygon_edges(points: &[[f64; 2]]) -> impl Iterator<Item = (&[f64; 2], &[f64; 2])> {
    points
        .iter()
        .zip(points.iter().skip(1).chain(points.first()))
}

/// The solid angle of a polygon of working-map positions (column, row; straight edges there):
/// ∬ sin θ dθ dφ over it, by Green's theorem the sum over its edges of Δφ · cos θ̄ · sinc(Δθ/2)
/// (θ̄ the edge's mean θ), where θ = π·row/height and φ = 2π·column/width. Exact for the
/// polygon in (φ, θ); 0 for fewer than three points.
fn solid_angle_of(points: &[[f64; 2]], (width, height): (usize, usize)) -> f64 {
    let (scale_phi, scale_theta) = (2.0 * PI / width as f64, PI / height as f64);
    let mut sum = 0.0;
    for (p, &q) in polygon_edges(points) {
        let d_phi = (q[0] - p[0]) * scale_phi;
        let half = 0.5 * (q[1] - p[1]) * scale_theta;
        let mean = 0.5 * (p[1] + q[1]) * scale_theta;
        let sinc = if half.abs() < 1e-8 {
            1.0
        } else {
            half.sin() / half
        };
        sum += d_phi * mean.cos() * sinc;
    }
    sum.abs()
}

/// Area and centroid of a simple polygon (shoelace); area 0 (and a NaN centroid) for fewer
/// than three points.
fn polygon_area_and_centroid(points: &[[f64; 2]]) -> (f64, [f64; 2]) {
    let (mut twice_area, mut cx, mut cy) = (0.0, 0.0, 0.0);
    for (p, &q) in polygon_edges(points) {
        let cross = p[0] * q[1] - q[0] * p[1];
        twice_area += cross;
        cx += (p[0] + q[0]) * cross;
        cy += (p[1] + q[1]) * cross;
    }
    let area = twice_area / 2.0;
    (
        area.abs(),
        [cx / (3.0 * twice_area), cy / (3.0 * twice_area)],
    )
}

/// A convex polygon of at most [`Polygon::MAX`] points (a triangle clipped by four lines has at
/// most seven), on the stack: the table's plan clips two triangles per straddling pixel, a
/// quarter of a camera frame's pixels.
#[derive(Clone, Copy)]
struct Polygon {
    points: [[f64; 2]; Polygon::MAX],
    len: usize,
}

impl Polygon {
    const MAX: usize = 8;

    fn new(points: &[[f64; 2]]) -> Self {
        let mut polygon = Self {
            points: [[0.0; 2]; Self::MAX],
            len: 0,
        };
        for &p in points.iter().take(Self::MAX) {
            polygon.push(p);
        }
        polygon
    }

    fn push(&mut self, p: [f64; 2]) {
        if self.len < Self::MAX {
            self.points[self.len] = p;
            self.len += 1;
        }
    }

    fn points(&self) -> &[[f64; 2]] {
        &self.points[..self.len]
    }
}

/// The polygon `points` (convex) clipped to the box `lo`–`hi` (Sutherland–Hodgman; an
/// infinite bound clips nothing). Two buffers take turns as input and output, and a bound that
/// every point is inside of is skipped: copying the polygon for each of the four bounds was 7%
/// of a coarse frame's plan in `memmove` alone (perf; a 64² angular map at
/// `--working-width 4096`).
fn clip_to_box(points: &[[f64; 2]], (lo, hi): ([f64; 2], [f64; 2])) -> Polygon {
    let mut buffers = [Polygon::new(points), Polygon::new(&[])];
    let mut current = 0;
    // (axis, bound, keep points whose coordinate is ≥ bound (true) or ≤ it).
    for (axis, bound, above) in [
        (0, lo[0], true),
        (0, hi[0], false),
        (1, lo[1], true),
        (1, hi[1], false),
    ] {
        let inside = |p: &[f64; 2]| {
            if above {
                p[axis] >= bound
            } else {
                p[axis] <= bound
            }
        };
        let input = &buffers[current];
        if input.len == 0 || !bound.is_finite() || input.points().iter().all(inside) {
            continue;
        }
        let [first, second] = &mut buffers;
        let (input, output) = if current == 0 {
            (&*first, second)
        } else {
            (&*second, first)
        };
        output.len = 0;
        let points = input.points();
        for (p, q) in polygon_edges(points) {
            match (inside(p), inside(q)) {
                (true, true) => output.push(*q),
                (true, false) | (false, true) => {
                    let t = (bound - p[axis]) / (q[axis] - p[axis]);
                    output.push([p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])]);
                    if inside(q) {
                        output.push(*q);
                    }
                }
                (false, false) => {}
            }
        }
        current ^= 1;
    }
    buffers[current]
}

/// Input rows per band of the table path. The bands are fixed by the input geometry, not by the
/// number of threads, so the sums are the same bits on any pool. 32 rows of a 1280×960 frame
/// make 30 bands (enough to keep a few threads busy though the image circle leaves the outer
/// bands light) of about 0.5 MB of pixels each.
const TABLE_BAND_ROWS: usize = 32;

/// The runs of the working pixels that one band of input rows *owns*: those whose first input
/// pixel lies in its rows. A working pixel that straddles two bands is summed whole by its
/// owner (which reads a few rows of the next band), so every working pixel's sum is taken by
/// one thread, over its runs in input order, exactly as one thread would take it alone. A
/// run's `target` is a *slot* of the band: the band sums into small arrays of its own
/// ([`BandSums`]), one entry per working pixel it owns (`targets[slot]`), which are then
/// copied into the map.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
struct TableBand {
    runs: Vec<Run>,
    targets: Vec<u32>,
}

/// A band's sums: per slot the f64 Σ rgb·Ω, and the map's f32 energy and luminance of it.
#[derive(Clone, Debug, Default)]
struct BandSums {
    sums: Vec<[f64; 3]>,
    energy: Vec<[f32; 3]>,
    luminance: Vec<f32>,
}

impl TableBand {
    /// The bands of `runs` (in input order, of inputs `sw` pixels wide and `sh` high, onto
    /// `pixels` working pixels).
    fn split(runs: &[Run], sw: usize, sh: usize, pixels: usize) -> Vec<TableBand> {
        let mut bands = vec![TableBand::default(); sh.div_ceil(TABLE_BAND_ROWS)];
        // Per working pixel: its owner band and its slot there.
        let mut owner = vec![(u32::MAX, 0u32); pixels];
        for run in runs {
            let t = run.target as usize;
            if owner[t].0 == u32::MAX {
                let b = run.start as usize / sw / TABLE_BAND_ROWS;
                owner[t] = (b as u32, bands[b].targets.len() as u32);
                bands[b].targets.push(run.target);
            }
            let (b, slot) = owner[t];
            bands[b as usize].runs.push(Run {
                target: slot,
                ..*run
            });
        }
        // Slots in the order of their working pixels, so that copying a band's sums into the
        // map writes it front to back (in first-seen order the writes jump between the map's
        // rows, a cache miss each).
        for band in &mut bands {
            let mut order: Vec<u32> = (0..band.targets.len() as u32).collect();
            order.sort_unstable_by_key(|&slot| band.targets[slot as usize]);
            let mut new_slot = vec![0u32; order.len()];
            for (new, &old) in order.iter().enumerate() {
                new_slot[old as usize] = new as u32;
            }
            band.targets = order
                .iter()
                .map(|&old| band.targets[old as usize])
                .collect();
            for run in &mut band.runs {
                run.target = new_slot[run.target as usize];
            }
        }
        bands
    }

    /// The map's energy and luminance of each slot into `out`.
    fn sum(&self, pixels: &[[f32; 3]], weights: &[f32], out: &mut BandSums) {
        let n = self.targets.len();
        out.sums.clear();
        out.sums.resize(n, [0.0; 3]);
        self.sum_runs(pixels, weights, &mut out.sums, |slot| slot as usize);
        out.energy.clear();
        out.luminance.clear();
        for sum in &out.sums {
            let (energy, luminance) = map_entry(*sum);
            out.energy.push(energy);
            out.luminance.push(luminance);
        }
    }

    /// Σ rgb·Ω of each run into `sums[index(slot)]`, added to what is there (Ω: the entries'
    /// `weights`). A run with a negative input poisons its sum with NaN, for the careful sum
    /// of [`Resampler::resample`].
    fn sum_runs(
        &self,
        pixels: &[[f32; 3]],
        weights: &[f32],
        sums: &mut [[f64; 3]],
        index: impl Fn(u32) -> usize,
    ) {
        for run in &self.runs {
            let (start, end) = (run.start as usize, run.end as usize);
            let first = run.entries as usize;
            let (pixels, omegas) = (&pixels[start..end], &weights[first..first + end - start]);
            // The run's Σ rgb·Ω in f32 vectors (glam's Vec3A: SSE lanes), in two partial sums
            // (even and odd pixels) so that a pixel's adds need not wait for the previous
            // pixel's (a run holds a few dozen input pixels at most; the sums across runs are
            // f64, as are all sums of the careful pass). `low` is the least input, to find a
            // negative one.
            let (mut even, mut odd, mut low) = (Vec3A::ZERO, Vec3A::ZERO, Vec3A::ZERO);
            // A pair's six floats r₀ g₀ b₀ r₁ g₁ b₁ are read as two overlapping 4-lane loads,
            // (r₀ g₀ b₀ r₁) and (b₀ r₁ g₁ b₁) turned to (r₁ g₁ b₁ b₀); the fourth lane is
            // never used (Vec3A ignores it), so the sums are those of three-lane loads, bit for
            // bit, in fewer instructions.
            let flat: &[f32] = bytemuck::cast_slice(pixels);
            let mut pairs = flat.chunks_exact(6).zip(omegas.chunks_exact(2));
            for (p, w) in &mut pairs {
                let a = Vec3A::from_vec4(Vec4::from_slice(&p[0..4]));
                let b = Vec4::from_slice(&p[2..6]);
                let b = Vec3A::from_vec4(Vec4::new(b.y, b.z, b.w, b.x));
                even += a * w[0];
                odd += b * w[1];
                low = low.min(a.min(b));
            }
            if pixels.len() % 2 == 1 {
                if let (Some(&p), Some(&w)) = (pixels.last(), omegas.last()) {
                    let a = Vec3A::from_array(p);
                    even += a * w;
                    low = low.min(a);
                }
            }
            let sum = (even + odd).to_array();
            let negative = low.cmplt(Vec3A::ZERO).any();
            let e = &mut sums[index(run.target)];
            if negative {
                e[0] = f64::NAN;
            } else {
                for c in 0..3 {
                    e[c] += f64::from(sum[c]);
                }
            }
        }
    }
}

/// A working pixel's f32 energy and luminance from its f64 Σ rgb·Ω.
fn map_entry(sum: [f64; 3]) -> ([f32; 3], f32) {
    // Clamped: a sum past f32's range must not become ∞ here, where nothing would catch it
    // (its luminance may still be finite).
    let energy = sum.map(|c| {
        let c = c as f32;
        if c > f32::MAX {
            f32::MAX
        } else {
            c
        }
    });
    // Not clamped: NaN or ∞ here must reach the careful sum of `Resampler::resample`
    // (f32::min would turn NaN into a finite value).
    (energy, super::luminance_f64(sum) as f32)
}

impl Plan {
    /// Calls `f(input index, solid angle, direction)` for every input pixel of working pixel
    /// `idx` (`width`: working map width, `sw`: input width).
    fn for_each_input(
        &self,
        idx: usize,
        width: usize,
        sw: usize,
        mut f: impl FnMut(usize, f32, [f32; 3]),
    ) {
        match self {
            Plan::Box {
                factor: k,
                row_solid_angle,
                row_theta,
                column_phi,
            } => {
                let (bx, by) = (idx % width, idx / width);
                for y in by * k..(by + 1) * k {
                    let (sin_t, cos_t) = row_theta[y];
                    let omega = row_solid_angle[y] as f32;
                    for x in bx * k..(bx + 1) * k {
                        let (sin_p, cos_p) = column_phi[x];
                        f(y * sw + x, omega, [sin_t * sin_p, cos_t, -sin_t * cos_p]);
                    }
                }
            }
            Plan::Overlap {
                input_rows: sh,
                working_rows: height,
                ..
            } => {
                let (sh, height) = (*sh, *height);
                let (j, i) = (idx % width, idx / width);
                for y in overlapping_cells(i, height, sh) {
                    let (cos_extent, theta) = row_overlap(y, sh, i, height);
                    let (sin_t, cos_t) = theta.sin_cos();
                    for x in overlapping_cells(j, width, sw) {
                        let (phi_extent, phi) = column_overlap(x, sw, j, width);
                        let omega = phi_extent * cos_extent;
                        if omega > 0.0 {
                            let (sin_p, cos_p) = phi.sin_cos();
                            let d = [sin_t * sin_p, cos_t, -sin_t * cos_p].map(|c| c as f32);
                            f(y * sw + x, omega as f32, d);
                        }
                    }
                }
            }
            Plan::Table {
                weights,
                directions,
                member_offsets,
                members,
                ..
            } => {
                let range = member_offsets[idx] as usize..member_offsets[idx + 1] as usize;
                for &(input, entry) in &members[range] {
                    let entry = entry as usize;
                    f(input as usize, weights[entry], directions[entry]);
                }
            }
        }
    }
}

/// One overlap of an input column (row) with a working column (row) of [`Plan::Overlap`].
#[derive(Clone, Copy, Debug, PartialEq)]
struct Overlap {
    input: u32,
    working: u32,
    /// The overlap's φ extent (columns) or cos θ extent (rows), in radians or as a difference
    /// of cosines.
    extent: f64,
}

/// The overlap of cell `a` of a division of [0, 1] into `na` cells with cell `b` of a division
/// into `nb`, in units of 1/(na·nb) (integers: exact): `(start, end)`, empty when end ≤ start.
fn cell_overlap(a: usize, na: usize, b: usize, nb: usize) -> (u64, u64) {
    let (a, na, b, nb) = (a as u64, na as u64, b as u64, nb as u64);
    ((a * nb).max(b * na), ((a + 1) * nb).min((b + 1) * na))
}

/// The cells of a division into `nb` cells that cell `a` of a division into `na` overlaps.
fn overlapping_cells(a: usize, na: usize, nb: usize) -> std::ops::Range<usize> {
    let (a, na, nb) = (a as u64, na as u64, nb as u64);
    let first = a * nb / na;
    let end = ((a + 1) * nb).div_ceil(na);
    first as usize..(end as usize).min(nb as usize)
}

/// The φ extent of the overlap of input column `x` of `sw` with working column `j` of `w`,
/// and the φ of its centre.
fn column_overlap(x: usize, sw: usize, j: usize, w: usize) -> (f64, f64) {
    let (lo, hi) = cell_overlap(x, sw, j, w);
    let unit = 2.0 * PI / (sw as f64 * w as f64);
    let extent = hi.saturating_sub(lo) as f64 * unit;
    (extent, 0.5 * (lo + hi) as f64 * unit)
}

/// The cos θ extent (the solid angle per radian of φ) of the overlap of input row `y` of `sh`
/// with working row `i` of `h`, and the θ of its centre.
fn row_overlap(y: usize, sh: usize, i: usize, h: usize) -> (f64, f64) {
    let (lo, hi) = cell_overlap(y, sh, i, h);
    let unit = PI / (sh as f64 * h as f64);
    if hi <= lo {
        return (0.0, 0.5 * (lo + hi) as f64 * unit);
    }
    let (a, b) = (lo as f64 * unit, hi as f64 * unit);
    // cos a − cos b without the cancellation of two close cosines.
    (
        2.0 * (0.5 * (a + b)).sin() * (0.5 * (b - a)).sin(),
        0.5 * (a + b),
    )
}

/// Every overlap of the `n_in` input cells with the `n_out` working cells
/// ([`crate::envmap::interval_overlaps`]), input cell by input cell, with its
/// `extent` (of the pair).
fn overlaps(n_in: usize, n_out: usize, extent: impl Fn(usize, usize) -> f64) -> Vec<Overlap> {
    crate::envmap::interval_overlaps(n_in as u32, n_out as u32)
        .into_iter()
        .map(|(a, b, _)| Overlap {
            input: a as u32,
            working: b as u32,
            extent: extent(a, b),
        })
        .filter(|o| o.extent > 0.0)
        .collect()
}

/// Resamples frames of one geometry (projection and size) to a working map.
#[derive(Clone, Debug)]
pub struct Resampler {
    projection: Projection,
    src_width: u32,
    src_height: u32,
    plan: Plan,
    map: WorkingMap,
    /// Scratch row of the box filter and the overlap path.
    column_sums: Vec<f32>,
    /// The table path's per-working-pixel sums on one thread (empty otherwise).
    table_sums: Vec<[f64; 3]>,
    /// The table path's sums of each band, with helper threads (empty otherwise).
    band_sums: Vec<BandSums>,
    arch: pulp::Arch,
}

impl Resampler {
    /// A resampler for `projection` frames of `src_width`×`src_height`. The working map is
    /// `working_width` wide, except for a lat-long input at least that wide whose sides are
    /// multiples of f = ⌊input width / working width⌋: that one is box-filtered by f (so an
    /// input between one and two working widths wide keeps its own size).
    pub fn new(
        projection: Projection,
        src_width: u32,
        src_height: u32,
        working_width: u32,
    ) -> Self {
        let (sw, sh) = (src_width as usize, src_height as usize);
        let target = working_width.max(2) as usize;
        let box_factor = (sw / target).max(1);
        // A lat-long input narrower than the working width goes through the table, whose
        // working map is `working_width` wide and cuts the input pixels into sub-pixels: kept at
        // its own size, a 17×9 map leaves 132 of 256 lights without power.
        let is_box = projection == Projection::LatLong
            && sw >= target
            && sw % box_factor == 0
            && sh % box_factor == 0;
        let (width, height, plan) = if is_box {
            let omegas = Projection::LatLong.solid_angles(src_width, src_height);
            let row_solid_angle = (0..sh).map(|y| omegas[y * sw]).collect();
            let angle_table = |n: usize, scale: f64| -> Vec<(f32, f32)> {
                (0..n)
                    .map(|i| {
                        let (s, c) = (scale * (i as f64 + 0.5) / n as f64).sin_cos();
                        (s as f32, c as f32)
                    })
                    .collect()
            };
            let plan = Plan::Box {
                factor: box_factor,
                row_solid_angle,
                row_theta: angle_table(sh, PI),
                column_phi: angle_table(sw, 2.0 * PI),
            };
            (sw / box_factor, sh / box_factor, plan)
        } else if projection == Projection::LatLong {
            let width = target;
            let height = (width / 2).max(1);
            let mut by_column = overlaps(sw, width, |x, j| column_overlap(x, sw, j, width).0);
            by_column.sort_by_key(|o| (o.working, o.input));
            let mut columns = vec![(0u32, 0u32); width];
            for group in by_column.chunk_by(|a, b| a.working == b.working) {
                columns[group[0].working as usize] = (group[0].input, group.len() as u32);
            }
            let mut rows = overlaps(sh, height, |y, i| row_overlap(y, sh, i, height).0);
            rows.sort_by_key(|o| (o.working, o.input));
            let plan = Plan::Overlap {
                columns,
                column_extents: by_column.iter().map(|o| o.extent as f32).collect(),
                rows,
                input_rows: sh,
                working_rows: height,
            };
            (width, height, plan)
        } else {
            let width = target;
            let height = (width / 2).max(1);
            (
                width,
                height,
                Self::table_plan(projection, src_width, src_height, width, height),
            )
        };
        Self::with_plan(projection, src_width, src_height, width, height, plan)
    }

    /// A resampler whose working map is exactly `working_width` × `working_width / 2` (at
    /// least 2 × 1) whatever the input, through the index table: each input pixel's energy
    /// goes to the working pixel of its centre (cut into sub-pixels where input pixels are
    /// larger than working ones), so the map's total is the input's integral. For callers that
    /// need that size (the ASG fit's target) where [`Self::new`] would box-filter a lat-long
    /// input to a size of its own.
    pub fn with_exact_width(
        projection: Projection,
        src_width: u32,
        src_height: u32,
        working_width: u32,
    ) -> Self {
        let width = working_width.max(2) as usize;
        let height = width / 2;
        let plan = Self::table_plan(projection, src_width, src_height, width, height);
        Self::with_plan(projection, src_width, src_height, width, height, plan)
    }

    fn with_plan(
        projection: Projection,
        src_width: u32,
        src_height: u32,
        width: usize,
        height: usize,
        plan: Plan,
    ) -> Self {
        let omegas = Projection::LatLong.solid_angles(width as u32, height as u32);
        let trig = |n: usize, scale: f64| -> Vec<(f64, f64)> {
            (0..n)
                .map(|i| (scale * (i as f64 + 0.5) / n as f64).sin_cos())
                .collect()
        };
        let row_trig_f64 = trig(height, PI);
        let column_trig_f64 = trig(width, 2.0 * PI);
        let to_f32 = |t: &[(f64, f64)]| t.iter().map(|&(s, c)| (s as f32, c as f32)).collect();
        let mut map = WorkingMap {
            width,
            height,
            energy: vec![[0.0; 3]; width * height],
            row_trig: to_f32(&row_trig_f64),
            row_trig_f64,
            column_trig: to_f32(&column_trig_f64),
            column_trig_f64,
            row_solid_angle: (0..height).map(|y| omegas[y * width]).collect(),
            luminance: vec![0.0; width * height],
            concentrated: vec![false; width * height],
            fine: Vec::new(),
            unseen: Vec::new(),
        };
        if projection != Projection::LatLong {
            if let Plan::Table {
                weights,
                member_offsets,
                members,
                ..
            } = &plan
            {
                map.unseen = unseen_parts(&map, weights, member_offsets, members);
            }
        }
        Self {
            projection,
            src_width,
            src_height,
            plan,
            map,
            column_sums: Vec::new(),
            table_sums: Vec::new(),
            band_sums: Vec::new(),
            arch: pulp::Arch::new(),
        }
    }

    fn table_plan(projection: Projection, sw: u32, sh: u32, width: usize, height: usize) -> Plan {
        let started = std::time::Instant::now();
        let plan = Self::build_table_plan(projection, sw, sh, width, height);
        let seconds = started.elapsed().as_secs_f64();
        // A frame with far fewer pixels than the working map has its pixels cut into many
        // sub-pixels (a 64² angular map at `--working-width 4096`: 67 million, 15–30 s): said,
        // so that a long first frame is not taken for a hang.
        if seconds >= SLOW_TABLE_S {
            tracing::info!(
                "the resampling table of {sw}×{sh} {} frames onto the {width}×{height} working \
                 map took {seconds:.1} s (once per frame size and projection; a working map \
                 with far more pixels than the frame, here {:.0}×, is slow to build: a smaller \
                 working width is faster)",
                projection.name(),
                (width * height) as f64 / (f64::from(sw) * f64::from(sh)).max(1.0)
            );
        }
        plan
    }

    fn build_table_plan(
        projection: Projection,
        sw: u32,
        sh: u32,
        width: usize,
        height: usize,
    ) -> Plan {
        let omegas = projection.solid_angles(sw, sh);
        let rectangles = projection.rectangle_solid_angles(sw, sh);
        let working_cells = Projection::LatLong.rectangle_solid_angles(width as u32, height as u32);
        let working_row_solid_angles: Vec<f64> = (0..height)
            .map(|row| working_cells.of((0.0, row as f64), (1.0, row as f64 + 1.0)))
            .collect();
        // A working pixel's height in θ: input pixels wider than half of it are split.
        let step = PI / height as f64;
        let row = sw as usize;
        let corners = corner_positions(projection, sw, sh, width, height);
        // Every input pixel's entries, row by row in parallel on rayon's threads (a
        // once-per-geometry cost; each pixel's entries are the same whatever the number of
        // threads), in input order and per input pixel in the order of the working pixels.
        let entries_of_rows: Vec<Vec<PixelPart>> = omegas
            .par_chunks(row)
            .enumerate()
            .map(|(y, omegas)| {
                let mut entries = Vec::with_capacity(row);
                let (mut shares, mut scratch) = (Vec::new(), StraddleScratch::default());
                let mut split_scratch = SplitScratch::default();
                for (x, &omega) in omegas.iter().enumerate() {
                    if omega.is_nan() || omega <= 0.0 {
                        continue;
                    }
                    let pixel = SplitPixel {
                        projection,
                        rectangles: &rectangles,
                        working_row_solid_angles: &working_row_solid_angles,
                        source: (sw, sh),
                        working: (width, height),
                        at: (x, y),
                        solid_angle: omega,
                        split: split_factor(projection, (sw, sh), (x, y), omega, step),
                    };
                    if pixel.split != (1, 1) {
                        let before = entries.len();
                        pixel.parts(&mut split_scratch, &mut entries);
                        if entries.len() > before {
                            continue;
                        }
                    }
                    let centre_dir =
                        projection.pixel_to_direction(sw, sh, x as f64 + 0.5, y as f64 + 0.5);
                    // The centre's working-map position (NaN outside the image).
                    let centre = working_position(centre_dir, (width, height));
                    // Where no sample point of a rim pixel is inside, the point nearest the
                    // circle's centre is (a sliver through its side: 0.0007 sr lost, a
                    // property test).
                    let nearest = || {
                        let (x0, y0) = (x as f64, y as f64);
                        rectangles
                            .point_inside((x0, y0), (x0 + 1.0, y0 + 1.0))
                            .and_then(|(u, v)| projection.pixel_to_direction(sw, sh, u, v))
                    };
                    let Some(d) = centre_dir
                        .or_else(|| rim_direction(projection, sw, sh, x, y))
                        .or_else(nearest)
                    else {
                        continue;
                    };
                    let t = if centre[0].is_nan() {
                        match working_pixel_of(d, width, height) {
                            Some(t) => t,
                            None => continue,
                        }
                    } else {
                        cell_of(centre, width, height)
                    };
                    // A pixel whose corners are not all in its centre's working pixel (or in
                    // the image) straddles working pixels: shared among them by area, unless
                    // it all lies in one.
                    let four = cell_corners(&corners, row + 1, (x, y));
                    let straddles = four
                        .iter()
                        .any(|&c| c[0].is_nan() || cell_of(c, width, height) != t);
                    if straddles {
                        shares.clear();
                        let patch = ImagePatch {
                            origin: (x as f64, y as f64),
                            size: (1.0, 1.0),
                            solid_angle: omega,
                        };
                        small_pixel_shares(
                            &pixel,
                            patch,
                            (four, centre),
                            &mut scratch,
                            &mut shares,
                        );
                        if shares.len() > 1 {
                            let input = (y * row + x) as u32;
                            for &(target, share, weighted) in &shares {
                                entries.push(PixelPart::at_centroid(
                                    (input, target),
                                    omega * share,
                                    weighted.map(|c| c / share),
                                    (width, height),
                                ));
                            }
                            continue;
                        }
                    }
                    entries.push(PixelPart {
                        input: (y * row + x) as u32,
                        target: t,
                        solid_angle: omega as f32,
                        direction: d.as_vec3().to_array(),
                    });
                }
                entries
            })
            .collect();
        // By working pixel, and in input order within one (a counting sort: stable).
        let mut member_offsets = vec![0u32; width * height + 1];
        for e in entries_of_rows.iter().flatten() {
            member_offsets[e.target as usize + 1] += 1;
        }
        for i in 1..member_offsets.len() {
            member_offsets[i] += member_offsets[i - 1];
        }
        let mut next = member_offsets.clone();
        let mut entries = vec![
            PixelPart {
                input: 0,
                target: 0,
                solid_angle: 0.0,
                direction: [0.0; 3],
            };
            member_offsets[width * height] as usize
        ];
        for e in entries_of_rows.into_iter().flatten() {
            let slot = &mut next[e.target as usize];
            entries[*slot as usize] = e;
            *slot += 1;
        }
        // The runs: consecutive input pixels of one working pixel (`entries` here indexes the
        // sorted entries), then in input order, and the entries laid out in the runs' order so
        // that the resampling reads them front to back.
        let mut runs: Vec<Run> = Vec::new();
        for (k, e) in entries.iter().enumerate() {
            match runs.last_mut() {
                Some(run) if run.target == e.target && run.end == e.input => run.end += 1,
                _ => runs.push(Run {
                    start: e.input,
                    end: e.input + 1,
                    target: e.target,
                    entries: k as u32,
                }),
            }
        }
        runs.sort_unstable_by_key(|r| (r.start, r.target));
        let mut weights = Vec::with_capacity(entries.len());
        let mut directions = Vec::with_capacity(entries.len());
        let mut entry_of_sorted = vec![0u32; entries.len()];
        for run in &mut runs {
            let sorted = run.entries as usize..(run.entries + run.end - run.start) as usize;
            run.entries = weights.len() as u32;
            for k in sorted {
                entry_of_sorted[k] = weights.len() as u32;
                weights.push(entries[k].solid_angle);
                directions.push(entries[k].direction);
            }
        }
        // Working pixel → its entries (`member_offsets`, above).
        let members = entries
            .iter()
            .zip(&entry_of_sorted)
            .map(|(e, &entry)| (e.input, entry))
            .collect();
        Plan::Table {
            bands: TableBand::split(&runs, sw as usize, sh as usize, width * height),
            weights,
            directions,
            member_offsets,
            members,
        }
    }

    /// The working map as last resampled (zeros before the first frame): its geometry serves
    /// the region pass's tests.
    #[cfg(test)]
    pub(crate) fn map_for_tests(&self) -> &WorkingMap {
        &self.map
    }

    /// Whether this resampler was built for frames like `frame`.
    pub fn fits(&self, frame: &HdrFrame) -> bool {
        self.projection == frame.projection
            && self.src_width == frame.width
            && self.src_height == frame.height
    }

    /// Whether frames go through the index table (not the lat-long box filter): only then can
    /// a thread pool help [`Self::resample`].
    pub fn uses_table(&self) -> bool {
        matches!(self.plan, Plan::Table { .. })
    }

    /// Resamples `frame` (which must fit) and returns the working map. Working pixels holding
    /// more than `concentrated_share` of the luminance energy keep their input pixels as fine
    /// samples. Non-finite or negative values count as 0 (sources sanitise them already).
    /// The table path sums its bands of input rows with `pool`'s threads helping the calling
    /// one if a pool is given (on the calling thread alone otherwise); the map is the same bits
    /// either way.
    pub fn resample(
        &mut self,
        frame: &HdrFrame,
        concentrated_share: f64,
        pool: Option<&rayon::ThreadPool>,
    ) -> &WorkingMap {
        let map = &mut self.map;
        let sw = self.src_width as usize;
        match &self.plan {
            Plan::Box {
                factor,
                row_solid_angle,
                ..
            } => {
                // One slack value: the horizontal sums read four lanes for three channels.
                self.column_sums.resize(3 * sw + 1, 0.0);
                let args = BoxFilter {
                    pixels: &frame.pixels,
                    sw,
                    factor: *factor,
                    row_solid_angle,
                    column_sums: &mut self.column_sums,
                    energy: &mut map.energy,
                    luminance: &mut map.luminance,
                    width: map.width,
                };
                // AVX2: the horizontal sums eight working pixels at a time (`BoxFilterV3`);
                // otherwise compiled for the widest vector unit the CPU has (runtime detection).
                #[cfg(target_arch = "x86_64")]
                if let Some(simd) = pulp::x86::V3::try_new() {
                    pulp::Simd::vectorize(simd, BoxFilterV3 { args, simd });
                } else {
                    self.arch.dispatch(args);
                }
                #[cfg(not(target_arch = "x86_64"))]
                self.arch.dispatch(args);
            }
            Plan::Overlap {
                columns,
                column_extents,
                rows,
                ..
            } => {
                // As the box filter: per working row, its input rows weighted by the cos θ
                // extents of their overlaps and summed column by column (f32, contiguous,
                // vectorised), then each working column's input columns weighted by their φ
                // extents.
                let width = map.width;
                let sums = &mut self.column_sums;
                sums.resize(3 * sw, 0.0);
                for rows_of_i in rows.chunk_by(|a, b| a.working == b.working) {
                    let i = rows_of_i[0].working as usize;
                    let bits = self.arch.dispatch(WeightedRows {
                        pixels: &frame.pixels,
                        sw,
                        rows: rows_of_i,
                        sums,
                    });
                    let out = &mut map.energy[i * width..(i + 1) * width];
                    let lum = &mut map.luminance[i * width..(i + 1) * width];
                    let mut extents = column_extents.iter();
                    for ((e, l), &(first, count)) in out.iter_mut().zip(lum.iter_mut()).zip(columns)
                    {
                        let mut acc = Vec3A::ZERO;
                        let first = first as usize;
                        for (p, &w) in sums[3 * first..3 * (first + count as usize)]
                            .chunks_exact(3)
                            .zip(extents.by_ref())
                        {
                            acc += Vec3A::new(p[0], p[1], p[2]) * w;
                        }
                        (*e, *l) = map_entry(acc.to_array().map(f64::from));
                    }
                    if bits & 0x8000_0000 != 0 {
                        // A negative input (or a NaN with its sign bit set) flags the whole
                        // working row for the careful sum, as on the box path.
                        out.iter_mut().for_each(|e| e[0] = f32::NAN);
                        lum.fill(f32::NAN);
                    }
                }
            }
            Plan::Table { bands, weights, .. } => {
                let pixels = &frame.pixels;
                if let Some(pool) = pool {
                    let band_sums = &mut self.band_sums;
                    band_sums.resize_with(bands.len(), BandSums::default);
                    // The decomposition thread and the pool's helpers take bands in turn
                    // (src/parallel.rs); which thread sums a band does not change its sums.
                    crate::parallel::for_each_chunk_mut(Some(pool), band_sums, 1, |b, out| {
                        if let (Some(band), [out]) = (bands.get(b), out) {
                            band.sum(pixels, weights, out);
                        }
                    });
                    // Each working pixel with input is owned by one band; the others stay 0,
                    // as `new` made them.
                    for (band, sums) in bands.iter().zip(band_sums.iter()) {
                        for ((&target, e), l) in
                            band.targets.iter().zip(&sums.energy).zip(&sums.luminance)
                        {
                            map.energy[target as usize] = *e;
                            map.luminance[target as usize] = *l;
                        }
                    }
                } else {
                    // One thread: the bands' runs straight into one f64 sum per working pixel,
                    // then the map in one pass, front to back. A working pixel's runs are
                    // summed in the same order as with helpers, so the bits are the same; this
                    // only saves the copying of the bands' sums into the map (writes that jump
                    // between the map's rows).
                    let sums = &mut self.table_sums;
                    sums.clear();
                    sums.resize(map.energy.len(), [0.0; 3]);
                    for band in bands {
                        band.sum_runs(pixels, weights, sums, |slot| {
                            band.targets[slot as usize] as usize
                        });
                    }
                    for ((e, l), sum) in map.energy.iter_mut().zip(&mut map.luminance).zip(sums) {
                        (*e, *l) = map_entry(*sum);
                    }
                }
            }
        }
        // Bad pixels (NaN, ±Inf, negative) should have been sanitised by the source. If any
        // slipped through, the working pixels they poisoned (NaN or ±Inf: both paths flag a
        // negative input with NaN, and any non-finite channel makes the luminance non-finite)
        // are summed again with those pixels counted as 0, so neither the lights nor the good
        // pixels beside them are lost. Sums of non-negative finite values stay finite, so a
        // finite total means there is nothing to redo.
        let mut total = self.arch.dispatch(LuminanceSum(&map.luminance));
        if !total.is_finite() {
            for idx in 0..map.energy.len() {
                if map.luminance[idx].is_finite()
                    && map.energy[idx].iter().all(|c| c.is_finite() && *c >= 0.0)
                {
                    continue;
                }
                let mut sum = [0.0f64; 3];
                self.plan.for_each_input(idx, map.width, sw, |i, omega, _| {
                    for c in 0..3 {
                        let v = frame.pixels[i][c];
                        if v.is_finite() && v > 0.0 {
                            sum[c] += f64::from(v) * f64::from(omega);
                        }
                    }
                });
                map.energy[idx] = sum.map(|c| (c as f32).min(f32::MAX));
                map.luminance[idx] = (super::luminance_f64(sum) as f32).min(f32::MAX);
            }
            total = luminance_sum(&map.luminance);
        }

        let threshold = concentrated_share * total;
        map.fine.clear();
        self.arch.dispatch(Flags {
            luminance: &map.luminance,
            concentrated: &mut map.concentrated,
            threshold,
        });
        let is_table = matches!(self.plan, Plan::Table { .. });
        for idx in flagged(&map.concentrated) {
            let pixel = idx as u32;
            let first = map.fine.len();
            self.plan
                .for_each_input(idx, map.width, sw, |i, solid_angle, dir| {
                    let clean = |v: f32| {
                        if v.is_finite() && v > 0.0 {
                            v * solid_angle
                        } else {
                            0.0
                        }
                    };
                    let energy = frame.pixels[i].map(clean);
                    map.fine.push(FineSample {
                        pixel,
                        dir,
                        energy,
                        solid_angle,
                    });
                });
            // The table's pieces of input pixels cover their working pixel to a fraction of a
            // percent at a pole (less at an image circle's rim, where the lens sees part of
            // it), and the working pixels beside it count their own solid angles: so its
            // pieces share its solid angle, in proportion to theirs, and the regions tile the
            // sphere (their solid angles sum to 4π). The box filter's blocks are the working
            // pixels exactly. A lens that sees part of the sphere keeps the pieces' own solid
            // angles, the part of the working pixel it sees ([`WorkingMap::unseen`]).
            if is_table && self.projection == Projection::LatLong {
                rescale_solid_angles(&mut map.fine[first..], map.row_solid_angle[idx / map.width]);
            }
        }
        &self.map
    }
}

/// The indices of the set flags, in order; eight flags are tested at a time (almost none is
/// set: a concentrated working pixel holds more than 1/(4n) of the map's energy).
fn flagged(flags: &[bool]) -> impl Iterator<Item = usize> + '_ {
    let bytes: &[u8] = bytemuck::cast_slice(flags);
    bytes
        .chunks(8)
        .enumerate()
        .filter(|(_, chunk)| {
            let mut word = [0u8; 8];
            word[..chunk.len()].copy_from_slice(chunk);
            u64::from_ne_bytes(word) != 0
        })
        .flat_map(|(i, chunk)| {
            chunk
                .iter()
                .enumerate()
                .filter(|&(_, &flag)| flag != 0)
                .map(move |(j, _)| 8 * i + j)
        })
}

/// The overlap path's vertical pass for one working row: `sums` (3·sw floats) becomes the
/// sum of the input rows `rows` weighted by their extents, two rows per pass over the sums;
/// returns the OR of the input floats' bits (its sign bit: a negative input). Run through
/// [`pulp::Arch::dispatch`], compiled for the CPU's vector unit.
struct WeightedRows<'a> {
    pixels: &'a [[f32; 3]],
    sw: usize,
    rows: &'a [Overlap],
    sums: &'a mut [f32],
}

impl pulp::WithSimd for WeightedRows<'_> {
    type Output = u32;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> u32 {
        let WeightedRows {
            pixels,
            sw,
            rows,
            sums,
        } = self;
        let row = |r: &Overlap| {
            let y = r.input as usize;
            (pixels[y * sw..(y + 1) * sw].as_flattened(), r.extent as f32)
        };
        let mut bits = 0u32;
        let mut pairs = rows.chunks_exact(2);
        let mut first = true;
        for pair in pairs.by_ref() {
            let ((p0, w0), (p1, w1)) = (row(&pair[0]), row(&pair[1]));
            if first {
                for ((a, p), q) in sums.iter_mut().zip(p0).zip(p1) {
                    *a = p * w0 + q * w1;
                    bits |= p.to_bits() | q.to_bits();
                }
            } else {
                for ((a, p), q) in sums.iter_mut().zip(p0).zip(p1) {
                    *a += p * w0 + q * w1;
                    bits |= p.to_bits() | q.to_bits();
                }
            }
            first = false;
        }
        if let [last] = pairs.remainder() {
            let (p0, w0) = row(last);
            if first {
                for (a, p) in sums.iter_mut().zip(p0) {
                    *a = p * w0;
                    bits |= p.to_bits();
                }
            } else {
                for (a, p) in sums.iter_mut().zip(p0) {
                    *a += p * w0;
                    bits |= p.to_bits();
                }
            }
        }
        bits
    }
}

/// The box filter's arguments, run through [`pulp::Arch::dispatch`] so that it is compiled for
/// the CPU's vector unit (`with_simd` and everything it calls are inlined into the
/// target-feature function).
struct BoxFilter<'a> {
    pixels: &'a [[f32; 3]],
    sw: usize,
    factor: usize,
    row_solid_angle: &'a [f64],
    column_sums: &'a mut [f32],
    energy: &'a mut [[f32; 3]],
    luminance: &'a mut [f32],
    width: usize,
}

impl pulp::WithSimd for BoxFilter<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        box_filter(self, None);
    }
}

/// The box filter on a CPU with AVX2: as [`BoxFilter`], with the horizontal sums of a
/// factor-4 filter done eight working pixels at a time ([`sum_columns_4_avx2`]).
#[cfg(target_arch = "x86_64")]
struct BoxFilterV3<'a> {
    args: BoxFilter<'a>,
    simd: pulp::x86::V3,
}

#[cfg(target_arch = "x86_64")]
impl pulp::WithSimd for BoxFilterV3<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        box_filter(self.args, Some(self.simd));
    }
}

/// Box filter of a lat-long input by `factor`×`factor` into `energy` and `luminance` (one
/// working row per `factor` input rows): the input rows are weighted by their solid angle and
/// summed column by column into `column_sums` (flat f32, so it vectorises; the first row
/// initialises the sums), then each run of `factor` columns is summed into its working pixel
/// with four-lane vectors (rgb plus one lane of the next pixel, ignored). A working row that saw
/// a negative input (sign bit in the OR of all its inputs' bits) gets NaN in its first channel,
/// so the careful sum redoes it; NaN and ±Inf inputs show in the sums by themselves.
///
/// With `avx2`, the horizontal sums of a factor-4 filter use [`sum_columns_4_avx2`].
#[inline(always)]
fn box_filter(args: BoxFilter<'_>, avx2: Avx2) {
    let BoxFilter {
        pixels,
        sw,
        factor: f,
        row_solid_angle,
        column_sums,
        energy,
        luminance,
        width,
    } = args;
    let row_len = 3 * sw;
    for (wy, ((rows, out), lum)) in pixels
        .chunks_exact(sw * f)
        .zip(energy.chunks_exact_mut(width))
        .zip(luminance.chunks_exact_mut(width))
        .enumerate()
    {
        let mut bits = 0u32;
        let omegas = &row_solid_angle[wy * f..(wy + 1) * f];
        let sums = &mut column_sums[..row_len];
        // Four, else two input rows per pass over the column sums (fewer loads and stores of
        // the sums); an odd factor starts with one row. The adds are grouped as in pairs of
        // rows, ((r0 + r1) + (r2 + r3)), so the sums do not depend on the grouping.
        let mut k = 0;
        if f % 2 == 1 {
            let (row, w) = (rows[..sw].as_flattened(), omegas[0] as f32);
            for (a, p) in sums.iter_mut().zip(row) {
                *a = p * w;
                bits |= p.to_bits();
            }
            k = 1;
        }
        if f % 4 == 0 {
            while k + 3 < f {
                let row = |j: usize| rows[(k + j) * sw..(k + j + 1) * sw].as_flattened();
                let (row0, row1, row2, row3) = (row(0), row(1), row(2), row(3));
                let w = |j: usize| omegas[k + j] as f32;
                let (w0, w1, w2, w3) = (w(0), w(1), w(2), w(3));
                let quads = sums.iter_mut().zip(row0).zip(row1).zip(row2).zip(row3);
                if k == 0 {
                    for ((((a, p), q), r), s) in quads {
                        *a = p * w0 + q * w1 + (r * w2 + s * w3);
                        bits |= (p.to_bits() | q.to_bits()) | (r.to_bits() | s.to_bits());
                    }
                } else {
                    for ((((a, p), q), r), s) in quads {
                        *a += p * w0 + q * w1;
                        *a += r * w2 + s * w3;
                        bits |= (p.to_bits() | q.to_bits()) | (r.to_bits() | s.to_bits());
                    }
                }
                k += 4;
            }
        }
        while k + 1 < f {
            let row0 = rows[k * sw..(k + 1) * sw].as_flattened();
            let row1 = rows[(k + 1) * sw..(k + 2) * sw].as_flattened();
            let (w0, w1) = (omegas[k] as f32, omegas[k + 1] as f32);
            if k == 0 {
                for ((a, p), q) in sums.iter_mut().zip(row0).zip(row1) {
                    *a = p * w0 + q * w1;
                    bits |= p.to_bits() | q.to_bits();
                }
            } else {
                for ((a, p), q) in sums.iter_mut().zip(row0).zip(row1) {
                    *a += p * w0 + q * w1;
                    bits |= p.to_bits() | q.to_bits();
                }
            }
            k += 2;
        }
        match f {
            1 => sum_columns::<1>(column_sums, out, lum),
            2 => sum_columns::<2>(column_sums, out, lum),
            4 => sum_columns_4(avx2, column_sums, out, lum),
            8 => sum_columns::<8>(column_sums, out, lum),
            _ => {
                for ((e, l), block) in out
                    .iter_mut()
                    .zip(lum.iter_mut())
                    .zip(column_sums.chunks_exact(3 * f))
                {
                    let mut sum = [0.0f32; 3];
                    for p in block.chunks_exact(3) {
                        sum[0] += p[0];
                        sum[1] += p[1];
                        sum[2] += p[2];
                    }
                    *e = sum;
                    *l = luminance_f32(sum);
                }
            }
        }
        if bits & 0x8000_0000 != 0 {
            // Flag the whole working row for the careful sum.
            out.iter_mut().for_each(|e| e[0] = f32::NAN);
            lum.fill(f32::NAN);
        }
    }
}

/// Sums each run of `F` rgb columns of `column_sums` (3·F·width values and one slack value)
/// into one working pixel and its luminance, four lanes at a time.
#[inline(always)]
fn sum_columns<const F: usize>(column_sums: &[f32], out: &mut [[f32; 3]], lum: &mut [f32]) {
    let lanes = |i: usize| -> [f32; 4] {
        let mut v = [0.0f32; 4];
        v.copy_from_slice(&column_sums[i..i + 4]);
        v
    };
    for (m, (e, l)) in out.iter_mut().zip(lum.iter_mut()).enumerate() {
        let base = 3 * F * m;
        let mut sum = lanes(base);
        for k in 1..F {
            let v = lanes(base + 3 * k);
            for (s, v) in sum.iter_mut().zip(v) {
                *s += v;
            }
        }
        let rgb = [sum[0], sum[1], sum[2]];
        *e = rgb;
        *l = luminance_f32(rgb);
    }
}

/// The AVX2 token of the box filter's horizontal sums (`None`: the portable path).
#[cfg(target_arch = "x86_64")]
type Avx2 = Option<pulp::x86::V3>;
#[cfg(not(target_arch = "x86_64"))]
type Avx2 = Option<std::convert::Infallible>;

/// [`sum_columns`]`::<4>`, with AVX2 where the CPU has it.
#[inline(always)]
fn sum_columns_4(avx2: Avx2, column_sums: &[f32], out: &mut [[f32; 3]], lum: &mut [f32]) {
    match avx2 {
        #[cfg(target_arch = "x86_64")]
        Some(simd) => sum_columns_4_avx2(simd, column_sums, out, lum),
        #[cfg(not(target_arch = "x86_64"))]
        Some(never) => match never {},
        None => sum_columns::<4>(column_sums, out, lum),
    }
}

/// [`sum_columns`]`::<4>` with AVX2, eight working pixels at a time, with the same results bit
/// for bit: each working pixel's four rgb columns are summed in the same order in the lanes of
/// one half of a 256-bit vector (two pixels per vector, rgb plus one ignored lane), four such
/// vectors are transposed to r, g and b of eight pixels (seven shuffles) for the luminance
/// (multiplies and adds as in [`crate::frame::luminance`], no fused multiply-add), and each
/// half's rgb lanes are the pixel's energy. The pixels after the last multiple of eight go
/// through the scalar path.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn sum_columns_4_avx2(
    simd: pulp::x86::V3,
    column_sums: &[f32],
    out: &mut [[f32; 3]],
    lum: &mut [f32],
) {
    use core::arch::x86_64::{__m128, __m256};
    use pulp::bytemuck::cast;
    const F: usize = 4;
    let avx = simd.avx;
    #[inline(always)]
    fn load(column_sums: &[f32], i: usize) -> __m128 {
        let mut v = [0.0f32; 4];
        v.copy_from_slice(&column_sums[i..i + 4]);
        cast(v)
    }
    // Working pixels `lo` and `hi`: the sums of their F rgb columns in the lanes of the low and
    // the high half, added in the scalar path's order.
    #[inline(always)]
    fn pair(simd: pulp::x86::V3, column_sums: &[f32], lo: usize, hi: usize) -> __m256 {
        let avx = simd.avx;
        let load = |i| load(column_sums, i);
        let (a, b) = (3 * F * lo, 3 * F * hi);
        let mut s = avx._mm256_set_m128(load(b), load(a));
        for k in 1..F {
            let v = avx._mm256_set_m128(load(b + 3 * k), load(a + 3 * k));
            s = avx._mm256_add_ps(s, v);
        }
        s
    }
    let pair = |lo, hi| pair(simd, column_sums, lo, hi);
    let w = crate::frame::LUMINANCE_WEIGHTS;
    let (w_r, w_g, w_b) = (
        avx._mm256_set1_ps(w[0]),
        avx._mm256_set1_ps(w[1]),
        avx._mm256_set1_ps(w[2]),
    );
    let groups = out.len().min(lum.len()) / 8;
    for (out, (lum, m)) in out
        .chunks_exact_mut(8)
        .zip(lum.chunks_exact_mut(8).zip((0..groups).map(|g| 8 * g)))
    {
        let s04 = pair(m, m + 4);
        let s15 = pair(m + 1, m + 5);
        let s26 = pair(m + 2, m + 6);
        let s37 = pair(m + 3, m + 7);
        // [r0 r1 g0 g1 | r4 r5 g4 g5], [b0 b1 · · | b4 b5 · ·], and the same for 2, 3, 6, 7.
        let t0 = avx._mm256_unpacklo_ps(s04, s15);
        let t1 = avx._mm256_unpackhi_ps(s04, s15);
        let t2 = avx._mm256_unpacklo_ps(s26, s37);
        let t3 = avx._mm256_unpackhi_ps(s26, s37);
        let r = avx._mm256_shuffle_ps::<0x44>(t0, t2);
        let g = avx._mm256_shuffle_ps::<0xEE>(t0, t2);
        let b = avx._mm256_shuffle_ps::<0x44>(t1, t3);
        let l = avx._mm256_add_ps(
            avx._mm256_add_ps(avx._mm256_mul_ps(w_r, r), avx._mm256_mul_ps(w_g, g)),
            avx._mm256_mul_ps(w_b, b),
        );
        lum.copy_from_slice(&cast::<__m256, [f32; 8]>(l));
        let halves = [
            avx._mm256_castps256_ps128(s04),
            avx._mm256_castps256_ps128(s15),
            avx._mm256_castps256_ps128(s26),
            avx._mm256_castps256_ps128(s37),
            avx._mm256_extractf128_ps::<1>(s04),
            avx._mm256_extractf128_ps::<1>(s15),
            avx._mm256_extractf128_ps::<1>(s26),
            avx._mm256_extractf128_ps::<1>(s37),
        ];
        for (e, half) in out.iter_mut().zip(halves) {
            let lanes = cast::<__m128, [f32; 4]>(half);
            *e = [lanes[0], lanes[1], lanes[2]];
        }
    }
    let done = 8 * groups;
    sum_columns::<F>(
        &column_sums[3 * F * done..],
        &mut out[done..],
        &mut lum[done..],
    );
}

/// Rec. 709 luminance of an f32 rgb triple.
#[inline(always)]
fn luminance_f32(rgb: [f32; 3]) -> f32 {
    crate::frame::luminance(rgb)
}

/// [`luminance_sum`] compiled for the CPU's vector unit.
struct LuminanceSum<'a>(&'a [f32]);

impl pulp::WithSimd for LuminanceSum<'_> {
    type Output = f64;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> f64 {
        luminance_sum(self.0)
    }
}

/// Flags the working pixels whose luminance exceeds `threshold` (compiled for the CPU's vector
/// unit).
struct Flags<'a> {
    luminance: &'a [f32],
    concentrated: &'a mut [bool],
    threshold: f64,
}

impl pulp::WithSimd for Flags<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        for (flag, &lum) in self.concentrated.iter_mut().zip(self.luminance) {
            *flag = f64::from(lum) > self.threshold;
        }
    }
}

/// Σ of the working pixels' luminance in f64 (four partial sums, so the adds overlap).
#[inline(always)]
fn luminance_sum(luminance: &[f32]) -> f64 {
    let mut partial = [0.0f64; 4];
    let quads = luminance.chunks_exact(4);
    let rest = quads.remainder();
    for quad in quads {
        for (p, &l) in partial.iter_mut().zip(quad) {
            *p += f64::from(l);
        }
    }
    partial.iter().sum::<f64>() + rest.iter().map(|&l| f64::from(l)).sum::<f64>()
}

/// The working pixel (row-major, of a `width`×`height` map) that direction `d` falls in.
fn working_pixel_of(d: DVec3, width: usize, height: usize) -> Option<u32> {
    let (px, py) = Projection::LatLong.direction_to_pixel(width as u32, height as u32, d)?;
    Some(cell_of([px, py], width, height))
}

/// Into how many sub-pixels across × down input pixel (x, y) of solid angle `omega` is cut so
/// that each is at most half a working pixel (`step` radians) along each image axis: (1, 1)
/// for pixels with √Ω under a sixth of a working pixel. Along an axis its size is the larger
/// of its extent there (the angle between the directions at the midpoints of opposite edges,
/// where both are in the image) and Ω over the other axis' extent (its mean width), so the
/// long pixels at the rim of an orthographic lens are caught too, and a pixel long along one
/// axis only is cut along that one.
fn split_factor(
    projection: Projection,
    (sw, sh): (u32, u32),
    (x, y): (usize, usize),
    omega: f64,
    step: f64,
) -> (usize, usize) {
    let mean_size = omega.sqrt();
    // Most pixels of camera frames are far smaller than a working pixel: no directions needed
    // (this lets through pixels up to 3:1 elongated whose mean size is under step/6; a 1280×960
    // equidistant frame's are step/7.5 at the default working size).
    if mean_size < step / 6.0 {
        return (1, 1);
    }
    let (x0, y0) = (x as f64, y as f64);
    let angle = |a: (f64, f64), b: (f64, f64)| match (
        projection.pixel_to_direction(sw, sh, a.0, a.1),
        projection.pixel_to_direction(sw, sh, b.0, b.1),
    ) {
        (Some(p), Some(q)) => p.angle_between(q),
        _ => 0.0,
    };
    let across = angle((x0, y0 + 0.5), (x0 + 1.0, y0 + 0.5));
    let down = angle((x0 + 0.5, y0), (x0 + 0.5, y0 + 1.0));
    // Each axis is cut by its own extent: a pixel of a 2048×1 map spans 180° down and 0.18°
    // across, and cutting it 256 × 256 (by its largest extent both ways) took 35 s a frame
    // geometry. An extent the middle lines miss (0 where both ends are one direction, as
    // across a 1-pixel-wide lat-long map) is the solid angle over the other extent; each axis
    // is then at least the solid angle over the other (a mean width).
    let guess = |along: f64, other: f64| match (along > 0.0, other > 0.0) {
        (true, _) => along,
        (false, true) => omega / other,
        (false, false) => mean_size,
    };
    let (width, height) = (guess(across, down), guess(down, across));
    let count = |size: f64| {
        let split = (2.0 * size / step).ceil();
        if split.is_finite() {
            (split as usize).clamp(1, MAX_SPLIT)
        } else {
            1
        }
    };
    (
        count(width.max(omega / height)),
        count(height.max(omega / width)),
    )
}

/// An input pixel to cut into `split.0` × `split.1` sub-pixels (across × down, [`PixelPart`]).
struct SplitPixel<'a> {
    projection: Projection,
    /// Exact solid angles of the input image's rectangles (sub-pixels, pieces of pixels).
    rectangles: &'a RectangleSolidAngles,
    /// The solid angle of a working pixel of each row of the working map.
    working_row_solid_angles: &'a [f64],
    source: (u32, u32),
    working: (usize, usize),
    at: (usize, usize),
    solid_angle: f64,
    split: (usize, usize),
}

impl SplitPixel<'_> {
    /// Appends the pixel's parts, one per working pixel it covers, in the order of the working
    /// pixels. Each sub-pixel that sees anything has its own exact solid angle
    /// ([`RectangleSolidAngles`]; they sum to the pixel's) and is shared among the working
    /// pixels it covers as a small pixel is ([`small_pixel_shares`]: binned whole by their
    /// centres, sub-pixels half a working pixel wide gave a uniform 340 × 255 fisheye's lights
    /// 0.64–1.31 of their regions' energy at 4096 lights). A part's direction is that of its
    /// pieces' centroid. Nothing is appended if no piece of any sub-pixel is inside.
    fn parts(&self, scratch: &mut SplitScratch, parts: &mut Vec<PixelPart>) {
        let ((sw, sh), (width, height), (x, y)) = (self.source, self.working, self.at);
        let (nx, ny) = self.split;
        let direction = |u: f64, v: f64| self.projection.pixel_to_direction(sw, sh, u, v);
        let sub_corner = |i: usize, j: usize| {
            (
                x as f64 + i as f64 / nx as f64,
                y as f64 + j as f64 / ny as f64,
            )
        };
        // The working-map positions of the sub-pixels' corners, (nx + 1) × (ny + 1).
        let SplitScratch {
            corners,
            solid_angles,
            edges,
            shares,
            pieces,
            straddle,
        } = scratch;
        corners.clear();
        for j in 0..=ny {
            for i in 0..=nx {
                let (u, v) = sub_corner(i, j);
                corners.push(working_position(direction(u, v), (width, height)));
            }
        }
        // Each sub-pixel with its own solid angle (evenly spaced in the image, they are far
        // from even on the sphere where the projection stretches: a stereographic rim; from
        // one grid whose shared edges are integrated once, [`RectangleSolidAngles::grid`]),
        // shared among the working pixels it covers; one whose centre is outside the image (a
        // rim sub-pixel) by the parts of it inside.
        let (xs, ys) = edges;
        xs.clear();
        xs.extend((0..=nx).map(|i| sub_corner(i, 0).0));
        ys.clear();
        ys.extend((0..=ny).map(|j| sub_corner(0, j).1));
        self.rectangles.grid(xs, ys, solid_angles);
        pieces.clear();
        let mut covered = 0.0;
        let size = (1.0 / nx as f64, 1.0 / ny as f64);
        for j in 0..ny {
            for i in 0..nx {
                let (u0, v0) = sub_corner(i, j);
                let solid_angle = solid_angles[j * nx + i];
                if solid_angle.is_nan() || solid_angle <= 0.0 {
                    continue;
                }
                let centre = working_position(
                    direction(u0 + size.0 / 2.0, v0 + size.1 / 2.0),
                    (width, height),
                );
                let four = cell_corners(corners, nx + 1, (i, j));
                let target = (!centre[0].is_nan()).then(|| cell_of(centre, width, height));
                let straddles = four
                    .iter()
                    .any(|&c| c[0].is_nan() || Some(cell_of(c, width, height)) != target);
                shares.clear();
                if straddles {
                    let patch = ImagePatch {
                        origin: (u0, v0),
                        size,
                        solid_angle,
                    };
                    small_pixel_shares(self, patch, (four, centre), straddle, shares);
                }
                if shares.is_empty() {
                    let Some(target) = target else { continue };
                    pieces.push((target, solid_angle, centre.map(|c| c * solid_angle)));
                }
                for &(target, share, weighted) in shares.iter() {
                    pieces.push((
                        target,
                        share * solid_angle,
                        weighted.map(|c| c * solid_angle),
                    ));
                }
                covered += solid_angle;
            }
        }
        if pieces.is_empty() {
            return;
        }
        // The sub-pixels' solid angles sum to the pixel's (exactly but for rounding, and for
        // rim sub-pixels no piece of which took: their share goes to the rest).
        let scale = self.solid_angle / covered;
        // Stable: each working pixel's pieces stay in scan order.
        pieces.sort_by_key(|p| p.0);
        let input = (y * sw as usize + x) as u32;
        for group in pieces.chunk_by(|a, b| a.0 == b.0) {
            let solid_angle: f64 = group.iter().map(|p| p.1).sum();
            let weighted = group
                .iter()
                .fold([0.0; 2], |m, p| [m[0] + p.2[0], m[1] + p.2[1]]);
            parts.push(PixelPart::at_centroid(
                (input, group[0].0),
                solid_angle * scale,
                weighted.map(|c| c / solid_angle),
                (width, height),
            ));
        }
    }
}

/// The buffers of [`SplitPixel::parts`], kept from pixel to pixel.
#[derive(Default)]
struct SplitScratch {
    corners: Vec<[f64; 2]>,
    /// The sub-pixels' solid angles, row-major.
    solid_angles: Vec<f64>,
    /// The sub-pixels' column and row edges.
    edges: (Vec<f64>, Vec<f64>),
    shares: Vec<(u32, f64, [f64; 2])>,
    pieces: Vec<(u32, f64, [f64; 2])>,
    straddle: StraddleScratch,
}

/// Scales the solid angles of `samples` (the input pixels of one working pixel) so that they
/// sum to `total`, the working pixel's.
fn rescale_solid_angles(samples: &mut [FineSample], total: f64) {
    let sum: f64 = samples.iter().map(|s| f64::from(s.solid_angle)).sum();
    if sum > 0.0 {
        let scale = total / sum;
        for s in samples {
            s.solid_angle = (f64::from(s.solid_angle) * scale) as f32;
        }
    }
}

/// The direction of the part of pixel (x, y) inside the image circle (or the field of view)
/// when its centre is outside: the normalised mean of the directions of the sub-pixel points
/// that are inside, on grids of 4×4, 16×16 and 64×64 points until one is. A rim pixel whose
/// centre is just outside still has a solid angle; without a direction it was left out, and
/// with it its energy (a sun on the rim vanished; 1.5% of a uniform orthographic 180° frame).
/// `None` only for a sliver no 64×64 point falls in.
fn rim_direction(projection: Projection, sw: u32, sh: u32, x: usize, y: usize) -> Option<DVec3> {
    for n in [4u32, 16, 64] {
        let mut sum = DVec3::ZERO;
        for j in 0..n {
            for i in 0..n {
                let (u, v) = (
                    x as f64 + (f64::from(i) + 0.5) / f64::from(n),
                    y as f64 + (f64::from(j) + 0.5) / f64::from(n),
                );
                if let Some(d) = projection.pixel_to_direction(sw, sh, u, v) {
                    sum += d;
                }
            }
        }
        if let Some(d) = sum.try_normalize() {
            return Some(d);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pixel long along one image axis only is cut along that axis only: a 2048×1 lat-long
    /// map's pixels (180° down, 0.18° across) into 1 × 256 sub-pixels, not 256 × 256 (which
    /// took 35 s to plan); a 1×512 map's (360° across) into 256 × 1; a square-ish pixel of a
    /// 17×9 map both ways alike.
    #[test]
    fn pixels_are_cut_along_their_long_axis_only() {
        let step = PI / 128.0;
        let split = |(w, h): (u32, u32), at: (usize, usize)| {
            let omega = Projection::LatLong.solid_angles(w, h)[at.1 * w as usize + at.0];
            split_factor(Projection::LatLong, (w, h), at, omega, step)
        };
        assert_eq!(split((2048, 1), (5, 0)), (1, MAX_SPLIT));
        assert_eq!(split((1, 512), (0, 256)), (MAX_SPLIT, 1));
        let (across, down) = split((17, 9), (3, 4));
        assert!(
            across > 1 && down > 1 && across.abs_diff(down) <= 2,
            "{across} {down}"
        );
        assert_eq!(split((1024, 512), (7, 200)), (1, 1));
    }

    /// The AVX2 horizontal sums give the portable path's energies and luminances bit for bit,
    /// on row widths with and without a remainder after the groups of eight.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_horizontal_sums_equal_the_portable_ones() {
        let Some(simd) = pulp::x86::V3::try_new() else {
            eprintln!("no AVX2 on this CPU: nothing to compare");
            return;
        };
        // Values over many magnitudes (a sun beside a dim sky), from a fixed sequence.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            let mantissa = (state >> 40) as f32 / (1u64 << 24) as f32;
            let exponent = ((state >> 32) % 24) as i32 - 12;
            mantissa * 2f32.powi(exponent)
        };
        let mut compared = 0;
        for width in (1..=21).chain([64, 67]) {
            let sums: Vec<f32> = (0..12 * width + 1).map(|_| next()).collect();
            let (mut e_simd, mut l_simd) = (vec![[0.0; 3]; width], vec![0.0; width]);
            let (mut e_plain, mut l_plain) = (vec![[0.0; 3]; width], vec![0.0; width]);
            simd.vectorize(|| sum_columns_4_avx2(simd, &sums, &mut e_simd, &mut l_simd));
            sum_columns::<4>(&sums, &mut e_plain, &mut l_plain);
            let bits = |e: &[[f32; 3]]| e.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&e_simd), bits(&e_plain), "energies, width {width}");
            let bits = |l: &[f32]| l.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&l_simd), bits(&l_plain), "luminances, width {width}");
            compared += width;
        }
        assert!(compared > 100);
    }

    /// The table path sums runs of input pixels in f32 vectors: its working map must equal a
    /// plain f64 sum over each working pixel's input pixels, and a negative, NaN or infinite
    /// input must count as 0 for its working pixel only.
    #[test]
    fn table_path_sums_each_working_pixel_and_ignores_bad_inputs() {
        let projection = Projection::Fisheye(crate::envmap::FisheyeCalibration::default());
        let (w, h) = (96u32, 80u32);
        let clean: Vec<[f32; 3]> = (0..w * h)
            .map(|i| {
                let v = 0.1 + (i % 17) as f32 * 0.37;
                [v, 0.5 * v, 2.0 - 0.1 * v]
            })
            .collect();
        // Far apart, so that each is in a run of its own (a NaN would hide a negative input
        // of its run: the whole working pixel is summed again with care).
        let (negative, nan, infinite) = (3000, 3600, 4321);
        let mut dirty = clean.clone();
        dirty[negative][0] = -1.0;
        dirty[nan][1] = f32::NAN;
        dirty[infinite][2] = f32::INFINITY;
        let mut expected = clean.clone();
        expected[negative][0] = 0.0;
        expected[nan][1] = 0.0;
        expected[infinite][2] = 0.0;
        let mut resampler = Resampler::new(projection, w, h, 32);
        assert!(matches!(resampler.plan, Plan::Table { .. }));
        let frame = HdrFrame::new(w, h, dirty, projection).unwrap();
        let map = resampler.resample(&frame, 1.0, None).clone();
        let touched = assert_plain_sums(&resampler.plan, &map, w, &expected);
        assert!(touched > 100, "{touched} working pixels with input");
    }

    /// The table path's working map is the same bits on the calling thread alone and with 2
    /// and 5 helper threads (the bands are fixed by the input geometry; each working pixel is summed
    /// by the band that owns it), including the concentrated pixels' fine samples, and equals
    /// a plain sum over each working pixel's input pixels.
    #[test]
    fn table_path_does_not_depend_on_the_number_of_threads() {
        let projection = Projection::Fisheye(crate::envmap::FisheyeCalibration::default());
        // 150 rows: five bands of 32 rows, the last one short.
        let (w, h) = (170u32, 150u32);
        let pixels: Vec<[f32; 3]> = (0..w * h)
            .map(|i| {
                let v = 0.05 + (i.wrapping_mul(2_654_435_761) >> 20) as f32 * 1e-3;
                // A bright spot, so that some working pixels are concentrated.
                let spot = if (i % w).abs_diff(60) < 4 && (i / w).abs_diff(40) < 4 {
                    1e4
                } else {
                    1.0
                };
                [v * spot, 0.7 * v * spot, 1.3 * v]
            })
            .collect();
        let frame = HdrFrame::new(w, h, pixels.clone(), projection).unwrap();
        let mut resampler = Resampler::new(projection, w, h, 64);
        let Plan::Table { bands, .. } = &resampler.plan else {
            panic!("a fisheye input uses the table");
        };
        assert_eq!(bands.len(), 5);
        let bits = |m: &WorkingMap| {
            let mut v: Vec<u32> = m.energy.iter().flatten().map(|c| c.to_bits()).collect();
            v.extend(m.luminance.iter().map(|l| l.to_bits()));
            for f in &m.fine {
                v.push(f.pixel);
                v.extend(f.energy.map(f32::to_bits));
                v.extend(f.dir.map(f32::to_bits));
            }
            v
        };
        let alone = resampler.resample(&frame, 0.002, None).clone();
        assert!(!alone.fine.is_empty(), "the spot is concentrated");
        for threads in [2, 5] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut fresh = Resampler::new(projection, w, h, 64);
            let pooled = fresh.resample(&frame, 0.002, Some(&pool));
            assert!(bits(pooled) == bits(&alone), "{threads} threads");
        }
        assert!(assert_plain_sums(&resampler.plan, &alone, w, &pixels) > 100);
    }

    /// Checks each working pixel's energy against a plain f64 sum of rgb·Ω over its input
    /// pixels (`pixels`, an input `w` wide); returns how many working pixels have input.
    fn assert_plain_sums(plan: &Plan, map: &WorkingMap, w: u32, pixels: &[[f32; 3]]) -> usize {
        let mut touched = 0;
        for idx in 0..map.energy.len() {
            let mut sum = [0.0f64; 3];
            plan.for_each_input(idx, map.width, w as usize, |i, omega, _| {
                for c in 0..3 {
                    sum[c] += f64::from(pixels[i][c]) * f64::from(omega);
                }
            });
            for c in 0..3 {
                let got = f64::from(map.energy[idx][c]);
                assert!(
                    (got - sum[c]).abs() <= 1e-6 * sum[c] + 1e-30,
                    "working pixel {idx} channel {c}: {got} against {}",
                    sum[c]
                );
            }
            touched += usize::from(sum[0] > 0.0);
        }
        touched
    }

    /// A small pixel's pieces in the working pixels it straddles have the solid angles of its
    /// overlaps with them: a square centred on a corner of four working pixels gives each the
    /// solid angle of its quarter (with each piece's centroid in its own working pixel); one
    /// across the φ = 2π seam halves between the last and the first column; a leaning one
    /// matches a numerical integral of sin θ over its part left of a column's edge. A square
    /// around a pole (corners spread over the map's columns) or with a corner outside the
    /// image is left to the caller.
    #[test]
    fn straddle_pieces_have_the_solid_angles_of_the_overlaps() {
        let size = (256, 128);
        let (d_phi, d_theta) = (2.0 * PI / 256.0, PI / 128.0);
        // The solid angle of columns a0..a1 and rows b0..b1 (continuous).
        let rectangle = |(a0, a1): (f64, f64), (b0, b1): (f64, f64)| {
            (a1 - a0) * d_phi * ((b0 * d_theta).cos() - (b1 * d_theta).cos())
        };
        let mut out = Vec::new();
        let square = |a: f64, b: f64, side: f64| {
            [[a, b], [a + side, b], [a, b + side], [a + side, b + side]]
        };
        assert!(straddle_pieces(square(9.5, 20.5, 1.0), size, &mut out));
        out.sort_by_key(|e| e.0);
        let targets: Vec<u32> = out.iter().map(|e| e.0).collect();
        assert_eq!(
            targets,
            [20 * 256 + 9, 20 * 256 + 10, 21 * 256 + 9, 21 * 256 + 10]
        );
        for &(target, solid_angle, weighted) in &out {
            let (column, row) = ((target % 256) as f64, (target / 256) as f64);
            let expected = rectangle(
                (column.max(9.5), (column + 1.0).min(10.5)),
                (row.max(20.5), (row + 1.0).min(21.5)),
            );
            assert!(
                (solid_angle / expected - 1.0).abs() < 1e-12,
                "{solid_angle} {expected}"
            );
            let [a, b] = weighted.map(|c| c / solid_angle);
            assert_eq!(cell_of([a, b], 256, 128), target);
        }
        out.clear();
        assert!(straddle_pieces(
            [[255.75, 3.2], [0.25, 3.2], [255.75, 3.7], [0.25, 3.7]],
            size,
            &mut out
        ));
        out.sort_by_key(|e| e.0);
        assert_eq!(
            out.iter().map(|e| e.0).collect::<Vec<_>>(),
            [3 * 256, 3 * 256 + 255]
        );
        let half = rectangle((0.0, 0.25), (3.2, 3.7));
        assert!(
            out.iter().all(|e| (e.1 / half - 1.0).abs() < 1e-12),
            "{out:?}"
        );
        // A parallelogram leaning one column right over its height, cut by the column edge
        // a = 11: its part left of the edge, by integrating sin θ over the rows.
        out.clear();
        let (a0, b0, shear) = (10.4, 5.1, 1.0);
        assert!(straddle_pieces(
            [
                [a0, b0],
                [a0 + 0.5, b0],
                [a0 + shear, b0 + 0.5],
                [a0 + 0.5 + shear, b0 + 0.5]
            ],
            size,
            &mut out
        ));
        let steps = 100_000;
        let dv = 0.5 / steps as f64;
        let left: f64 = (0..steps)
            .map(|k| {
                let b = b0 + (k as f64 + 0.5) * dv;
                let start = a0 + shear * (b - b0) / 0.5;
                let width = (11.0 - start).clamp(0.0, 0.5);
                width * d_phi * (b * d_theta).sin() * dv * d_theta
            })
            .sum();
        let got = out
            .iter()
            .find(|e| e.0 == 5 * 256 + 10)
            .map_or(0.0, |e| e.1);
        assert!((got / left - 1.0).abs() < 1e-6, "{got} against {left}");
        out.clear();
        assert!(!straddle_pieces(
            [[3.0, 0.2], [130.0, 0.2], [3.0, 0.4], [130.0, 0.4]],
            size,
            &mut out
        ));
        let mut outside = square(9.5, 20.5, 1.0);
        outside[3] = [f64::NAN; 2];
        assert!(!straddle_pieces(outside, size, &mut out));
        assert!(out.is_empty());
    }

    /// A uniform frame through the table gives every working pixel inside the image its own
    /// solid angle's worth of energy: the input pixels that straddle working pixels are shared
    /// among them by the solid angles of their pieces (binned whole by their centres, the
    /// working pixels of a 1280 × 960 fisheye got 0 to 7.2 times theirs, 0.87–1.15 more than
    /// 45° from the zenith; of a 1024² angular map 0.78–1.24 in its middle rows). Exact for a
    /// lat-long input (its pixels are squares of (φ, θ)) but in the pole rows (10⁻⁴ off); the
    /// fisheye's rows within 0.1 %, its zenith row 0.2 %; the angular map's within 0.5 % (at its
    /// singular rim), its pole rows 1.7 % (the squares around a pole are quartered until they
    /// hold under 10⁻³ of their working pixel, and their centres take them).
    #[test]
    fn table_path_keeps_a_uniform_frame_uniform() {
        let fisheye = Projection::Fisheye(crate::envmap::FisheyeCalibration::default());
        // (projection, size, rows inside the image, tolerance: in the rows at a pole of the
        // working map, elsewhere).
        for (projection, w, h, rows, (at_pole, tolerance)) in [
            (
                Projection::LatLong,
                1000u32,
                500u32,
                0..128usize,
                (5e-4, 1e-6),
            ),
            (fisheye, 1280, 960, 0..64, (3e-3, 1e-3)),
            (Projection::AngularMap, 1024, 1024, 0..128, (2.5e-2, 5e-3)),
        ] {
            let frame = HdrFrame::new(w, h, vec![[2.0; 3]; (w * h) as usize], projection).unwrap();
            let mut resampler = Resampler::with_exact_width(projection, w, h, 256);
            let map = resampler.resample(&frame, 1.0, None);
            // The working pixel furthest off: (|ratio − 1|, column, row, ratio).
            let mut worst = (0.0f64, 0, 0, 1.0);
            for row in rows {
                for (column, e) in map.energy[row * map.width..(row + 1) * map.width]
                    .iter()
                    .enumerate()
                {
                    let ratio = f64::from(e[1]) / (2.0 * map.row_solid_angle[row]);
                    let scale = if row == 0 || row == map.height - 1 {
                        tolerance / at_pole
                    } else {
                        1.0
                    };
                    if (ratio - 1.0).abs() * scale >= worst.0 {
                        worst = ((ratio - 1.0).abs() * scale, column, row, ratio);
                    }
                }
            }
            eprintln!("{projection:?} {w}×{h}: {worst:?}");
            let (off, column, row, ratio) = worst;
            assert!(
                off < tolerance,
                "{projection:?} {w}×{h}: working pixel ({column}, {row}) has {ratio} of its energy"
            );
        }
    }

    /// A working pixel's f64 sum beyond f32's range is stored as f32::MAX, not ∞: on the table
    /// and overlap paths its luminance can stay finite (blue weighs 0.07), so the careful sum
    /// would not run.
    #[test]
    fn table_and_overlap_sums_beyond_f32_range_are_clamped() {
        // 7×3 inputs onto a 2×1 map: not an integer factor, so a lat-long input takes the
        // overlap path and a fisheye the index table; each working pixel spans 2π sr, so 3e38
        // in blue sums past f32::MAX.
        let fisheye = Projection::Fisheye(crate::envmap::FisheyeCalibration::default());
        for projection in [Projection::LatLong, fisheye] {
            let pixels = vec![[0.0, 0.0, 3.0e38]; 7 * 3];
            let frame = HdrFrame::new(7, 3, pixels, projection).unwrap();
            let mut resampler = Resampler::new(projection, 7, 3, 2);
            assert_eq!(
                matches!(resampler.plan, Plan::Overlap { .. }),
                projection == Projection::LatLong
            );
            let map = resampler.resample(&frame, 0.25, None);
            assert!(map.luminance.iter().all(|l| l.is_finite()));
            assert!(map
                .energy
                .iter()
                .flatten()
                .all(|c| c.is_finite() && *c >= 0.0));
            assert!(
                map.energy.iter().any(|e| e[2] == f32::MAX),
                "{projection:?}"
            );
        }
    }

    /// A lat-long input whose sides are not multiples of the working map's is resampled by
    /// exact overlap: a uniform map gives every working pixel its own solid angle (to f32
    /// rounding) at every size, down (1000 × 500, 1920 × 960: 3.9 and 3.75 input pixels per
    /// working pixel, where binning by centres made stripes of ±13 %) and up (255 × 128,
    /// 3 × 2, 1 × 1, 2000 × 2); a working pixel's input parts tile it (their solid angles sum to
    /// its own, their directions lie in it); and a negative, NaN or infinite input counts as 0
    /// for the working pixels it overlaps only.
    #[test]
    fn overlap_path_keeps_a_uniform_map_uniform_and_tiles_each_working_pixel() {
        for (sw, sh) in [
            (1000, 500),
            (1920, 960),
            (255, 128),
            (3, 2),
            (1, 1),
            (2000, 2),
        ] {
            let mut resampler = Resampler::new(Projection::LatLong, sw, sh, 256);
            assert!(matches!(resampler.plan, Plan::Overlap { .. }), "{sw}×{sh}");
            let frame = HdrFrame::new(
                sw,
                sh,
                vec![[2.0; 3]; (sw * sh) as usize],
                Projection::LatLong,
            )
            .unwrap();
            let map = resampler.resample(&frame, 1.0, None).clone();
            assert_eq!((map.width, map.height), (256, 128));
            for (idx, e) in map.energy.iter().enumerate() {
                let omega = map.row_solid_angle[idx / map.width];
                let ratio = f64::from(e[1]) / (2.0 * omega);
                assert!((ratio - 1.0).abs() < 2e-6, "{sw}×{sh} pixel {idx}: {ratio}");
            }
            for idx in [0, 300, 128 * 64 + 17, 256 * 128 - 1] {
                let (row, column) = (idx / map.width, idx % map.width);
                let theta = |r: usize| PI * r as f64 / map.height as f64;
                let phi = |c: usize| 2.0 * PI * c as f64 / map.width as f64;
                let mut omega = 0.0;
                resampler
                    .plan
                    .for_each_input(idx, map.width, sw as usize, |_, o, d| {
                        omega += f64::from(o);
                        let d = DVec3::from(d.map(f64::from));
                        let t = d.y.clamp(-1.0, 1.0).acos();
                        let p = (d.x.atan2(-d.z)).rem_euclid(2.0 * PI);
                        assert!(t >= theta(row) - 1e-6 && t <= theta(row + 1) + 1e-6, "{t}");
                        assert!(
                            p >= phi(column) - 1e-6 && p <= phi(column + 1) + 1e-6,
                            "{p}"
                        );
                    });
                let expected = map.row_solid_angle[row];
                assert!(
                    (omega / expected - 1.0).abs() < 1e-5,
                    "{sw}×{sh} {idx}: {omega}"
                );
            }
        }
        let (sw, sh) = (1000u32, 500u32);
        let clean: Vec<[f32; 3]> = (0..sw * sh)
            .map(|i| {
                let v = 0.1 + (i % 23) as f32 * 0.29;
                [v, 0.5 * v, 2.0 - 0.05 * v]
            })
            .collect();
        let (negative, nan, infinite) = (123_456, 250_777, 400_001);
        let mut dirty = clean.clone();
        dirty[negative][0] = -1.0;
        dirty[nan][1] = f32::NAN;
        dirty[infinite][2] = f32::INFINITY;
        let mut expected = clean;
        expected[negative][0] = 0.0;
        expected[nan][1] = 0.0;
        expected[infinite][2] = 0.0;
        let mut resampler = Resampler::new(Projection::LatLong, sw, sh, 256);
        let frame = HdrFrame::new(sw, sh, dirty, Projection::LatLong).unwrap();
        let map = resampler.resample(&frame, 1.0, None).clone();
        let touched = assert_plain_sums(&resampler.plan, &map, sw, &expected);
        assert_eq!(touched, 256 * 128);
    }
}
