//! The wavelet stage end to end (`[wavelet]`, src/wavelet_stage.rs): clients that subscribe with
//! representation `wavelet` receive the sets the library computes for the same frames
//! (`OctahedralMap::from_frame` then `approximate`), capped as asked; the received sets
//! reconstruct the frame's energy; without the stage a `wavelet` subscribe is refused with
//! error 6; SIGHUP changes the settings live.
//!
//! The comparison uses a replay: there the stage transforms every frame in order (lossless, like
//! the replay's decomposition), and every step is deterministic, so every set a client receives
//! must equal, bit for bit, the library's set for that frame's octahedral map filtered in time
//! with the lights' taps (`SetFilter`); the set's ∫L dω then equals the lights' of the same seq. A client may still skip sets
//! (newest wins), so the test matches by seq; the stage's counters show that every frame was
//! transformed, i.e. that the replay reproduced the whole stream.

mod common;

use common::{
    assert_ordered_to_the_end, assert_unsupported, every_transport, http_get, metric_value,
    read_until_goodbye, record_sky, subscribe_all, wait_until, SMALL_SKY,
};
use envlight::capture::FrameSource;
use envlight::config::Config;
use envlight::daemon::{Daemon, DaemonOptions};
use envlight::record::{Pacing, ReplaySource};
use envlight::set_filter::SetFilter;
use envlight::stream::client::{Client, Endpoint};
use envlight::stream::protocol::{decode_message, encode_wavelet_frame};
use envlight::stream::{Message, Representation, WaveletFrame};
use envlight::wavelet::sphere::OctahedralMap;
use envlight::wavelet::{approximate, Basis};
use std::path::Path;

fn config(dir: &Path, extra: &str) -> Config {
    common::config(dir, 2.0, extra)
}

/// Everything a wavelet client received until the goodbye, with each set's stale flag.
fn read_sets(client: Client) -> (Vec<(WaveletFrame, bool)>, Option<String>) {
    read_until_goodbye(client, |message| match message {
        Message::Wavelet(m) => {
            let stale = m.stale;
            Ok((m.into_wavelet_frame(), stale))
        }
        other => Err(other),
    })
}

