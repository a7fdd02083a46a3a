//! The viewer in a real browser: headless Chromium driven through WebDriver (Debian's
//! `chromium` and `chromium-driver`; a few JSON-over-HTTP calls, spoken here directly). It
//! loads the page, waits for the first frame, drags the sun on the compass with synthesized
//! pointer events, and checks that the canvas changed, that the frame-rate readout is above
//! zero and that the server made no LB solve. Screenshots at 1280x800 and at a phone's size
//! go to docs/images/viewer-test*.png (the README links them). Without Chromium the test fails under
//! `SYLVA_REQUIRE_BROWSER=1` (CI) and says SKIPPED otherwise.

use std::io::{BufRead, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use base64::Engine;
use serde_json::{json, Value};
use sylva_testkit::{missing, Need};

use super::view_cli::Viewer;

/// The W3C WebDriver element key.
const ELEMENT: &str = "element-6066-11e4-a52e-4f735466cecf";

fn which(name: &str) -> Option<PathBuf> {
    std::env::var_os("PATH")?
        .to_str()?
        .split(':')
        .map(|d| Path::new(d).join(name))
        .find(|p| p.is_file())
}

struct Driver {
    process: Child,
    port: u16,
    session: String,
}

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.call("DELETE", &format!("/session/{}", self.session), None);
        let _ = self.process.kill();
        let _ = self.process.wait();
    }
}

