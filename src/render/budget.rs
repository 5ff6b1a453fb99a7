//! Fixed frame budget: choose how many lights to render so a frame takes the configured time.
//!
//! The lights of a frame are used as a prefix of the progressive set (sorted by id), so fewer
//! lights still cover the sphere evenly (Havran et al. 2005 adapt the count the same way); the
//! dropped lights' power is merged into the prefix ([`super::light_prefix`]). The
//! controller is pure CPU logic, fed one measured frame time per frame (GPU timestamps, or CPU
//! wall time where the adapter has none), so it is tested with a simulated timer.
//!
//! Control law: a damped proportional controller on the logarithm of the time. With
//! e = ln(target / measured), the light count moves as ln n ← ln n + g·e (gain g = 0.5 by
//! default, each step at most ×2 or ×½). Frame time grows at most linearly with n, so the loop
//! gain on ln t is ≤ g < 1 and the count converges without overshoot. A hysteresis deadband
//! stops chatter: the controller starts adjusting only when |e| exceeds `deadband_out` (8%) and
//! stops once |e| falls below `deadband_in` (3%); inside the band the count is held.

/// Controller settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BudgetSettings {
    /// Target frame time in milliseconds.
    pub target_ms: f64,
    pub min_lights: usize,
    pub max_lights: usize,
    /// Proportional gain on ln(time), in (0, 1].
    pub gain: f64,
    /// Relative error (in ln) above which the controller starts adjusting.
    pub deadband_out: f64,
    /// Relative error (in ln) below which it stops adjusting.
    pub deadband_in: f64,
}

impl BudgetSettings {
    pub fn new(target_ms: f64, max_lights: usize) -> Self {
        Self {
            target_ms,
            min_lights: 1,
            max_lights: max_lights.max(1),
            gain: 0.5,
            deadband_out: 0.08,
            deadband_in: 0.03,
        }
    }
}

/// The controller's state.
#[derive(Clone, Debug)]
pub struct BudgetController {
    settings: BudgetSettings,
    log_count: f64,
    adjusting: bool,
    last_ms: Option<f64>,
}

impl BudgetController {
    /// Starts at `initial` lights (clamped to the settings' range).
    pub fn new(settings: BudgetSettings, initial: usize) -> Self {
        let n = initial.clamp(settings.min_lights.max(1), settings.max_lights.max(1));
        Self {
            settings,
            log_count: (n as f64).ln(),
            adjusting: true,
            last_ms: None,
        }
    }

    /// Light count to use for the next frame.
    pub fn count(&self) -> usize {
        let lo = self.settings.min_lights.max(1);
        let hi = self.settings.max_lights.max(lo);
        (self.log_count.exp().round() as usize).clamp(lo, hi)
    }

    /// The newest measured frame time (ms), if any.
    pub fn last_ms(&self) -> Option<f64> {
        self.last_ms
    }

