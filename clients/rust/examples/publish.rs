//! Publish N frames of synthetic moving boxes for one vehicle sensor and print what came back
//! for each seq as one JSON line on stdout: `{"seq", "stamp_ns", "detections": {...},
//! "tracks": {...}}`, or `"error"`, or `"timeout"`.
//!
//!     cargo run --example publish -- --endpoint tcp/127.0.0.1:7447 --frames 20
//!
//! By default each frame waits for its answer (lockstep). With `--stream` frames go out every
//! `--period-ms` whatever comes back (`sent <seq>` on stderr as each goes), and the answers are
//! printed in arrival order once every frame is answered or `--timeout-s` passed. A last line
//! on stderr, `summary {...}`, gives the publisher's counts (held, lost, error notices).
//!
//! Exit status 0 when every frame was answered with tracks, 1 otherwise, 2 on bad usage.

mod common;

use std::collections::{HashMap, HashSet};
use std::time::{Duration, Instant};

use serde_json::json;
use simpletrack_client::wire::{BoxColumns, Detection, FrameError};
use simpletrack_client::zenoh::Wait;
use simpletrack_client::{
    DetectionPublisher, FrameOptions, Mode, PublisherOptions, TrackMessage, TrackSubscriber,
    TrackSubscriberOptions, ZenohOptions, DEFAULT_CACHE_FRAMES,
};

use common::{boxes_json, error_json, fail, tracks_json, Args};

const USAGE: &str = "usage: publish --endpoint tcp/HOST:PORT [--mode peer|client] \
[--vehicle veh-rust] [--sensor lidar] [--frames 20] [--prefix fleet] [--period-ms 100] \
[--start-stamp-ns NS] [--timeout-s 10] [--cache-frames 100] [--resume] [--stream]";

/// A road user moving in a straight line at constant speed.
struct Mover {
    class: &'static str,
    start: [f64; 3],
    size: [f32; 3],
    yaw: f32,
    score: f64,
    velocity: [f64; 2],
}

const MOVERS: [Mover; 3] = [
    Mover {
        class: "Car",
        start: [10.0, 2.0, 0.8],
        size: [4.5, 1.9, 1.6],
        yaw: 0.0,
        score: 0.9,
        velocity: [10.0, 0.0],
    },
    Mover {
        class: "Pedestrian",
        start: [5.0, -4.0, 0.9],
        size: [0.8, 0.7, 1.8],
        yaw: std::f32::consts::FRAC_PI_2,
        score: 0.8,
        velocity: [0.0, 1.2],
    },
    Mover {
        class: "Car",
        start: [40.0, 6.0, 0.8],
        size: [4.2, 1.8, 1.5],
        yaw: std::f32::consts::PI,
        score: 0.7,
        velocity: [-5.0, 0.0],
    },
];

fn boxes_at(t_s: f64) -> BoxColumns {
    let detections: Vec<Detection> = MOVERS
        .iter()
        .map(|m| {
            let (p, v) = (m.start, m.velocity);
            Detection {
                class: m.class.into(),
                center: [
                    (p[0] + v[0] * t_s) as f32,
                    (p[1] + v[1] * t_s) as f32,
                    p[2] as f32,
                ],
                size: m.size,
                yaw: m.yaw,
                score: m.score,
                velocity: Some([v[0] as f32, v[1] as f32]),
            }
        })
        .collect();
    BoxColumns::from_detections(&["Car", "Pedestrian", "Cyclist"], &detections)
}

fn main() {
    let args = Args::parse(USAGE, &["resume", "stream"]);
    let endpoint = args.get("endpoint", "");
    if endpoint.is_empty() {
        fail(USAGE, "--endpoint is required");
    }
    let (vehicle, sensor) = (args.get("vehicle", "veh-rust"), args.get("sensor", "lidar"));
    let run = Run {
        frames: args.number("frames", 20),
        period_ns: args.number::<u64>("period-ms", 100) * 1_000_000,
        timeout: Duration::from_secs_f64(args.number("timeout-s", 10.0)),
        start: args.optional("start-stamp-ns").unwrap_or_else(now_ns),
    };
    let prefix = args.get("prefix", "fleet");
    let mut zenoh = ZenohOptions::connect_to([endpoint.as_str()]);
    zenoh.mode = match args.get("mode", "peer").as_str() {
        "peer" => Mode::Peer,
        "client" => Mode::Client,
        other => fail(
            USAGE,
            &format!("--mode {other:?} is neither peer nor client"),
        ),
    };

    let session = zenoh.open().unwrap_or_else(|e| fail(USAGE, &e.to_string()));
    let tracks = TrackSubscriber::new(
        &session,
        TrackSubscriberOptions {
            prefix: prefix.clone(),
            ..TrackSubscriberOptions::sensor(&vehicle, &sensor)
        },
    )
    .unwrap_or_else(|e| fail(USAGE, &e.to_string()));
    let options = PublisherOptions {
        prefix,
        cache_frames: args.number("cache-frames", DEFAULT_CACHE_FRAMES),
        ..PublisherOptions::default()
    };
    let mut publisher = DetectionPublisher::new(&session, &vehicle, &sensor, options)
        .unwrap_or_else(|e| fail(USAGE, &e.to_string()));
    if !publisher.wait_for_service(run.timeout) {
        eprintln!(
            "error: no service subscribed to {vehicle}/{sensor} within {:?}",
            run.timeout
        );
        std::process::exit(1);
    }
    if args.flag("resume") {
        match publisher.resume(Duration::from_secs(2)) {
            Ok(last) => eprintln!(
                "resume: service's last seq {last:?}, next seq {}",
                publisher.next_seq()
            ),
            Err(e) => eprintln!("resume failed: {e}"),
        }
    }

    let answered = if args.flag("stream") {
        stream(&run, &mut publisher, &tracks)
    } else {
        lockstep(&run, &mut publisher, &tracks)
    };
    let errors = publisher.errors().by_reason();
    let summary = json!({
        "sent": publisher.sent(), "answered": answered, "held": publisher.held(),
        "lost": publisher.lost(), "repeats_dropped": tracks.duplicates(),
        "error_notices": errors.iter().map(|(r, n)| (r.as_str().to_owned(), json!(n))).collect::<serde_json::Map<_, _>>(),
    });
    eprintln!("summary {summary}");
    let ok = answered == run.frames;
    drop(publisher);
    drop(tracks);
    let _ = session.close().wait();
    std::process::exit(if ok { 0 } else { 1 });
}

