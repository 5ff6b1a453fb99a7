//! Daemon metrics in the Prometheus text format, and the health verdict.
//!
//! [`Metrics`] owns a `prometheus_client` registry. Counters that the pipeline keeps itself
//! (frames captured, dropped, decomposed, source errors) are copied from
//! [`PipelineStats`] when the endpoint is scraped ([`Metrics::update_pipeline`]), so they are
//! exact at that moment; the stream server counts clients, frames sent and frames skipped as
//! they happen; latencies go into histograms:
//!
//! | metric | kind | meaning |
//! |---|---|---|
//! | `envlight_frames_captured_total` | counter | frames the source delivered |
//! | `envlight_frames_dropped_total` | counter | frames dropped because the decomposition was behind |
//! | `envlight_frames_decomposed_total` | counter | light lists published |
//! | `envlight_capture_errors_total` | counter | source errors |
//! | `envlight_lights` | gauge | lights in the newest light list |
//! | `envlight_filter_delay_frames` | gauge | the lights' temporal filter's delay in frames (Σ k·w_k; 0 unfiltered), shared by the filtered wavelet and SH sets |
//! | `envlight_source_stale` | gauge | 1 while the newest lights are stale (source lost) |
//! | `envlight_source_failures_total` | counter | times a live source (camera) was lost |
//! | `envlight_source_reconnect_attempts_total` | counter | attempts to reopen a lost source |
//! | `envlight_decompose_seconds` | histogram | decomposition time per frame |
//! | `envlight_delivery_seconds` | histogram | frame reaches the decomposition → last byte written to a client |
//! | `envlight_clients_connected` | gauge | clients connected, by endpoint |
//! | `envlight_client_frames_sent_total` | counter | frames written to clients, by endpoint |
//! | `envlight_client_frames_skipped_total` | counter | frames a slow client skipped, by endpoint |
//! | `envlight_client_skipped_frames` | gauge | frames skipped so far, per connected client |
//! | `envlight_client_errors_total` | counter | connections closed for a protocol error or a timeout, by endpoint |
//! | `envlight_pass_shares_total` | counter | shares of a pass written by an `envlight-pass` thread (`stream.pass_threads`) |
//! | `envlight_pass_shares_returned_total` | counter | shares the passing thread wrote itself because their `envlight-pass` thread was still busy |
//! | `envlight_frames_rendered_total` | counter | frames the render thread drew (`[render] enabled`) |
//! | `envlight_render_seconds` | histogram | render time per frame |
//! | `envlight_render_lights` | gauge | lights used by the newest rendered frame |
//!
//! The per-client gauge is removed when the client disconnects, so its cardinality is bounded
//! by the client limit.

use crate::pipeline::PipelineStats;
use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::Histogram;
use prometheus_client::registry::Registry;
use std::sync::atomic::Ordering;
use std::time::Duration;

/// Label of the per-endpoint families: `endpoint="uds"|"tcp"|"websocket"`.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct EndpointLabel {
    pub endpoint: &'static str,
}

/// Label of the per-client gauge: the endpoint and the peer, e.g. `tcp 127.0.0.1:50112 #7`.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct ClientLabel {
    pub client: String,
}

/// Every metric of the daemon.
pub struct Metrics {
    registry: Registry,
    frames_captured: Counter,
    frames_dropped: Counter,
    frames_decomposed: Counter,
    capture_errors: Counter,
    lights: Gauge,
    filter_delay_frames: Gauge<f64, std::sync::atomic::AtomicU64>,
    source_failures: Counter,
    source_reconnects: Counter,
    pub source_stale: Gauge,
    pub decompose_seconds: Histogram,
    pub delivery_seconds: Histogram,
    pub clients_connected: Family<EndpointLabel, Gauge>,
    pub frames_sent: Family<EndpointLabel, Counter>,
    pub frames_skipped: Family<EndpointLabel, Counter>,
    pub client_skipped: Family<ClientLabel, Gauge>,
    pub client_errors: Family<EndpointLabel, Counter>,
    /// Shares of a pass written by the `envlight-pass` threads.
    pub pass_shares: Counter,
    /// Shares the passing thread wrote itself: their `envlight-pass` thread was still busy.
    pub pass_shares_returned: Counter,
    pub frames_rendered: Counter,
    pub render_seconds: Histogram,
    pub render_lights: Gauge,
    /// ASG stage (`[asg]`): sets fitted and published.
    pub asg_fits: Counter,
    /// ASG stage: frames that were replaced by a newer one before the stage was free.
    pub asg_frames_skipped: Counter,
    /// ASG stage: frames whose fit failed.
    pub asg_fit_errors: Counter,
    /// ASG stage: fit time per frame.
    pub asg_fit_seconds: Histogram,
    /// Wavelet stage (`[wavelet]`): sets computed and published.
    pub wavelet_sets: Counter,
    /// Wavelet stage: frames that were replaced by a newer one before the stage was free.
    pub wavelet_frames_skipped: Counter,
    /// Wavelet stage: frames that gave no set.
    pub wavelet_errors: Counter,
    /// Wavelet stage: time per set (resample, transform, selection).
    pub wavelet_seconds: Histogram,
    /// SH stage (`[sh]`): sets computed and published.
    pub sh_sets: Counter,
    /// SH stage: frames that were replaced by a newer one before the stage was free.
    pub sh_frames_skipped: Counter,
    /// SH stage: frames that gave no set.
    pub sh_errors: Counter,
    /// SH stage: time per set (projection).
    pub sh_seconds: Histogram,
}

