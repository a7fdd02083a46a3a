//! Issue 19: what a hostile user tried, each now a clear error (or a quiet exit), never a
//! panic, an abort, a hang or a destroyed input.

use crate::common;

use common::sylva;
use std::fs;
use std::process::{Command, Stdio};

/// A one-triangle OBJ.
const TRIANGLE_OBJ: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";

fn fails_with(args: &[&str], want: &str) {
    let (ok, stdout, stderr) = sylva(args);
    assert!(!ok, "{args:?} should fail: {stdout}");
    assert!(stderr.contains(want), "{args:?}: {stderr}");
    assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
}

#[test]
fn absurd_sizes_are_refused_before_allocating() {
    // Item 2: more photons than anyone can wait for.
    fails_with(
        &["spp", "slab", "--photons", "10000000000000"],
        "photons must be 1 to 10^12",
    );
    fails_with(
        &["spp", "trees", "dogrose", "--photons", "10000000000000"],
        "photons must be 1 to 10^12",
    );
    // Item 3: LB grids beyond memory are refused before the grid is allocated.
    for grid in ["2000", "1600"] {
        fails_with(&["bench", "lb", "--grid", grid, "--device", "cpu"], "needs");
    }
    // Item 8: thread counts.
    fails_with(
        &["--threads", "100000", "scene", "list"],
        "--threads 100000: must be 1 to 256",
    );
    // Item 14: one limit per quantity, wherever it is given.
    fails_with(
        &["voxelize", "dogrose", "--grid", "4096"],
        "between 4 and 2048",
    );
    fails_with(
        &["lb", "solve", "--model", "dogrose", "--grid", "4096"],
        "must be 4 to 2048",
    );
    fails_with(
        &["lb", "solve", "--shape", "cube", "--grid", "4096"],
        "between 3 and 2048",
    );
    fails_with(
        &["render", "demo", "--width", "20000", "--height", "10"],
        "must be 1 to 16384",
    );
}

#[test]
fn outputs_never_destroy_inputs_or_each_other() {
    let dir = tempfile::tempdir().unwrap();
    let d = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    // Item 4: the grid and its preview under one name.
    fails_with(
        &[
            "lb",
            "solve",
            "--shape",
            "cube",
            "--grid",
            "8",
            "-o",
            &d("l.png"),
        ],
        "named twice",
    );
    fails_with(
        &[
            "lb",
            "solve",
            "--shape",
            "cube",
            "--grid",
            "8",
            "-o",
            &d("a.sgrid"),
            "--png",
            &d("a.sgrid"),
        ],
        "named twice",
    );
    // The input grid as the output.
    fs::write(d("ok.obj"), TRIANGLE_OBJ).unwrap();
    let (ok, _, e) = sylva(&[
        "voxelize",
        &d("ok.obj"),
        "--grid",
        "8",
        "-o",
        &d("in.sgrid"),
    ]);
    assert!(ok, "{e}");
    let before = fs::read(d("in.sgrid")).unwrap();
    fails_with(
        &[
            "lb",
            "solve",
            "--input",
            &d("in.sgrid"),
            "-o",
            &d("in.sgrid"),
        ],
        "is an input of this command",
    );
    assert_eq!(fs::read(d("in.sgrid")).unwrap(), before);
    // The model as the voxelizer's output.
    fails_with(
        &["voxelize", &d("ok.obj"), "--grid", "8", "-o", &d("ok.obj")],
        "is an input of this command",
    );
    assert_eq!(fs::read_to_string(d("ok.obj")).unwrap(), TRIANGLE_OBJ);
    // The scene's own mesh as the export's OBJ.
    fs::write(d("scene.obj"), TRIANGLE_OBJ).unwrap();
    fs::write(
        d("s.toml"),
        "[[models]]\nname = \"m\"\nmesh = \"scene.obj\"\n[[instances]]\nmodel = \"m\"\nposition = [0.0, 0.0, 0.0]\n",
    )
    .unwrap();
    fails_with(
        &[
            "export",
            &d("s.toml"),
            "--format",
            "obj",
            "-o",
            dir.path().to_str().unwrap(),
        ],
        "is an input of this command",
    );
    assert_eq!(fs::read_to_string(d("scene.obj")).unwrap(), TRIANGLE_OBJ);
}

