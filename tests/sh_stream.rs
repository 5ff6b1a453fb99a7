//! The spherical-harmonics stage end to end (`[sh]`, src/sh_stage.rs): clients that subscribe
//! with representation `sh` receive the coefficients the library computes for the same frames
//! (`envlight::sh::project`), capped to whole bands as asked, over every transport and format;
//! the received sets hold the frame's ∫L dω; without the stage an `sh` subscribe is refused with
//! error 6; SIGHUP changes the degree live.
//!
//! As for the wavelet stage (tests/wavelet_stream.rs), the comparison uses a replay, in which
//! the stage projects every frame in order; the projection is deterministic, so every set a
//! client receives must equal the library's for that frame filtered in time with the lights'
//! taps (`SetFilter`), bit for bit (matched by seq: a client may skip sets, newest wins), and
//! its ∫L dω the filtered lights' Σ rgb of the same seq.

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
use envlight::stream::{Message, Representation, ShFrame};
use std::path::Path;

fn config(dir: &Path, extra: &str) -> Config {
    common::config(dir, 2.0, extra)
}

/// Everything an SH client received until the goodbye, with each set's stale flag.
fn read_sets(client: Client) -> (Vec<(ShFrame, bool)>, Option<String>) {
    read_until_goodbye(client, |message| match message {
        Message::Sh(m) => {
            let stale = m.stale;
            Ok((m.into_sh_frame(), stale))
        }
        other => Err(other),
    })
}

#[test]
fn sh_clients_receive_what_the_library_computes() {
    let dir = tempfile::tempdir().unwrap();
    let recording = dir.path().join("session");
    let n = record_sky(&recording, 12);
    assert_eq!(n, 12, "every frame recorded");
    let config = config(dir.path(), "[sh]\nenabled = true\ndegree = 3\n");
    assert_eq!(config.sh.settings.degree, 3);
    // Filtered in time with the lights' taps (the recording's: the defaults).
    let taps = config
        .sh
        .settings
        .filter_taps
        .clone()
        .expect("filtered by default");
    assert_eq!(Some(&taps), config.decompose.filter_taps.as_ref());

    // What the library gives for the recorded frames through the filter (a replay feeds the
    // stage every frame: numbers 0, 1, 2, …), each frame's ∫L dω through the same filter,
    // and its own ∫L dω.
    let mut replay = ReplaySource::open(&recording, Pacing::AsFastAsPossible).unwrap();
    let mut set_filter = SetFilter::<f64>::new(&taps).unwrap();
    let mut integral_filter = SetFilter::<f64>::new(&taps).unwrap();
    let mut expected = Vec::new();
    let mut own_integrals = Vec::new();
    while let Some(frame) = replay.next_frame().unwrap() {
        let mut set = envlight::sh::project(&frame, 3);
        set_filter.apply(frame.seq, set.values_mut());
        let solid_angles = frame.projection.solid_angles(frame.width, frame.height);
        let mut integral = [0.0f64; 3];
        for (rgb, omega) in frame.pixels.iter().zip(solid_angles) {
            for c in 0..3 {
                integral[c] += f64::from(rgb[c]) * omega;
            }
        }
        own_integrals.push(integral);
        integral_filter.apply(frame.seq, &mut integral);
        expected.push((ShFrame::new(frame.seq, frame.time, &set), integral));
    }
    assert_eq!(expected.len() as u64, n);

    let daemon = common::start_replay(config, &recording);
    let addrs = daemon.addresses().clone();
    let tcp = Endpoint::Tcp(addrs.stream.tcp.unwrap().to_string());
    // Caps: all 16; 4 keeps degrees 0 and 1; 1 the constant; 15 degrees 0–2 (9).
    let endpoints = every_transport(&addrs.stream, [0, 4, 1, 15]);
    let clients = subscribe_all(&endpoints, Representation::Sh, read_sets);
    let lights = common::spawn_lights_reader(&tcp);
    let http = addrs.metrics.unwrap();
    wait_until("the end of the replay", || daemon.source_finished());
    let metrics = http_get(http, "/metrics").1;
    let summary = daemon.shutdown().unwrap();
    let stats = summary.sh.expect("the SH stage ran");
    assert_eq!(stats.sets, n, "a replay projects every frame");
    assert_eq!((stats.frames_skipped, stats.errors), (0, 0));
    assert_eq!(stats.plans, 1, "one projection plan for one frame size");
    assert_eq!(metric_value(&metrics, "envlight_sh_sets_total"), n as f64);
    assert_eq!(
        metric_value(&metrics, "envlight_sh_seconds_count"),
        n as f64
    );

    let mut full_sets = 0;
    for ((endpoint, format, cap), client) in endpoints.iter().zip(clients) {
        let what = format!("{endpoint} {format:?} cap {cap}");
        let (sets, goodbye) = client.join().unwrap();
        let seqs: Vec<u64> = sets.iter().map(|(s, _)| s.seq).collect();
        assert_ordered_to_the_end(&what, goodbye.as_deref(), &seqs, n - 1);
        let count = match cap {
            0 => 16,
            4 => 4,
            1 => 1,
            15 => 9,
            other => panic!("no count for cap {other}"),
        };
        for (set, stale) in &sets {
            let (want, integral) = &expected[set.seq as usize];
            assert!(!stale);
            assert_eq!(set.time, want.time, "{what}");
            assert_eq!(
                set.coefficients,
                want.coefficients[..count],
                "{what} seq {}",
                set.seq
            );
            // Any cap keeps the constant, so ∫L dω: the frame's to f32 rounding.
            let received = set.to_coefficients().unwrap().integral();
            for c in 0..3 {
                assert!(
                    (received[c] - integral[c]).abs() <= 1e-6 * integral[c].abs(),
                    "{what} channel {c}: {} against {}",
                    received[c],
                    integral[c]
                );
            }
            full_sets += usize::from(*cap == 0);
        }
    }
    assert!(full_sets >= 2);

    // The same moment as the lights: each set's ∫L dω equals the filtered lights' Σ rgb of
    // the same seq, and the frame's own would not (the sun moves).
    let (lights, _) = lights.join().unwrap();
    common::assert_sets_follow_the_lights(
        &lights,
        |seq| {
            expected[seq as usize]
                .0
                .to_coefficients()
                .unwrap()
                .integral()
        },
        |seq| own_integrals[seq as usize],
    );
}

