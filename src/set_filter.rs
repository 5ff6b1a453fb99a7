//! Temporal FIR filtering of dense sets — a frame's SH coefficients, a frame's octahedral map
//! before its wavelet transform — with the lights' taps, so that every representation the
//! daemon streams describes the same moment.
//!
//! The lights are filtered by [`crate::decompose::filter::FirFilter`]: with the default
//! binomial taps they lag the frames by 3 frames (100 ms at 30 frames/s). A set computed from
//! the newest frame alone would lead them by that much, and a client that shades with both
//! (lights for the key light and its shadows, an SH set for the ambient, say) would see the
//! two disagree whenever the light changes. The sets below are linear in the frame, so the
//! filter is exact here: the filtered set *is* the set of the filtered map,
//! `x̄(t) = Σ_k w_k x(t−k)` with the same normalised taps w (newest first) and the same delay.
//!
//! Steps of [`SetFilter::apply`], for the set of the frame numbered `number` (the decompose
//! thread's count of frames offered to the stage, [`crate::frame_feed::FedFrame::number`]):
//!
//! 1. **Start.** The first set, a set of another length (a new SH degree or map side), or a
//!    number that does not follow the last one (a restarted count) fills the whole window with
//!    this set — as the lights' filter does when an id appears — so the first output is the set
//!    itself and nothing stale leaks in.
//! 2. **Gaps.** A live stage that was busy skips frames (the feed keeps only the newest). The
//!    frames between the last set and this one are filled in by linear interpolation between
//!    the two, so the window stays one frame per decomposed frame, as the lights' is, and the
//!    delay stays the lights' delay in frames. (A linear ramp comes through a symmetric filter
//!    exactly delayed whether frames were skipped or not: tested.)
//! 3. **Sum.** The output is Σ_k w_k x(t−k) over the window, accumulated in f64.
//!
//! Memory: the window holds `taps × len` values (7 × 243 for a degree-8 SH set, 7 × 12,288
//! f32 for the default 64² wavelet map; a 1024² map with 7 taps takes 88 MB).

use crate::decompose::filter::FirFilter;

/// A value the filter can hold: f32 (octahedral map texels) or f64 (SH coefficients).
pub trait SetValue: Copy + Default + Send + 'static {
    fn to_f64(self) -> f64;
    fn from_f64(value: f64) -> Self;
}

impl SetValue for f32 {
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
    fn from_f64(value: f64) -> Self {
        // Sets are sums of finite pixels; a sum past f32 saturates rather than turning ∞.
        value.clamp(f64::from(f32::MIN), f64::from(f32::MAX)) as f32
    }
}

impl SetValue for f64 {
    fn to_f64(self) -> f64 {
        self
    }
    fn from_f64(value: f64) -> Self {
        value
    }
}

/// A FIR filter over a sequence of equally long sets. See the module documentation.
#[derive(Clone, Debug)]
pub struct SetFilter<T: SetValue> {
    /// Normalised taps, newest first.
    taps: Vec<f64>,
    /// The window: `taps.len()` sets of `len` values, slot `head` the newest.
    window: Vec<T>,
    len: usize,
    head: usize,
    /// The number of the newest set; `None` before the first.
    last: Option<u64>,
    /// Scratch for the sum.
    sum: Vec<f64>,
}

impl<T: SetValue> SetFilter<T> {
    /// A filter with `taps` (newest first), checked and normalised as the lights' filter does
    /// ([`FirFilter::new`]: 1..=64 finite, non-negative numbers, not all 0).
    pub fn new(taps: &[f64]) -> Result<Self, String> {
        let taps = FirFilter::new(taps)?.taps().to_vec();
        Ok(Self {
            taps,
            window: Vec::new(),
            len: 0,
            head: 0,
            last: None,
            sum: Vec::new(),
        })
    }

    /// The normalised taps, newest first.
    pub fn taps(&self) -> &[f64] {
        &self.taps
    }

    /// Group delay in frames, Σ k·w_k: the lights' ([`FirFilter::delay_frames`]) for the same
    /// taps.
    pub fn delay_frames(&self) -> f64 {
        crate::decompose::filter::group_delay(&self.taps)
    }

