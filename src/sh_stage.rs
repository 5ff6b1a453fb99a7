//! The daemon's spherical-harmonics stage (`[sh]`): the newest frames projected onto the real
//! SH basis up to a degree ([`crate::sh`]), computed on their own thread and published on a
//! latest-value channel for the stream server (representation 3, docs/protocol.md).
//!
//! ```text
//! envlight-decompose ──FrameFeed (one slot, newest wins)──► envlight-sh ──watch──► stream server
//!   (after publishing its lights)                          (ShProjector)   Latest<ShFrame>
//! ```
//!
//! Per frame, [`ShProjector::project`]: take the projection plan of the frame's shape (built
//! once per size and projection, [`crate::sh::Projector`]; [`ShStats::plans`] counts them),
//! sum the pixels against the basis in f64, round to f32 and check the set as the wire would
//! ([`validate_sh_set`]). Deterministic, so what a client receives equals
//! [`crate::sh::project`] of the same frame, bit for bit, and a replay reproduces it.
//!
//! **In time.** With [`ShSettings::filter_taps`] (the daemon passes `[decompose]`'s taps unless
//! `[sh] filter = false`) each set is then filtered with the lights' FIR taps
//! ([`crate::set_filter`]): the set is linear in the frame, so the filtered set is the set of
//! the filtered map, it lags the frames by the lights' delay (3 frames by default) and
//! describes the same moment as the lights of the same seq (their ∫L dω agree, tested).
//! Frames the stage skipped while busy are filled in by interpolation, so the delay stays the
//! lights' in frames. A replay feeds every frame, so it still reproduces the stream.
//!
//! The thread is the generic runner of [`crate::slow_stage`], shared with the ASG and wavelet
//! stages: the decompose thread offers each frame after publishing its lights, a live feed keeps
//! only the newest (skips counted), a lossless feed (replay) makes every frame projected in
//! order; [`DaemonStage::reconfigure`] (SIGHUP) swaps the degree before the next frame (a new
//! plan); [`DaemonStage::join`] turns a panic into an error.

use crate::frame::HdrFrame;
use crate::publication::{Latest, StaleHandle};
use crate::set_filter::StageFilter;
use crate::sh::{Projector, MAX_DEGREE};
use crate::slow_stage::{
    DaemonStage, PublishHook, SetStageStats, StageKind, StageStatsHandle, StageWorker,
};
use crate::stream::protocol::{validate_sh_set, ShFrame};

/// Name of the SH thread.
pub const SH_THREAD_NAME: &str = "envlight-sh";

/// Default degree: 2, the nine coefficients per channel of irradiance environment maps
/// (Ramamoorthi & Hanrahan 2001) and of engines' light probes.
pub const DEFAULT_DEGREE: usize = 2;

/// What the stage computes.
#[derive(Clone, Debug, PartialEq)]
pub struct ShSettings {
    /// The highest band, 0..=[`MAX_DEGREE`]: (degree + 1)² coefficients per channel.
    pub degree: usize,
    /// FIR taps (newest first) that filter the sets in time, the lights' taps
    /// ([`crate::decompose::DecomposeSettings::filter_taps`]); `None`: each frame's own set.
    pub filter_taps: Option<Vec<f64>>,
}

impl Default for ShSettings {
    /// Degree [`DEFAULT_DEGREE`], filtered with the lights' default taps.
    fn default() -> Self {
        Self {
            degree: DEFAULT_DEGREE,
            filter_taps: Some(crate::decompose::filter::DEFAULT_TAPS.to_vec()),
        }
    }
}

impl ShSettings {
    /// Checks every field (the error names the field and the value).
    pub fn validate(&self) -> Result<(), ShStageError> {
        if self.degree > MAX_DEGREE {
            return Err(ShStageError::Settings {
                field: "degree",
                value: self.degree.to_string(),
                rule: format!("an integer in 0..={MAX_DEGREE}"),
            });
        }
        self.filter()?;
        Ok(())
    }

    /// The temporal filter the settings ask for.
    fn filter(&self) -> Result<StageFilter<f64>, ShStageError> {
        StageFilter::new(self.filter_taps.as_deref()).map_err(|rule| ShStageError::Settings {
            field: "filter_taps",
            value: format!("{:?}", self.filter_taps.as_deref().unwrap_or_default()),
            rule,
        })
    }
}