#[test]
fn the_render_thread_shades_with_sh_lighting() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("latest.png");
    let extra = format!(
        "{SMALL_SKY}[sh]\nenabled = true\ndegree = 4\n\
         [render]\nenabled = true\nwidth = 48\nheight = 32\nlighting = \"sh\"\n\
         latest_png = \"{}\"\n",
        png.display()
    );
    let (daemon, image) = common::render_three_frames(config(dir.path(), &extra), &png);
    assert_eq!(image.dimensions(), (48, 32));
    assert!(
        image.pixels().any(|p| p.0[..3].iter().any(|&c| c > 32)),
        "the sky lights the scene"
    );
    daemon.shutdown().unwrap();
    // Without the stage the config is refused, naming the key.
    let refused = envlight::config::RawConfig::parse(
        "[render]\nenabled = true\nlighting = \"sh\"\n",
        Path::new("envlight.toml"),
    )
    .unwrap()
    .validate()
    .unwrap_err()
    .to_string();
    assert!(
        refused.contains("render.lighting") && refused.contains("[sh]"),
        "{refused}"
    );
}

#[test]
fn sh_subscribe_without_the_stage_is_unsupported() {
    let dir = tempfile::tempdir().unwrap();
    let daemon = Daemon::start(config(dir.path(), SMALL_SKY), DaemonOptions::default()).unwrap();
    assert!(daemon.sh().is_none());
    let tcp = daemon.addresses().stream.tcp.unwrap();
    assert_unsupported(tcp, Representation::Sh, "[sh] enabled = true");
    daemon.shutdown().unwrap();
}