/// Latency buckets from 50 µs to about 1.6 s, doubling.
fn latency_buckets() -> impl Iterator<Item = f64> {
    prometheus_client::metrics::histogram::exponential_buckets(50e-6, 2.0, 16)
}

impl Default for Metrics {
    fn default() -> Self {
        Self::new()
    }
}

impl Metrics {
    /// All metrics at zero, registered under the `envlight_` prefix.
    pub fn new() -> Self {
        let mut registry = Registry::with_prefix("envlight");
        let frames_captured = Counter::default();
        let frames_dropped = Counter::default();
        let frames_decomposed = Counter::default();
        let capture_errors = Counter::default();
        let lights = Gauge::default();
        let source_stale = Gauge::default();
        let source_failures = Counter::default();
        let source_reconnects = Counter::default();
        let decompose_seconds = Histogram::new(latency_buckets());
        let delivery_seconds = Histogram::new(latency_buckets());
        let clients_connected = Family::<EndpointLabel, Gauge>::default();
        let frames_sent = Family::<EndpointLabel, Counter>::default();
        let frames_skipped = Family::<EndpointLabel, Counter>::default();
        let client_skipped = Family::<ClientLabel, Gauge>::default();
        let client_errors = Family::<EndpointLabel, Counter>::default();
        let pass_shares = Counter::default();
        let pass_shares_returned = Counter::default();
        let frames_rendered = Counter::default();
        let render_seconds = Histogram::new(latency_buckets());
        let render_lights = Gauge::default();
        let asg_fits = Counter::default();
        let asg_frames_skipped = Counter::default();
        let asg_fit_errors = Counter::default();
        // 1 ms to about 16 s, doubling: fits take far longer than decompositions.
        let asg_fit_seconds = Histogram::new(
            prometheus_client::metrics::histogram::exponential_buckets(1e-3, 2.0, 15),
        );
        let wavelet_sets = Counter::default();
        let wavelet_frames_skipped = Counter::default();
        let wavelet_errors = Counter::default();
        let wavelet_seconds = Histogram::new(latency_buckets());
        registry.register(
            "wavelet_sets",
            "Wavelet coefficient sets computed and published by the [wavelet] stage",
            wavelet_sets.clone(),
        );
        registry.register(
            "wavelet_frames_skipped",
            "Frames the [wavelet] stage skipped because a newer one arrived while it was busy",
            wavelet_frames_skipped.clone(),
        );
        registry.register(
            "wavelet_errors",
            "Frames the [wavelet] stage could not turn into a set",
            wavelet_errors.clone(),
        );
        registry.register(
            "wavelet_seconds",
            "Wavelet stage time per set: resampling, transform and selection",
            wavelet_seconds.clone(),
        );
        let sh_sets = Counter::default();
        let sh_frames_skipped = Counter::default();
        let sh_errors = Counter::default();
        let sh_seconds = Histogram::new(latency_buckets());
        registry.register(
            "sh_sets",
            "Spherical-harmonic sets computed and published by the [sh] stage",
            sh_sets.clone(),
        );
        registry.register(
            "sh_frames_skipped",
            "Frames the [sh] stage skipped because a newer one arrived while it was busy",
            sh_frames_skipped.clone(),
        );
        registry.register(
            "sh_errors",
            "Frames the [sh] stage could not turn into a set",
            sh_errors.clone(),
        );
        registry.register(
            "sh_seconds",
            "SH stage time per set: the projection of the frame",
            sh_seconds.clone(),
        );
        registry.register(
            "asg_fits",
            "ASG sets fitted and published by the [asg] stage",
            asg_fits.clone(),
        );
        registry.register(
            "asg_frames_skipped",
            "Frames the [asg] stage skipped because a newer one arrived while it was fitting",
            asg_frames_skipped.clone(),
        );
        registry.register(
            "asg_fit_errors",
            "Frames the [asg] stage could not fit",
            asg_fit_errors.clone(),
        );
        registry.register(
            "asg_fit_seconds",
            "ASG fit time per frame",
            asg_fit_seconds.clone(),
        );
        registry.register(
            "pass_shares",
            "Shares of a pass (the clients one thread writes a light list to) written by the \
             envlight-pass threads",
            pass_shares.clone(),
        );
        registry.register(
            "pass_shares_returned",
            "Shares of a pass the passing thread wrote itself because their envlight-pass thread \
             was still busy with the last one",
            pass_shares_returned.clone(),
        );
        registry.register(
            "frames_rendered",
            "Frames the render thread drew",
            frames_rendered.clone(),
        );
        registry.register(
            "render_seconds",
            "Render time per frame (GPU timestamps where the adapter has them)",
            render_seconds.clone(),
        );
        registry.register(
            "render_lights",
            "Lights the render thread used in its newest frame (the budget controller's choice)",
            render_lights.clone(),
        );
        registry.register(
            "frames_captured",
            "Frames the source delivered",
            frames_captured.clone(),
        );
        registry.register(
            "frames_dropped",
            "Frames dropped because the decomposition was behind (oldest first)",
            frames_dropped.clone(),
        );
        registry.register(
            "frames_decomposed",
            "Light lists decomposed and published",
            frames_decomposed.clone(),
        );
        registry.register(
            "capture_errors",
            "Errors returned by the frame source",
            capture_errors.clone(),
        );
        registry.register("lights", "Lights in the newest light list", lights.clone());
        let filter_delay_frames = Gauge::<f64, std::sync::atomic::AtomicU64>::default();
        registry.register(
            "filter_delay_frames",
            "Delay of the lights' temporal FIR filter in frames (sum of k times tap k; 0 without \
             the filter); the wavelet and SH sets, when filtered, share it",
            filter_delay_frames.clone(),
        );
        registry.register(
            "source_failures",
            "Times the source (a camera) was lost: unplugged, I/O error, timeout",
            source_failures.clone(),
        );
        registry.register(
            "source_reconnect_attempts",
            "Attempts to reopen a lost source",
            source_reconnects.clone(),
        );
        registry.register(
            "source_stale",
            "1 while the newest lights are stale because the source is lost",
            source_stale.clone(),
        );
        registry.register(
            "decompose_seconds",
            "Decomposition time per frame",
            decompose_seconds.clone(),
        );
        registry.register(
            "delivery_seconds",
            "Time from a frame's arrival at the decomposition to the last byte written to a client",
            delivery_seconds.clone(),
        );
        registry.register(
            "clients_connected",
            "Clients connected",
            clients_connected.clone(),
        );
        registry.register(
            "client_frames_sent",
            "Frames written to clients",
            frames_sent.clone(),
        );
        registry.register(
            "client_frames_skipped",
            "Frames slow clients skipped (they got a newer one instead)",
            frames_skipped.clone(),
        );
        registry.register(
            "client_skipped_frames",
            "Frames skipped so far by each connected client",
            client_skipped.clone(),
        );
        registry.register(
            "client_errors",
            "Connections closed for a protocol error or a timeout",
            client_errors.clone(),
        );
        Self {
            registry,
            frames_captured,
            frames_dropped,
            frames_decomposed,
            capture_errors,
            lights,
            filter_delay_frames,
            source_failures,
            source_reconnects,
            source_stale,
            decompose_seconds,
            delivery_seconds,
            clients_connected,
            frames_sent,
            frames_skipped,
            client_skipped,
            client_errors,
            pass_shares,
            pass_shares_returned,
            frames_rendered,
            render_seconds,
            render_lights,
            asg_fits,
            asg_frames_skipped,
            asg_fit_errors,
            asg_fit_seconds,
            wavelet_sets,
            wavelet_frames_skipped,
            wavelet_errors,
            wavelet_seconds,
            sh_sets,
            sh_frames_skipped,
            sh_errors,
            sh_seconds,
        }
    }