#[test]
fn unreadable_inputs_are_named_and_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n);
    // Item 5: /dev/zero and a FIFO as a scene file: refused before a byte is read.
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink("/dev/zero", p("zero.toml")).unwrap();
        fails_with(
            &["scene", "info", p("zero.toml").to_str().unwrap()],
            "is not a regular file",
        );
        assert!(Command::new("mkfifo")
            .arg(p("fifo.toml"))
            .status()
            .unwrap()
            .success());
        fails_with(
            &["scene", "info", p("fifo.toml").to_str().unwrap()],
            "is not a regular file",
        );
    }
    // Item 13: an empty scene file.
    fs::write(p("empty.toml"), "").unwrap();
    fails_with(
        &["scene", "info", p("empty.toml").to_str().unwrap()],
        "is the file empty or truncated?",
    );
}

#[test]
fn sun_below_the_horizon_is_refused_and_negative_numbers_parse() {
    // Item 12: `--elevation -10` (with a space) reaches sylva, which explains the problem.
    fails_with(
        &["render", "demo", "--elevation", "-10", "--mode", "local"],
        "10.0° below the horizon",
    );
    fails_with(
        &["render", "demo", "--sun", "0,-1,0", "--mode", "local"],
        "90.0° below the horizon",
    );
    // Issue 31 item 10: past the zenith, the help's range (not the internal [-90, 90]).
    fails_with(
        &["render", "demo", "--elevation", "95", "--mode", "local"],
        "--elevation 95: degrees above the horizon, 0 to 90",
    );
}

#[test]
fn scene_list_agrees_with_scene_info() {
    // Item 14: beech has 270,217,524 instanced triangles.
    let (ok, out, _) = sylva(&["scene", "list"]);
    assert!(
        ok && out.contains("about 270 M instanced triangles"),
        "{out}"
    );
    let (ok, out, _) = sylva(&["bench", "--help"]);
    assert!(ok, "{out}");
    for sub in ["lb", "scene", "voxelize", "trace"] {
        assert!(out.contains(sub), "bench --help lacks {sub}: {out}");
    }
    // Help of the commands that take models names every model format.
    for args in [&["voxelize", "--help"][..], &["lb", "solve", "--help"]] {
        let (ok, out, _) = sylva(args);
        assert!(ok, "{out}");
        for ext in [".xml", ".obj", ".gltf", ".glb"] {
            assert!(out.contains(ext), "{args:?} lacks {ext}: {out}");
        }
    }
}

#[cfg(unix)]
#[test]
fn a_closed_pipe_ends_the_output_quietly() {
    // Item 10: `sylva lb info x.sgrid | head -1`.
    let dir = tempfile::tempdir().unwrap();
    let grid = dir.path().join("g.sgrid");
    let (ok, _, e) = sylva(&[
        "lb",
        "solve",
        "--shape",
        "cube",
        "--grid",
        "8",
        "--steps",
        "2",
        "-o",
        grid.to_str().unwrap(),
    ]);
    assert!(ok, "{e}");
    let mut child = Command::new(env!("CARGO_BIN_EXE_sylva"))
        .args(["lb", "info", grid.to_str().unwrap()])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // The reader goes away before sylva writes a line.
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_ne!(out.status.code(), Some(101), "{stderr}");
}

#[test]
fn probing_for_a_gpu_prints_no_driver_warnings() {
    // Item 15: without XDG_RUNTIME_DIR, Mesa's device-select layer (installed with lavapipe)
    // warns on every Vulkan instance; `--device auto` must probe quietly.
    let dir = tempfile::tempdir().unwrap();
    let grid = dir.path().join("g.sgrid");
    let out = Command::new(env!("CARGO_BIN_EXE_sylva"))
        .args([
            "lb", "solve", "--shape", "cube", "--grid", "8", "--steps", "2",
        ])
        .args(["--device", "auto", "-o", grid.to_str().unwrap()])
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("NODEVICE_SELECT")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(!stderr.contains("XDG_RUNTIME_DIR"), "{stderr}");
}

