//! Print the tracks (and error notices) of one sensor, a vehicle or the fleet as JSON lines.
//!
//!     cargo run --example subscribe -- --endpoint tcp/127.0.0.1:7447 --vehicle veh-rust
//!
//! Stops after `--count` track frames, or when none came for `--idle-s` seconds.

mod common;

use std::time::{Duration, Instant};

use serde_json::json;
use simpletrack_client::{
    ErrorSubscriber, ErrorSubscriberOptions, TrackSubscriber, TrackSubscriberOptions, ZenohOptions,
};

use common::{error_json, fail, tracks_json, Args};

const USAGE: &str = "usage: subscribe --endpoint tcp/HOST:PORT [--vehicle '*'] [--sensor '*'] \
[--prefix fleet] [--count N] [--idle-s 10]";

fn main() {
    let args = Args::parse(USAGE, &[]);
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
    let tracks = TrackSubscriber::new(
        &session,
        TrackSubscriberOptions {
            prefix: prefix.clone(),
            vehicle: vehicle.clone(),
            sensor: sensor.clone(),
            ..TrackSubscriberOptions::default()
        },
    )
    .unwrap_or_else(|e| fail(USAGE, &e.to_string()));
    let errors = ErrorSubscriber::new(
        &session,
        ErrorSubscriberOptions {
            prefix,
            vehicle,
            sensor,
            ..Default::default()
        },
    )
    .unwrap_or_else(|e| fail(USAGE, &e.to_string()));

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
        println!(
            "{}",
            json!({
                "key": msg.key, "seq": msg.seq(), "stamp_ns": msg.stamp_ns(),
                "latency_ms": msg.latency_s() * 1e3, "tracks": tracks_json(&msg.frame.tracks),
            })
        );
    }
    eprintln!(
        "{seen} track frames, {} repeats dropped, {} invalid; {} error notices",
        tracks.duplicates(),
        tracks.invalid(),
        errors.received()
    );
    drop((tracks, errors));
    let _ = session.close();
}