#[test]
fn wavelet_clients_receive_what_the_library_computes() {
    let dir = tempfile::tempdir().unwrap();
    let recording = dir.path().join("session");
    let n = record_sky(&recording, 12);
    assert_eq!(n, 12, "every frame recorded");
    // The defaults (haar, 64², 256 coefficients) with the stage on.
    let config = config(dir.path(), "[wavelet]\nenabled = true\n");
    let settings = &config.wavelet.settings;
    assert_eq!(
        (settings.basis, settings.side, settings.coefficients),
        (Basis::Haar, 64, 256)
    );
    // Filtered in time with the lights' taps (the recording's: the defaults).
    let taps = settings.filter_taps.clone().expect("filtered by default");
    assert_eq!(Some(&taps), config.decompose.filter_taps.as_ref());

    // What the library gives for the recorded frames, and each frame's octahedral map, filtered
    // in time (a replay feeds the stage every frame: numbers 0, 1, 2, …); and each frame's own
    // map's energy.
    let mut replay = ReplaySource::open(&recording, Pacing::AsFastAsPossible).unwrap();
    let mut filter = SetFilter::<f32>::new(&taps).unwrap();
    let mut expected = Vec::new();
    let mut unfiltered_integrals = Vec::new();
    while let Some(frame) = replay.next_frame().unwrap() {
        let own = OctahedralMap::from_frame(&frame, 64).unwrap();
        unfiltered_integrals.push(own.integral());
        let mut texels = own.into_texels();
        filter.apply(frame.seq, bytemuck::cast_slice_mut(&mut texels));
        let map = OctahedralMap::new(64, texels).unwrap();
        let set = approximate(map.texels(), 64, Basis::Haar, 6, 256).unwrap();
        let wavelet = WaveletFrame {
            seq: frame.seq,
            time: frame.time,
            set,
        };
        expected.push((wavelet, map));
    }
    assert_eq!(expected.len() as u64, n);

    // Original timing (the sky's 30 fps), so that the clients are connected early on.
    let daemon = common::start_replay(config, &recording);
    let addrs = daemon.addresses().clone();
    let tcp = Endpoint::Tcp(addrs.stream.tcp.unwrap().to_string());
    let endpoints = every_transport(&addrs.stream, [0, 32, 1, 0]);
    let clients = subscribe_all(&endpoints, Representation::Wavelet, read_sets);
    // A lights client on the same daemon is unaffected.
    let lights = common::spawn_lights_reader(&tcp);
    let http = addrs.metrics.unwrap();
    wait_until("the end of the replay", || daemon.source_finished());
    let metrics = http_get(http, "/metrics").1;
    let summary = daemon.shutdown().unwrap();
    let stats = summary.wavelet.expect("the wavelet stage ran");
    assert_eq!(stats.sets, n, "a replay transforms every frame");
    assert_eq!((stats.frames_skipped, stats.errors), (0, 0));
    assert_eq!(stats.plans, 1, "one resampling plan for one frame size");
    assert_eq!(summary.pipeline.frames_decomposed, n);
    assert_eq!(
        metric_value(&metrics, "envlight_wavelet_sets_total"),
        n as f64
    );
    assert_eq!(
        metric_value(&metrics, "envlight_wavelet_frames_skipped_total"),
        0.0
    );
    assert_eq!(
        metric_value(&metrics, "envlight_wavelet_seconds_count"),
        n as f64
    );

    let mut full_sets = 0;
    for ((endpoint, format, cap), client) in endpoints.iter().zip(clients) {
        let what = format!("{endpoint} {format:?} cap {cap}");
        let (sets, goodbye) = client.join().unwrap();
        let seqs: Vec<u64> = sets.iter().map(|(s, _)| s.seq).collect();
        assert_ordered_to_the_end(&what, goodbye.as_deref(), &seqs, n - 1);
        let cap = (*cap != 0).then_some(*cap as usize);
        for (set, stale) in &sets {
            let (want, map) = &expected[set.seq as usize];
            assert!(!stale);
            assert_eq!(set.time, want.time, "{what}");
            // The capped set is the encoder's selection of the library's set, bit for bit.
            let mut bytes = Vec::new();
            encode_wavelet_frame(want, cap, false, &mut bytes);
            let Ok(Message::Wavelet(capped)) = decode_message(&bytes) else {
                panic!("the expected set does not encode");
            };
            assert_eq!(set.set, capped.set, "{what} seq {}", set.seq);
            let count = cap.unwrap_or(usize::MAX).min(256);
            assert_eq!(set.set.coefficients.len(), count, "{what}");
            if cap.is_none() {
                assert_eq!(*set, *want, "{what}");
                check_reconstruction(set, map);
                full_sets += 1;
            }
        }
        if cap == Some(1) {
            // The single largest coefficient is the scaling one (the map's mean × side).
            assert!(sets.iter().all(|(s, _)| s.set.coefficients[0].0 == 0));
        }
    }
    assert!(full_sets >= 2);

    // The same moment as the lights: each set's ∫L dω (its scaling coefficient) equals the
    // filtered lights' Σ rgb of the same seq, and would not without the filter (the sun moves).
    let (lights, _) = lights.join().unwrap();
    common::assert_sets_follow_the_lights(
        &lights,
        |seq| expected[seq as usize].0.integral(),
        |seq| unfiltered_integrals[seq as usize],
    );
}

/// The received set reconstructs the frame: its energy (∫L dω, from the scaling coefficient
/// alone and from the reconstructed map) equals the map's to 1e-5 relative (the resampling
/// preserves the frame's energy; the kept scaling coefficient carries all of it; f32 rounding
/// is ~1e-7), and the map's RGB L2 error is what Parseval says the dropped coefficients hold,
/// and below 12 % (the sky at 64² with 256 of 4,096 Haar coefficients: 9.7–9.8 % measured on
/// these frames).
fn check_reconstruction(received: &WaveletFrame, map: &OctahedralMap) {
    let want = map.integral();
    let from_scaling = received.integral();
    let reconstructed = received.set.reconstruct().unwrap();
    let omega = 4.0 * std::f64::consts::PI / (64.0 * 64.0);
    for c in 0..3 {
        let sum: f64 = reconstructed.iter().map(|t| t[c]).sum::<f64>() * omega;
        for got in [sum, from_scaling[c]] {
            assert!(
                (got - want[c]).abs() <= 1e-5 * want[c].abs(),
                "channel {c}: {got} vs {}",
                want[c]
            );
        }
    }
    let error2: f64 = reconstructed
        .iter()
        .zip(map.texels())
        .map(|(r, t)| {
            (0..3)
                .map(|c| (r[c] - f64::from(t[c])).powi(2))
                .sum::<f64>()
        })
        .sum();
    let total2: f64 = map
        .texels()
        .iter()
        .map(|t| t.iter().map(|&v| f64::from(v).powi(2)).sum::<f64>())
        .sum();
    let relative = (error2 / total2).sqrt();
    assert!(relative < 0.12, "relative L2 error {relative}");
    // Parseval: the error is the energy of the dropped coefficients.
    let coefficients =
        envlight::wavelet::approx::Coefficients::analyze(map.texels(), 64, Basis::Haar, 6).unwrap();
    let kept: f64 = received
        .set
        .coefficients
        .iter()
        .map(|&(i, _)| coefficients.norm2(i as usize))
        .sum();
    let dropped = coefficients.energy() - kept;
    assert!(
        (error2 - dropped).abs() <= 1e-6 * total2,
        "{error2} vs {dropped}"
    );
    eprintln!(
        "seq {}: relative L2 error of the 256-coefficient set {relative:.4}",
        received.seq
    );
}

