//! `sylva view`: bad input refused before anything is served; the server prints its URL,
//! serves the page only with the token, and Ctrl-C stops it cleanly.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Child, Command, Stdio};

use crate::common::sylva;

/// `sylva view ARGS` started, with the URL it printed.
pub(crate) struct Viewer {
    pub child: Child,
    pub url: String,
    pub lines: std::sync::mpsc::Receiver<String>,
}

impl Viewer {
    pub fn start(args: &[&str]) -> Viewer {
        let mut child = Command::new(env!("CARGO_BIN_EXE_sylva"))
            .arg("view")
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("run sylva view");
        let (tx, lines) = std::sync::mpsc::channel();
        let out = child.stdout.take().unwrap();
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                let _ = tx.send(line);
            }
        });
        let first = lines
            .recv_timeout(std::time::Duration::from_secs(60))
            .expect("sylva view prints its URL");
        let url = first
            .split_whitespace()
            .find(|w| w.starts_with("http://"))
            .unwrap_or_else(|| panic!("no URL in '{first}'"))
            .to_string();
        Viewer { child, url, lines }
    }

    /// Sends SIGINT (Ctrl-C) and waits for the process: its exit status and what it printed
    /// after the URL.
    pub fn interrupt(mut self) -> (bool, Vec<String>) {
        // SAFETY: kill(2) on our own child's pid.
        let rc = unsafe { libc::kill(self.child.id() as i32, libc::SIGINT) };
        assert_eq!(rc, 0);
        let status = self.child.wait().unwrap();
        // The reader thread may still hold the last lines: take them until it has read the
        // pipe's end (the process is gone, so that comes), not only what arrived so far.
        let mut lines = Vec::new();
        while let Ok(line) = self.lines.recv_timeout(std::time::Duration::from_secs(10)) {
            lines.push(line);
        }
        (status.success(), lines)
    }

    /// `sylva view shade` on a 16-cell grid (its bases solved in seconds), caching and
    /// saving under `dir`, with `extra` arguments.
    pub fn shade(dir: &std::path::Path, extra: &[&str]) -> Viewer {
        let cache = dir.join("cache");
        let mut args = vec![
            "shade",
            "--port",
            "0",
            "--lb-grid",
            "16",
            "--cache-dir",
            cache.to_str().unwrap(),
            "--output",
            dir.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        Viewer::start(&args)
    }

    /// Host and port of the URL.
    pub fn authority(&self) -> String {
        self.url
            .trim_start_matches("http://")
            .split('/')
            .next()
            .unwrap()
            .to_string()
    }
}

impl Drop for Viewer {
    /// A test that fails leaves no server behind.
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

fn get(authority: &str, path: &str) -> u16 {
    let mut s = TcpStream::connect(authority).unwrap();
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: {authority}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut text = String::new();
    s.read_to_string(&mut text).unwrap();
    text[9..12].parse().unwrap()
}

#[test]
fn view_refuses_bad_input_before_it_serves() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("a-file");
    std::fs::write(&file, b"x").unwrap();
    let busy = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = busy.local_addr().unwrap().port().to_string();
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["shade", "--lat", "91"], "91"),
        (vec!["shade", "--port", &port], "--port"),
        (
            vec!["shade", "--output", file.to_str().unwrap()],
            "not a folder",
        ),
        (vec!["shade", "--light", "spp"], "spp"),
        (vec!["shade", "--samples", "0"], "samples"),
        (vec!["shade", "--gather-rays", "-1"], "gather-rays"),
    ];
    for (args, word) in cases {
        let mut all = vec!["view"];
        all.extend(&args);
        let (ok, _, err) = sylva(&all);
        assert!(!ok, "{args:?} was accepted");
        assert!(err.contains(word), "{args:?}: '{err}' should name {word}");
        assert!(!err.contains("panicked"), "{err}");
    }
    for (args, word) in [
        (["shade", "--drag-seconds", "0"], "drag-seconds"),
        (["shade", "--sun-elevation", "-3"], "sun-elevation"),
    ] {
        let (ok, _, err) = sylva(&[&["bench", "view"][..], &args[..]].concat());
        assert!(!ok && err.contains(word), "{args:?}: {err}");
    }
}

#[test]
fn view_serves_the_page_with_its_token_and_ctrl_c_stops_it() {
    let dir = tempfile::tempdir().unwrap();
    let viewer = Viewer::shade(dir.path(), &[]);
    assert!(
        viewer.url.starts_with("http://127.0.0.1:"),
        "{}",
        viewer.url
    );
    let token_path = viewer
        .url
        .split_once(viewer.authority().as_str())
        .unwrap()
        .1
        .to_string();
    assert_eq!(get(&viewer.authority(), &token_path), 200);
    assert_eq!(get(&viewer.authority(), "/"), 403);
    let (ok, lines) = viewer.interrupt();
    assert!(ok, "Ctrl-C did not stop the viewer cleanly: {lines:?}");
    assert!(lines.iter().any(|l| l.contains("stopped")), "{lines:?}");
}