#[test]
fn sighup_reload_applies_a_new_degree_from_the_next_frame() {
    let dir = tempfile::tempdir().unwrap();
    let stage = "[sh]\nenabled = true\ndegree = 1\n";
    let mut daemon = Daemon::start(
        config(dir.path(), &format!("{SMALL_SKY}{stage}")),
        DaemonOptions::default(),
    )
    .unwrap();
    let mut rx = daemon.sh().unwrap().subscribe();
    wait_until("a first set", || {
        rx.borrow_and_update()
            .as_ref()
            .is_some_and(|p| p.payload.degree() == Some(1))
    });
    let changed = stage.replace("degree = 1", "degree = 4");
    let report = daemon.reload(config(dir.path(), &format!("{SMALL_SKY}{changed}")));
    assert_eq!(report.applied, vec!["[sh]".to_owned()]);
    assert!(report.needs_restart.is_empty(), "{report:?}");
    wait_until("a set of the new degree", || {
        rx.borrow_and_update()
            .as_ref()
            .is_some_and(|p| p.payload.degree() == Some(4))
    });
    // A bad degree changes nothing; turning the stage off needs a restart.
    let bad = envlight::config::RawConfig::parse(
        &format!("{SMALL_SKY}[sh]\ndegree = 99\n"),
        Path::new("bad.toml"),
    )
    .unwrap()
    .validate();
    assert!(bad.is_err_and(|e| e.to_string().contains("sh.degree")));
    let off = changed.replace("enabled = true", "enabled = false");
    let report = daemon.reload(config(dir.path(), &format!("{SMALL_SKY}{off}")));
    assert!(
        report.needs_restart.iter().any(|s| s.starts_with("[sh]")),
        "{report:?}"
    );
    assert!(daemon.sh().is_some());
    let summary = daemon.shutdown().unwrap();
    let stats = summary.sh.unwrap();
    assert!(stats.sets >= 2 && stats.errors == 0, "{stats:?}");
    assert_eq!(stats.plans, 2, "a new plan for the new degree");
}

/// The SH filter follows the lights': new [decompose] taps reach the stage, another
/// [decompose] change restarts its window with the lights', `filter = false` turns it off
/// (each a new worker, which keeps the projection plan).
/// A replay filters the SH sets with the recording's taps (the lights'), not with those of
/// the config it is started with, and reports their delay: here the config asks for
/// `[1, 2, 1]` (delay 1), the recording was made with the defaults (delay 3). The stage used
/// the config's taps, so its sets described another moment than the replayed lights.
#[test]
fn a_replay_filters_the_sets_with_the_recordings_taps() {
    let dir = tempfile::tempdir().unwrap();
    let recording = dir.path().join("session");
    let n = record_sky(&recording, 10);
    let config = config(
        dir.path(),
        "[decompose]\nfilter_taps = [1.0, 2.0, 1.0]\n[sh]\nenabled = true\n",
    );
    assert_eq!(config.sh.settings.filter_taps, Some(vec![1.0, 2.0, 1.0]));
    let mut daemon = common::start_replay(config, &recording);
    let addrs = daemon.addresses().clone();
    let tcp = Endpoint::Tcp(addrs.stream.tcp.unwrap().to_string());
    let endpoints = every_transport(&addrs.stream, [0; 4]);
    let clients = subscribe_all(&endpoints, Representation::Sh, read_sets);
    let lights = common::spawn_lights_reader(&tcp);
    let http = addrs.metrics.unwrap();
    let delay = metric_value(
        &http_get(http, "/metrics").1,
        "envlight_filter_delay_frames",
    );
    assert_eq!(delay, 3.0, "the recording's taps' delay");
    // A reload's new sky is read by nobody: a replay reads its recording (it said "restart
    // envlight to apply", which would not apply it either).
    let other_sky = self::config(
        dir.path(),
        "[decompose]\nfilter_taps = [1.0, 2.0, 1.0]\n[sh]\nenabled = true\n\
         [sky]\nwidth = 128\nheight = 64\n",
    );
    let report = daemon.reload(other_sky);
    assert!(
        report
            .needs_restart
            .iter()
            .any(|s| s.starts_with("[source] / [sky] (a replay reads its recording")),
        "{report:?}"
    );
    wait_until("the end of the replay", || daemon.source_finished());
    daemon.shutdown().unwrap();

    let mut own_integrals = Vec::new();
    let mut replay = ReplaySource::open(&recording, Pacing::AsFastAsPossible).unwrap();
    while let Some(frame) = replay.next_frame().unwrap() {
        let set = envlight::sh::project(&frame, 2);
        own_integrals.push(set.integral());
    }
    assert_eq!(own_integrals.len() as u64, n);
    let (lights, _) = lights.join().unwrap();
    for client in clients {
        let (sets, _) = client.join().unwrap();
        let received: std::collections::HashMap<u64, [f64; 3]> = sets
            .iter()
            .map(|(set, _)| (set.seq, set.to_coefficients().unwrap().integral()))
            .collect();
        let lights: Vec<_> = lights
            .iter()
            .filter(|f| received.contains_key(&f.seq))
            .cloned()
            .collect();
        common::assert_sets_follow_the_lights(
            &lights,
            |seq| received[&seq],
            |seq| own_integrals[seq as usize],
        );
    }
}

