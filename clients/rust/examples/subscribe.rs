//! Print the tracks (and error notices) of one sensor, a vehicle or the fleet as JSON lines;
//! with `--fused`, the fused vehicles' one object list (`VehicleTrackSubscriber`).
//!
//!     cargo run --example subscribe -- --endpoint tcp/127.0.0.1:7447 --vehicle veh-rust
//!     cargo run --example subscribe -- --endpoint tcp/127.0.0.1:7447 --vehicle veh01 --fused
//!
//! Stops after `--count` track messages, or when none came for `--idle-s` seconds; then
//! prints what was counted as one JSON line on stderr.

mod common;

use std::time::{Duration, Instant};

use serde_json::{json, Value};
use simpletrack_client::zenoh::Wait;
use simpletrack_client::{
    ErrorSubscriber, ErrorSubscriberOptions, Subscription, TrackSubscriber, TrackSubscriberOptions,
    VehicleTrackSubscriber, VehicleTrackSubscriberOptions, ZenohOptions,
};

use common::{error_json, fail, tracks_json, vehicle_frame_json, walk_json, Args};

const USAGE: &str = "usage: subscribe --endpoint tcp/HOST:PORT [--vehicle '*'] [--sensor '*'] \
[--fused] [--prefix fleet] [--count N] [--idle-s 10]";

/// Receive until `count` messages or `idle` without one, printing each; errors alongside.
fn run<M>(
    tracks: &Subscription<M>,
    errors: &ErrorSubscriber,
    count: u64,
    idle: Duration,
    show: impl Fn(&M) -> Value,
) -> u64 {
    let (mut seen, mut last) = (0u64, Instant::now());
    while seen < count && last.elapsed() < idle {
        for e in errors.drain() {
            println!("{}", json!({"error": error_json(&e)}));
        }
        let Some(msg) = tracks.recv(Some(Duration::from_millis(50))) else {
            continue;
        };
        seen += 1;
        last = Instant::now();
        println!("{}", show(&msg));
    }
    seen
}

fn summary<M>(tracks: &Subscription<M>, errors: &ErrorSubscriber, seen: u64) -> Value {
    let reasons = tracks.invalid_reasons().into_iter();
    let reasons: serde_json::Map<String, Value> = reasons
        .map(|(r, n)| (r.as_str().to_owned(), json!(n)))
        .collect();
    json!({
        "messages": seen, "received": tracks.received(), "dropped": tracks.dropped(),
        "duplicates": tracks.duplicates(), "stale": tracks.stale(), "invalid": tracks.invalid(),
        "invalid_reasons": reasons, "error_notices": errors.received(),
    })
}

fn main() {
    let args = Args::parse(USAGE, &["fused"]);
    let endpoint = args.get("endpoint", "");
    if endpoint.is_empty() {
        fail(USAGE, "--endpoint is required");
    }
    let (vehicle, sensor, prefix) = (
        args.get("vehicle", "*"),
        args.get("sensor", "*"),
        args.get("prefix", "fleet"),
    );
    let count: u64 = args.number("count", u64::MAX);
    let idle = Duration::from_secs_f64(args.number("idle-s", 10.0));

    let session = ZenohOptions::connect_to([endpoint.as_str()])
        .open()
        .unwrap_or_else(|e| fail(USAGE, &e.to_string()));
    let errors = ErrorSubscriber::new(
        &session,
        ErrorSubscriberOptions {
            prefix: prefix.clone(),
            vehicle: vehicle.clone(),
            sensor: sensor.clone(),
            ..Default::default()
        },
    )
    .unwrap_or_else(|e| fail(USAGE, &e.to_string()));
    let counted = if args.flag("fused") {
        let options = VehicleTrackSubscriberOptions {
            prefix,
            ..VehicleTrackSubscriberOptions::vehicle(&vehicle)
        };
        let tracks = VehicleTrackSubscriber::new(&session, options)
            .unwrap_or_else(|e| fail(USAGE, &e.to_string()));
        let seen = run(&tracks, &errors, count, idle, |msg| {
            json!({
                "key": msg.key, "seq": msg.seq(), "stamp_ns": msg.stamp_ns(),
                "latency_ms": msg.latency_s() * 1e3, "walk": walk_json(msg),
                "decoded": vehicle_frame_json(&msg.frame),
            })
        });
        summary(&tracks, &errors, seen)
    } else {
        let options = TrackSubscriberOptions {
            prefix,
            vehicle,
            sensor,
            ..TrackSubscriberOptions::default()
        };
        let tracks =
            TrackSubscriber::new(&session, options).unwrap_or_else(|e| fail(USAGE, &e.to_string()));
        let seen = run(&tracks, &errors, count, idle, |msg| {
            json!({
                "key": msg.key, "seq": msg.seq(), "stamp_ns": msg.stamp_ns(),
                "latency_ms": msg.latency_s() * 1e3, "tracks": tracks_json(&msg.frame.tracks),
            })
        });
        summary(&tracks, &errors, seen)
    };
    eprintln!("{}", json!({ "summary": counted }));
    drop(errors);
    let _ = session.close().wait();
}
