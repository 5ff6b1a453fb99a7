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

    /// Exact solid angles of rectangles of a `width`×`height` image (sub-pixels, pieces of
    /// pixels): [`RectangleSolidAngles::of`].
    pub fn rectangle_solid_angles(&self, width: u32, height: u32) -> RectangleSolidAngles {
        let radial = match self {
            Projection::LatLong => {
                return RectangleSolidAngles(Rectangles::LatLong { width, height });
            }
            Projection::Fisheye(cal) => fisheye::fisheye_map(cal, width, height),
            Projection::AngularMap => fisheye::angular_map(width, height),
        };
        RectangleSolidAngles(radial.map_or(Rectangles::Nothing, Rectangles::Radial))
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

/// Exact solid angles of rectangles of one image ([`Projection::rectangle_solid_angles`]).
#[derive(Clone, Debug)]
pub struct RectangleSolidAngles(Rectangles);

#[derive(Clone, Debug)]
enum Rectangles {
    LatLong {
        width: u32,
        height: u32,
    },
    Radial(fisheye::RadialMap),
    /// An image that sees nothing (a calibration that does not resolve for it).
    Nothing,
}

impl RectangleSolidAngles {
    /// The solid angle (steradians) of the part of the image rectangle from `top_left` to
    /// `bottom_right` (continuous pixel positions) that sees directions: of a whole pixel,
    /// what [`Projection::solid_angles`] gives it (a lens's to about 1e-9 relative: the
    /// integrals along its edges are taken to that); 0 for an empty or non-finite rectangle.
    pub fn of(&self, top_left: (f64, f64), bottom_right: (f64, f64)) -> f64 {
        let ((x0, y0), (x1, y1)) = (top_left, bottom_right);
        if ![x0, y0, x1, y1].iter().all(|v| v.is_finite()) {
            return 0.0;
        }
        match &self.0 {
            Rectangles::LatLong { width, height } => {
                latlong::rectangle_solid_angle(*width, *height, top_left, bottom_right)
            }
            Rectangles::Radial(map) => map.rectangle_solid_angle(top_left, bottom_right),
            Rectangles::Nothing => 0.0,
        }
    }

    /// The solid angles of the cells of the grid with column edges `xs` and row edges `ys`
    /// (increasing, continuous pixel positions), row-major into `out` ((`xs.len()` − 1) ×
    /// (`ys.len()` − 1) values): each what [`RectangleSolidAngles::of`] gives its cell, to the
    /// bit, but a lens's edges shared by two cells are integrated once (half the edge integrals of
    /// asking cell by cell; the sub-pixels of a coarse frame's pixels, `SplitPixel::parts`).
    pub fn grid(&self, xs: &[f64], ys: &[f64], out: &mut Vec<f64>) {
        out.clear();
        let cells = xs.len().saturating_sub(1) * ys.len().saturating_sub(1);
        let finite = xs.iter().chain(ys).all(|v| v.is_finite());
        match &self.0 {
            Rectangles::Radial(map) if finite => map.grid_solid_angles(xs, ys, out),
            _ => {
                for y in ys.windows(2) {
                    for x in xs.windows(2) {
                        out.push(self.of((x[0], y[0]), (x[1], y[1])));
                    }
                }
            }
        }
        debug_assert_eq!(out.len(), cells);
    }

    /// A point of the image rectangle from `top_left` to `bottom_right` that sees a direction,
    /// if any does (and the rectangle is valid): for a lens or the angular map, the point
    /// nearest the image circle's centre, which is inside the circle wherever any point of
    /// the rectangle is (a sliver of the circle through a pixel's side, between two corners
    /// outside it, has one); for a lat-long map, the rectangle's centre.
    pub fn point_inside(
        &self,
        top_left: (f64, f64),
        bottom_right: (f64, f64),
    ) -> Option<(f64, f64)> {
        let ((x0, y0), (x1, y1)) = (top_left, bottom_right);
        if ![x0, y0, x1, y1].iter().all(|v| v.is_finite()) || x0 > x1 || y0 > y1 {
            return None;
        }
        match &self.0 {
            Rectangles::LatLong { .. } => Some(((x0 + x1) / 2.0, (y0 + y1) / 2.0)),
            Rectangles::Radial(map) => map.nearest_point_inside(top_left, bottom_right),
            Rectangles::Nothing => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rectangle's solid angle is what `solid_angles` gives a pixel, the sub-rectangles of
    /// a pixel sum to it, and the whole image's is the image's total, for every projection
    /// (rim pixels of the lenses included, where the circle cuts the rectangle).
    #[test]
    fn rectangle_solid_angles_agree_with_the_pixels_and_add_up() {
        let lens = |model, fov_deg| {
            Projection::Fisheye(FisheyeCalibration {
                model,
                fov_deg,
                rotation_deg: 30.0,
                ..FisheyeCalibration::default()
            })
        };
        let mut projections = vec![Projection::LatLong, Projection::AngularMap];
        for model in FisheyeModel::ALL {
            projections.push(lens(model, 180.0));
        }
        projections.push(lens(FisheyeModel::Equisolid, 300.0));
        projections.push(lens(FisheyeModel::Stereographic, 250.0));
        let (w, h) = (23u32, 17u32);
        for projection in projections {
            let pixels = projection.solid_angles(w, h);
            let rectangles = projection.rectangle_solid_angles(w, h);
            let whole = rectangles.of((0.0, 0.0), (f64::from(w), f64::from(h)));
            let total: f64 = pixels.iter().sum();
            assert!((whole - total).abs() <= 1e-12 * total, "{projection:?}");
            for y in 0..h {
                for x in 0..w {
                    let (x0, y0) = (f64::from(x), f64::from(y));
                    let pixel = pixels[(y * w + x) as usize];
                    let omega = rectangles.of((x0, y0), (x0 + 1.0, y0 + 1.0));
                    assert!(
                        (omega - pixel).abs() <= 1e-12 * total / f64::from(w * h),
                        "{projection:?} ({x}, {y}): {omega} vs {pixel}"
                    );
                    let mut sum = 0.0;
                    for j in 0..5 {
                        for i in 0..3 {
                            let (u, v) = (x0 + f64::from(i) / 3.0, y0 + f64::from(j) / 5.0);
                            sum += rectangles.of((u, v), (u + 1.0 / 3.0, v + 0.2));
                        }
                    }
                    assert!(
                        (sum - pixel).abs() <= 1e-11 * total / f64::from(w * h),
                        "{projection:?} ({x}, {y}): sub-rectangles {sum} vs {pixel}"
                    );
                }
            }
            // The grid's cells are what `of` gives each, to the bit (uneven cells, some
            // across the image circle, one empty).
            let xs: Vec<f64> = (0..=3 * w)
                .map(|i| f64::from(i) / 3.0 + 0.01 * f64::from(i % 2))
                .chain([f64::from(w) + 0.5, f64::from(w) + 0.5])
                .collect();
            let ys: Vec<f64> = (0..=2 * h + 1).map(|j| f64::from(j) / 2.0 - 0.3).collect();
            let mut grid = Vec::new();
            rectangles.grid(&xs, &ys, &mut grid);
            assert_eq!(grid.len(), (xs.len() - 1) * (ys.len() - 1));
            for (j, y) in ys.windows(2).enumerate() {
                for (i, x) in xs.windows(2).enumerate() {
                    let cell = grid[j * (xs.len() - 1) + i];
                    let expected = rectangles.of((x[0], y[0]), (x[1], y[1]));
                    assert_eq!(cell.to_bits(), expected.to_bits(), "{projection:?} {i} {j}");
                }
            }
            let sum: f64 = grid.iter().sum();
            assert!(
                (sum - total).abs() <= 1e-11 * total,
                "{projection:?}: {sum} vs {total}"
            );
        }
        // A sliver of the image circle through a pixel's side, both of the side's corners
        // outside it: the point found is inside, and in the pixel.
        let lens = Projection::Fisheye(FisheyeCalibration {
            model: FisheyeModel::Stereographic,
            center: Some([0.005, 1.175]),
            ..FisheyeCalibration::default()
        });
        let rectangles = lens.rectangle_solid_angles(2, 5);
        assert!(lens.pixel_to_direction(2, 5, 1.0, 1.0).is_none());
        assert!(lens.pixel_to_direction(2, 5, 1.0, 2.0).is_none());
        assert!(rectangles.of((1.0, 1.0), (2.0, 2.0)) > 0.0);
        let (u, v) = rectangles.point_inside((1.0, 1.0), (2.0, 2.0)).unwrap();
        assert!((1.0..=2.0).contains(&u) && (1.0..=2.0).contains(&v));
        assert!(lens.pixel_to_direction(2, 5, u, v).is_some());
        assert_eq!(rectangles.point_inside((1.5, 3.0), (2.0, 5.0)), None);
        let nothing = Projection::LatLong.rectangle_solid_angles(4, 2);
        assert_eq!(nothing.of((1.0, 1.0), (1.0, 2.0)), 0.0);
        assert_eq!(nothing.of((f64::NAN, 0.0), (1.0, 2.0)), 0.0);
    }
}