    /// Copies the pipeline's own counters into the metrics.
    pub fn update_pipeline(&self, stats: &PipelineStats) {
        self.frames_captured
            .inner()
            .store(stats.frames_captured, Ordering::Relaxed);
        self.frames_dropped
            .inner()
            .store(stats.frames_dropped, Ordering::Relaxed);
        self.frames_decomposed
            .inner()
            .store(stats.frames_decomposed, Ordering::Relaxed);
        self.capture_errors
            .inner()
            .store(stats.capture_errors, Ordering::Relaxed);
        self.lights
            .set(i64::try_from(stats.light_count).unwrap_or(i64::MAX));
    }

    /// Sets the lights' temporal filter's delay in frames (0 without a filter).
    pub fn set_filter_delay(&self, frames: f64) {
        self.filter_delay_frames.set(frames);
    }

    /// Copies the ASG stage's counters into the metrics.
    pub fn update_asg(&self, stats: &crate::asg_stage::AsgStats) {
        self.asg_fits.inner().store(stats.fits, Ordering::Relaxed);
        self.asg_frames_skipped
            .inner()
            .store(stats.frames_skipped, Ordering::Relaxed);
        self.asg_fit_errors
            .inner()
            .store(stats.fit_errors, Ordering::Relaxed);
    }

