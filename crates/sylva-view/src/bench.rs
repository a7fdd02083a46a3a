//! `sylva bench view`: drives a server's WebSocket the way the page does while the user drags
//! the sun, and measures what the user feels: input-to-frame latency, frames per second, and
//! how long after the last input the refined frame arrives.
//!
//! Like the page, the client keeps one view request in flight while dragging: the next input
//! goes out when the frame answering the previous one arrives (the server would drop the
//! stale ones anyway). The sun sweeps `sweep_deg` of azimuth per second of dragging.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use serde::Serialize;
use tokio_tungstenite::tungstenite::Message;

use crate::orbit::Orbit;
use crate::protocol::{decode_frame, ClientMessage, FrameHeader, SunControl, ViewRequest};

/// What the benchmark does.
#[derive(Debug, Clone)]
pub struct ViewBenchPlan {
    /// Frame size the page asks for.
    pub width: u32,
    pub height: u32,
    /// Seconds of dragging.
    pub drag_seconds: f64,
    /// Degrees of sun azimuth per second of dragging.
    pub sweep_deg: f64,
    pub elevation_deg: f64,
    /// Final-gather rays of the refined frame.
    pub gather_rays: u32,
    /// Drags measured (each followed by its refinement).
    pub runs: u32,
    /// Longest wait for any one frame.
    pub timeout: Duration,
}

impl ViewBenchPlan {
    /// Refuses a plan that measures nothing or would never end.
    pub fn check(&self) -> Result<(), String> {
        if !(self.drag_seconds.is_finite() && (0.1..=600.0).contains(&self.drag_seconds)) {
            return Err(format!("--drag-seconds {}: 0.1 to 600", self.drag_seconds));
        }
        if !(self.elevation_deg > 0.0 && self.elevation_deg <= 90.0) {
            return Err(format!("--sun-elevation {}: (0, 90]", self.elevation_deg));
        }
        Ok(())
    }
}

/// What it measured.
#[derive(Debug, Clone, Default, Serialize)]
pub struct ViewBenchReport {
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub runs: u32,
    /// Input sent to the frame answering it arriving, while dragging (all runs).
    pub latency_median_ms: f64,
    pub latency_p95_ms: f64,
    /// Preview frames received per second of dragging (median over runs).
    pub fps: f64,
    /// Median time the server took to move the sun per preview, and to render it.
    pub relight_ms: f64,
    pub preview_render_ms: f64,
    /// Median preview size (pixels wide) and JPEG bytes.
    pub preview_width: u32,
    pub preview_bytes: usize,
    /// The last input to the first refined frame of it (median over runs).
    pub refined_ms: f64,
    pub refined_bytes: usize,
    /// LB solves the server reported after all of it (0: moving the sun solves nothing).
    pub lb_solves: u64,
}

impl std::fmt::Display for ViewBenchReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "bench view {} at {}x{}, {} drag(s):",
            self.scene, self.width, self.height, self.runs
        )?;
        writeln!(
            f,
            "  dragging: input to frame median {:.1} ms, p95 {:.1} ms; {:.1} frames/s \
             (the sun moved in {:.1} ms, previews rendered in {:.1} ms, {} px wide, {} bytes)",
            self.latency_median_ms,
            self.latency_p95_ms,
            self.fps,
            self.relight_ms,
            self.preview_render_ms,
            self.preview_width,
            self.preview_bytes
        )?;
        writeln!(
            f,
            "  released: refined frame {:.0} ms after the last input ({} bytes)",
            self.refined_ms, self.refined_bytes
        )?;
        writeln!(f, "  LB solves while viewing: {}", self.lb_solves)
    }
}

#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error("connecting to the viewer: {0}")]
    Connect(String),
    #[error("the viewer: {0}")]
    Protocol(String),
    #[error("no frame within {0:?}")]
    Timeout(Duration),
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

/// Runs `plan` against the server at `addr` with `token` (its own single-threaded runtime).
pub fn run(
    addr: SocketAddr,
    token: &str,
    plan: &ViewBenchPlan,
) -> Result<ViewBenchReport, BenchError> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| BenchError::Connect(e.to_string()))?
        .block_on(drive(addr, token, plan))
}

type Socket =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// The next message that is a frame, or the JSON of a text message (errors are failures).
async fn next_frame(
    ws: &mut Socket,
    timeout: Duration,
) -> Result<(FrameHeader, usize), BenchError> {
    loop {
        let m = tokio::time::timeout(timeout, ws.next())
            .await
            .map_err(|_| BenchError::Timeout(timeout))?
            .ok_or_else(|| BenchError::Protocol("closed the connection".into()))?
            .map_err(|e| BenchError::Protocol(e.to_string()))?;
        match m {
            Message::Binary(b) => {
                let (h, jpeg) = decode_frame(&b).map_err(BenchError::Protocol)?;
                return Ok((h, jpeg.len()));
            }
            Message::Text(t) => {
                let v: serde_json::Value =
                    serde_json::from_str(&t).map_err(|e| BenchError::Protocol(e.to_string()))?;
                if v["type"] == "error" {
                    return Err(BenchError::Protocol(v["message"].to_string()));
                }
            }
            _ => {}
        }
    }
}