    /// Forgets the window: the next set starts it afresh.
    pub fn reset(&mut self) {
        self.last = None;
    }

    /// Replaces `values`, the set of frame `number`, by the filtered set (steps in the module
    /// documentation).
    pub fn apply(&mut self, number: u64, values: &mut [T]) {
        let n = self.taps.len();
        let len = values.len();
        let follows = match self.last {
            Some(last) if len == self.len => number.checked_sub(last).filter(|&gap| gap > 0),
            _ => None,
        };
        self.last = Some(number);
        let Some(gap) = follows else {
            self.len = len;
            self.head = 0;
            self.window.clear();
            for _ in 0..n {
                self.window.extend_from_slice(values);
            }
            return;
        };
        // The frames skipped since the last set, interpolated; only the newest n − 1 of them
        // can reach the window beside this set.
        let missing = gap - 1;
        let first_kept = missing.saturating_sub(n as u64 - 1) + 1;
        let previous = self.head;
        for j in first_kept..=missing {
            let t = j as f64 / gap as f64;
            let slot = (self.head + 1) % n;
            for i in 0..len {
                let a = self.window[previous * len + i].to_f64();
                let b = values[i].to_f64();
                self.window[slot * len + i] = T::from_f64(a + (b - a) * t);
            }
            self.head = slot;
        }
        self.head = (self.head + 1) % n;
        self.window[self.head * len..(self.head + 1) * len].copy_from_slice(values);

        self.sum.clear();
        self.sum.resize(len, 0.0);
        for (k, w) in self.taps.iter().enumerate() {
            let slot = (self.head + n - k) % n;
            let set = &self.window[slot * len..(slot + 1) * len];
            for (s, v) in self.sum.iter_mut().zip(set) {
                *s += w * v.to_f64();
            }
        }
        for (v, s) in values.iter_mut().zip(&self.sum) {
            *v = T::from_f64(*s);
        }
    }
}

/// A stage's filter in time (the SH and wavelet stages', and the ASG stage's lobe states,
/// [`crate::asg::temporal`]): a [`SetFilter`] where the settings
/// give taps, nothing otherwise, and the number of the next frame in the feed
/// ([`crate::slow_stage::StageWorker::frame_number`]), which counts up by one per set when
/// nobody says.
#[derive(Clone, Debug)]
pub struct StageFilter<T: SetValue> {
    filter: Option<SetFilter<T>>,
    next_number: u64,
}

impl<T: SetValue> StageFilter<T> {
    /// Filtering with `taps` (checked as [`SetFilter::new`] checks them), or not at all.
    pub fn new(taps: Option<&[f64]>) -> Result<Self, String> {
        Ok(Self {
            filter: taps.map(SetFilter::new).transpose()?,
            next_number: 0,
        })
    }

    /// Whether the sets are filtered (the settings gave taps).
    pub fn is_filtering(&self) -> bool {
        self.filter.is_some()
    }

    /// The delay in frames (0 without a filter).
    pub fn delay_frames(&self) -> f64 {
        self.filter.as_ref().map_or(0.0, SetFilter::delay_frames)
    }

    /// The number in the feed of the frame whose set comes next.
    pub fn set_next_number(&mut self, number: u64) {
        self.next_number = number;
    }