/// Issue 31 item 6: an output that cannot be written fails before the LB and the frame, with
/// the real reason (the cache directory is never created: no LB work started).
#[test]
fn unwritable_outputs_fail_before_the_work_with_the_real_reason() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    fs::create_dir(p("dir.png")).unwrap();
    fs::write(p("afile"), b"x").unwrap();
    let mut cases = vec![
        (p("dir.png"), "is a directory".to_string()),
        (
            p("afile/x.png"),
            format!("{} is a file, not a directory", p("afile")),
        ),
    ];
    // /sys takes no new file even from root, whom permission bits would let through.
    if cfg!(target_os = "linux") && std::path::Path::new("/sys/kernel").is_dir() {
        cases.push((
            "/sys/x.png".into(),
            "no file can be created in the directory /sys".into(),
        ));
    }
    let cache = p("cache");
    for (output, want) in &cases {
        let args = [
            "render",
            "catalpa",
            "--width",
            "16",
            "--height",
            "16",
            "--cache-dir",
            &cache,
            "-o",
            output,
        ];
        fails_with(&args, want);
        let (_, _, stderr) = sylva(&args);
        assert!(!stderr.contains("File exists"), "{stderr}");
        assert!(
            !stderr.contains("LB"),
            "the LB ran before the check: {stderr}"
        );
        assert!(
            !std::path::Path::new(&cache).exists(),
            "the LB ran before the check"
        );
    }
    fails_with(
        &["relight", "demo", "--suns", "2", "-o", &p("afile")],
        "is a file, not a directory",
    );
    fails_with(
        &["voxelize", "dogrose", "-o", &p("dir.png")],
        "is a directory",
    );
}

/// Issue 31 item 8: negative counts get the range message, and a cause already in the
/// message is not printed again.
#[test]
fn negative_counts_and_repeated_causes() {
    fails_with(
        &["render", "demo", "--gather-rays", "-1"],
        "-1 is not in 0..=256",
    );
    fails_with(
        &["--threads", "-1", "scene", "list"],
        "--threads -1: must be 1 to 256",
    );
    fails_with(
        &["scene", "list", "--threads", "-1"],
        "--threads -1: must be 1 to 256",
    );
    let (ok, _, stderr) = sylva(&["render", "catalpa", "-o", "/sys/x.png"]);
    if cfg!(target_os = "linux") && std::path::Path::new("/sys/kernel").is_dir() {
        assert!(!ok);
        assert!(
            stderr.contains("Permission denied") && !stderr.contains("caused by"),
            "{stderr}"
        );
    }
}

/// Two dogroses side by side, small grids and image: quick to render.
const TWO_ROSES: &str = r#"
name = "roses"

[[models]]
name = "rose"
species = "dogrose"

[[instances]]
model = "rose"
position = [0.0, 0.0, 0.0]

[[instances]]
model = "rose"
position = [1.6, 0.0, 0.8]

[ground]
size = [20.0, 20.0]

[camera]
position = [0.5, 2.5, -6.0]
look_at = [0.5, 0.7, 0.0]
fov = 40.0
resolution = [40, 32]

[lb]
grid = 12
"#;

/// Issue 31 item 2: a sequence the disk cannot hold is refused once the image size is known,
/// before any LB solve or frame, and writes nothing; frames no longer pile up in memory.
#[test]
fn a_relit_sequence_too_large_for_the_disk_is_refused_before_work() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("roses.toml");
    fs::write(&scene, TWO_ROSES).unwrap();
    let (seq, cache) = (dir.path().join("seq"), dir.path().join("cache"));
    let t = std::time::Instant::now();
    // 1000 frames of 16384² need 4.8 TB (12 bytes a pixel held until the exposure is
    // known, 3 each for the PNG and the animation).
    let args = [
        "relight",
        scene.to_str().unwrap(),
        "--suns",
        "1000",
        "--width",
        "16384",
        "--height",
        "16384",
        "--device",
        "cpu",
        "-o",
        seq.to_str().unwrap(),
        "--cache-dir",
        cache.to_str().unwrap(),
    ];
    let (ok, stdout, stderr) = sylva(&args);
    assert!(!ok, "{stdout}");
    assert!(
        stderr.contains("1000 frames of 16384x16384 need up to 4.4 TiB on disk")
            && stderr.contains("fewer --suns"),
        "{stderr}"
    );
    assert!(
        !stdout.contains("LB") && !stdout.contains("frame"),
        "{stdout}"
    );
    assert!(
        !seq.exists() && !cache.exists(),
        "work began or files were written"
    );
    assert!(t.elapsed().as_secs() < 60, "not refused up front");
}