/// Errors of the SH stage.
#[derive(Debug, thiserror::Error)]
pub enum ShStageError {
    #[error("invalid [sh] setting {field} = {value}: must be {rule}")]
    Settings {
        field: &'static str,
        value: String,
        rule: String,
    },
    #[error("frame {seq}: the SH set would not be accepted on the wire: {source}")]
    Invalid {
        seq: u64,
        #[source]
        source: crate::stream::ProtocolError,
    },
    #[error("cannot start thread {SH_THREAD_NAME}: {0}")]
    Spawn(#[source] std::io::Error),
    #[error("thread {SH_THREAD_NAME} panicked: {0}")]
    Panicked(String),
}

/// Frames to SH sets, with the projection plan kept from frame to frame and, if the settings
/// ask, the temporal filter's window.
pub struct ShProjector {
    settings: ShSettings,
    plan: Option<Projector>,
    plans: u64,
    filter: StageFilter<f64>,
}

impl ShProjector {
    /// A projector with validated `settings`.
    pub fn new(settings: ShSettings) -> Result<Self, ShStageError> {
        settings.validate()?;
        let filter = settings.filter()?;
        Ok(Self {
            settings,
            plan: None,
            plans: 0,
            filter,
        })
    }

    /// The temporal filter's delay in frames (0 without one).
    pub fn delay_frames(&self) -> f64 {
        self.filter.delay_frames()
    }

    /// The settings.
    pub fn settings(&self) -> &ShSettings {
        &self.settings
    }

    /// Projection plans built so far (one per frame shape met, again after a shape change).
    pub fn plans(&self) -> u64 {
        self.plans
    }

    /// The set of `frame`, filtered in time if the settings ask: frames are taken to follow
    /// one another unless [`StageWorker::frame_number`] says how many were skipped.
    pub fn project(&mut self, frame: &HdrFrame) -> Result<ShFrame, ShStageError> {
        let set = self.coefficients(frame);
        let sh = ShFrame::new(frame.seq, frame.time, &set);
        validate_sh_set(&sh.coefficients).map_err(|source| ShStageError::Invalid {
            seq: frame.seq,
            source,
        })?;
        Ok(sh)
    }

    /// The coefficients of `frame` in f64, before the wire's rounding (the renderer's
    /// `--lighting sh`), with the plan and the filter kept as for [`ShProjector::project`].
    pub fn coefficients(&mut self, frame: &HdrFrame) -> crate::sh::ShCoefficients {
        let plan = match self.plan.take() {
            Some(plan) if plan.fits(frame) => plan,
            _ => {
                self.plans += 1;
                Projector::new(
                    self.settings.degree,
                    frame.width,
                    frame.height,
                    frame.projection,
                )
            }
        };
        let set = plan.project(frame);
        self.plan = Some(plan);
        // The plan was built for this frame's shape, so it always projects it.
        let mut set = set.unwrap_or_else(|| crate::sh::ShCoefficients::zero(self.settings.degree));
        self.filter.apply(set.values_mut());
        set
    }
}

impl StageWorker for ShProjector {
    type Output = ShFrame;
    type Error = ShStageError;

    fn process(&mut self, frame: &HdrFrame) -> Result<ShFrame, ShStageError> {
        self.project(frame)
    }

    fn plans(&self) -> u64 {
        self.plans
    }

    fn frame_number(&mut self, number: u64) {
        self.filter.set_next_number(number);
    }

    /// New settings keep the projection plan when the degree is unchanged (it depends on the
    /// frame's shape and the degree alone); everything else is the new worker's.
    fn take_over(&mut self, new: Self) {
        let plan = self
            .plan
            .take()
            .filter(|plan| plan.degree() == new.settings.degree);
        let plans = self.plans;
        *self = new;
        self.plan = plan;
        self.plans = plans;
    }
}

impl StageKind for ShProjector {
    type Settings = ShSettings;
    type Stats = ShStats;
    type SettingsError = ShStageError;
    type StageError = ShStageError;
    const THREAD_NAME: &'static str = SH_THREAD_NAME;

    fn from_settings(settings: ShSettings) -> Result<Self, ShStageError> {
        Self::new(settings)
    }

    fn log_start(&self, lossless: bool) {
        tracing::info!(
            degree = self.settings.degree,
            filter_delay_frames = self.delay_frames(),
            lossless,
            "starting the SH stage"
        );
    }