    /// Copies the wavelet stage's counters into the metrics.
    pub fn update_wavelet(&self, stats: &crate::wavelet_stage::WaveletStats) {
        self.wavelet_sets
            .inner()
            .store(stats.sets, Ordering::Relaxed);
        self.wavelet_frames_skipped
            .inner()
            .store(stats.frames_skipped, Ordering::Relaxed);
        self.wavelet_errors
            .inner()
            .store(stats.errors, Ordering::Relaxed);
    }

    /// Copies the SH stage's counters into the metrics.
    pub fn update_sh(&self, stats: &crate::sh_stage::ShStats) {
        self.sh_sets.inner().store(stats.sets, Ordering::Relaxed);
        self.sh_frames_skipped
            .inner()
            .store(stats.frames_skipped, Ordering::Relaxed);
        self.sh_errors
            .inner()
            .store(stats.errors, Ordering::Relaxed);
    }

    /// Copies a live source's failure and reconnect counts into the metrics.
    pub fn update_source(&self, failures: u64, reconnect_attempts: u64) {
        self.source_failures
            .inner()
            .store(failures, Ordering::Relaxed);
        self.source_reconnects
            .inner()
            .store(reconnect_attempts, Ordering::Relaxed);
    }

    /// Records one decomposition time.
    pub fn observe_decompose(&self, time: Duration) {
        self.decompose_seconds.observe(time.as_secs_f64());
    }

    /// The registry in the Prometheus text exposition format.
    pub fn encode(&self) -> String {
        let mut text = String::new();
        // Writing into a String cannot fail.
        let _ = prometheus_client::encoding::text::encode(&mut text, &self.registry);
        text
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exposition_names_every_metric_with_its_value() {
        let metrics = Metrics::new();
        metrics.update_pipeline(&PipelineStats {
            frames_captured: 12,
            frames_dropped: 3,
            frames_decomposed: 9,
            capture_errors: 1,
            light_count: 256,
            ..PipelineStats::default()
        });
        metrics.observe_decompose(Duration::from_micros(900));
        let tcp = EndpointLabel { endpoint: "tcp" };
        metrics.clients_connected.get_or_create(&tcp).inc();
        metrics.frames_skipped.get_or_create(&tcp).inc_by(5);
        let client = ClientLabel {
            client: "tcp 127.0.0.1:1 #1".into(),
        };
        metrics.client_skipped.get_or_create(&client).set(5);
        let text = metrics.encode();
        for line in [
            "envlight_frames_captured_total 12",
            "envlight_frames_dropped_total 3",
            "envlight_frames_decomposed_total 9",
            "envlight_capture_errors_total 1",
            "envlight_lights 256",
            "envlight_decompose_seconds_count 1",
            "envlight_clients_connected{endpoint=\"tcp\"} 1",
            "envlight_client_frames_skipped_total{endpoint=\"tcp\"} 5",
            "envlight_client_skipped_frames{client=\"tcp 127.0.0.1:1 #1\"} 5",
        ] {
            assert!(text.contains(line), "missing {line:?} in\n{text}");
        }
        metrics.client_skipped.remove(&client);
        assert!(!metrics.encode().contains("#1\""));
    }
}