struct Run {
    frames: u64,
    period_ns: u64,
    timeout: Duration,
    start: u64,
}

impl Run {
    /// Frame k's stamp and boxes: every mover where it is k periods after the start.
    fn frame(&self, k: u64) -> (u64, BoxColumns) {
        (
            self.start + k * self.period_ns,
            boxes_at((k * self.period_ns) as f64 * 1e-9),
        )
    }
}

fn tracks_line(
    seq: u64,
    stamp_ns: u64,
    boxes: &BoxColumns,
    msg: &TrackMessage,
) -> serde_json::Value {
    json!({
        "seq": seq, "stamp_ns": stamp_ns, "detections": boxes_json(boxes),
        "tracks": tracks_json(&msg.frame.tracks), "instance": msg.frame.instance,
        "latency_ms": (msg.received_ns as f64 - msg.frame.received_ns as f64) * 1e-6,
    })
}

fn publish(publisher: &mut DetectionPublisher, stamp_ns: u64, boxes: &BoxColumns) -> u64 {
    publisher
        .publish_with(boxes, &FrameOptions::at(stamp_ns))
        .unwrap_or_else(|e| fail(USAGE, &e.to_string()))
}

/// Each frame waits for its answer; one line per frame, in seq order.
fn lockstep(run: &Run, publisher: &mut DetectionPublisher, tracks: &TrackSubscriber) -> u64 {
    let mut answered = 0;
    for k in 0..run.frames {
        let (stamp_ns, boxes) = run.frame(k);
        let seq = publish(publisher, stamp_ns, &boxes);
        let line = match wait_for(tracks, publisher, seq, run.timeout) {
            Answer::Tracks(msg) => {
                answered += 1;
                tracks_line(seq, stamp_ns, &boxes, &msg)
            }
            Answer::Error(e) => json!({"seq": seq, "stamp_ns": stamp_ns, "error": error_json(&e)}),
            Answer::Timeout => json!({"seq": seq, "stamp_ns": stamp_ns, "timeout": true}),
        };
        println!("{line}");
    }
    answered
}

/// What came back while streaming, in arrival order.
#[derive(Default)]
struct Arrivals {
    lines: Vec<serde_json::Value>,
    answered: HashSet<u64>,
}

impl Arrivals {
    fn collect(
        &mut self,
        publisher: &DetectionPublisher,
        tracks: &TrackSubscriber,
        sent: &Sent,
        wait: Duration,
    ) {
        for e in publisher.errors().drain() {
            self.lines.push(json!({"error": error_json(&e)}));
        }
        if let Some(msg) = tracks.recv(Some(wait)) {
            if let Some((stamp_ns, boxes)) = sent.get(&msg.seq()) {
                self.answered.insert(msg.seq());
                self.lines
                    .push(tracks_line(msg.seq(), *stamp_ns, boxes, &msg));
            }
        }
    }
}

type Sent = HashMap<u64, (u64, BoxColumns)>;

/// Frames go out on the period whatever comes back; answers are printed in arrival order.
fn stream(run: &Run, publisher: &mut DetectionPublisher, tracks: &TrackSubscriber) -> u64 {
    let t0 = Instant::now();
    let mut sent = Sent::new();
    let mut arrivals = Arrivals::default();
    for k in 0..run.frames {
        let (stamp_ns, boxes) = run.frame(k);
        let seq = publish(publisher, stamp_ns, &boxes);
        sent.insert(seq, (stamp_ns, boxes));
        eprintln!("sent {seq}");
        let next = t0 + Duration::from_nanos((k + 1) * run.period_ns);
        while Instant::now() < next {
            let wait = next
                .saturating_duration_since(Instant::now())
                .min(Duration::from_millis(10));
            arrivals.collect(publisher, tracks, &sent, wait);
        }
    }
    let deadline = Instant::now() + run.timeout;
    while arrivals.answered.len() < sent.len() && Instant::now() < deadline {
        arrivals.collect(publisher, tracks, &sent, Duration::from_millis(20));
    }
    for (arrival, mut line) in arrivals.lines.into_iter().enumerate() {
        line["arrival"] = json!(arrival);
        println!("{line}");
    }
    arrivals.answered.len() as u64
}

enum Answer {
    Tracks(Box<TrackMessage>),
    Error(FrameError),
    Timeout,
}

fn wait_for(
    tracks: &TrackSubscriber,
    publisher: &DetectionPublisher,
    seq: u64,
    timeout: Duration,
) -> Answer {
    let deadline = Instant::now() + timeout;
    while Instant::now() < deadline {
        if let Some(e) = publisher.errors().try_recv() {
            if e.frames().contains(&Some(seq)) {
                return Answer::Error(e);
            }
        }
        if let Some(msg) = tracks.recv(Some(Duration::from_millis(20))) {
            if msg.seq() == seq {
                return Answer::Tracks(Box::new(msg));
            }
        }
    }
    Answer::Timeout
}

fn now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}