#[test]
fn sighup_keeps_the_sh_filter_on_the_lights_taps() {
    let dir = tempfile::tempdir().unwrap();
    let stage = "[sh]\nenabled = true\n";
    let with = |decompose: &str, stage: &str| {
        let sky = SMALL_SKY.replace(
            "working_width = 16\n",
            &format!("working_width = 16\n{decompose}"),
        );
        config(dir.path(), &format!("{sky}{stage}"))
    };
    let mut daemon = Daemon::start(with("", stage), DaemonOptions::default()).unwrap();
    let mut rx = daemon.sh().unwrap().subscribe();
    let mut sets = 0;
    let mut next_set = |what: &str| common::wait_for_next_publication(&mut rx, &mut sets, what);
    next_set("a first set");
    let http = daemon.addresses().metrics.unwrap();
    let delay = || {
        metric_value(
            &http_get(http, "/metrics").1,
            "envlight_filter_delay_frames",
        )
    };
    assert_eq!(delay(), 3.0, "the default taps' delay");

    let taps = "filter_taps = [1.0, 2.0, 1.0]\n";
    let report = daemon.reload(with(taps, stage));
    assert_eq!(report.applied, ["[decompose]", "[sh]"], "{report:?}");
    assert_eq!(delay(), 1.0, "the new taps' delay");
    next_set("a set with the new taps");

    let report = daemon.reload(with(&format!("{taps}merge = true\n"), stage));
    assert_eq!(
        report.applied,
        [
            "[decompose]",
            "[sh] (its temporal filter restarts with the lights')"
        ],
        "{report:?}"
    );
    next_set("a set after the restart");

    let off = format!("{stage}filter = false\n");
    let report = daemon.reload(with(&format!("{taps}merge = true\n"), &off));
    assert_eq!(report.applied, ["[sh]"], "{report:?}");
    next_set("an unfiltered set");
    // Unchanged: nothing to apply.
    let report = daemon.reload(with(&format!("{taps}merge = true\n"), &off));
    assert!(report.applied.is_empty(), "{report:?}");
    let stats = daemon.shutdown().unwrap().sh.unwrap();
    // Each change is a new worker, which keeps the projection plan: the degree stays (every
    // change rebuilt it before).
    assert_eq!(stats.plans, 1, "one plan through the three changes");
    assert_eq!(stats.errors, 0);
}

#[test]
fn the_python_example_client_reads_sh_sets() {
    common::require_python3();
    let dir = tempfile::tempdir().unwrap();
    let extra = format!("{SMALL_SKY}[sh]\nenabled = true\ndegree = 3\n");
    let daemon = Daemon::start(config(dir.path(), &extra), DaemonOptions::default()).unwrap();
    let tcp = daemon.addresses().stream.tcp.unwrap();
    // A cap of 5 keeps the bands that fit whole: degrees 0 and 1.
    // Binary frames and JSON lines alike.
    let address = tcp.to_string();
    for (form, lines) in common::python_client_both_forms(&[
        &address,
        "--representation",
        "sh",
        "--frames",
        "2",
        "--max-lights",
        "5",
    ]) {
        assert_eq!(lines.len(), 2, "{form}: {lines:?}");
        assert!(
            lines.iter().all(|l| {
                l.contains(": SH degree 1 (4 coefficients), total rgb [")
                    && l.contains("], irradiance up [")
            }),
            "{form}: {lines:?}"
        );
    }
    daemon.shutdown().unwrap();
}
