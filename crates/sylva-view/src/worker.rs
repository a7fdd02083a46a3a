//! The render worker: one thread that owns the prepared scene and answers every page.
//!
//! Each page has a [`Mailbox`]. A new view replaces the one still waiting there (the latest
//! input wins; nothing queues), and bumps the mailbox's generation, which the worker checks
//! between the strips of a refinement pass: a pass whose view is stale is dropped mid-frame.
//! A changed view is answered first with a preview (reduced size, no final gather, one ray
//! per pixel, its size adapted so that a preview takes about the frame budget); once input
//! has stopped for the settle time, refinement passes at full size with the full gather
//! accumulate samples (1, then 2 per pass, jittered) up to the most samples. Pages are
//! served round robin. Moving the sun calls [`PreparedScene::set_sun`]: the relit light's
//! weights, no LB solve (the frames report [`sylva_lb::solves_started`] since preparation).

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use axum::body::Bytes;
use sylva_light::Silent;
use sylva_pipeline::PreparedScene;
use sylva_render::output::{write_exr, write_png};
use sylva_render::tonemap::{srgb8, ToneStats};
use sylva_render::{Frame, Mode, Radiance, Region, ToneMap};
use tokio::sync::{mpsc, watch};

use crate::orbit::Orbit;
use crate::protocol::{encode_frame, FrameHeader, ServerMessage, View};

/// Rows a refinement pass renders between checks for newer input (a multiple of the
/// renderer's 8-pixel tiles).
const STRIP_ROWS: u32 = 32;
/// Smallest and largest preview scale (of each side of the refined frame).
const PREVIEW_SCALE: (f32, f32) = (0.2, 1.0);
/// Text messages waiting for a page before further ones are dropped.
const MESSAGE_QUEUE: usize = 16;

/// How the worker renders.
#[derive(Debug, Clone)]
pub struct WorkerOptions {
    /// Most pixels of a frame a page may ask for.
    pub max_pixels: u64,
    /// Samples per pixel a refined frame accumulates before refinement stops.
    pub max_samples: u32,
    /// What a preview may take; its size adapts to it.
    pub preview_budget: Duration,
    /// Quiet time after the last input before refinement starts.
    pub settle: Duration,
    /// Where saved frames go.
    pub output_dir: PathBuf,
    pub jpeg_quality: (u8, u8),
}

impl Default for WorkerOptions {
    fn default() -> Self {
        WorkerOptions {
            max_pixels: 1920 * 1200,
            max_samples: 16,
            preview_budget: Duration::from_millis(60),
            settle: Duration::from_millis(150),
            output_dir: PathBuf::from("sylva-out"),
            jpeg_quality: (70, 90),
        }
    }
}

/// A saved frame's format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SaveFormat {
    Png,
    Exr,
}

impl SaveFormat {
    pub fn parse(s: &str) -> Result<SaveFormat, String> {
        match s {
            "png" => Ok(SaveFormat::Png),
            "exr" => Ok(SaveFormat::Exr),
            f => Err(format!("save format '{f}': png or exr")),
        }
    }
}

#[derive(Default)]
struct Inbox {
    view: Option<View>,
    save: Option<SaveFormat>,
}

/// One page's connection to the worker.
pub struct Mailbox {
    id: u64,
    inbox: Mutex<Inbox>,
    generation: AtomicU64,
    alive: AtomicBool,
    frames: watch::Sender<Option<Bytes>>,
    messages: mpsc::Sender<ServerMessage>,
}

impl Mailbox {
    /// Sends a text message unless the page has fallen behind (then it is dropped: frames
    /// and errors are advisory, the next one supersedes it).
    pub fn say(&self, message: ServerMessage) {
        let _ = self.messages.try_send(message);
    }

    /// Sends a text message, waiting while the page's queue is full: the page's own input
    /// loop uses this, so a page that floods without reading is slowed to its own pace.
    pub async fn tell(&self, message: ServerMessage) {
        let _ = self.messages.send(message).await;
    }

    fn stale(&self, generation: u64) -> bool {
        !self.alive.load(Ordering::SeqCst) || self.generation.load(Ordering::SeqCst) != generation
    }
}

