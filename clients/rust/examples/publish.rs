//! Publish N frames of synthetic moving boxes for one vehicle sensor, in lockstep with the
//! service, and print what came back for each seq as one JSON line on stdout:
//! `{"seq", "stamp_ns", "detections": {...}, "tracks": {...}}`, or `"error"`, or `"timeout"`.
//!
//!     cargo run --example publish -- --endpoint tcp/127.0.0.1:7447 --frames 20
//!
//! Exit status 0 when every frame was answered with tracks, 1 otherwise, 2 on bad usage.

mod common;

use std::time::Duration;

use serde_json::json;
use simpletrack_client::wire::{BoxColumns, Detection};
use simpletrack_client::{
    DetectionPublisher, FrameOptions, PublisherOptions, TrackSubscriber, TrackSubscriberOptions,
    ZenohOptions,
};

use common::{boxes_json, error_json, fail, tracks_json, Args};

const USAGE: &str =
    "usage: publish --endpoint tcp/HOST:PORT [--vehicle veh-rust] [--sensor lidar] \
[--frames 20] [--prefix fleet] [--period-ms 100] [--start-stamp-ns NS] [--timeout-s 10] [--resume]";

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
    let args = Args::parse(USAGE, &["resume"]);
    let endpoint = args.get("endpoint", "");
    if endpoint.is_empty() {
        fail(USAGE, "--endpoint is required");
    }
    let (vehicle, sensor) = (args.get("vehicle", "veh-rust"), args.get("sensor", "lidar"));
    let frames: u64 = args.number("frames", 20);
    let period_ns: u64 = args.number::<u64>("period-ms", 100) * 1_000_000;
    let timeout = Duration::from_secs_f64(args.number("timeout-s", 10.0));
    let prefix = args.get("prefix", "fleet");

    let session = ZenohOptions::connect_to([endpoint.as_str()])
        .open()
        .unwrap_or_else(|e| fail(USAGE, &e.to_string()));
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
        ..PublisherOptions::default()
    };
    let mut publisher = DetectionPublisher::new(&session, &vehicle, &sensor, options)
        .unwrap_or_else(|e| fail(USAGE, &e.to_string()));
    if !publisher.wait_for_service(timeout) {
        eprintln!("error: no service subscribed to {vehicle}/{sensor} within {timeout:?}");
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

    let start: u64 = args.optional("start-stamp-ns").unwrap_or_else(now_ns);
    let mut answered = 0;
    for k in 0..frames {
        let stamp_ns = start + k * period_ns;
        let boxes = boxes_at((k * period_ns) as f64 * 1e-9);
        let seq = match publisher.publish_with(&boxes, &FrameOptions::at(stamp_ns)) {
            Ok(seq) => seq,
            Err(e) => fail(USAGE, &e.to_string()),
        };
        let line = match wait_for(&tracks, &publisher, seq, timeout) {
            Answer::Tracks(msg) => {
                answered += 1;
                json!({
                    "seq": seq, "stamp_ns": stamp_ns, "detections": boxes_json(&boxes),
                    "tracks": tracks_json(&msg.frame.tracks), "instance": msg.frame.instance,
                    "latency_ms": (msg.received_ns as f64 - msg.frame.received_ns as f64) * 1e-6,
                })
            }
            Answer::Error(e) => json!({"seq": seq, "stamp_ns": stamp_ns, "error": error_json(&e)}),
            Answer::Timeout => json!({"seq": seq, "stamp_ns": stamp_ns, "timeout": true}),
        };
        println!("{line}");
    }
    eprintln!(
        "sent {} frames, {answered} answered with tracks, {} error notices, {} repeats dropped",
        publisher.sent(),
        publisher.errors().received(),
        tracks.duplicates()
    );
    drop(publisher);
    drop(tracks);
    let _ = session.close();
    std::process::exit(if answered == frames { 0 } else { 1 });
}

enum Answer {
    Tracks(Box<simpletrack_client::TrackMessage>),
    Error(simpletrack_client::wire::FrameError),
    Timeout,
}

fn wait_for(
    tracks: &TrackSubscriber,
    publisher: &DetectionPublisher,
    seq: u64,
    timeout: Duration,
) -> Answer {
    let deadline = std::time::Instant::now() + timeout;
    while std::time::Instant::now() < deadline {
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
