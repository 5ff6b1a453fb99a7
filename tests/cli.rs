//! Integration tests of the `envlight` binary: output form, exit codes and error messages.

use exr::prelude::{
    AnyChannel, AnyChannels, Encoding, FlatSamples, Image, ImageAttributes, IntegerBounds, Layer,
    LayerAttributes, SmallVec, WritableImage,
};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn envlight(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_envlight"))
        .args(args)
        .env_remove("RUST_LOG")
        .output()
        .expect("run envlight")
}

fn data(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
        .display()
        .to_string()
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// Parses JSON lines and checks every light: unit dir, finite non-negative rgb, solid angle ≥ 0.
fn check_frames(text: &str, max_lights: usize) -> Vec<Value> {
    let frames: Vec<Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("bad JSON {l:?}: {e}")))
        .collect();
    for f in &frames {
        assert!(f["time"].as_f64().is_some_and(f64::is_finite), "{f}");
        let lights = f["lights"].as_array().expect("lights array");
        assert!(
            !lights.is_empty() && lights.len() <= max_lights,
            "{}",
            lights.len()
        );
        for l in lights {
            assert!(l["id"].as_u64().is_some(), "{l}");
            let dir: Vec<f64> = l["dir"]
                .as_array()
                .expect("dir")
                .iter()
                .map(|c| c.as_f64().expect("number"))
                .collect();
            assert_eq!(dir.len(), 3);
            let norm = dir.iter().map(|c| c * c).sum::<f64>().sqrt();
            assert!((norm - 1.0).abs() < 1e-3, "dir {dir:?} is not unit");
            let rgb = l["rgb"].as_array().expect("rgb");
            assert_eq!(rgb.len(), 3);
            for c in rgb {
                let c = c.as_f64().expect("rgb must be numbers (no NaN)");
                assert!(c.is_finite() && c >= 0.0, "{l}");
            }
            let omega = l["solid_angle"].as_f64().expect("solid_angle");
            assert!(omega.is_finite() && omega >= 0.0, "{l}");
        }
    }
    frames
}

fn assert_fails_naming(o: &Output, needles: &[&str]) {
    let err = stderr(o);
    assert!(!o.status.success(), "expected failure; stderr: {err}");
    assert!(err.contains("error:"), "{err}");
    for n in needles {
        assert!(err.contains(n), "stderr does not mention {n:?}: {err}");
    }
}

fn write_rgb(path: &Path, w: usize, h: usize, value: f32) {
    exr::prelude::write_rgb_file(path, w, h, |_, _| (value, value, value)).unwrap();
}