/// What a page's connection reads: its frames (only the latest is kept) and messages.
pub struct Connection {
    pub mailbox: Arc<Mailbox>,
    pub frames: watch::Receiver<Option<Bytes>>,
    pub messages: mpsc::Receiver<ServerMessage>,
}

#[derive(Default)]
struct HubState {
    clients: Vec<Arc<Mailbox>>,
    epoch: u64,
    shutdown: bool,
    next_id: u64,
}

/// Where pages post their input and the worker waits for it.
#[derive(Default)]
pub struct Hub {
    state: Mutex<HubState>,
    wake: Condvar,
}

impl Hub {
    pub fn new() -> Arc<Hub> {
        Arc::new(Hub::default())
    }

    /// A new page's mailbox.
    pub fn connect(&self) -> Connection {
        let (frames, frames_rx) = watch::channel(None);
        let (messages, messages_rx) = mpsc::channel(MESSAGE_QUEUE);
        let mut s = self.state.lock().expect("hub");
        s.next_id += 1;
        let mailbox = Arc::new(Mailbox {
            id: s.next_id,
            inbox: Mutex::default(),
            generation: AtomicU64::new(0),
            alive: AtomicBool::new(true),
            frames,
            messages,
        });
        s.clients.push(mailbox.clone());
        Connection {
            mailbox,
            frames: frames_rx,
            messages: messages_rx,
        }
    }

    fn touch(&self, f: impl FnOnce(&mut HubState)) {
        let mut s = self.state.lock().expect("hub");
        f(&mut s);
        s.epoch += 1;
        self.wake.notify_all();
    }

    /// The page's latest view: replaces one still waiting, and makes a pass in progress for
    /// an earlier one stop at its next strip.
    pub fn post_view(&self, mailbox: &Mailbox, view: View) {
        mailbox.inbox.lock().expect("inbox").view = Some(view);
        mailbox.generation.fetch_add(1, Ordering::SeqCst);
        self.touch(|_| {});
    }

    pub fn post_save(&self, mailbox: &Mailbox, format: SaveFormat) {
        mailbox.inbox.lock().expect("inbox").save = Some(format);
        self.touch(|_| {});
    }

    /// The page is gone: its work stops at the next strip and its state is freed.
    pub fn disconnect(&self, mailbox: &Mailbox) {
        mailbox.alive.store(false, Ordering::SeqCst);
        self.touch(|s| s.clients.retain(|c| c.id != mailbox.id));
    }

    /// Pages connected now.
    pub fn clients(&self) -> usize {
        self.state.lock().expect("hub").clients.len()
    }

    /// Ends [`Worker::run`] (at its next wait or strip).
    pub fn shutdown(&self) {
        self.touch(|s| s.shutdown = true);
        for c in &self.state.lock().expect("hub").clients {
            c.alive.store(false, Ordering::SeqCst);
        }
    }
}

/// A refined frame's samples so far.
struct Accumulated {
    width: u32,
    height: u32,
    /// Per pixel, the sum over samples.
    sum: Vec<Radiance>,
    samples: u32,
    passes: u32,
    seconds: f64,
}

impl Accumulated {
    fn mean(&self) -> Frame {
        let k = 1.0 / self.samples.max(1) as f32;
        let pixels = self
            .sum
            .iter()
            .map(|r| Radiance {
                local: r.local * k,
                indirect: r.indirect * k,
                albedo: r.albedo * k,
                sky: r.sky * k,
            })
            .collect();
        frame_of(self.width, self.height, pixels)
    }
}

fn frame_of(width: u32, height: u32, pixels: Vec<Radiance>) -> Frame {
    Frame {
        region: Region::full(width, height),
        width,
        height,
        pixels,
        timings: Default::default(),
        stats: Default::default(),
    }
}

/// What fixes a page's exposure: moving the sun keeps it (so the light is seen to change),
/// another camera or mode measures it again.
#[derive(Debug, Clone, Copy, PartialEq)]
struct ExposureKey {
    orbit: Orbit,
    mode: Mode,
}

struct PageState {
    view: View,
    generation: u64,
    preview_scale: f32,
    refine_after: Instant,
    refined: Option<Accumulated>,
    done: bool,
    exposure: Option<(ExposureKey, ToneStats)>,
}

