//! A real server on a free port, over a small prepared scene (the built-in `shade`: two
//! models relit from their physical base solutions on a 24-cell grid).

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};
use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use sylva_lb::CpuSolver;
use sylva_light::relight::{GlobalGridOptions, SunWeights};
use sylva_light::{Light, Silent};
use sylva_pipeline::{load_scene, BasisUse, LbPlan, PrepareOptions, PreparedScene, RelightPlan};
use sylva_view::protocol::{decode_frame, ClientMessage, FrameHeader, ViewRequest};
use sylva_view::{ReadyScene, ServeOptions, Server, WorkerOptions};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::Message;

use crate::protocol::request;

/// One test at a time on the one server (prepared once: its LB solves are the slow part).
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());
static SERVER: OnceLock<Server> = OnceLock::new();

const TOKEN: &str = "0123456789abcdef0123456789abcdef";

fn prepare_shade() -> Result<ReadyScene, String> {
    let scene = load_scene("shade", None).map_err(|e| e.to_string())?;
    let scene = PreparedScene::new(
        scene,
        &PrepareOptions {
            lb: Some(LbPlan {
                solver: &CpuSolver,
                grid: Some(24),
                cache_dir: None,
                light: Light::Physical,
            }),
            light: Light::Physical,
            forest: Some(GlobalGridOptions { sites: 32 }),
            gather_rays: 2,
            relight: Some(RelightPlan {
                basis: BasisUse::Always,
                sun: SunWeights::ThreeBasis,
                ambient: 0.0,
                ..RelightPlan::default()
            }),
            largest_frame: Some((256, 256, 2)),
            ..PrepareOptions::default()
        },
        &Silent,
    )
    .map_err(|e| e.to_string())?;
    Ok(ReadyScene {
        scene,
        width: 48,
        height: 32,
        light: "the physical light, relit".into(),
        lat: 48.1,
        lon: 11.6,
    })
}

/// Where the server saves frames.
fn saves() -> PathBuf {
    Path::new(env!("CARGO_TARGET_TMPDIR")).join("sylva-view-saves")
}

/// The server every test talks to (each over pages of its own).
fn server() -> &'static Server {
    SERVER.get_or_init(|| start(&saves(), 3))
}

fn start(output_dir: &Path, max_samples: u32) -> Server {
    let opts = ServeOptions {
        host: "127.0.0.1".into(),
        port: 0,
        token: Some(TOKEN.into()),
        worker: WorkerOptions {
            max_pixels: 256 * 256,
            max_samples,
            output_dir: output_dir.to_path_buf(),
            ..WorkerOptions::default()
        },
    };
    let mut server = Server::start(opts, |status| {
        status("preparing shade".into());
        prepare_shade()
    })
    .unwrap();
    server.wait_ready().unwrap();
    server
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
}

/// The status code of `GET path` with `headers`.
fn http_status(addr: SocketAddr, path: &str) -> (u16, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut text = String::new();
    s.read_to_string(&mut text).unwrap();
    let code = text[9..12].parse().unwrap();
    (code, text)
}

type Socket =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

async fn open(addr: SocketAddr, token: &str, origin: Option<&str>) -> Result<Socket, String> {
    let mut req = format!("ws://{addr}/ws?token={token}")
        .into_client_request()
        .unwrap();
    if let Some(o) = origin {
        req.headers_mut().insert("Origin", o.parse().unwrap());
    }
    let (mut ws, _) = tokio_tungstenite::connect_async(req)
        .await
        .map_err(|e| e.to_string())?;
    // Up to the hello.
    loop {
        let v = next_text(&mut ws).await;
        if v["type"] == "hello" {
            return Ok(ws);
        }
    }
}

enum Got {
    Frame(FrameHeader, image::RgbImage),
    Text(serde_json::Value),
}

async fn next(ws: &mut Socket) -> Got {
    loop {
        let m = tokio::time::timeout(Duration::from_secs(120), ws.next())
            .await
            .expect("a message within 2 minutes")
            .expect("the connection open")
            .expect("a good message");
        match m {
            Message::Binary(b) => {
                let (h, jpeg) = decode_frame(&b).unwrap();
                let img = image::load_from_memory(jpeg).unwrap().to_rgb8();
                return Got::Frame(h, img);
            }
            Message::Text(t) => return Got::Text(serde_json::from_str(&t).unwrap()),
            _ => {}
        }
    }
}

async fn next_text(ws: &mut Socket) -> serde_json::Value {
    loop {
        if let Got::Text(v) = next(ws).await {
            return v;
        }
    }
}