    /// Filters `values`, the next frame's set, in place (nothing without a filter).
    pub fn apply(&mut self, values: &mut [T]) {
        let number = self.next_number;
        self.next_number = number.wrapping_add(1);
        if let Some(filter) = &mut self.filter {
            filter.apply(number, values);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decompose::filter::DEFAULT_TAPS;

    fn default_filter() -> SetFilter<f64> {
        SetFilter::new(&DEFAULT_TAPS).unwrap()
    }

    #[test]
    fn a_constant_set_stays_constant_and_the_first_set_passes_unchanged() {
        let mut f = default_filter();
        for number in 0..20 {
            let mut set = vec![3.5, -1.25, 0.0];
            f.apply(number, &mut set);
            for (got, want) in set.iter().zip([3.5, -1.25, 0.0]) {
                assert!(
                    (got - want).abs() <= 1e-12,
                    "frame {number}: {got} vs {want}"
                );
            }
        }
    }

    /// A symmetric filter passes a linear ramp delayed by exactly its delay, once its window
    /// is full.
    #[test]
    fn a_ramp_comes_out_delayed_by_the_lights_delay() {
        let mut f = default_filter();
        assert_eq!(f.delay_frames(), 3.0);
        assert_eq!(
            f.delay_frames(),
            FirFilter::with_default_taps().delay_frames()
        );
        let ramp = |t: u64| vec![2.0 * t as f64 + 1.0, -0.5 * t as f64];
        for t in 0..30 {
            let mut set = ramp(t);
            f.apply(t, &mut set);
            if t >= 6 {
                let want = ramp(t - 3);
                for (g, w) in set.iter().zip(&want) {
                    assert!((g - w).abs() < 1e-9, "frame {t}: {set:?} vs {want:?}");
                }
            }
        }
    }

    /// Skipped frames are interpolated: on a ramp the output is the same whether the stage saw
    /// every frame or only some, including gaps longer than the window.
    #[test]
    fn skipped_frames_do_not_change_a_ramp_or_the_delay() {
        let ramp = |t: u64| vec![10.0 + t as f64 * 0.75; 4];
        for seen in [
            &[0u64, 1, 2, 5, 6, 7, 12, 13, 14, 15, 16, 18, 30, 31][..],
            &[0, 3, 6, 9, 12, 15, 18],
        ] {
            let mut f = default_filter();
            for &t in seen {
                let mut set = ramp(t);
                f.apply(t, &mut set);
                if t >= 6 {
                    assert!((set[0] - ramp(t - 3)[0]).abs() < 1e-9, "frame {t}: {set:?}");
                }
            }
        }
    }

    #[test]
    fn the_filter_is_the_weighted_sum_of_the_window() {
        let taps = [1.0, 2.0, 1.0];
        let mut f = SetFilter::<f32>::new(&taps).unwrap();
        let inputs = [4.0f32, 8.0, 0.0, 2.0];
        let mut out = Vec::new();
        for (t, &x) in inputs.iter().enumerate() {
            let mut set = [x];
            f.apply(t as u64, &mut set);
            out.push(set[0]);
        }
        // The window starts full of the first set.
        assert_eq!(out, [4.0, 5.0, 5.0, 2.5]);
    }

    #[test]
    fn a_new_length_or_a_restarted_count_starts_afresh() {
        let mut f = default_filter();
        for t in 0..10 {
            f.apply(t, &mut [1.0, 1.0]);
        }
        let mut longer = [5.0, 5.0, 5.0];
        f.apply(10, &mut longer);
        assert_eq!(longer, [5.0; 3], "another length: the set itself");
        let mut restarted = [7.0, 7.0, 7.0];
        f.apply(3, &mut restarted);
        assert_eq!(restarted, [7.0; 3], "a number that does not follow");
        let mut same = [7.0, 7.0, 7.0];
        f.apply(3, &mut same);
        assert_eq!(same, [7.0; 3], "the same number again");
        f.reset();
        let mut after_reset = [1.0, 2.0, 3.0];
        f.apply(4, &mut after_reset);
        assert_eq!(after_reset, [1.0, 2.0, 3.0]);
    }

    #[test]
    fn bad_taps_are_refused_as_the_lights_filter_refuses_them() {
        for taps in [&[][..], &[0.0, 0.0], &[1.0, -1.0], &[f64::NAN]] {
            let ours = SetFilter::<f64>::new(taps).err();
            let lights = FirFilter::new(taps).err();
            assert!(ours.is_some() && ours == lights, "{taps:?}");
        }
    }

    #[test]
    fn f32_sums_beyond_range_saturate() {
        let mut f = SetFilter::<f32>::new(&[1.0]).unwrap();
        let mut set = [f32::MAX, -f32::MAX];
        f.apply(0, &mut set);
        f.apply(1, &mut set);
        assert_eq!(set, [f32::MAX, -f32::MAX]);
        assert_eq!(f32::from_f64(1e300), f32::MAX);
    }
}