/// The thread that renders for every page; [`Worker::run`] returns at [`Hub::shutdown`].
pub struct Worker {
    scene: PreparedScene,
    hub: Arc<Hub>,
    opts: WorkerOptions,
    pages: HashMap<u64, PageState>,
    solves_at_start: u64,
    round: usize,
    saved: u32,
    /// How long the last move of the sun took (the relit light's weights, the sun grid).
    relight_seconds: f64,
}

impl Worker {
    pub fn new(scene: PreparedScene, hub: Arc<Hub>, opts: WorkerOptions) -> Worker {
        Worker {
            scene,
            hub,
            opts,
            pages: HashMap::new(),
            solves_at_start: sylva_lb::solves_started(),
            round: 0,
            saved: 0,
            relight_seconds: 0.0,
        }
    }

    pub fn run(mut self) {
        loop {
            let (clients, epoch) = {
                let s = self.hub.state.lock().expect("hub");
                if s.shutdown {
                    return;
                }
                (s.clients.clone(), s.epoch)
            };
            self.pages
                .retain(|id, _| clients.iter().any(|c| c.id == *id));
            if clients.is_empty() {
                self.wait(epoch, None);
                continue;
            }
            self.round = (self.round + 1) % clients.len();
            let order: Vec<&Arc<Mailbox>> = clients[self.round..]
                .iter()
                .chain(&clients[..self.round])
                .collect();
            // New input first (the page waits on it), then saves, then refinement.
            if let Some(mb) = order
                .iter()
                .find(|mb| mb.inbox.lock().expect("inbox").view.is_some())
            {
                let view = mb.inbox.lock().expect("inbox").view.take();
                if let Some(view) = view {
                    self.new_view(mb, view);
                }
                continue;
            }
            if let Some(mb) = order
                .iter()
                .find(|mb| mb.inbox.lock().expect("inbox").save.is_some())
            {
                let format = mb.inbox.lock().expect("inbox").save.take();
                if let Some(format) = format {
                    self.save(mb, format);
                }
                continue;
            }
            let now = Instant::now();
            let due = order.iter().find(|mb| {
                self.pages
                    .get(&mb.id)
                    .is_some_and(|p| !p.done && p.refine_after <= now)
            });
            if let Some(mb) = due {
                let mb = Arc::clone(mb);
                self.refine(&mb);
                continue;
            }
            let next = self
                .pages
                .values()
                .filter(|p| !p.done)
                .map(|p| p.refine_after)
                .min();
            self.wait(epoch, next);
        }
    }

    /// Sleeps until a page posts something, or until `until`.
    fn wait(&self, epoch: u64, until: Option<Instant>) {
        let mut s = self.hub.state.lock().expect("hub");
        while s.epoch == epoch && !s.shutdown {
            match until {
                Some(t) => {
                    let now = Instant::now();
                    if t <= now {
                        return;
                    }
                    s = self.hub.wake.wait_timeout(s, t - now).expect("hub").0;
                }
                None => s = self.hub.wake.wait(s).expect("hub"),
            }
        }
    }

    fn new_view(&mut self, mb: &Mailbox, view: View) {
        let generation = mb.generation.load(Ordering::SeqCst);
        let settle = if view.interacting {
            self.opts.settle
        } else {
            Duration::ZERO
        };
        if let Some(page) = self.pages.get_mut(&mb.id) {
            if page.view.same_image(&view) {
                // The same picture (a drag ending where it was): keep refining it.
                page.generation = generation;
                page.view = view;
                page.refine_after = Instant::now() + settle;
                return;
            }
        }
        if let Err(message) = self.set_sun(view.to_sun) {
            mb.say(ServerMessage::Error {
                seq: Some(view.seq),
                message,
            });
            return;
        }
        let page = self.pages.entry(mb.id).or_insert_with(|| PageState {
            view: view.clone(),
            generation,
            preview_scale: 0.5,
            refine_after: Instant::now(),
            refined: None,
            done: false,
            exposure: None,
        });
        page.view = view.clone();
        page.generation = generation;
        page.refined = None;
        page.done = false;
        // The preview: reduced size, no final gather, one ray per pixel.
        let scale = page.preview_scale;
        let (w, h) = (
            ((view.width as f32 * scale).round() as u32).clamp(8, view.width.max(8)),
            ((view.height as f32 * scale).round() as u32).clamp(8, view.height.max(8)),
        );
        let camera = view.camera(&self.scene.scene.camera, w, h);
        let mut settings = self.scene.settings(camera, 1, 0);
        settings.shading.gather_rays = 0;
        let t = Instant::now();
        let frame = match self.scene.render(&settings, &Silent) {
            Ok(f) => f,
            Err(e) => {
                mb.say(ServerMessage::Error {
                    seq: Some(view.seq),
                    message: format!("preview: {e}"),
                });
                return;
            }
        };
        let seconds = t.elapsed().as_secs_f64();
        let page = self.pages.get_mut(&mb.id).expect("inserted above");
        // Aim the next preview at the budget (square root: time goes with the area).
        let budget = self.opts.preview_budget.as_secs_f64();
        let step = (budget / seconds.max(1e-4)).sqrt().clamp(0.7, 1.4) as f32;
        page.preview_scale = (page.preview_scale * step).clamp(PREVIEW_SCALE.0, PREVIEW_SCALE.1);
        page.refine_after = Instant::now() + settle;
        self.send(mb, &frame, false, 1, seconds);
    }