/// One WebDriver call: `method path` with a JSON body; the response's `value`.
fn call(port: u16, method: &str, path: &str, body: Option<&Value>) -> Result<Value, String> {
    let mut s = TcpStream::connect(("127.0.0.1", port)).map_err(|e| e.to_string())?;
    s.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
    let body = body.map(|b| b.to_string()).unwrap_or_default();
    write!(
        s,
        "{method} {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Type: application/json\r\n\
         Content-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )
    .map_err(|e| e.to_string())?;
    // chromedriver keeps the connection open whatever the request says: read the headers,
    // then Content-Length bytes.
    let mut reader = std::io::BufReader::new(s);
    let mut length = 0usize;
    loop {
        let mut line = String::new();
        reader.read_line(&mut line).map_err(|e| e.to_string())?;
        let line = line.trim_end();
        if line.is_empty() {
            break;
        }
        if let Some((k, v)) = line.split_once(':') {
            if k.eq_ignore_ascii_case("content-length") {
                length = v
                    .trim()
                    .parse()
                    .map_err(|_| format!("bad length: {line}"))?;
            }
        }
    }
    let mut body = vec![0u8; length];
    reader.read_exact(&mut body).map_err(|e| e.to_string())?;
    let json = String::from_utf8_lossy(&body);
    let v: Value = serde_json::from_str(&json).map_err(|e| format!("{e}: {json}"))?;
    if v["value"]["error"].is_string() {
        return Err(format!("{method} {path}: {}", v["value"]));
    }
    Ok(v["value"].clone())
}

impl Driver {
    fn start(chromedriver: &Path, chromium: &Path) -> Driver {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let process = Command::new(chromedriver)
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start chromedriver");
        let t = Instant::now();
        while call(port, "GET", "/status", None).is_err() {
            assert!(
                t.elapsed() < Duration::from_secs(30),
                "chromedriver did not start"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        let caps = json!({"capabilities": {"alwaysMatch": {
            "browserName": "chrome",
            "goog:chromeOptions": {
                "binary": chromium,
                "args": ["--headless=new", "--no-sandbox", "--disable-gpu",
                         "--disable-dev-shm-usage", "--window-size=1280,800",
                         "--hide-scrollbars", "--force-device-scale-factor=1"]
            }
        }}});
        let v = call(port, "POST", "/session", Some(&caps)).expect("a Chromium session");
        let session = v["sessionId"].as_str().expect("a session id").to_string();
        Driver {
            process,
            port,
            session,
        }
    }

    fn call(&self, method: &str, path: &str, body: Option<&Value>) -> Result<Value, String> {
        call(self.port, method, path, body)
    }

    fn session(&self, method: &str, path: &str, body: Value) -> Value {
        let path = format!("/session/{}{path}", self.session);
        let body = (method == "POST").then_some(&body);
        self.call(method, &path, body).unwrap()
    }

    fn script(&self, js: &str) -> Value {
        self.session("POST", "/execute/sync", json!({"script": js, "args": []}))
    }

    /// Polls `js` until it returns true.
    fn wait_for(&self, js: &str, within: Duration, what: &str) {
        let t = Instant::now();
        while self.script(js) != json!(true) {
            assert!(t.elapsed() < within, "waited {within:?} for {what}");
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    fn screenshot(&self, path: &Path) {
        let png = self.session("GET", "/screenshot", Value::Null);
        let bytes = base64::engine::general_purpose::STANDARD
            .decode(png.as_str().unwrap())
            .unwrap();
        assert!(image::load_from_memory(&bytes).is_ok());
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        sylva_core::atomic_write(path, &bytes).unwrap();
    }
}

/// A checksum of the canvas's pixels, the number of frames drawn, and the LB solves the
/// server reported.
const CANVAS: &str = "const c = document.getElementById('frame');
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let s = 0;
    for (let i = 0; i < d.length; i += 7) s = (s * 31 + d[i]) >>> 0;
    return [s, Number(c.dataset.frames || 0), c.dataset.solves || ''];";

#[test]
fn the_page_drags_the_sun_in_chromium_and_the_light_follows_without_an_lb_solve() {
    let (Some(chromium), Some(chromedriver)) = (which("chromium"), which("chromedriver")) else {
        missing(
            Need::Browser,
            "no chromium and chromedriver on PATH (Debian: apt-get install chromium chromium-driver)",
        );
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let viewer = Viewer::shade(dir.path(), &["--samples", "4"]);
    let driver = Driver::start(&chromedriver, &chromium);
    driver.session("POST", "/url", json!({"url": viewer.url}));
    driver.wait_for(
        "return Number(document.getElementById('frame').dataset.frames || 0) > 0",
        Duration::from_secs(1500),
        "the first frame",
    );
    // Let the refinement finish, then remember the picture.
    std::thread::sleep(Duration::from_secs(2));
    let before = driver.script(CANVAS);

    // Drag the sun on the compass, from its centre (overhead) towards the east rim.
    let compass = driver.session(
        "POST",
        "/element",
        json!({"using": "css selector", "value": "#compass"}),
    );
    let origin = json!({ELEMENT: compass[ELEMENT]});
    let mut steps = vec![
        json!({"type": "pointerMove", "duration": 0, "origin": origin, "x": 0, "y": 0}),
        json!({"type": "pointerDown", "button": 0}),
    ];
    for k in 1..=12 {
        steps.push(
            json!({"type": "pointerMove", "duration": 60, "origin": origin, "x": 3 * k, "y": -k}),
        );
    }
    steps.push(json!({"type": "pointerUp", "button": 0}));
    driver.session(
        "POST",
        "/actions",
        json!({"actions": [{"type": "pointer", "id": "mouse",
                            "parameters": {"pointerType": "mouse"}, "actions": steps}]}),
    );
    let fps = driver.script("return document.getElementById('stat-fps').textContent");
    let fps: f64 = fps
        .as_str()
        .unwrap()
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap_or(0.0);
    assert!(fps > 0.0, "the frame-rate readout says {fps}");
    let frames_before = before[1].as_u64().unwrap();
    driver.wait_for(
        &format!(
            "return Number(document.getElementById('frame').dataset.frames) > {}",
            frames_before + 2
        ),
        Duration::from_secs(120),
        "frames after the drag",
    );
    // The refined frame of the sun's new place.
    let refined = "return !document.getElementById('stat-samples').textContent.includes('preview')";
    driver.wait_for(refined, Duration::from_secs(300), "a refined frame");
    let after = driver.script(CANVAS);
    assert_ne!(before[0], after[0], "the canvas did not change");
    assert_eq!(
        after[2],
        json!("0"),
        "the server made LB solves while the sun moved"
    );
    let elevation = driver.script("return document.getElementById('sun-elev').textContent");
    assert_ne!(elevation, json!("90.0°"), "the sun did not move");

    // Screenshots for the README: a laptop's screen and a phone's.
    let images = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/images");
    driver.screenshot(&images.join("viewer-test.png"));
    driver.session("POST", "/window/rect", json!({"width": 390, "height": 844}));
    std::thread::sleep(Duration::from_secs(1));
    driver.wait_for(
        refined,
        Duration::from_secs(300),
        "a refined frame at a phone's size",
    );
    driver.screenshot(&images.join("viewer-test-phone.png"));
    drop(driver);
    let (ok, _) = viewer.interrupt();
    assert!(ok);
}
