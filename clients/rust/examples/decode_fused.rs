//! Decode `VehicleTrackFrame` payloads given on stdin, one hex line each, and print each as a
//! JSON line: `{"decoded": <the golden vectors' form>, "walk": <what the accessors give>}`,
//! or `{"valid": false, "reason", "field"}`. The check that this crate reads a fused frame
//! as the Python and C++ decoders do (tests/native/test_fused_frame_every_client.py).

mod common;

use std::io::{self, BufRead, Write};

use serde_json::json;
use simpletrack_client::wire::{decode_vehicle_track_frame, DecodeLimits};
use simpletrack_client::VehicleTrackMessage;

use common::{unhex, vehicle_frame_json, walk_json};

fn main() {
    let limits = DecodeLimits::default();
    let stdout = io::stdout();
    let mut out = io::BufWriter::new(stdout.lock());
    for line in io::stdin().lock().lines() {
        let line = line.unwrap_or_default();
        let Some(payload) = unhex(line.trim()) else {
            eprintln!("error: not hex: {line:?}");
            std::process::exit(2);
        };
        let v = match decode_vehicle_track_frame(&payload, &limits) {
            Ok(frame) => {
                let msg = VehicleTrackMessage {
                    key: String::new(),
                    frame,
                    received_ns: 0,
                };
                json!({"decoded": vehicle_frame_json(&msg.frame), "walk": walk_json(&msg)})
            }
            Err(r) => json!({"valid": false, "reason": r.reason.as_str(), "field": r.field}),
        };
        let _ = writeln!(out, "{v}");
    }
}