    /// Moves the scene's sun (shared by every page) when it is not there already.
    fn set_sun(&mut self, to_sun: glam::Vec3) -> Result<(), String> {
        if self.scene.to_sun == to_sun.normalize_or_zero() {
            // Not moved: keep the last move's time for the frame header.
            return Ok(());
        }
        let t = Instant::now();
        let moved = self.scene.set_sun(to_sun).map_err(|e| format!("sun: {e}"));
        self.relight_seconds = t.elapsed().as_secs_f64();
        moved
    }

    /// One refinement pass for the page: full size and gather, rendered in strips so newer
    /// input or a closed page stops it within a strip.
    fn refine(&mut self, mb: &Mailbox) {
        let Some(page) = self.pages.get(&mb.id) else {
            return;
        };
        let (view, generation) = (page.view.clone(), page.generation);
        let (samples, passes) = page
            .refined
            .as_ref()
            .map_or((0, 0), |a| (a.samples, a.passes));
        if mb.stale(generation) {
            return;
        }
        if let Err(message) = self.set_sun(view.to_sun) {
            mb.say(ServerMessage::Error {
                seq: Some(view.seq),
                message,
            });
            self.pages.get_mut(&mb.id).expect("checked").done = true;
            return;
        }
        let (w, h) = (view.width, view.height);
        let rpp = if samples == 0 { 1 } else { 2 };
        let camera = view.camera(&self.scene.scene.camera, w, h);
        let mut settings = self.scene.settings(camera, rpp, passes as u64 + 1);
        settings.shading.gather_rays = view.gather_rays;
        let t = Instant::now();
        let mut pixels = Vec::with_capacity(w as usize * h as usize);
        let mut y = 0;
        while y < h {
            if mb.stale(generation) {
                return;
            }
            let rows = STRIP_ROWS.min(h - y);
            settings.region = Region {
                x0: 0,
                y0: y,
                width: w,
                height: rows,
            };
            match self.scene.render(&settings, &Silent) {
                Ok(f) => pixels.extend_from_slice(&f.pixels),
                Err(e) => {
                    mb.say(ServerMessage::Error {
                        seq: Some(view.seq),
                        message: format!("refining: {e}"),
                    });
                    self.pages.get_mut(&mb.id).expect("checked").done = true;
                    return;
                }
            }
            y += rows;
        }
        let seconds = t.elapsed().as_secs_f64();
        let max_samples = self.opts.max_samples;
        let page = self.pages.get_mut(&mb.id).expect("checked");
        let acc = page.refined.get_or_insert_with(|| Accumulated {
            width: w,
            height: h,
            sum: vec![Radiance::default(); pixels.len()],
            samples: 0,
            passes: 0,
            seconds: 0.0,
        });
        let k = rpp as f32;
        for (s, p) in acc.sum.iter_mut().zip(&pixels) {
            s.local += p.local * k;
            s.indirect += p.indirect * k;
            s.albedo += p.albedo * k;
            s.sky += p.sky * k;
        }
        acc.samples += rpp;
        acc.passes += 1;
        acc.seconds += seconds;
        let (frame, samples, total) = (acc.mean(), acc.samples, acc.seconds);
        page.done = samples >= max_samples;
        self.send(mb, &frame, true, samples, total);
    }

