//! A hierarchical warp from the unit square to an image: `HierarchicalWarp`.
//!
//! The image is split recursively in two along its longer side (a k-d tree down to single
//! pixels). At each node a point u ∈ \[0,1\]² goes to the child whose share of the node's mass
//! covers its coordinate along the split axis, and that coordinate is rescaled to the child
//! (McCool & Harwood's probability trees; Clarberg et al. 2005's hierarchical warping). Masses
//! come from a summed-area table in f64, so no tree is stored.
//!
//! Why: with a row-by-row inverse CDF ([`super::PiecewiseConstant2d`]) every point in a bright
//! source's rows depends on that source, so a sun moving within its row slides points far along
//! the row. Here a change of the map moves only the points whose tree paths see it change: a
//! source moving inside a node leaves every split above that node, and every point outside it,
//! untouched.

/// Hierarchical warp over a non-negative W×H weight image.
#[derive(Clone, Debug)]
pub struct HierarchicalWarp {
    width: usize,
    height: usize,
    /// (H+1)×(W+1) summed-area table: `sat[y][x]` = Σ weights over \[0,x)×\[0,y).
    sat: Vec<f64>,
}

impl HierarchicalWarp {
    /// Builds the warp from `width*height` weights, row-major; negative or non-finite weights
    /// count as 0.
    pub fn new(weights: &[f64], width: usize, height: usize) -> Self {
        assert_eq!(
            weights.len(),
            width * height,
            "weights must be width*height"
        );
        assert!(width > 0 && height > 0, "warp needs a non-empty image");
        let stride = width + 1;
        let mut sat = vec![0.0f64; stride * (height + 1)];
        for y in 0..height {
            let mut row_sum = 0.0;
            for x in 0..width {
                let w = weights[y * width + x];
                if w.is_finite() && w > 0.0 {
                    row_sum += w;
                }
                sat[(y + 1) * stride + x + 1] = sat[y * stride + x + 1] + row_sum;
            }
        }
        Self { width, height, sat }
    }

    #[inline]
    fn mass(&self, x0: usize, y0: usize, x1: usize, y1: usize) -> f64 {
        let s = self.width + 1;
        let m = self.sat[y1 * s + x1] - self.sat[y0 * s + x1] - self.sat[y1 * s + x0]
            + self.sat[y0 * s + x0];
        m.max(0.0)
    }

    /// Maps u ∈ \[0,1\]² to p = (x/W, y/H) ∈ \[0,1\]².
    pub fn sample(&self, u: [f64; 2]) -> [f64; 2] {
        let mut u = [u[0].clamp(0.0, 1.0), u[1].clamp(0.0, 1.0)];
        let (mut x0, mut y0, mut x1, mut y1) = (0, 0, self.width, self.height);
        while x1 - x0 > 1 || y1 - y0 > 1 {
            let split_x = x1 - x0 >= y1 - y0;
            let (axis, mid) = if split_x {
                (0, (x0 + x1) / 2)
            } else {
                (1, (y0 + y1) / 2)
            };
            let (first, second) = if split_x {
                (self.mass(x0, y0, mid, y1), self.mass(mid, y0, x1, y1))
            } else {
                (self.mass(x0, y0, x1, mid), self.mass(x0, mid, x1, y1))
            };
            let total = first + second;
            // An empty node splits by area, so the warp stays defined.
            let fraction = if total > 0.0 {
                first / total
            } else {
                let (lo, hi) = if split_x { (x0, x1) } else { (y0, y1) };
                (mid - lo) as f64 / (hi - lo) as f64
            };
            let go_first = u[axis] < fraction || fraction >= 1.0;
            if go_first {
                u[axis] = if fraction > 0.0 {
                    (u[axis] / fraction).min(1.0)
                } else {
                    0.5
                };
                if split_x {
                    x1 = mid
                } else {
                    y1 = mid
                }
            } else {
                u[axis] = ((u[axis] - fraction) / (1.0 - fraction)).clamp(0.0, 1.0);
                if split_x {
                    x0 = mid
                } else {
                    y0 = mid
                }
            }
        }
        [
            (x0 as f64 + u[0]) / self.width as f64,
            (y0 as f64 + u[1]) / self.height as f64,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_land_in_proportion_to_the_weights() {
        let (w, h) = (8, 4);
        let weights: Vec<f64> = (0..w * h).map(|i| ((i * 7) % 5) as f64).collect();
        let total: f64 = weights.iter().sum();
        let warp = HierarchicalWarp::new(&weights, w, h);
        let n = 400;
        let mut counts = vec![0usize; w * h];
        for j in 0..n {
            for i in 0..n {
                let p = warp.sample([(i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64]);
                let x = ((p[0] * w as f64) as usize).min(w - 1);
                let y = ((p[1] * h as f64) as usize).min(h - 1);
                counts[y * w + x] += 1;
            }
        }
        for (k, &c) in counts.iter().enumerate() {
            let expected = weights[k] / total;
            let got = c as f64 / (n * n) as f64;
            assert!(
                (got - expected).abs() < 0.01,
                "pixel {k}: {got} vs {expected}"
            );
            if weights[k] == 0.0 {
                assert_eq!(c, 0, "pixel {k} has no weight");
            }
        }
    }

    #[test]
    fn a_change_inside_one_half_leaves_the_other_half_alone() {
        let (w, h) = (16, 8);
        let mut weights = vec![1.0; w * h];
        weights[3 * w + 12] = 500.0;
        let before = HierarchicalWarp::new(&weights, w, h);
        weights[3 * w + 12] = 1.0;
        weights[3 * w + 13] = 500.0; // the bright pixel moves within the right half
        let after = HierarchicalWarp::new(&weights, w, h);
        let mut moved_left = 0;
        for j in 0..50 {
            for i in 0..50 {
                let u = [(i as f64 + 0.5) / 50.0, (j as f64 + 0.5) / 50.0];
                let (a, b) = (before.sample(u), after.sample(u));
                if a[0] < 0.5 && (a[0] - b[0]).abs() + (a[1] - b[1]).abs() > 1e-12 {
                    moved_left += 1;
                }
            }
        }
        assert_eq!(moved_left, 0);
    }

    #[test]
    fn empty_image_is_uniform() {
        let warp = HierarchicalWarp::new(&[0.0; 12], 4, 3);
        let p = warp.sample([0.3, 0.6]);
        assert!(p.iter().all(|c| (0.0..=1.0).contains(c)));
    }
}