    fn spawn_error(error: std::io::Error) -> ShStageError {
        ShStageError::Spawn(error)
    }

    fn panic_error(message: String) -> ShStageError {
        ShStageError::Panicked(message)
    }
}

/// One publication of the SH stage: the set is the
/// [`Publication::payload`](crate::publication::Publication::payload), `compute_time` the
/// projection's.
pub type PublishedSh = crate::publication::Publication<ShFrame>;

/// What SH consumers receive: the newest publication, `None` until the first one.
pub type LatestSh = Latest<ShFrame>;

/// Marks the newest SH set stale; see [`DaemonStage::mark_stale`].
pub type ShStaleHandle = StaleHandle<ShFrame>;

/// Called on the SH thread after each published set (metrics).
pub type ShHook = PublishHook<ShFrame>;

/// Counters of the SH stage (errors: values beyond f32; plans: one per frame size and projection
/// met; `last_time`: the most recent projection).
pub type ShStats = SetStageStats;

/// The running SH stage ([`DaemonStage`]: start, feed, subscribe, reconfigure, join). See
/// the module documentation.
pub type ShStage = DaemonStage<ShProjector>;

/// Reads the stage's counters; valid after the stage has ended.
pub type ShStatsHandle = StageStatsHandle<ShProjector>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::envmap::Projection;
    use crate::frame_feed::CloseOnDrop;
    use crate::set_filter::SetFilter;
    use std::sync::Arc;

    fn frame(seq: u64, width: u32) -> HdrFrame {
        let height = width / 2;
        let pixels = (0..width * height)
            .map(|i| {
                let v = 0.1 + ((i * 13 + seq as u32 * 5) % 17) as f32;
                [v, 0.5 * v, 0.25 * v]
            })
            .collect();
        let mut f = HdrFrame::new(width, height, pixels, Projection::LatLong).unwrap();
        f.seq = seq;
        f.time = seq as f64 / 30.0;
        f
    }

    #[test]
    fn the_projector_equals_the_library_and_plans_once_per_shape() {
        let mut p = ShProjector::new(ShSettings {
            degree: 3,
            filter_taps: None,
        })
        .unwrap();
        for (seq, width) in [(0, 32), (1, 32), (2, 32), (3, 64), (4, 64)] {
            let f = frame(seq, width);
            let got = p.project(&f).unwrap();
            let want = ShFrame::new(seq, f.time, &crate::sh::project(&f, 3));
            assert_eq!(got, want, "seq {seq}");
            assert_eq!(got.degree(), Some(3));
        }
        assert_eq!(p.plans(), 2, "one plan per frame size");
    }

    /// New settings of the same degree keep the projection plan; a new degree makes a new
    /// one. Each set is the new settings' all the same.
    #[test]
    fn a_reconfiguration_keeps_the_plan_while_the_degree_stays() {
        let unfiltered = ShSettings {
            degree: 2,
            filter_taps: None,
        };
        let mut p = ShProjector::new(unfiltered.clone()).unwrap();
        p.project(&frame(0, 32)).unwrap();
        let filtered = ShSettings {
            filter_taps: Some(crate::decompose::filter::DEFAULT_TAPS.to_vec()),
            ..unfiltered
        };
        p.take_over(ShProjector::new(filtered.clone()).unwrap());
        let got = p.project(&frame(1, 32)).unwrap();
        let mut fresh = ShProjector::new(filtered).unwrap();
        assert_eq!(got, fresh.project(&frame(1, 32)).unwrap());
        assert_eq!(p.plans(), 1, "the plan kept");
        let higher = ShSettings {
            degree: 3,
            filter_taps: None,
        };
        p.take_over(ShProjector::new(higher.clone()).unwrap());
        let got = p.project(&frame(2, 32)).unwrap();
        let mut fresh = ShProjector::new(higher).unwrap();
        assert_eq!(got, fresh.project(&frame(2, 32)).unwrap());
        assert_eq!(p.plans(), 2, "a new plan for the new degree");
    }