    /// Feeds the time of the frame just rendered with [`Self::count`] lights; returns the count
    /// for the next frame. Non-finite or non-positive times are ignored.
    pub fn update(&mut self, measured_ms: f64) -> usize {
        if !(measured_ms.is_finite() && measured_ms > 0.0) {
            return self.count();
        }
        self.last_ms = Some(measured_ms);
        let s = &self.settings;
        let e = (s.target_ms / measured_ms).ln();
        if e.abs() > s.deadband_out {
            self.adjusting = true;
        } else if e.abs() < s.deadband_in {
            self.adjusting = false;
        }
        if self.adjusting {
            let step = (s.gain * e).clamp(-std::f64::consts::LN_2, std::f64::consts::LN_2);
            let lo = (s.min_lights.max(1) as f64).ln();
            let hi = (s.max_lights.max(1) as f64).ln();
            self.log_count = (self.log_count + step).clamp(lo, hi.max(lo));
        }
        self.count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A simulated frame timer: fixed cost + per-light cost, with deterministic ±`noise` jitter.
    struct SimTimer {
        fixed_ms: f64,
        per_light_ms: f64,
        noise: f64,
        state: u64,
    }

    impl SimTimer {
        fn frame(&mut self, n: usize) -> f64 {
            // xorshift64*: uniform in [-1, 1).
            self.state ^= self.state >> 12;
            self.state ^= self.state << 25;
            self.state ^= self.state >> 27;
            let r =
                (self.state.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64;
            (self.fixed_ms + self.per_light_ms * n as f64) * (1.0 + self.noise * (2.0 * r - 1.0))
        }
    }

    fn run(timer: &mut SimTimer, ctl: &mut BudgetController, frames: usize) -> Vec<(usize, f64)> {
        (0..frames)
            .map(|_| {
                let n = ctl.count();
                let t = timer.frame(n);
                ctl.update(t);
                (n, t)
            })
            .collect()
    }

    /// Number of times the count reverses its direction of change.
    fn reversals(counts: &[usize]) -> usize {
        let steps: Vec<i64> = counts
            .windows(2)
            .map(|w| w[1] as i64 - w[0] as i64)
            .filter(|&d| d != 0)
            .collect();
        steps
            .windows(2)
            .filter(|w| w[0].signum() != w[1].signum())
            .count()
    }

    #[test]
    fn converges_within_ten_percent_without_oscillating() {
        for (initial, fixed, per_light) in [(16, 1.0, 0.05), (512, 2.0, 0.1), (1, 0.5, 0.02)] {
            let target = 8.0;
            let mut timer = SimTimer {
                fixed_ms: fixed,
                per_light_ms: per_light,
                noise: 0.0,
                state: 0x9e37_79b9_7f4a_7c15,
            };
            let mut ctl = BudgetController::new(BudgetSettings::new(target, 1024), initial);
            let trace = run(&mut timer, &mut ctl, 60);
            let ideal = (target - fixed) / per_light;
            let (n_end, t_end) = *trace.last().unwrap();
            assert!(
                (t_end / target - 1.0).abs() < 0.10,
                "start {initial}: ends at {t_end} ms with {n_end} lights (ideal {ideal})"
            );
            // Converged within 20 frames and held still afterwards (no limit cycle).
            let tail: Vec<usize> = trace[20..].iter().map(|p| p.0).collect();
            assert!(tail.iter().all(|&n| n == tail[0]), "{tail:?}");
            // Monotone approach: the count never reverses direction.
            let counts: Vec<usize> = trace.iter().map(|p| p.0).collect();
            assert_eq!(reversals(&counts), 0, "{counts:?}");
        }
    }

    #[test]
    fn holds_steady_under_noise_and_follows_a_load_change() {
        let target = 8.0;
        let mut timer = SimTimer {
            fixed_ms: 1.0,
            per_light_ms: 0.04,
            noise: 0.04,
            state: 12345,
        };
        let mut ctl = BudgetController::new(BudgetSettings::new(target, 4096), 32);
        let trace = run(&mut timer, &mut ctl, 200);
        let tail = &trace[40..];
        let mean_t: f64 = tail.iter().map(|p| p.1).sum::<f64>() / tail.len() as f64;
        assert!((mean_t / target - 1.0).abs() < 0.10, "mean {mean_t} ms");
        // ±4% timer noise inside the deadband: the count barely moves.
        let counts: Vec<usize> = tail.iter().map(|p| p.0).collect();
        assert!(reversals(&counts) <= 4, "{counts:?}");
        let (lo, hi) = (counts.iter().min().unwrap(), counts.iter().max().unwrap());
        assert!(
            (*hi as f64) < 1.15 * (*lo as f64),
            "count wanders {lo}..{hi}"
        );

        // The scene gets twice as expensive per light: the count halves, roughly.
        let before = *counts.last().unwrap();
        timer.per_light_ms *= 2.0;
        let trace = run(&mut timer, &mut ctl, 60);
        let after = trace.last().unwrap().0;
        let ratio = after as f64 / before as f64;
        assert!((0.4..0.6).contains(&ratio), "{before} → {after}");
        let mean_t: f64 = trace[30..].iter().map(|p| p.1).sum::<f64>() / 30.0;
        assert!((mean_t / target - 1.0).abs() < 0.10, "mean {mean_t} ms");
    }

    #[test]
    fn clamps_and_ignores_bad_times() {
        let mut ctl = BudgetController::new(BudgetSettings::new(8.0, 64), 1000);
        assert_eq!(ctl.count(), 64);
        // Far under budget at the maximum: stays at the maximum.
        assert_eq!(ctl.update(0.1), 64);
        assert_eq!(ctl.update(f64::NAN), 64);
        assert_eq!(ctl.update(-1.0), 64);
        // Far over budget: at most halves per frame, never below 1.
        assert_eq!(ctl.update(1000.0), 32);
        for _ in 0..20 {
            ctl.update(1000.0);
        }
        assert_eq!(ctl.count(), 1);
        assert_eq!(ctl.last_ms(), Some(1000.0));
    }
}