/// Frames until one answering `seq` (refined or not, as asked) arrives.
async fn frame_for(ws: &mut Socket, seq: u64, refined: bool) -> (FrameHeader, image::RgbImage) {
    loop {
        match next(ws).await {
            Got::Frame(h, img) if h.seq == seq && h.refined == refined => return (h, img),
            Got::Frame(..) => {}
            Got::Text(v) => assert_ne!(v["type"], "error", "{v}"),
        }
    }
}

async fn send(ws: &mut Socket, r: &ViewRequest) {
    let text = serde_json::to_string(&ClientMessage::View(r.clone())).unwrap();
    ws.send(Message::Text(text.into())).await.unwrap();
}

fn mean(img: &image::RgbImage) -> f64 {
    img.as_raw().iter().map(|&v| v as f64).sum::<f64>() / img.as_raw().len() as f64
}

#[test]
fn the_page_and_its_socket_need_the_token_and_this_servers_origin() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let server = server();
    let addr = server.addr();
    assert_eq!(http_status(addr, "/").0, 403);
    assert_eq!(http_status(addr, "/?token=wrong").0, 403);
    let (code, page) = http_status(addr, &format!("/?token={TOKEN}"));
    assert_eq!(code, 200);
    assert!(page.contains("<canvas id=\"frame\""));
    assert_eq!(http_status(addr, "/app.js").0, 200);
    let rt = runtime();
    rt.block_on(async {
        assert!(open(addr, "wrong", None).await.unwrap_err().contains("403"));
        let e = open(addr, TOKEN, Some("http://evil.example"))
            .await
            .unwrap_err();
        assert!(e.contains("403"), "{e}");
        // The page's own origin, and a client with none (not a browser), are let in.
        open(addr, TOKEN, Some(&format!("http://{addr}")))
            .await
            .unwrap();
        open(addr, TOKEN, None).await.unwrap();
    });
}

#[test]
fn frames_follow_the_sun_refine_when_input_stops_and_no_lb_solve_is_made() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let server = server();
    runtime().block_on(async {
        let mut ws = open(server.addr(), TOKEN, None).await.unwrap();
        // Dragging: previews, smaller than the frame asked for or at most its size.
        let mut means = Vec::new();
        for (seq, elevation) in [(1, 70.0), (2, 12.0)] {
            send(&mut ws, &request(seq, elevation, 180.0)).await;
            let (h, img) = frame_for(&mut ws, seq, false).await;
            assert!(h.width <= 48 && h.height <= 32 && h.samples == 1);
            assert_eq!((img.width(), img.height()), (h.width, h.height));
            assert_eq!(h.lb_solves, 0);
            means.push(mean(&img));
        }
        // The exposure stays (only the sun moved): the low sun's frame is darker.
        assert!(means[1] < means[0], "{means:?}");
        // Released: refinement passes at the full size accumulate samples (1, then 2 each).
        let r = ViewRequest {
            interacting: false,
            ..request(2, 12.0, 180.0)
        };
        send(&mut ws, &ViewRequest { seq: 3, ..r }).await;
        let (h, img) = frame_for(&mut ws, 3, true).await;
        assert_eq!((h.width, h.height, h.samples), (48, 32, 1));
        assert_eq!((img.width(), img.height()), (48, 32));
        let (h, _) = frame_for(&mut ws, 3, true).await;
        assert_eq!(h.samples, 3);
        assert_eq!(h.lb_solves, 0, "moving the sun solved the LB");
        // The sun of a clock time: resolved by the server, reported in the frame.
        let clock = serde_json::json!({
            "type": "view", "seq": 4, "mode": "lb", "gather_rays": 0, "exposure": 1.0,
            "width": 40, "height": 24, "interacting": true,
            "camera": request(0, 1.0, 0.0).camera,
            "sun": {"by": "clock", "lat": 48.1, "lon": 11.6, "date": "2026-06-21",
                    "time": "09:00", "utc_offset": "+02:00"}
        });
        ws.send(Message::Text(clock.to_string().into()))
            .await
            .unwrap();
        let (h, _) = frame_for(&mut ws, 4, false).await;
        assert!(h.sun_elevation > 30.0 && h.sun_elevation < 45.0, "{h:?}");
        assert!(h.sun_azimuth > 80.0 && h.sun_azimuth < 120.0, "{h:?}");
    });
}

#[test]
fn the_latest_input_wins_and_stale_requests_are_dropped() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let server = server();
    runtime().block_on(async {
        let mut ws = open(server.addr(), TOKEN, None).await.unwrap();
        for seq in 1..=30 {
            send(&mut ws, &request(seq, 20.0 + seq as f64, 3.0 * seq as f64)).await;
        }
        let mut answered = Vec::new();
        loop {
            match next(&mut ws).await {
                Got::Frame(h, _) if !h.refined => {
                    answered.push(h.seq);
                    if h.seq == 30 {
                        break;
                    }
                }
                _ => {}
            }
        }
        // Answers come in order, end with the latest, and skip what went stale.
        assert!(answered.windows(2).all(|w| w[0] < w[1]), "{answered:?}");
        assert!(answered.len() < 30, "nothing was dropped: {answered:?}");
    });
}