    /// Filtered, the stage's set is the library's set of each frame through the lights' FIR
    /// taps, with the frames the stage skipped (a gap in the feed's numbers) filled in.
    #[test]
    fn the_filtered_projector_is_the_library_through_the_set_filter() {
        let taps = crate::decompose::filter::DEFAULT_TAPS;
        let mut p = ShProjector::new(ShSettings {
            degree: 2,
            filter_taps: Some(taps.to_vec()),
        })
        .unwrap();
        assert_eq!(p.delay_frames(), 3.0);
        let mut reference = SetFilter::<f64>::new(&taps).unwrap();
        let mut differs = false;
        for number in [0u64, 1, 2, 4, 5, 9, 10, 11] {
            let f = frame(number, 32);
            p.frame_number(number);
            let got = p.project(&f).unwrap();
            let mut want = crate::sh::project(&f, 2);
            let unfiltered = ShFrame::new(number, f.time, &want);
            reference.apply(number, want.values_mut());
            assert_eq!(got, ShFrame::new(number, f.time, &want), "frame {number}");
            differs |= got != unfiltered;
        }
        assert!(
            differs,
            "the frames change, so filtering must change the sets"
        );
    }

    #[test]
    fn bad_filter_taps_are_refused_by_name() {
        let e = ShProjector::new(ShSettings {
            degree: 2,
            filter_taps: Some(vec![1.0, -2.0]),
        })
        .err()
        .unwrap();
        assert!(
            e.to_string().contains("filter_taps = [1.0, -2.0]")
                && e.to_string().contains("negative"),
            "{e}"
        );
    }

    #[test]
    fn a_degree_above_the_highest_is_refused_by_name() {
        let settings = ShSettings {
            degree: 16,
            ..ShSettings::default()
        };
        match ShStage::start(settings, false, None) {
            Err(
                e @ ShStageError::Settings {
                    field: "degree", ..
                },
            ) => {
                assert!(e.to_string().contains("degree = 16"), "{e}")
            }
            other => panic!("{:?}", other.err()),
        }
        assert!(ShSettings::default().validate().is_ok());
        assert!(ShSettings {
            degree: 0,
            filter_taps: None
        }
        .validate()
        .is_ok());
    }

    #[test]
    fn coefficients_beyond_f32_saturate() {
        // Radiance near f32::MAX over a whole map sums past f32: the coefficients saturate,
        // which the wire accepts (finite); a NaN cannot arise (non-finite pixels count as 0).
        let mut f = frame(0, 32);
        for p in &mut f.pixels {
            *p = [f32::MAX; 3];
        }
        let set = ShProjector::new(ShSettings::default())
            .unwrap()
            .project(&f)
            .unwrap();
        assert!(set.coefficients.iter().flatten().all(|v| v.is_finite()));
        assert_eq!(set.coefficients[0], [f32::MAX; 3]);
    }

    #[test]
    fn lossless_stage_projects_every_frame_and_stale_republishes() {
        let stage = ShStage::start(ShSettings::default(), true, None).unwrap();
        let mut rx = stage.subscribe();
        let feed = stage.feed();
        let sender = std::thread::Builder::new()
            .name("test-feeder".into())
            .spawn(move || {
                let _close = CloseOnDrop(feed.clone());
                for seq in 0..6 {
                    feed.offer(frame(seq, 32));
                }
            })
            .unwrap();
        let mut seen = Vec::new();
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        rt.block_on(async {
            while rx.changed().await.is_ok() {
                let p = rx.borrow_and_update().clone().unwrap();
                let last = p.payload.seq == 5;
                seen.push(p);
                if last {
                    break;
                }
            }
        });
        sender.join().unwrap();
        let live = stage.subscribe().borrow().clone().unwrap();
        assert!(stage.mark_stale());
        let stale = stage.subscribe().borrow().clone().unwrap();
        assert!(stale.stale && Arc::ptr_eq(&stale.payload, &live.payload));
        let stats = stage.join().unwrap();
        assert_eq!(
            (stats.frames_offered, stats.frames_skipped, stats.sets),
            (6, 0, 6)
        );
        assert_eq!((stats.errors, stats.plans), (0, 1));
        // Every frame in order through a projector of its own (filtered: each set depends on
        // the frames before it), compared where the receiver looked (it may skip sets).
        let mut p = ShProjector::new(ShSettings::default()).unwrap();
        let want: Vec<ShFrame> = (0..6)
            .map(|seq| p.project(&frame(seq, 32)).unwrap())
            .collect();
        for published in &seen {
            assert_eq!(*published.payload, want[published.payload.seq as usize]);
        }
        assert_eq!(live.index, 6, "every set was published");
    }
}