async fn send(ws: &mut Socket, request: ViewRequest) -> Result<(), BenchError> {
    let text = serde_json::to_string(&ClientMessage::View(request)).expect("requests serialise");
    ws.send(Message::Text(text.into()))
        .await
        .map_err(|e| BenchError::Protocol(e.to_string()))
}

async fn drive(
    addr: SocketAddr,
    token: &str,
    plan: &ViewBenchPlan,
) -> Result<ViewBenchReport, BenchError> {
    let url = format!("ws://{addr}/ws?token={token}");
    let (mut ws, _) = tokio_tungstenite::connect_async(url)
        .await
        .map_err(|e| BenchError::Connect(e.to_string()))?;
    // Status lines until the hello.
    let hello = loop {
        let m = tokio::time::timeout(Duration::from_secs(3600), ws.next())
            .await
            .map_err(|_| BenchError::Timeout(Duration::from_secs(3600)))?
            .ok_or_else(|| BenchError::Protocol("closed before the scene was ready".into()))?
            .map_err(|e| BenchError::Protocol(e.to_string()))?;
        if let Message::Text(t) = m {
            let v: serde_json::Value =
                serde_json::from_str(&t).map_err(|e| BenchError::Protocol(e.to_string()))?;
            match v["type"].as_str() {
                Some("hello") => break v,
                Some("error") => return Err(BenchError::Protocol(v["message"].to_string())),
                _ => {}
            }
        }
    };
    let camera: Orbit = serde_json::from_value(hello["camera"].clone())
        .map_err(|e| BenchError::Protocol(format!("hello: {e}")))?;
    let scene = hello["scene"].as_str().unwrap_or("").to_string();
    let mut seq = 0u64;
    let mut request = |azimuth: f64, interacting: bool| {
        seq += 1;
        ViewRequest {
            seq,
            sun: SunControl::Angles {
                elevation: plan.elevation_deg,
                azimuth,
            },
            camera,
            mode: "full".into(),
            gather_rays: plan.gather_rays,
            exposure: 0.0,
            width: plan.width,
            height: plan.height,
            interacting,
        }
    };
    let (mut latencies, mut fps, mut refined_ms) = (Vec::new(), Vec::new(), Vec::new());
    let (mut widths, mut preview_bytes, mut refined_bytes) = (Vec::new(), Vec::new(), 0);
    let (mut relight_ms, mut render_ms) = (Vec::new(), Vec::new());
    let mut lb_solves = 0;
    let mut azimuth = 0.0;
    for _ in 0..plan.runs {
        let start = Instant::now();
        let mut frames = 0u32;
        let mut last;
        loop {
            azimuth = (azimuth + plan.sweep_deg * 0.016).rem_euclid(360.0);
            let r = request(azimuth, true);
            last = r.clone();
            let sent = Instant::now();
            send(&mut ws, r).await?;
            // The frame answering this input (an earlier refinement's may come first).
            loop {
                let (h, bytes) = next_frame(&mut ws, plan.timeout).await?;
                if h.seq == last.seq && !h.refined {
                    latencies.push(sent.elapsed().as_secs_f64() * 1e3);
                    widths.push(h.width as f64);
                    relight_ms.push(h.relight_ms);
                    render_ms.push(h.render_ms);
                    preview_bytes.push(bytes as f64);
                    frames += 1;
                    break;
                }
            }
            if start.elapsed().as_secs_f64() >= plan.drag_seconds {
                break;
            }
        }
        fps.push(frames as f64 / start.elapsed().as_secs_f64());
        // Release: the same view, no longer interacting; the refined frame follows.
        let released = Instant::now();
        send(
            &mut ws,
            ViewRequest {
                interacting: false,
                ..last.clone()
            },
        )
        .await?;
        loop {
            let (h, bytes) = next_frame(&mut ws, plan.timeout).await?;
            if h.refined && h.seq > last.seq - 1 {
                refined_ms.push(released.elapsed().as_secs_f64() * 1e3);
                lb_solves = h.lb_solves;
                refined_bytes = bytes;
                break;
            }
        }
    }
    let _ = ws.close(None).await;
    Ok(ViewBenchReport {
        scene,
        width: plan.width,
        height: plan.height,
        runs: plan.runs,
        latency_median_ms: median(&mut latencies.clone()),
        latency_p95_ms: percentile(&mut latencies, 0.95),
        fps: median(&mut fps),
        relight_ms: median(&mut relight_ms),
        preview_render_ms: median(&mut render_ms),
        preview_width: median(&mut widths) as u32,
        preview_bytes: median(&mut preview_bytes) as usize,
        refined_ms: median(&mut refined_ms),
        refined_bytes,
        lb_solves,
    })
}