/// Issue 31 item 4: a coarse grid far costlier than the default's says so before any LB
/// work; the default says nothing.
#[test]
fn a_costly_global_grid_is_announced_before_it_starts() {
    use std::io::{BufRead, BufReader};
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("roses.toml");
    fs::write(&scene, TWO_ROSES).unwrap();
    let cache = dir.path().join("cache");
    let out = dir.path().join("r.png");
    let base = [
        "render",
        scene.to_str().unwrap(),
        "--device",
        "cpu",
        "--cache-dir",
        cache.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ];
    // 512 sites: thousands of times the default's cost. The warning comes first; the run is
    // stopped there.
    let mut child = Command::new(env!("CARGO_BIN_EXE_sylva"))
        .args(base)
        .args(["--global-grid", "512"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut warning = None;
    for line in BufReader::new(child.stderr.take().unwrap()).lines() {
        let line = line.unwrap();
        if line.contains("--global-grid 512") {
            warning = Some(line);
            break;
        }
    }
    // Still at work (the solves it announced) or ended: stop it either way.
    let _ = child.kill();
    let _ = child.wait();
    let w = warning.expect("a warning before the solves");
    assert!(
        w.starts_with("warning: --global-grid 512: the coarse grid (")
            && w.contains("× the default's (64 sites)"),
        "{w}"
    );
    // The default grid: no warning, and the render runs to the end.
    let (ok, stdout, stderr) = sylva(&base);
    assert!(ok, "{stdout}{stderr}");
    assert!(!stderr.contains("the default's"), "{stderr}");
    assert!(stdout.contains("forest grid"), "{stdout}");
}

/// Issue 31 item 9: a generator that places nothing is an error naming the file, the line and
/// the model, not an empty image; `basis` and `relight` refuse the options they do not use.
#[test]
fn silent_no_ops_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("empty.toml");
    fs::write(
        &scene,
        "[[models]]\nname = \"rose\"\nspecies = \"dogrose\"\n\n[[instances]]\nmodel = \"rose\"\n\
         count = 0\narea = { min = [0.0, 0.0], max = [10.0, 10.0] }\n",
    )
    .unwrap();
    let out = dir.path().join("e.png");
    let s = scene.to_str().unwrap();
    let (ok, _, stderr) = sylva(&["render", s, "-o", out.to_str().unwrap()]);
    assert!(!ok && !out.exists(), "an empty scene rendered: {stderr}");
    assert!(
        stderr.contains("empty.toml: line 5: instances of 'rose': count = 0 places no instance"),
        "{stderr}"
    );
    let (ok, _, stderr) = sylva(&["scene", "info", s]);
    assert!(
        !ok && stderr.contains("count = 0 places no instance"),
        "{stderr}"
    );

    // Options of a frame or of other lights: not options of these commands at all.
    for (command, option, value) in [
        ("basis", "--gather-rays", Some("999")),
        ("basis", "--width", Some("100")),
        ("basis", "--elevation", Some("30")),
        ("basis", "--seed", Some("3")),
        ("basis", "--shadows", Some("kd")),
        ("basis", "--sun-weights", Some("exact")),
        ("basis", "--ambient", Some("0.5")),
        ("basis", "--basis", Some("always")),
        ("basis", "--cpu-shading", None),
        ("relight", "--azimuth", Some("30")),
        ("relight", "--sun", Some("0,1,0")),
        ("relight", "--basis", Some("never")),
    ] {
        let mut args = vec![command, "demo", option];
        args.extend(value);
        let (ok, _, stderr) = sylva(&args);
        assert!(!ok, "{args:?}");
        assert!(
            stderr.contains(&format!("unexpected argument '{option}'")),
            "{args:?}: {stderr}"
        );
    }
    // A grid size out of range, or with the grid turned off, is refused whatever the light.
    for args in [
        &["relight", "demo", "--global-grid", "0"][..],
        &["render", "demo", "--light", "spp", "--global-grid", "0"],
        &["basis", "demo", "--no-global", "--global-grid", "32"],
    ] {
        let (ok, _, stderr) = sylva(args);
        assert!(!ok, "{args:?}");
        assert!(stderr.contains("--global-grid"), "{args:?}: {stderr}");
    }
}

/// Issue 27: the sun of a date, time and place. Every bad request is one line on stderr,
/// before any work: nothing written, no cache made.
#[test]
fn the_sun_of_a_bad_date_time_or_place_is_refused_with_nothing_written() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let out = out.to_str().unwrap();
    let png = dir.path().join("r.png");
    let png = png.to_str().unwrap();
    let cache = dir.path().join("cache");
    let cache = cache.to_str().unwrap();
    let day = |extra: &[&'static str]| {
        let mut a = vec!["relight", "demo", "--lat", "48.1", "--lon", "11.6"];
        a.extend(["--date", "2026-06-21"]);
        a.extend(extra.iter().copied());
        a
    };
    let cases: Vec<(Vec<&str>, &str)> =
        vec![
        (
            vec!["relight", "demo", "--lat", "91", "--lon", "11.6", "--date", "2026-06-21"],
            "--lat: latitude 91°: degrees north of the equator, -90 to 90",
        ),
        (
            vec!["relight", "demo", "--lat", "48.1", "--lon", "200", "--date", "2026-06-21"],
            "--lon: longitude 200°: degrees east of Greenwich, -180 to 180",
        ),
        (
            vec!["relight", "demo", "--lat", "48.1", "--lon", "11.6", "--date", "2026-02-30"],
            "--date: date '2026-02-30' does not exist: February 2026 has 28 days",
        ),
        (day(&["--step", "0"]), "--step: step '0': the sun needs a step longer than zero"),
        (day(&["--step", "15"]), "--step: step '15': expected hours, minutes and seconds"),
        (
            day(&["--from", "21:00", "--to", "05:00"]),
            "the path starts at 21:00, after it ends at 05:00",
        ),
        (day(&["--from", "25:00"]), "--from: time '25:00': expected a local clock time"),
        (day(&["--utc-offset", "+15:00"]), "--utc-offset: UTC offset '+15:00'"),
        (day(&["--step", "1m"]), "1440 suns from 00:00 to 23:59 every 1m: at most 1000"),
        (
            vec!["relight", "demo", "--lat", "80", "--lon", "15", "--date", "2026-12-21"],
            "the sun never rises above the horizon at 80.0°N on 2026-12-21 between 00:00 and 23:59",
        ),
        (
            vec![
                "render", "demo", "--lat", "48.1", "--lon", "11.6", "--date", "2026-06-21",
                "--time", "23:30", "--utc-offset", "+02:00",
            ],
            "° below the horizon at 48.1°N 11.6°E on 2026-06-21 at 23:30 (UTC+02:00)",
        ),
    ];
    for (mut args, want) in cases {
        args.extend(["-o", if args[0] == "render" { png } else { out }]);
        args.extend(["--cache-dir", cache]);
        let (ok, stdout, stderr) = sylva(&args);
        assert!(!ok, "{args:?} should fail: {stdout}");
        assert!(stderr.contains(want), "{args:?}: {stderr}");
        assert_eq!(stderr.lines().count(), 1, "one line: {stderr}");
        assert_eq!(
            fs::read_dir(dir.path()).unwrap().count(),
            0,
            "{args:?} wrote something"
        );
    }
    // The ways to give a sun exclude each other, and the place needs all its parts (clap).
    for (args, want) in [
        (
            &[
                "relight",
                "demo",
                "--suns",
                "4",
                "--lat",
                "1",
                "--lon",
                "2",
                "--date",
                "2026-06-21",
            ][..],
            "cannot be used with",
        ),
        (
            &[
                "relight",
                "demo",
                "--path-azimuth",
                "30",
                "--lat",
                "1",
                "--lon",
                "2",
                "--date",
                "2026-06-21",
            ],
            "cannot be used with",
        ),
        (
            &[
                "render",
                "demo",
                "--sun",
                "0,1,0",
                "--lat",
                "1",
                "--lon",
                "2",
                "--date",
                "2026-06-21",
                "--time",
                "12:00",
            ],
            "cannot be used with",
        ),
        (
            &[
                "render",
                "demo",
                "--elevation",
                "30",
                "--lat",
                "1",
                "--lon",
                "2",
                "--date",
                "2026-06-21",
                "--time",
                "12:00",
            ],
            "cannot be used with",
        ),
        (&["relight", "demo", "--lat", "48.1"], "--lon <LON>"),
        (&["relight", "demo", "--step", "15m"], "--date <DATE>"),
        (
            &[
                "render",
                "demo",
                "--lat",
                "1",
                "--lon",
                "2",
                "--date",
                "2026-06-21",
            ],
            "--time <TIME>",
        ),
        (&["render", "demo", "--time", "12:00"], "--date <DATE>"),
        (
            &["render", "demo", "--from", "12:00"],
            "unexpected argument '--from'",
        ),
        (
            &["relight", "demo", "--time", "12:00"],
            "unexpected argument '--time'",
        ),
    ] {
        let (ok, stdout, stderr) = sylva(args);
        assert!(!ok, "{args:?} should fail: {stdout}");
        assert!(stderr.contains(want), "{args:?}: {stderr}");
    }
}