#[test]
fn hostile_messages_get_errors_and_every_other_page_is_still_served() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let server = server();
    runtime().block_on(async {
        let mut a = open(server.addr(), TOKEN, None).await.unwrap();
        let mut b = open(server.addr(), TOKEN, None).await.unwrap();
        let bad: Vec<Message> = vec![
            Message::Text("not json".into()),
            Message::Text(r#"{"type":"view","seq":1}"#.into()),
            Message::Text(
                serde_json::to_string(&ClientMessage::View(ViewRequest {
                    width: 100_000,
                    ..request(2, 30.0, 0.0)
                }))
                .unwrap()
                .into(),
            ),
            Message::Text(format!(r#"{{"type":"save","format":"{}"}}"#, "x".repeat(5000)).into()),
            Message::Text(r#"{"type":"save","format":"gif"}"#.into()),
            Message::Binary(vec![0u8; 100].into()),
        ];
        for m in bad {
            a.send(m).await.unwrap();
            let v = next_text(&mut a).await;
            assert_eq!(v["type"], "error", "{v}");
        }
        // A page with nothing refined yet cannot save.
        a.send(Message::Text(r#"{"type":"save","format":"png"}"#.into()))
            .await
            .unwrap();
        assert!(next_text(&mut a).await["message"]
            .as_str()
            .unwrap()
            .contains("nothing to save"));
        // The other page was never disturbed, and the first still works.
        send(&mut b, &request(5, 30.0, 40.0)).await;
        frame_for(&mut b, 5, false).await;
        send(&mut a, &request(6, 30.0, 40.0)).await;
        frame_for(&mut a, 6, false).await;
        // Too fast: beyond the rate limit the rest of the second is dropped, with one error.
        for seq in 7..400 {
            a.send(Message::Text("{}".into())).await.unwrap();
            let _ = seq;
        }
        let mut limited = false;
        for _ in 0..400 {
            let v = next_text(&mut a).await;
            if v["message"]
                .as_str()
                .unwrap_or("")
                .contains("messages a second")
            {
                limited = true;
                break;
            }
        }
        assert!(limited);
        // A message beyond the transport's limit ends that page only.
        let huge = "x".repeat(1 << 20);
        let _ = a.send(Message::Text(huge.into())).await;
        send(&mut b, &request(9, 35.0, 60.0)).await;
        frame_for(&mut b, 9, false).await;
    });
}

#[test]
fn a_page_that_leaves_mid_frame_frees_its_work_and_saves_write_the_refined_frame() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let server = server();
    runtime().block_on(async {
        // A large refinement asked for, then the page closes.
        let mut a = open(server.addr(), TOKEN, None).await.unwrap();
        let r = ViewRequest {
            width: 256,
            height: 256,
            interacting: false,
            gather_rays: 16,
            ..request(1, 40.0, 0.0)
        };
        send(&mut a, &r).await;
        frame_for(&mut a, 1, false).await;
        drop(a);
        let mut waited = 0;
        while server.clients() > 0 && waited < 100 {
            tokio::time::sleep(Duration::from_millis(50)).await;
            waited += 1;
        }
        assert_eq!(server.clients(), 0, "the closed page is still served");
        // Another page is answered (the worker is not still refining for the closed one).
        let mut b = open(server.addr(), TOKEN, None).await.unwrap();
        let r = ViewRequest {
            interacting: false,
            ..request(2, 40.0, 0.0)
        };
        send(&mut b, &r).await;
        frame_for(&mut b, 2, true).await;
        for (format, ext) in [("png", "png"), ("exr", "exr")] {
            let m = format!(r#"{{"type":"save","format":"{format}"}}"#);
            b.send(Message::Text(m.into())).await.unwrap();
            let v = loop {
                let v = next_text(&mut b).await;
                if v["type"] == "saved" {
                    break v;
                }
                assert_ne!(v["type"], "error", "{v}");
            };
            let path = std::path::PathBuf::from(v["path"].as_str().unwrap());
            assert!(path.starts_with(saves()) && path.extension().unwrap() == ext);
            let img = image::open(&path).unwrap();
            assert_eq!((img.width(), img.height()), (48, 32));
            assert!(v["samples"].as_u64().unwrap() >= 1);
        }
    });
}