#[test]
fn sky_run_prints_json_lines() {
    let o = envlight(&["decompose", "--frames", "3", "--lights", "16"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let frames = check_frames(&stdout(&o), 16);
    assert_eq!(frames.len(), 3);
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(f["seq"].as_u64(), Some(i as u64));
    }
    let err = stderr(&o);
    assert!(err.contains("built-in sky"), "{err}");
    assert!(err.contains("filter delay"), "{err}");
    assert!(err.contains("3 frames"), "{err}");
}

#[test]
fn hdr_file_to_out_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("lights.jsonl");
    let o = envlight(&[
        "decompose",
        &data("rooitou_park_1k.hdr"),
        "--lights",
        "64",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(o.stdout.is_empty());
    let text = std::fs::read_to_string(&out).unwrap();
    let frames = check_frames(&text, 64);
    assert_eq!(frames.len(), 1);
    assert_eq!(frames[0]["seq"].as_u64(), Some(0));
}

#[test]
fn options_are_accepted() {
    let o = envlight(&[
        "decompose",
        "--frames",
        "2",
        "--lights",
        "8",
        "--no-filter",
        "--no-merge",
        "--placement",
        "sample-point",
        "--warp",
        "hierarchical",
        "--working-width",
        "32",
        "--sky-size",
        "64x32",
        "--no-clouds",
        "--seed",
        "7",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let frames = check_frames(&stdout(&o), 8);
    assert_eq!(frames.len(), 2);
    // Without merging every light is there.
    assert!(frames
        .iter()
        .all(|f| f["lights"].as_array().unwrap().len() == 8));

    let o = decompose_small_sky(2, 8, &["--taps", "1,2,1", "--merge-fraction", "0.5"]);
    assert_logged(&o, "delay: 1 frames");

    let o = decompose_small_sky(1, 8, &["--merge", "--pdf-exponent", "1"]);
    assert_logged(&o, "merge at 0.1");
    assert_logged(&o, "concentrated Lloyd step off");
    assert_logged(&o, "refinement of concentrated sources on");
    check_frames(&stdout(&o), 8);

    let o = decompose_small_sky(1, 8, &["--no-refine-concentrated"]);
    assert_logged(&o, "refinement of concentrated sources off");
    check_frames(&stdout(&o), 8);

    let o = decompose_small_sky(2, 16, &["--concentrated-lloyd"]);
    assert_logged(&o, "concentrated Lloyd step on");
    assert_eq!(check_frames(&stdout(&o), 16).len(), 2);

    let o = decompose_small_sky(2, 8, &[]);
    assert_logged(&o, "bright lights: fold");
    // `fade` may add fading lights (ids from 2^24); every other id is a point-set index.
    let o = decompose_small_sky(12, 16, &["--bright-history", "fade"]);
    assert_logged(&o, "bright lights: fade");
    for frame in check_frames(&stdout(&o), 16 + 16 * 6 / 10) {
        for l in frame["lights"].as_array().unwrap() {
            let id = l["id"].as_u64().unwrap();
            assert!(!(16..1 << 24).contains(&id), "{l}");
        }
    }
    let o = decompose_small_sky(2, 16, &[]);
    assert_logged(&o, "split of bright lights off");
    let o = decompose_small_sky(2, 16, &["--split"]);
    assert_logged(&o, "split of bright lights above 3.5× the mean light");
    check_frames(&stdout(&o), 16);
    let o = decompose_small_sky(2, 16, &["--split-factor", "2"]);
    assert_logged(&o, "split of bright lights above 2× the mean light");
    check_frames(&stdout(&o), 16);
    let o = envlight(&["decompose", "--frames", "1", "--split-factor", "0.5"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--split-factor"), "{}", stderr(&o));
    let o = decompose_small_sky(2, 8, &["--bright-history", "blend"]);
    assert_logged(&o, "bright lights: blend");
    let o = envlight(&["decompose", "--frames", "1", "--bright-history", "merge"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--bright-history"), "{}", stderr(&o));
}

/// `envlight decompose` of `frames` frames of a 64×32 built-in sky into `lights` lights with
/// `options`; it must succeed.
fn decompose_small_sky(frames: u32, lights: u32, options: &[&str]) -> Output {
    let o = run_small_sky(frames, lights, options);
    assert!(o.status.success(), "{options:?}: {}", stderr(&o));
    o
}

/// `envlight decompose` of `frames` frames of a 64×32 sky into `lights` lights, with
/// `options`; success or not.
fn run_small_sky(frames: u32, lights: u32, options: &[&str]) -> Output {
    let (frames, lights) = (frames.to_string(), lights.to_string());
    let mut args = vec!["decompose", "--frames", &frames, "--lights", &lights];
    args.extend_from_slice(options);
    args.extend_from_slice(&["--sky-size", "64x32"]);
    envlight(&args)
}

/// The run's log (stderr) contains `text`.
fn assert_logged(o: &Output, text: &str) {
    assert!(
        stderr(o).contains(text),
        "{text:?} not logged: {}",
        stderr(o)
    );
}

#[test]
fn merge_flags_conflict_and_exponent_is_checked() {
    let o = envlight(&["decompose", "--frames", "1", "--merge", "--no-merge"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let o = envlight(&["decompose", "--frames", "1", "--pdf-exponent", "0"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("--pdf-exponent"), "{}", stderr(&o));
}

#[test]
fn fisheye_options_decompose() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fish.exr");
    write_rgb(&path, 32, 32, 1.0);
    let o = envlight(&[
        "decompose",
        s(&path),
        "--lights",
        "8",
        "--projection",
        "fisheye",
        "--fisheye-model",
        "equisolid",
        "--center",
        "16,16",
        "--radius",
        "16",
        "--fov",
        "190",
        "--rotation",
        "-10",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    check_frames(&stdout(&o), 8);

    // An image circle outside the image is named.
    let o = envlight(&[
        "decompose",
        s(&path),
        "--projection",
        "fisheye",
        "--center",
        "500,500",
        "--radius",
        "10",
    ]);
    assert_fails_naming(&o, &["--center", "32x32"]);
    assert_eq!(o.status.code(), Some(1));

    // A centre left of or above the image (a circle cut by the border) is a value, not an
    // unknown option `-1`.
    let o = envlight(&[
        "decompose",
        s(&path),
        "--lights",
        "8",
        "--projection",
        "fisheye",
        "--center",
        "-4,16",
        "--radius",
        "20",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    check_frames(&stdout(&o), 8);
}

#[test]
fn config_file_is_used_and_flags_override_it() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("envlight.toml");
    std::fs::write(
        &config,
        "[source]\nframes = 2\n[sky]\nwidth = 64\nheight = 32\n[decompose]\nlights = 4\nmerge = false\n",
    )
    .unwrap();
    let o = envlight(&["decompose", "--config", s(&config)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let frames = check_frames(&stdout(&o), 4);
    assert_eq!(frames.len(), 2);
    assert!(frames
        .iter()
        .all(|f| f["lights"].as_array().unwrap().len() == 4));

    let o = envlight(&["decompose", "--config", s(&config), "--lights", "6"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(check_frames(&stdout(&o), 6)
        .iter()
        .all(|f| f["lights"].as_array().unwrap().len() == 6));

    // The shipped config works as is.
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/envlight.toml");
    let o = envlight(&[
        "decompose",
        "--config",
        s(&shipped),
        "--frames",
        "1",
        "--sky-size",
        "64x32",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));

    std::fs::write(&config, "[decompose]\nlightz = 4\n").unwrap();
    let o = envlight(&["decompose", "--config", s(&config)]);
    assert_fails_naming(&o, &["lightz", "envlight.toml"]);

    std::fs::write(&config, "[source.fisheye]\nfov_deg = 400\n").unwrap();
    let o = envlight(&["decompose", "--config", s(&config)]);
    assert_fails_naming(&o, &["source.fisheye.fov_deg", "400"]);
}

/// INPUT and --device replace the configured source whatever its kind, and a mistake on the
/// command line is a usage error that names it (not the config file, nor a flag the command
/// would have ignored).
#[test]
fn the_command_line_replaces_the_configured_source_and_names_its_own_mistakes() {
    let dir = tempfile::tempdir().unwrap();
    let frame = dir.path().join("in.exr");
    write_rgb(&frame, 16, 8, 1.0);
    let config = |name: &str, text: &str| {
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        path.display().to_string()
    };
    let camera = config("cam.toml", "[source]\nkind = \"v4l2\"\n");
    let sequence = config(
        "seq.toml",
        &format!("[source]\nkind = \"sequence\"\npaths = [{:?}]\n", s(&frame)),
    );
    let unfiltered = config("nf.toml", "[decompose]\nfilter = false\n");
    // INPUT files replace a configured camera (decompose waited for the camera).
    let o = envlight(&["decompose", "--config", &camera, s(&frame), "-n", "4"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(check_frames(&stdout(&o), 4).len(), 1);
    let out = dir.path().join("check.txt");
    let o = envlight(&["check-config", "--config", &sequence]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("seq.toml: ok"), "{}", stdout(&o));
    let usage_errors: [(&[&str], &[&str]); 11] = [
        (&["sh", "--radius", "5"], &["--radius", "INPUT", "sky"]),
        (&["wavelet", "approx", "--fov", "120"], &["--fov", "INPUT"]),
        (
            &["sh", "v4l2:/dev/video0"],
            &["INPUT v4l2:/dev/video0", "reads frame files"],
        ),
        (&["sh", ""], &["invalid INPUT", "empty path"]),
        (&["decompose", ""], &["invalid INPUT", "empty path"]),
        (&["run", ""], &["invalid INPUT", "empty path"]),
        (
            &["run", "v4l2:/dev/video0", s(&frame)],
            &["INPUT v4l2:/dev/video0", "only INPUT"],
        ),
        (
            &[
                "decompose",
                "--config",
                &unfiltered,
                "--bright-history",
                "fade",
            ],
            &["--bright-history", "decompose.filter = false"],
        ),
        (
            &["decompose", "--sky-size", "100x0"],
            &["--sky-size height 0"],
        ),
        (
            &["calibrate-fisheye", "--config", &camera, s(&frame)],
            &["--config", "--device"],
        ),
        (
            &[
                "calibrate-response",
                "--config",
                &camera,
                s(&frame),
                s(&frame),
                "--exposures",
                "0.01,0.04",
                "-o",
                s(&out),
            ],
            &["--config", "--device"],
        ),
    ];
    for (args, needles) in usage_errors {
        let o = envlight(args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        assert_fails_naming(&o, needles);
        assert!(
            !stderr(&o).contains("invalid setting"),
            "{args:?}: {}",
            stderr(&o)
        );
    }
    assert!(!out.exists());
}

/// Relative paths in a config file are the file's folder's: the same config works from any
/// working directory (a service runs from `/`), for files, patterns and a folder whose name
/// holds glob characters; a path given on the command line stays the working directory's.
#[test]
fn relative_paths_in_a_config_file_are_its_folders() {
    let dir = tempfile::tempdir().unwrap();
    let folder = dir.path().join("rig [a]");
    std::fs::create_dir_all(folder.join("takes")).unwrap();
    write_rgb(&folder.join("takes/f_1.exr"), 8, 4, 1.0);
    write_rgb(&folder.join("takes/f_2.exr"), 8, 4, 2.0);
    std::fs::write(folder.join("response.txt"), "0 0 0 0\n1 1 1 1\n").unwrap();
    let config = folder.join("envlight.toml");
    let elsewhere = dir.path();
    for paths in [
        r#"["takes/f_1.exr", "takes/f_2.exr"]"#,
        r#"["takes/*.exr"]"#,
        r#"["takes"]"#,
    ] {
        std::fs::write(
            &config,
            format!(
                "[source]\nkind = \"sequence\"\npaths = {paths}\n[camera]\n\
                 response = \"curve\"\ncurve = \"response.txt\"\n[decompose]\nlights = 4\n"
            ),
        )
        .unwrap();
        let o = Command::new(env!("CARGO_BIN_EXE_envlight"))
            .args(["decompose", "--config", s(&config)])
            .current_dir(elsewhere)
            .env_remove("RUST_LOG")
            .output()
            .unwrap();
        assert!(o.status.success(), "{paths}: {}", stderr(&o));
        assert_eq!(check_frames(&stdout(&o), 4).len(), 2, "{paths}");
        let o = Command::new(env!("CARGO_BIN_EXE_envlight"))
            .args(["check-config", s(&config)])
            .current_dir(elsewhere)
            .output()
            .unwrap();
        assert!(o.status.success(), "{paths}: {}", stderr(&o));
    }
    // INPUT on the command line is the working directory's (here: no such file).
    let o = Command::new(env!("CARGO_BIN_EXE_envlight"))
        .args(["decompose", "--config", s(&config), "takes/f_1.exr"])
        .current_dir(elsewhere)
        .output()
        .unwrap();
    assert_fails_naming(&o, &["takes/f_1.exr"]);
}

#[test]
fn broken_pipe_ends_quietly() {
    use std::io::Read;
    let mut child = Command::new(env!("CARGO_BIN_EXE_envlight"))
        .args([
            "decompose",
            "--frames",
            "0",
            "--lights",
            "4",
            "--sky-size",
            "32x16",
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdout = child.stdout.take().unwrap();
    let mut first = [0u8; 16];
    stdout.read_exact(&mut first).unwrap();
    drop(stdout);
    let status = child.wait().unwrap();
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    assert!(status.success(), "{status}: {err}");
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn no_subcommand_prints_help_and_version_works() {
    let o = envlight(&[]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("decompose"), "{}", stderr(&o));
    let o = envlight(&["--version"]);
    assert!(o.status.success());
    assert!(stdout(&o).contains(env!("CARGO_PKG_VERSION")));
    let o = envlight(&["decompose", "--help"]);
    assert!(o.status.success());
    assert!(stdout(&o).contains("solid_angle"));
}

// ------------------------------------------------------------------------------------------------
// Errors

#[test]
fn missing_file_is_named() {
    let o = envlight(&["decompose", "/nonexistent/frame_0001.exr"]);
    assert_fails_naming(&o, &["/nonexistent/frame_0001.exr"]);
    assert_eq!(o.status.code(), Some(1));
}

/// An INPUT that is not UTF-8 is a usage error that names it (clap's own message did not say
/// which argument), for every command that takes INPUT; the same file is read through its
/// directory.
#[test]
fn non_utf8_input_is_named_and_read_through_its_directory() {
    use std::os::unix::ffi::OsStrExt;
    let dir = tempfile::tempdir().unwrap();
    let frame = dir
        .path()
        .join(std::ffi::OsStr::from_bytes(b"take_\xff_1.exr"));
    write_rgb(&frame, 8, 4, 1.0);
    for command in [
        &["decompose"][..],
        &["run"],
        &["record", "--out", "unused"],
        &["fit-asg"],
        &["render"],
        &["wavelet", "approx"],
        &["sh"],
    ] {
        let o = Command::new(env!("CARGO_BIN_EXE_envlight"))
            .args(command)
            .arg(&frame)
            .env_remove("RUST_LOG")
            .output()
            .expect("run envlight");
        assert_eq!(o.status.code(), Some(2), "{command:?}: {}", stderr(&o));
        let err = stderr(&o);
        assert!(
            err.contains("take_\u{fffd}_1.exr") && err.contains("not valid UTF-8"),
            "{command:?}: {err}"
        );
    }
    let o = envlight(&["decompose", "-n", "4", s(dir.path())]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(check_frames(&stdout(&o), 4).len(), 1);

    // With more frames: a character of several bytes before a name's number (its sorting
    // panicked), and a pattern, which cannot match the name that is not UTF-8, says so.
    write_rgb(&dir.path().join("take_é2.exr"), 8, 4, 1.0);
    write_rgb(&dir.path().join("take_—3.exr"), 8, 4, 1.0);
    let o = envlight(&["decompose", "-n", "4", s(dir.path())]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(check_frames(&stdout(&o), 4).len(), 3);
    let pattern = format!("{}/*.exr", s(dir.path()));
    let o = envlight(&["decompose", "-n", "4", &pattern]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(check_frames(&stdout(&o), 4).len(), 2);
    let err = stderr(&o);
    assert!(
        err.contains("1 frame file(s) in") && err.contains("give the directory to read them"),
        "{err}"
    );
}

/// A light file without frames is an error naming it, before any GPU work (an empty render
/// that exits 0 would look like success).
#[test]
fn render_of_an_empty_light_file_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let lights = dir.path().join("lights.jsonl");
    std::fs::write(&lights, "\n  \n").unwrap();
    let out = dir.path().join("out");
    let o = envlight(&["render", "--lights", s(&lights), "--out", s(&out)]);
    assert_fails_naming(&o, &[s(&lights), "no light frames"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(!out.exists(), "nothing is written");
}

#[test]
fn corrupt_exr_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("garbage.exr");
    std::fs::write(
        &path,
        b"this is not an OpenEXR file at all, just some garbage bytes",
    )
    .unwrap();
    let o = envlight(&["decompose", s(&path)]);
    assert_fails_naming(&o, &["garbage.exr"]);
    assert_eq!(o.status.code(), Some(1));
}

#[test]
fn truncated_hdr_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(data("noon_grass_1k.hdr")).unwrap();
    let path = dir.path().join("half.hdr");
    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    let o = envlight(&["decompose", s(&path)]);
    assert_fails_naming(&o, &["half.hdr"]);
    assert_eq!(o.status.code(), Some(1));
}

#[test]
fn size_change_is_fatal_and_named() {
    let dir = tempfile::tempdir().unwrap();
    write_rgb(&dir.path().join("frame_1.exr"), 16, 8, 1.0);
    write_rgb(&dir.path().join("frame_2.exr"), 32, 16, 1.0);
    let o = envlight(&["decompose", s(dir.path()), "--lights", "4"]);
    assert_fails_naming(&o, &["frame_2.exr", "32x16", "16x8"]);
    assert_eq!(o.status.code(), Some(1));
    // The first frame was written before the error.
    assert_eq!(stdout(&o).lines().count(), 1);
}

#[test]
fn unsupported_channels_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("depth.exr");
    let (w, h) = (8usize, 4usize);
    let channel = AnyChannel::new("Z", FlatSamples::F32(vec![1.0; w * h]));
    let layer = Layer::new(
        (w, h),
        LayerAttributes::default(),
        Encoding::UNCOMPRESSED,
        AnyChannels::sort(SmallVec::from_vec(vec![channel])),
    );
    let image = Image::from_layers(
        ImageAttributes::new(IntegerBounds::from_dimensions((w, h))),
        vec![layer],
    );
    image.write().to_file(&path).unwrap();
    let o = envlight(&["decompose", s(&path)]);
    assert_fails_naming(&o, &["depth.exr", "Z"]);
    assert_eq!(o.status.code(), Some(1));
}

/// A data window other than the display window is read as the whole map (docs in
/// capture/image_file.rs), and a warning says so: it shifts every direction.
#[test]
fn a_cropped_data_window_is_read_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("crop.exr");
    let (w, h) = (16usize, 8usize);
    let channels = ["R", "G", "B"]
        .map(|name| AnyChannel::new(name, FlatSamples::F32(vec![1.0; w * h])))
        .to_vec();
    let attributes = LayerAttributes {
        layer_position: exr::math::Vec2(4, 2),
        ..LayerAttributes::default()
    };
    let layer = Layer::new(
        (w, h),
        attributes,
        Encoding::UNCOMPRESSED,
        AnyChannels::sort(SmallVec::from_vec(channels)),
    );
    let image = Image::from_layers(
        ImageAttributes::new(IntegerBounds::from_dimensions((32, 16))),
        vec![layer],
    );
    image.write().to_file(&path).unwrap();
    let o = envlight(&["decompose", "-n", "4", s(&path)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(check_frames(&stdout(&o), 4).len(), 1);
    let err = stderr(&o);
    assert!(
        err.contains("its data window (16x8 at 4, 2) is not its display window (32x16 at 0, 0)"),
        "{err}"
    );
}

/// A Blender-style multilayer frame is read from its beauty pass (`ViewLayer.Combined`, which
/// sorts after `ViewLayer.AO`: the AO pass was read, without a word), with a warning naming
/// the layer read and the others; primaries other than Rec. 709's (ACES AP0) are warned of.
#[test]
fn a_multilayer_frame_is_read_from_its_beauty_pass_with_warnings() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("render.exr");
    let (w, h) = (16usize, 8usize);
    let layer_channels = |layer: &str, value: f32| {
        ["R", "G", "B"].map(|c| {
            AnyChannel::new(
                format!("ViewLayer.{layer}.{c}").as_str(),
                FlatSamples::F32(vec![value; w * h]),
            )
        })
    };
    let mut channels = layer_channels("AO", 0.5).to_vec();
    channels.extend(layer_channels("Combined", 10.0));
    let layer = Layer::new(
        (w, h),
        LayerAttributes::default(),
        Encoding::UNCOMPRESSED,
        AnyChannels::sort(SmallVec::from_vec(channels)),
    );
    let mut attributes = ImageAttributes::new(IntegerBounds::from_dimensions((w, h)));
    attributes.chromaticities = Some(exr::meta::attribute::Chromaticities {
        red: exr::math::Vec2(0.7347, 0.2653),
        green: exr::math::Vec2(0.0, 1.0),
        blue: exr::math::Vec2(0.0001, -0.077),
        white: exr::math::Vec2(0.32168, 0.33767),
    });
    Image::from_layers(attributes, vec![layer])
        .write()
        .to_file(&path)
        .unwrap();
    let o = envlight(&["decompose", "-n", "4", "--no-filter", s(&path)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let frames = check_frames(&stdout(&o), 4);
    let red: f64 = frames[0]["lights"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| l["rgb"][0].as_f64().unwrap())
        .sum();
    let sphere = 4.0 * std::f64::consts::PI;
    assert!(
        (red - 10.0 * sphere).abs() < 1e-3 * red,
        "{red}: not the Combined pass"
    );
    let err = stderr(&o);
    assert!(
        err.contains("read from the layer ViewLayer.Combined (part 0)")
            && err.contains("not read: ViewLayer.AO (part 0)"),
        "{err}"
    );
    assert!(
        err.contains("chromaticities") && err.contains("(0.7347, 0.2653)"),
        "{err}"
    );
}

#[test]
fn bad_light_counts_name_the_flag() {
    for n in ["0", "100000000"] {
        let o = envlight(&["decompose", "--lights", n, "--frames", "1"]);
        let max = envlight::decompose::MAX_POINTS.to_string();
        assert_fails_naming(&o, &["--lights", n, &max]);
        // A value out of range is a usage error, as clap's own range checks are.
        assert_eq!(o.status.code(), Some(2));
    }
    let o = envlight(&["decompose", "--loop"]);
    assert_fails_naming(&o, &["--loop"]);
    let o = envlight(&["decompose", "--lights", "many"]);
    assert_fails_naming(&o, &["--lights"]);
    assert_eq!(o.status.code(), Some(2));
}

/// A negative number given to an option is that option's value, checked like any other
/// (clap alone took `-5` for an unknown flag and suggested `-- -5`, which does not help).
#[test]
fn negative_values_are_checked_as_values() {
    let o = envlight(&["decompose", "--fps", "-5", "--frames", "1"]);
    assert_fails_naming(&o, &["--fps", "-5", "at least"]);
    for (option, value) in [("--lights", "-3"), ("--frames", "-1")] {
        let o = envlight(&["decompose", option, value]);
        assert_fails_naming(&o, &[option, value]);
        assert!(
            !stderr(&o).contains("unexpected argument"),
            "{}",
            stderr(&o)
        );
    }
    // Numeric options take any value that starts with '-': -inf, negative sizes, a flag given
    // in the value's place (refused by the option's parser, naming the option).
    for (option, value) in [
        ("--fps", "-inf"),
        ("--sky-size", "-1x-1"),
        ("--fps", "--frames"),
    ] {
        let o = envlight(&["decompose", option, value, "--frames", "1"]);
        assert_fails_naming(&o, &[option, value]);
        assert!(
            !stderr(&o).contains("unexpected argument"),
            "{}",
            stderr(&o)
        );
    }
    // Others keep clap's check: a path option followed by a flag is missing its value.
    let o = envlight(&["decompose", "--out", "--frames", "1"]);
    assert_fails_naming(&o, &["--out", "a value is required"]);
    let o = envlight(&["fit-asg", "--temporal-weight", "-1", "--frames", "1"]);
    assert_fails_naming(&o, &["temporal_weight", "-1"]);
    // Positional arguments are unchanged: `-5` there is still an unknown flag.
    let o = envlight(&["decompose", "-5"]);
    assert_fails_naming(&o, &["-5"]);
    assert_eq!(o.status.code(), Some(2));
}

/// A setting that two flags make invalid together names the flag, not a config key of a file
/// that was never given ("invalid setting in defaults").
#[test]
fn conflicting_flags_are_named() {
    let o = envlight(&[
        "decompose",
        "--split",
        "--placement",
        "sample-point",
        "--frames",
        "1",
    ]);
    assert_fails_naming(&o, &["invalid --split:", "centroid"]);
    assert!(!stderr(&o).contains("defaults"), "{}", stderr(&o));
    let o = envlight(&[
        "decompose",
        "--split-factor",
        "2",
        "--placement",
        "sample-point",
    ]);
    assert_fails_naming(&o, &["invalid --split-factor", "centroid"]);
    // A comma list that starts with a negative number is the option's value, checked as such.
    let o = envlight(&["decompose", "--taps", "-1,2,1", "--frames", "1"]);
    assert_fails_naming(&o, &["--taps"]);
    assert!(
        !stderr(&o).contains("unexpected argument"),
        "{}",
        stderr(&o)
    );
}

/// `render --out` is a folder: an image file name is refused before anything is created, and
/// --size has the range of render.width / render.height.
#[test]
fn render_out_and_size_are_checked_before_rendering() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("frame.png");
    let o = envlight(&["render", "--out", s(&png), "--size", "8x4", "--frames", "1"]);
    assert_fails_naming(&o, &["frame.png", "folder"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(!png.exists());
    for size in ["0x4", "16385x2"] {
        let o = envlight(&["render", "--out", s(dir.path()), "--size", size]);
        assert_fails_naming(&o, &["--size", size, "1..=16384"]);
    }
}

/// Numbers are checked where they are given and shown short: an f32 option past f32's range
/// names the option and the value (it became inf: "got inf"), a frame rate of 1e-300 is shown
/// as such (it was three hundred zeros), noise past 100× the signal is refused (1e300 left
/// every error NaN).
#[test]
fn extreme_numbers_name_the_option_and_are_shown_short() {
    let o = envlight(&[
        "wavelet",
        "relight",
        "--brdf",
        "phong",
        "--exponent",
        "1e39",
    ]);
    assert_fails_naming(&o, &["--exponent", "1e39", "3.4e38"]);
    let o = envlight(&["render", "--exposure", "1e39", "--out", "unused-folder"]);
    assert_fails_naming(&o, &["--exposure", "1e39"]);
    let o = envlight(&["decompose", "--fps", "1e-300", "--frames", "1"]);
    assert_fails_naming(&o, &["--fps", "got 1e-300"]);
    assert!(stderr(&o).len() < 400, "{}", stderr(&o));
    for noise in ["1e300", "-1"] {
        let o = envlight(&["wavelet", "recover", "--noise", noise, "--size", "4"]);
        assert_fails_naming(&o, &["--noise", noise, "0..=100"]);
    }
}

/// `subscribe` to a path that is a file or a folder says so (it said "Connection refused").
#[test]
fn subscribe_to_a_file_says_it_is_no_socket() {
    let o = envlight(&["subscribe", &data("rooitou_park_1k.hdr")]);
    assert_fails_naming(&o, &["rooitou_park_1k.hdr", "a file, not a socket"]);
    let dir = tempfile::tempdir().unwrap();
    let o = envlight(&["subscribe", &format!("unix:{}", s(dir.path()))]);
    assert_fails_naming(&o, &["a directory, not a socket"]);
}

/// `subscribe` to an endpoint nobody serves asks whether the daemon runs there, and names
/// the default endpoints.
#[test]
fn subscribe_where_no_daemon_serves_asks_whether_it_runs() {
    // A port that was free a moment ago (bound, then released).
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let dir = tempfile::tempdir().unwrap();
    for address in [
        format!("tcp:127.0.0.1:{port}"),
        format!("ws://127.0.0.1:{port}/"),
        format!("unix:{}", s(&dir.path().join("none.sock"))),
    ] {
        let o = envlight(&["subscribe", &address]);
        assert_fails_naming(
            &o,
            &[
                &address,
                "is `envlight run` serving there?",
                "tcp:127.0.0.1:7878",
            ],
        );
    }
}

#[test]
fn bad_taps_name_the_flag() {
    // Spaces after the commas are fine.
    let o = envlight(&[
        "decompose",
        "--taps",
        "1, 2, 1",
        "--frames",
        "1",
        "--lights",
        "4",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = envlight(&["decompose", "--taps", "1,x,1"]);
    assert_fails_naming(&o, &["--taps"]);
    assert_eq!(o.status.code(), Some(2));
    let o = envlight(&["decompose", "--taps", "0,0", "--frames", "1"]);
    assert_fails_naming(&o, &["--taps"]);
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn bad_fov_names_the_flag() {
    // Below a degree is no fisheye (1e-308 was accepted).
    for fov in ["400", "0.5", "1e-308"] {
        let o = envlight(&[
            "decompose",
            &data("rooitou_park_1k.hdr"),
            "--projection",
            "fisheye",
            "--fov",
            fov,
        ]);
        assert_fails_naming(&o, &["--fov", fov, "[1, 360)"]);
        assert_eq!(o.status.code(), Some(2));
    }
}

#[test]
fn unwritable_out_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let out: PathBuf = dir.path().join("no/such/dir/lights.jsonl");
    let o = envlight(&["decompose", "--frames", "1", "--out", s(&out)]);
    assert_fails_naming(&o, &[s(&out)]);
    assert_eq!(o.status.code(), Some(1));
}

// ------------------------------------------------------------------------------------------------
// Awkward pixels

#[test]
fn nan_inf_negative_pixels_are_sanitised_with_one_warning() {
    let image =
        envlight::capture::image_file::read_hdr_image(Path::new(&data("AllHalfValues.exr")))
            .unwrap();
    let bad = image
        .pixels
        .iter()
        .filter(|p| p.iter().any(|c| !(c.is_finite() && *c >= 0.0)))
        .count();
    assert!(bad > 0);

    let o = envlight(&["decompose", &data("AllHalfValues.exr"), "--lights", "32"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = stdout(&o);
    assert!(!out.contains("NaN") && !out.contains("null"), "{out}");
    check_frames(&out, 32);
    let err = stderr(&o);
    let warnings: Vec<&str> = err.lines().filter(|l| l.contains("WARN")).collect();
    assert_eq!(warnings.len(), 1, "{err}");
    assert!(warnings[0].contains(&bad.to_string()), "{err}");
}

#[test]
fn black_frame_gives_black_lights() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("black.exr");
    write_rgb(&path, 32, 16, 0.0);
    let o = envlight(&["decompose", s(&path), "--lights", "8"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = stdout(&o);
    assert!(!out.contains("NaN") && !out.contains("null"), "{out}");
    let frames = check_frames(&out, 8);
    for l in frames[0]["lights"].as_array().unwrap() {
        for c in l["rgb"].as_array().unwrap() {
            assert_eq!(c.as_f64(), Some(0.0), "{l}");
        }
    }
}

#[test]
fn latest_file_holds_only_the_newest_frame() {
    let dir = tempfile::tempdir().unwrap();
    let latest = dir.path().join("lights.json");
    let o = envlight(&[
        "decompose",
        "--frames",
        "3",
        "--lights",
        "8",
        "--sky-size",
        "64x32",
        "--latest",
        latest.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        check_frames(&stdout(&o), 8).len(),
        3,
        "stdout still has every frame"
    );
    let text = std::fs::read_to_string(&latest).unwrap();
    let frames = check_frames(&text, 8);
    assert_eq!(frames.len(), 1);
    assert_eq!(frames[0]["seq"].as_u64(), Some(2));
    assert!(!dir.path().join("lights.json.tmp").exists());

    let o = run_small_sky(1, 4, &["--latest", "/nonexistent-dir/lights.json"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("/nonexistent-dir/lights.json"),
        "{}",
        stderr(&o)
    );

    // --out on --latest or on its temporary file (also through `..`, or when it exists
    // already) is refused before anything is written: the newest frame would replace the
    // stream. A directory as --latest is refused before the first frame, leaving no DIR.tmp.
    let sub = dir.path().join("sub");
    std::fs::create_dir(&sub).unwrap();
    std::fs::write(dir.path().join("kept.json"), "kept\n").unwrap();
    for (out, latest) in [
        ("a.json", "a.json"),
        ("b.json.tmp", "b.json"),
        ("sub/../c.json", "c.json"),
        ("kept.json", "kept.json"),
    ] {
        let (out, latest) = (dir.path().join(out), dir.path().join(latest));
        let o = run_small_sky(2, 4, &["--out", s(&out), "--latest", s(&latest)]);
        assert_eq!(o.status.code(), Some(1), "{out:?} {latest:?}");
        assert!(
            stderr(&o).contains("the newest frame would replace the stream"),
            "{}",
            stderr(&o)
        );
    }
    assert_eq!(
        std::fs::read_to_string(dir.path().join("kept.json")).unwrap(),
        "kept\n"
    );
    for name in ["a.json", "b.json", "b.json.tmp", "c.json"] {
        assert!(!dir.path().join(name).exists(), "{name} was written");
    }
    let o = run_small_sky(1, 4, &["--latest", s(&sub)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("is a directory"), "{}", stderr(&o));
    assert!(!dir.path().join("sub.tmp").exists());

    // An input named as --latest's temporary file (here the config file) is refused and
    // kept: it was overwritten with the first frame and renamed to --latest (an audit).
    let config = dir.path().join("lt.tmp");
    std::fs::write(&config, "# mine\n").unwrap();
    let latest = dir.path().join("lt");
    let o = run_small_sky(1, 4, &["--config", s(&config), "--latest", s(&latest)]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("--latest's temporary file") && stderr(&o).contains("lt.tmp"),
        "{}",
        stderr(&o)
    );
    assert_eq!(std::fs::read_to_string(&config).unwrap(), "# mine\n");
    assert!(!latest.exists());
}

/// Options that do not go together, or that the chosen mode would ignore, are usage errors
/// (exit status 2, naming the options), never silently dropped.
#[test]
fn options_the_mode_would_ignore_are_usage_errors() {
    let hdr = data("rooitou_park_1k.hdr");
    let out = tempfile::tempdir().unwrap();
    let out = s(out.path());
    let lights = tempfile::NamedTempFile::new().unwrap();
    let lights = s(lights.path());
    for (args, needle) in [
        (vec!["decompose", "--loop", "--frames", "2"], "--loop"),
        (vec!["decompose", "--rotation", "5"], "--projection fisheye"),
        (
            vec!["decompose", "--projection", "fisheye", "--frames", "1"],
            "the built-in sky is always lat-long",
        ),
        (vec!["decompose", &hdr, "--sky-size", "8x4"], "--sky-size"),
        // A camera is no sky and no file sequence (these were accepted and ignored; the
        // device need not exist: the usage is checked before it is opened).
        (
            vec![
                "decompose",
                "--device",
                "/nonexistent/video9",
                "--seed",
                "3",
            ],
            "not to INPUT files or a camera",
        ),
        (
            vec!["decompose", "--device", "/nonexistent/video9", "--loop"],
            "not a camera",
        ),
        (
            vec!["decompose", "--no-filter", "--bright-history", "fade"],
            "--bright-history",
        ),
        (vec!["subscribe", "tcp:"], "HOST:PORT"),
        (
            vec!["render", "--out", out, "--lobes", "4"],
            "--lighting asg",
        ),
        (
            vec!["render", "--out", out, "--fit-height", "8"],
            "--lighting asg",
        ),
        (
            vec!["render", "--out", out, "--lights", lights, "-n", "5"],
            "--light-count",
        ),
        (
            vec![
                "render",
                "--out",
                out,
                "--lighting",
                "asg",
                "--budget-ms",
                "5",
            ],
            "--budget-ms",
        ),
        (
            vec![
                "render",
                "--out",
                out,
                "--lighting",
                "asg",
                "--lights",
                lights,
            ],
            "--lights",
        ),
        (
            vec!["wavelet", "approx", "--projection", "angular"],
            "--projection",
        ),
        (vec!["wavelet", "relight", "--alpha", "0.2"], "--brdf"),
        (
            vec!["wavelet", "relight", "--brdf", "phong", "--alpha", "0.2"],
            "--alpha",
        ),
        (
            vec!["wavelet", "relight", "--brdf", "ggx", "--exponent", "8"],
            "--exponent",
        ),
        (vec!["wavelet", "recover", "--frames", "2"], "--frames"),
        (vec!["wavelet", "relight", "--ground"], "--scene"),
        // The outputs' former names: --json (now --out) and a CSV --out (now --radiance).
        (
            vec!["wavelet", "relight", "--json", "lines.json"],
            "--json is now --out",
        ),
        (
            vec!["wavelet", "relight", "--out", "radiance.CSV"],
            "--radiance FILE.csv",
        ),
        (
            vec!["render", "--out", out, "--lighting", "asg", "--no-culling"],
            "--no-culling",
        ),
        (
            vec!["render", "--out", out, "--no-shadows", "--shadow-res", "64"],
            "--no-shadows",
        ),
        (vec!["subscribe", "ws://127.0.0.1"], "HOST:PORT"),
        (
            vec!["subscribe", "http://127.0.0.1:7879/"],
            "not an envlight endpoint",
        ),
        (
            vec!["wavelet", "recover", "--seed", "3", "--noise", "0"],
            "--noise 0",
        ),
        (
            vec!["wavelet", "recover", &hdr, &data("noon_grass_1k.hdr")],
            "INPUT names 2 files",
        ),
        (
            vec!["render", "--out", out, "--shadow-res", "8193"],
            "16..=8192",
        ),
        (
            vec!["render", "--out", out, "--shadow-res", "8"],
            "16..=8192",
        ),
    ] {
        let o = envlight(&args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains(needle), "{args:?}: {}", stderr(&o));
    }
    // The default of --lighting given explicitly goes with --lights (it was a clap conflict).
    let o = envlight(&[
        "render",
        "--lights",
        lights,
        "--lighting",
        "lights",
        "--out",
        out,
    ]);
    assert!(stderr(&o).contains("no light frames"), "{}", stderr(&o));
    assert_eq!(o.status.code(), Some(1));
}

/// `fit-asg` filters the lobes with the lights' default taps: its lines are the `--no-filter`
/// fits through `LobeFilter` (`--taps 1` is no filter); the loss stays the fit's own.
#[test]
fn fit_asg_filters_the_lobes_with_the_lights_taps() {
    use envlight::asg::temporal::LobeFilter;
    use envlight::asg::Asg;
    let lines = |extra: &[&str]| -> Vec<(Vec<Asg>, f64)> {
        let mut args = vec![
            "fit-asg",
            "--frames",
            "6",
            "--height",
            "8",
            "--iterations",
            "30",
            "--lobes",
            "3",
        ];
        args.extend_from_slice(extra);
        let o = envlight(&args);
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
        stdout(&o)
            .lines()
            .map(|line| {
                let v: serde_json::Value = serde_json::from_str(line).unwrap();
                let lobes = serde_json::from_value(v["lobes"].clone()).unwrap();
                (lobes, v["loss"].as_f64().unwrap())
            })
            .collect()
    };
    let filtered = lines(&[]);
    let own = lines(&["--no-filter"]);
    assert_eq!(lines(&["--taps", "1"]), own);
    assert_eq!((filtered.len(), own.len()), (6, 6));
    let mut reference = LobeFilter::new(Some(&envlight::decompose::filter::DEFAULT_TAPS)).unwrap();
    let mut differs = false;
    for (t, ((got, got_loss), (own, own_loss))) in filtered.iter().zip(&own).enumerate() {
        assert_eq!(got_loss, own_loss, "frame {t}: the fit's own loss");
        let mut want = own.clone();
        reference.apply(&mut want);
        for (g, w) in got.iter().zip(&want) {
            let close = |a: &[f64], b: &[f64]| {
                a.iter()
                    .zip(b)
                    .all(|(x, y)| (x - y).abs() <= 1e-12 * y.abs().max(1.0))
            };
            assert!(
                close(&g.axis, &w.axis)
                    && close(&g.tangent, &w.tangent)
                    && close(&g.rgb, &w.rgb)
                    && close(&[g.lambda, g.mu], &[w.lambda, w.mu]),
                "frame {t}: {g:?} vs {w:?}"
            );
        }
        differs |= got != own;
    }
    assert!(
        differs,
        "the sky moves, so the filter must change the lobes"
    );
    let o = envlight(&["fit-asg", "--taps", "1,-1"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("invalid --taps"), "{}", stderr(&o));
}

/// `fit-asg --frames` limits INPUT files too (it used to apply to the sky only).
#[test]
fn fit_asg_frames_limits_input_files() {
    let hdr = data("rooitou_park_1k.hdr");
    let o = envlight(&[
        "fit-asg",
        &hdr,
        &hdr,
        "--frames",
        "1",
        "--lobes",
        "2",
        "--iterations",
        "4",
        "--warm-iterations",
        "2",
        "--height",
        "8",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(stdout(&o).lines().count(), 1, "{}", stdout(&o));
}

/// An output path that is one of the command's input files is refused before it is created
/// (creating it truncated the input: `decompose f.exr -o f.exr` left an empty f.exr), under
/// any name that leads to it.
#[test]
fn outputs_that_are_inputs_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("frame.exr");
    write_rgb(&input, 16, 8, 1.0);
    let link = dir.path().join("link.exr");
    std::os::unix::fs::symlink(&input, &link).unwrap();
    let original = std::fs::read(&input).unwrap();
    let (input, link) = (s(&input), s(&link));
    for (args, option) in [
        (vec!["decompose", input, "-o", input], "--out"),
        (vec!["decompose", input, "--latest", link], "--latest"),
        (vec!["fit-asg", input, "--out", link], "--out"),
        (vec!["wavelet", "approx", input, "--out", input], "--out"),
        (vec!["sh", input, "--out", link], "--out"),
        (
            vec![
                "wavelet",
                "approx",
                input,
                "--size",
                "8",
                "--reconstruct",
                link,
            ],
            "--reconstruct",
        ),
        (
            vec!["wavelet", "recover", input, "--size", "2", "--out", input],
            "--out",
        ),
        (
            vec!["wavelet", "relight", input, "--size", "2", "--out", link],
            "--out",
        ),
    ] {
        let o = envlight(&args);
        assert_fails_naming(&o, &[option, "is the input file", "frame.exr"]);
        assert_eq!(std::fs::read(input).unwrap(), original, "{args:?}");
    }
}

/// `decompose --out` or `--latest` on its own `--config` file, or on the response curve that
/// file names, is refused before anything is written (the config was truncated).
#[test]
fn decompose_outputs_may_not_overwrite_its_config_or_curve() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("c.toml");
    let curve = dir.path().join("curve.txt");
    let text = "[camera]\nresponse = \"curve\"\ncurve = \"curve.txt\"\n";
    std::fs::write(&config, text).unwrap();
    std::fs::write(&curve, "0 0.01 0.01 0.01\n1 1 1 1\n").unwrap();
    let (c, k) = (config.to_str().unwrap(), curve.to_str().unwrap());
    for (option, output, name) in [
        ("--out", c, "c.toml"),
        ("--latest", c, "c.toml"),
        ("--out", k, "curve.txt"),
    ] {
        let o = envlight(&["decompose", "--config", c, "--frames", "1", option, output]);
        assert_fails_naming(&o, &[option, "is the input file", name]);
    }
    assert_eq!(std::fs::read_to_string(&config).unwrap(), text);
    assert!(std::fs::read_to_string(&curve)
        .unwrap()
        .starts_with("0 0.01"));
}

/// `--latest` on a pipe (or a device: as root, `--latest /dev/null` replaced /dev/null with a
/// regular file) is refused before anything is written: the path is replaced by a rename.
#[test]
fn latest_refuses_paths_a_rename_would_destroy() {
    use std::os::unix::fs::FileTypeExt;
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("pipe.json");
    let made = Command::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(made.success());
    let o = envlight(&[
        "decompose",
        "--frames",
        "1",
        "--sky-size",
        "64x32",
        "--latest",
        fifo.to_str().unwrap(),
    ]);
    assert_fails_naming(&o, &["--latest", "pipe.json", "a device, pipe or socket"]);
    assert!(std::fs::metadata(&fifo).unwrap().file_type().is_fifo());
}

/// Two outputs on one file, or an output on the mesh `wavelet relight` reads, are refused
/// before anything is written (the second output overwrote the first, or the mesh, with exit
/// status 0); `wavelet recover --out` a directory fails before the work.
#[test]
fn outputs_that_overwrite_each_other_or_the_mesh_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("frame.exr");
    write_rgb(&input, 16, 8, 1.0);
    let mesh = dir.path().join("tri.obj");
    let mesh_text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
    std::fs::write(&mesh, mesh_text).unwrap();
    let same = dir.path().join("same.out");
    let same_exr = dir.path().join("same.exr");
    let (input, mesh_path, same_path) = (s(&input), s(&mesh), s(&same));
    let same_exr_path = s(&same_exr);
    for (args, needles) in [
        (
            vec![
                "wavelet",
                "relight",
                input,
                "--size",
                "2",
                "--scene",
                mesh_path,
                "--radiance",
                mesh_path,
            ],
            vec!["--radiance", "is the input file", "tri.obj"],
        ),
        (
            vec![
                "wavelet", "relight", input, "--size", "2", "--scene", mesh_path, "--out",
                mesh_path,
            ],
            vec!["--out", "is the input file", "tri.obj"],
        ),
        (
            vec![
                "wavelet",
                "relight",
                input,
                "--size",
                "2",
                "--out",
                same_path,
                "--radiance",
                same_path,
            ],
            vec!["--radiance", "is also the --out output", "same.out"],
        ),
        (
            vec![
                "wavelet",
                "approx",
                input,
                "--size",
                "8",
                "--out",
                same_exr_path,
                "--reconstruct",
                same_exr_path,
            ],
            vec!["--reconstruct", "is also the --out output", "same.exr"],
        ),
        (
            vec![
                "wavelet",
                "approx",
                input,
                "--size",
                "8",
                "--reconstruct",
                same_path,
            ],
            vec!["--reconstruct", "same.out", "give a path ending in .exr"],
        ),
        (
            vec![
                "wavelet", "recover", input, "--size", "2", "--out", same_path,
            ],
            vec!["--out", "same.out", "give a path ending in .exr"],
        ),
    ] {
        let _ = std::fs::remove_file(&same);
        let _ = std::fs::remove_file(&same_exr);
        let o = envlight(&args);
        assert_fails_naming(&o, &needles);
        assert_eq!(
            std::fs::read_to_string(&mesh).unwrap(),
            mesh_text,
            "{args:?}"
        );
    }
    // An existing file named by both --out and --reconstruct is kept: the conflict is found
    // before --out is created (it was emptied first; an audit).
    std::fs::write(&same_exr, "kept").unwrap();
    let o = envlight(&[
        "wavelet",
        "approx",
        input,
        "--size",
        "8",
        "--out",
        same_exr_path,
        "--reconstruct",
        same_exr_path,
    ]);
    assert_fails_naming(
        &o,
        &["--reconstruct", "is also the --out output", "same.exr"],
    );
    assert_eq!(std::fs::read_to_string(&same_exr).unwrap(), "kept");
    // And with {seq}, the file of the frame whose number --out's name holds.
    let r0 = dir.path().join("r0.exr");
    std::fs::write(&r0, "kept").unwrap();
    let pattern = dir.path().join("r{seq}.exr");
    let o = envlight(&[
        "wavelet",
        "approx",
        input,
        "--size",
        "8",
        "--out",
        s(&r0),
        "--reconstruct",
        s(&pattern),
    ]);
    assert_fails_naming(&o, &["--reconstruct", "is also the --out output"]);
    assert_eq!(std::fs::read_to_string(&r0).unwrap(), "kept");
    // The files the mesh references (its material library) are inputs too, and two names of
    // one existing file are refused before --out truncates it.
    let with_mtl = dir.path().join("mtl.obj");
    let mtl = dir.path().join("grey.mtl");
    std::fs::write(&with_mtl, format!("mtllib grey.mtl\n{mesh_text}")).unwrap();
    std::fs::write(&mtl, "newmtl grey\nKd 0.5 0.5 0.5\n").unwrap();
    let o = envlight(&[
        "wavelet",
        "relight",
        input,
        "--size",
        "2",
        "--scene",
        s(&with_mtl),
        "--radiance",
        s(&mtl),
    ]);
    assert_fails_naming(&o, &["--radiance", "is the input file", "grey.mtl"]);
    let json = dir.path().join("o.json");
    let linked = dir.path().join("o.csv");
    std::fs::write(&json, "{}").unwrap();
    std::fs::hard_link(&json, &linked).unwrap();
    let o = envlight(&[
        "wavelet",
        "relight",
        input,
        "--size",
        "2",
        "--out",
        s(&json),
        "--radiance",
        s(&linked),
    ]);
    assert_fails_naming(&o, &["--radiance", "is also the --out output"]);
    assert_eq!(std::fs::read_to_string(&json).unwrap(), "{}");
    // --radiance in a folder that does not exist fails before the work (and before --out is
    // written): the precomputation and every frame ran first, then the output failed.
    let fresh_json = dir.path().join("fresh.json");
    let o = envlight(&[
        "wavelet",
        "relight",
        input,
        "--size",
        "2",
        "--out",
        s(&fresh_json),
        "--radiance",
        s(&dir.path().join("nodir/a.csv")),
    ]);
    assert_fails_naming(&o, &["--radiance", "nodir", "does not exist"]);
    assert!(!fresh_json.exists(), "--out was written first");
    let o = envlight(&[
        "wavelet",
        "recover",
        input,
        "--size",
        "4",
        "--out",
        s(dir.path()),
    ]);
    assert_fails_naming(&o, &["--out", "is a directory"]);
    assert!(
        stdout(&o).is_empty(),
        "the work was done first: {}",
        stdout(&o)
    );
    // A 2×2 grid has no texel above the horizon: its upper-hemisphere error is null, not 0.
    let o = envlight(&["wavelet", "recover", input, "--size", "2"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let report: Value = serde_json::from_str(stdout(&o).trim()).unwrap();
    assert!(report["upper_hemisphere_error"].is_null(), "{report}");
    assert!(report["relative_error"].is_f64(), "{report}");
}

/// `subscribe --timeout` gives up on a server that accepts and sends nothing, over TCP and
/// over WebSocket (whose upgrade then never completes): exit 1 naming the address and the
/// timeout (it waited for ever), with `--frames 0` too. Out-of-range values are usage errors.
#[test]
fn subscribe_times_out_on_a_silent_server() {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let address = listener.local_addr().unwrap();
    let _silent = std::thread::Builder::new()
        .name("silent-server".into())
        .spawn(move || {
            let held: Vec<_> = listener.incoming().take(3).collect();
            std::thread::sleep(std::time::Duration::from_secs(10));
            drop(held);
        })
        .unwrap();
    for target in [address.to_string(), format!("ws://{address}/")] {
        let started = std::time::Instant::now();
        let o = envlight(&["subscribe", &target, "--timeout", "0.3"]);
        assert_fails_naming(&o, &[&target, "no message within 0.3 s (--timeout)"]);
        assert!(
            started.elapsed() < std::time::Duration::from_secs(8),
            "{target}"
        );
    }
    // --frames 0 is no limit: it waits for frames like the others (it exited 0 at once).
    let o = envlight(&[
        "subscribe",
        &address.to_string(),
        "--frames",
        "0",
        "--timeout",
        "0.3",
    ]);
    assert_fails_naming(&o, &["no message within 0.3 s (--timeout)"]);
    for bad in ["0", "-1", "nan", "1e9", "x"] {
        let o = envlight(&["subscribe", "127.0.0.1:1", "--timeout", bad]);
        assert_eq!(o.status.code(), Some(2), "{bad}: {}", stderr(&o));
    }
}

/// `subscribe --representation asg` refuses a server that sends a light frame instead (it
/// printed it as if asked for; an audit): exit 1 naming the address and both representations.
#[test]
fn subscribe_refuses_frames_of_another_representation() {
    use std::io::{Read, Write};
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let address = listener.local_addr().unwrap();
    let server = std::thread::Builder::new()
        .name("wrong-server".into())
        .spawn(move || {
            let (mut stream, _) = listener.accept().unwrap();
            let mut request = [0u8; 64];
            let _ = stream.read(&mut request);
            let frame = envlight::light::LightFrame {
                seq: 1,
                time: 0.5,
                lights: Vec::new(),
            };
            let mut out = Vec::new();
            envlight::stream::protocol::encode_frame(&frame, None, false, &mut out);
            let _ = stream.write_all(&out);
            std::thread::sleep(std::time::Duration::from_secs(2));
        })
        .unwrap();
    let target = address.to_string();
    let o = envlight(&[
        "subscribe",
        &target,
        "--representation",
        "asg",
        "--timeout",
        "5",
    ]);
    assert_fails_naming(
        &o,
        &[&target, "representation Lights", "subscription to Asg"],
    );
    assert_eq!(o.status.code(), Some(1));
    server.join().unwrap();
}

/// Commands that print one result end quietly (status 0, no panic) when stdout is closed;
/// `println!` panicked on the broken pipe.
#[test]
fn one_shot_printers_survive_a_closed_stdout() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("c.toml");
    std::fs::write(&config, "").unwrap();
    for args in [
        vec!["wavelet", "recover", "--size", "2"],
        vec!["check-config", s(&config)],
    ] {
        let mut child = Command::new(env!("CARGO_BIN_EXE_envlight"))
            .args(&args)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        drop(child.stdout.take());
        let o = child.wait_with_output().unwrap();
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
        assert!(!stderr(&o).contains("panicked"), "{args:?}: {}", stderr(&o));
    }
}

#[test]
fn relight_transport_count_is_checked() {
    for n in ["0", "65"] {
        let o = envlight(&["wavelet", "relight", "--size", "8", "--transport", n]);
        assert_fails_naming(&o, &["--transport", n, "1..=64"]);
    }
}

/// An input that adds no frame beside others that do (a pattern matching nothing, an empty
/// directory) is named in a warning instead of being dropped without a word.
#[test]
fn inputs_without_frames_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let frame = dir.path().join("f_1.exr");
    write_rgb(&frame, 8, 4, 1.0);
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let pattern = dir.path().join("nomatch_*.exr");
    let o = envlight(&["decompose", "-n", "4", s(&frame), s(&pattern), s(&empty)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let err = stderr(&o);
    for input in [s(&pattern), s(&empty)] {
        assert!(
            err.contains(&format!("{input}: no .exr or .hdr frames")),
            "{input}: {err}"
        );
    }
}

/// A light list whose frames repeat a seq is refused before the repeat is rendered: the images
/// are named by seq, so the first frame's would be overwritten. The list is read a frame at a
/// time, so a bad line later in it stops the render there, naming the file and the line, with
/// the frames before it rendered.
#[test]
fn render_refuses_repeated_seqs() {
    let dir = tempfile::tempdir().unwrap();
    let lights = dir.path().join("lights.jsonl");
    let frame = "{\"seq\":7,\"time\":0.0,\"lights\":[{\"id\":0,\"dir\":[0.0,1.0,0.0],\
                 \"rgb\":[1.0,1.0,1.0],\"solid_angle\":0.1}]}";
    std::fs::write(&lights, format!("{frame}\n{frame}\n")).unwrap();
    let out = dir.path().join("out");
    let o = envlight(&["render", "--lights", s(&lights), "--out", s(&out)]);
    assert_fails_naming(&o, &["lights.jsonl", "seq 7 appears more than once"]);
    assert!(out.join("frame_00007.png").is_file());
    let bad_frame = frame.replace("[0.0,1.0,0.0]", "[0.0,0.0,0.0]");
    std::fs::write(
        &lights,
        format!("{frame}\n{}\n", bad_frame.replace("7", "8")),
    )
    .unwrap();
    let out = dir.path().join("out2");
    let o = envlight(&["render", "--lights", s(&lights), "--out", s(&out)]);
    assert_fails_naming(
        &o,
        &["lights.jsonl", "line 2", "light 0", "not a direction"],
    );
    assert!(out.join("frame_00007.png").is_file());
    let empty = dir.path().join("empty.jsonl");
    std::fs::write(&empty, "\n\n").unwrap();
    let o = envlight(&["render", "--lights", s(&empty), "--out", s(&out)]);
    assert_fails_naming(&o, &["empty.jsonl", "no light frames"]);
}

/// Stated defaults given explicitly are accepted, and flag errors name the flag: wavelet
/// commands took `--projection latlong` (the default) as a usage error with the sky, and
/// `render -n 0` named the config key decompose.lights.

#[test]
fn explicit_defaults_work_and_flag_errors_name_the_flag() {
    let o = envlight(&[
        "wavelet",
        "approx",
        "--projection",
        "latlong",
        "--size",
        "8",
        "-k",
        "4",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let dir = tempfile::tempdir().unwrap();
    let o = envlight(&["render", "-n", "0", "--out", s(dir.path()), "--size", "8x8"]);
    assert_fails_naming(&o, &["invalid --light-count 0"]);
}

/// stderr whose reader has gone away (`2>&1 | head`, a journald stream that closed) ends a
/// command with its own exit status, not a panic: the log subscriber reported its failed write
/// with `eprintln!`, which panicked on the same stderr (status 101), and so did the final
/// error message.
#[test]
fn a_closed_stderr_is_not_a_panic() {
    for (args, code) in [
        (&["decompose", "--frames", "2", "-n", "4"][..], 0),
        (&["decompose", "/nonexistent/frame_1.exr"][..], 1),
        (&["render", "--lobes", "4"][..], 2),
    ] {
        let mut child = Command::new(env!("CARGO_BIN_EXE_envlight"))
            .args(args)
            .env_remove("RUST_LOG")
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("run envlight");
        drop(child.stderr.take());
        let status = child.wait().unwrap();
        assert_eq!(status.code(), Some(code), "{args:?}");
    }
}

/// `run --fast` paces a replay: without --replay it is a usage error, also with INPUT (clap's
/// `requires` let it pass there, and the flag was ignored).
#[test]
fn run_fast_without_replay_is_a_usage_error() {
    for args in [
        &["run", "--fast"][..],
        &["run", "--fast", &data("rooitou_park_1k.hdr")],
    ] {
        let o = envlight(args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains("--replay"), "{}", stderr(&o));
    }
}

/// Range errors of the wavelet commands' numeric flags name the flag and come as usage errors
/// (exit 2) before any input is read (they named no flag, and came after the frames were
/// read); a number too small for f32 is refused as such, not as 0 (found by an audit).
#[test]
fn wavelet_flag_ranges_name_the_flag() {
    for (args, needles) in [
        (
            vec!["wavelet", "recover", "--size", "4", "--rank-tol", "0"],
            vec!["--rank-tol", "(0, 1)"],
        ),
        (
            vec!["wavelet", "recover", "--size", "4", "--split", "2"],
            vec!["--split", "[0, 1]"],
        ),
        (
            vec!["wavelet", "recover", "--size", "4", "--exponent", "-1"],
            vec!["--exponent", "≥ 0"],
        ),
        (
            vec!["wavelet", "relight", "--brdf", "ggx", "--alpha", "0"],
            vec!["--alpha", "[0.001, 1]"],
        ),
        (
            vec!["render", "--exposure", "1e-300", "--out", "unused"],
            vec!["--exposure", "too small for single precision"],
        ),
    ] {
        let o = envlight(&args);
        assert_fails_naming(&o, &needles);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
    }
}

/// A flag at fault is named alone: `render --fit-height 3` named "--lobes or --fit-height";
/// `render --out FILE` said "File exists" without naming --out, after starting the GPU;
/// `wavelet recover --observations` past what the views give was all of them, silently.
#[test]
fn render_and_recover_name_the_one_flag_at_fault() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("afile");
    std::fs::write(&file, "kept").unwrap();
    let folder = dir.path().join("frames");
    let cases: [(Vec<&str>, &str); 4] = [
        (
            vec![
                "render",
                "--lighting",
                "asg",
                "--fit-height",
                "3",
                "--out",
                s(&folder),
            ],
            "invalid --fit-height",
        ),
        (
            vec![
                "render",
                "--lighting",
                "asg",
                "--lobes",
                "65",
                "--out",
                s(&folder),
            ],
            "invalid --lobes",
        ),
        (
            vec!["render", "--frames", "1", "--out", s(&file)],
            "is a file, but --out is the folder",
        ),
        (
            vec![
                "wavelet",
                "recover",
                "--size",
                "2",
                "--observations",
                "100000",
            ],
            "the object gives",
        ),
    ];
    for (args, needle) in cases {
        let o = envlight(&args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains(needle), "{args:?}: {}", stderr(&o));
        assert!(!stderr(&o).contains(" or --"), "{args:?}: {}", stderr(&o));
    }
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "kept");
    assert!(!folder.exists());
}

/// The wavelet commands read fisheye frames as `decompose` does (`--projection fisheye` with
/// its calibration flags; only lat-long and angular were offered): a uniform 180° frame of
/// radiance 2 holds 2 × 2π; calibration flags without the projection, and a bad value, are
/// usage errors naming the flag; a circle off the image is named at the first frame.
#[test]
fn wavelet_commands_read_fisheye_frames() {
    let dir = tempfile::tempdir().unwrap();
    let frame = dir.path().join("fisheye.exr");
    write_rgb(&frame, 96, 64, 2.0);
    let input = s(&frame);
    let o = envlight(&[
        "wavelet",
        "approx",
        input,
        "--projection",
        "fisheye",
        "--size",
        "16",
        "-k",
        "256",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let line: Value = serde_json::from_str(stdout(&o).lines().next().unwrap()).unwrap();
    for c in 0..3 {
        let integral = line["integral"][c].as_f64().unwrap();
        let expected = 2.0 * std::f64::consts::TAU;
        assert!((integral / expected - 1.0).abs() < 0.01, "{line}");
    }
    // The radius halves the circle: a quarter of the pixels, the same hemisphere.
    let o = envlight(&[
        "wavelet",
        "approx",
        input,
        "--projection",
        "fisheye",
        "--radius",
        "16",
        "--size",
        "8",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for (args, needle, code) in [
        (
            vec!["wavelet", "approx", input, "--radius", "16"],
            "need --projection fisheye",
            2,
        ),
        (
            vec![
                "wavelet",
                "relight",
                input,
                "--projection",
                "fisheye",
                "--fov",
                "0.5",
            ],
            "invalid --fov 0.5",
            2,
        ),
        (
            vec![
                "wavelet",
                "approx",
                input,
                "--projection",
                "fisheye",
                "--center",
                "900,900",
            ],
            "does not overlap the 96x64 image",
            1,
        ),
    ] {
        let o = envlight(&args);
        assert_eq!(o.status.code(), Some(code), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains(needle), "{args:?}: {}", stderr(&o));
    }
}

/// `envlight sh` prints the wire's JSON SH frame per frame (what a daemon's `sh` client gets),
/// plus the frame's ∫L dω; a fisheye input works; a bad degree is a usage error and a missing
/// file is named.
#[test]
fn sh_prints_wire_frames_of_spherical_harmonics() {
    use envlight::stream::protocol::parse_json_message;
    use envlight::stream::Message;
    let o = envlight(&["sh", "--frames", "2", "--degree", "3"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let lines: Vec<String> = stdout(&o).lines().map(str::to_owned).collect();
    assert_eq!(lines.len(), 2);
    for (seq, line) in lines.iter().enumerate() {
        let Ok(Message::Sh(frame)) = parse_json_message(line) else {
            panic!("not an SH frame: {line}");
        };
        assert_eq!((frame.seq, frame.stale), (seq as u64, false));
        let set = frame.into_sh_frame().to_coefficients().unwrap();
        assert_eq!(set.degree(), 3);
        let value: Value = serde_json::from_str(line).unwrap();
        let integral: Vec<f64> = value["integral"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        for (received, printed) in set.integral().into_iter().zip(integral) {
            assert!(printed > 0.0, "{line}");
            assert!((received - printed).abs() <= 1e-6 * printed, "{line}");
        }
    }
    // A file through a fisheye lens; the flags are decompose's.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sh.jsonl");
    let o = envlight(&[
        "sh",
        &data("rooitou_park_1k.hdr"),
        "--projection",
        "fisheye",
        "--radius",
        "200",
        "--degree",
        "1",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = std::fs::read_to_string(&out).unwrap();
    assert!(matches!(
        parse_json_message(text.trim()),
        Ok(Message::Sh(frame)) if frame.coefficients.len() == 4
    ));
    let o = envlight(&["sh", "--degree", "16"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("0..=15"), "{}", stderr(&o));
    let o = envlight(&["sh", "--taps", "0,0"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("invalid --taps"), "{}", stderr(&o));
}

/// `envlight sh` filters the sets in time with the lights' taps (as `envlight decompose` its
/// lights): the first frame's set is its own, later ones are the taps' weighted sums of the
/// frames' own sets (`--no-filter`), and `--taps 1` is no filter at all.
#[test]
fn sh_filters_the_sets_with_the_lights_taps() {
    use envlight::set_filter::SetFilter;
    use envlight::stream::protocol::parse_json_message;
    use envlight::stream::Message;
    let sets = |extra: &[&str]| -> Vec<Vec<f64>> {
        let mut args = vec!["sh", "--frames", "8", "--degree", "2"];
        args.extend_from_slice(extra);
        let o = envlight(&args);
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
        stdout(&o)
            .lines()
            .map(|line| match parse_json_message(line) {
                Ok(Message::Sh(frame)) => frame
                    .coefficients
                    .iter()
                    .flatten()
                    .map(|&v| f64::from(v))
                    .collect(),
                _ => panic!("not an SH frame: {line}"),
            })
            .collect()
    };
    let filtered = sets(&[]);
    let own = sets(&["--no-filter"]);
    assert_eq!(sets(&["--taps", "1"]), own);
    assert_eq!((filtered.len(), own.len()), (8, 8));
    assert_eq!(filtered[0], own[0], "the first set is the frame's own");
    let mut reference = SetFilter::<f64>::new(&envlight::decompose::filter::DEFAULT_TAPS).unwrap();
    let mut differs = false;
    for (t, (got, own)) in filtered.iter().zip(&own).enumerate() {
        let mut want = own.clone();
        reference.apply(t as u64, &mut want);
        // The frames' own sets went through f32 on the way out; the filter saw them in f64.
        for (g, w) in got.iter().zip(&want) {
            assert!(
                (g - w).abs() <= 1e-6 * want[0].abs(),
                "frame {t}: {g} vs {w}"
            );
        }
        differs |= got != own;
    }
    assert!(differs, "the sky moves, so the filter must change the sets");
    let o = envlight(&["sh", "/nonexistent/sky.hdr"]);
    assert_fails_naming(&o, &["/nonexistent/sky.hdr"]);
    assert_eq!(o.status.code(), Some(1));
}