#[test]
fn wavelet_subscribe_without_the_stage_is_unsupported() {
    let dir = tempfile::tempdir().unwrap();
    let daemon = Daemon::start(config(dir.path(), SMALL_SKY), DaemonOptions::default()).unwrap();
    assert!(daemon.wavelet().is_none());
    let tcp = daemon.addresses().stream.tcp.unwrap();
    assert_unsupported(tcp, Representation::Wavelet, "[wavelet] enabled = true");
    daemon.shutdown().unwrap();
}

#[test]
fn sighup_reload_applies_new_wavelet_settings_from_the_next_frame() {
    let dir = tempfile::tempdir().unwrap();
    let stage = "[wavelet]\nenabled = true\nbasis = \"db2\"\nside = 16\ncoefficients = 20\n";
    let mut daemon = Daemon::start(
        config(dir.path(), &format!("{SMALL_SKY}{stage}")),
        DaemonOptions::default(),
    )
    .unwrap();
    let mut rx = daemon.wavelet().unwrap().subscribe();
    wait_until("a first set", || {
        rx.borrow_and_update().as_ref().is_some_and(|p| {
            let set = &p.payload.set;
            (set.basis, set.side, set.levels, set.coefficients.len())
                == (Basis::Daubechies(2), 16, 4, 20)
        })
    });
    let changed = stage
        .replace("db2", "coif1")
        .replace("side = 16", "side = 32");
    let report = daemon.reload(config(dir.path(), &format!("{SMALL_SKY}{changed}")));
    assert_eq!(report.applied, vec!["[wavelet]".to_owned()]);
    assert!(report.needs_restart.is_empty(), "{report:?}");
    wait_until("a set with the new settings", || {
        rx.borrow_and_update().as_ref().is_some_and(|p| {
            let set = &p.payload.set;
            (set.basis, set.side, set.levels) == (Basis::Coiflet(1), 32, 5)
        })
    });
    // Turning the stage off needs a restart; the stage keeps running.
    let off = changed.replace("enabled = true", "enabled = false");
    let report = daemon.reload(config(dir.path(), &format!("{SMALL_SKY}{off}")));
    assert!(
        report
            .needs_restart
            .iter()
            .any(|s| s.starts_with("[wavelet]")),
        "{report:?}"
    );
    assert!(daemon.wavelet().is_some());
    let summary = daemon.shutdown().unwrap();
    let stats = summary.wavelet.unwrap();
    assert!(stats.sets >= 2 && stats.errors == 0, "{stats:?}");
    assert_eq!(stats.plans, 2, "a new plan for the new side");
}

#[test]
fn the_python_example_client_reads_wavelet_sets() {
    common::require_python3();
    let dir = tempfile::tempdir().unwrap();
    let extra = format!("{SMALL_SKY}[wavelet]\nenabled = true\nside = 16\ncoefficients = 40\n");
    let daemon = Daemon::start(config(dir.path(), &extra), DaemonOptions::default()).unwrap();
    let tcp = daemon.addresses().stream.tcp.unwrap();
    // Binary frames and JSON lines alike.
    let address = tcp.to_string();
    for (form, lines) in common::python_client_both_forms(&[
        &address,
        "--representation",
        "wavelet",
        "--frames",
        "2",
        "--max-lights",
        "5",
    ]) {
        assert_eq!(lines.len(), 2, "{form}: {lines:?}");
        assert!(
            lines
                .iter()
                .all(|l| l.contains(": 5 wavelet coefficients (haar on 16^2, 4 levels)")),
            "{form}: {lines:?}"
        );
    }
    daemon.shutdown().unwrap();
}