    /// Tone maps, encodes and hands the frame to the page's connection.
    fn send(&mut self, mb: &Mailbox, frame: &Frame, refined: bool, samples: u32, seconds: f64) {
        let t = Instant::now();
        let page = self.pages.get_mut(&mb.id).expect("a page with a frame");
        let pixels = display_pixels(page, frame);
        let quality = if refined {
            self.opts.jpeg_quality.1
        } else {
            self.opts.jpeg_quality.0
        };
        let jpeg = match encode_jpeg(frame.width, frame.height, &pixels, quality) {
            Ok(j) => j,
            Err(e) => {
                mb.say(ServerMessage::Error {
                    seq: Some(page.view.seq),
                    message: format!("encoding the frame: {e}"),
                });
                return;
            }
        };
        let header = FrameHeader {
            seq: page.view.seq,
            refined,
            width: frame.width,
            height: frame.height,
            samples,
            render_ms: seconds * 1e3,
            encode_ms: t.elapsed().as_secs_f64() * 1e3,
            relight_ms: self.relight_seconds * 1e3,
            sun_elevation: page.view.sun.elevation,
            sun_azimuth: page.view.sun.azimuth,
            lb_solves: sylva_lb::solves_started() - self.solves_at_start,
        };
        mb.frames
            .send_replace(Some(Bytes::from(encode_frame(&header, &jpeg))));
    }

    /// Writes the page's refined frame as it stands.
    fn save(&mut self, mb: &Mailbox, format: SaveFormat) {
        let Some(page) = self.pages.get_mut(&mb.id) else {
            return mb.say(no_refined_frame());
        };
        let Some(acc) = &page.refined else {
            return mb.say(no_refined_frame());
        };
        let (frame, samples) = (acc.mean(), acc.samples);
        let dir = &self.opts.output_dir;
        let stem = format!(
            "view-{}",
            sylva_core::file_stem(&self.scene.scene.name, "scene")
        );
        let ext = match format {
            SaveFormat::Png => "png",
            SaveFormat::Exr => "exr",
        };
        let path = loop {
            self.saved += 1;
            let p = dir.join(format!("{stem}-{:03}.{ext}", self.saved));
            if !p.exists() {
                break p;
            }
        };
        let result = match format {
            SaveFormat::Png => {
                let pixels = display_pixels(page, &frame);
                write_png(&path, frame.width, frame.height, &pixels)
            }
            SaveFormat::Exr => {
                let hdr = frame.compose(page.view.mode);
                write_exr(&path, frame.width, frame.height, &hdr)
            }
        };
        mb.say(match result {
            Ok(()) => ServerMessage::Saved {
                path: path.display().to_string(),
                samples,
            },
            Err(e) => ServerMessage::Error {
                seq: None,
                message: format!("saving: {e}"),
            },
        });
    }
}

fn no_refined_frame() -> ServerMessage {
    ServerMessage::Error {
        seq: None,
        message: "nothing to save yet: wait for the first refined frame".into(),
    }
}

/// The page's mode, exposed as the page asks (stops about an exposure measured once per
/// camera and mode), in 8-bit sRGB.
fn display_pixels(page: &mut PageState, frame: &Frame) -> Vec<[u8; 3]> {
    let hdr = frame.compose(page.view.mode);
    let key = ExposureKey {
        orbit: page.view.orbit,
        mode: page.view.mode,
    };
    let tm = ToneMap::default();
    let stats = match page.exposure {
        Some((k, s)) if k == key => s,
        _ => {
            let s = tm.measure(&hdr);
            page.exposure = Some((key, s));
            s
        }
    };
    let gain = 2f32.powf(page.view.exposure);
    let scaled: Vec<[f32; 3]> = hdr.iter().map(|p| p.map(|c| c * gain)).collect();
    tm.apply_with(&scaled, stats)
        .into_iter()
        .map(srgb8)
        .collect()
}

/// 8-bit sRGB pixels as a baseline JPEG.
pub fn encode_jpeg(
    width: u32,
    height: u32,
    pixels: &[[u8; 3]],
    quality: u8,
) -> Result<Vec<u8>, image::ImageError> {
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, quality).encode(
        pixels.as_flattened(),
        width,
        height,
        image::ExtendedColorType::Rgb8,
    )?;
    Ok(out)
}
