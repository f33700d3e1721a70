//! Decode payloads given on stdin and print each verdict as a JSON line: the check that
//! holds this crate's decoders to the Python reference's verdicts on arbitrary payloads.
//!
//! Input lines: `D <hex>` (DetectionFrame), `T <hex>` (TrackFrame), `V <hex>`
//! (VehicleTrackFrame), `E <hex>` (FrameError).
//! Output lines: `{"valid": true}` or `{"valid": false, "reason", "field", "seq", "stamp_ns"}`.

mod common;

use std::io::{self, BufRead, Write};

use serde_json::json;
use simpletrack_client::wire::{
    decode_detection_frame, decode_frame_error, decode_track_frame, decode_vehicle_track_frame,
    DecodeLimits, Rejection,
};

use common::unhex;

fn main() {
    let limits = DecodeLimits::default();
    let stdout = io::stdout();
    let mut out = io::BufWriter::new(stdout.lock());
    for line in io::stdin().lock().lines() {
        let line = line.unwrap_or_default();
        let (kind, hex) = line.split_once(' ').unwrap_or((line.as_str(), ""));
        let Some(payload) = unhex(hex.trim()) else {
            eprintln!("error: not hex: {hex:?}");
            std::process::exit(2);
        };
        let verdict: Result<(), Rejection> = match kind {
            "D" => decode_detection_frame(&payload, &limits).map(drop),
            "T" => decode_track_frame(&payload, &limits).map(drop),
            "V" => decode_vehicle_track_frame(&payload, &limits).map(drop),
            "E" => decode_frame_error(&payload, &limits).map(drop),
            other => {
                eprintln!("error: unknown message kind {other:?} (D, T, V or E)");
                std::process::exit(2);
            }
        };
        let v = match verdict {
            Ok(()) => json!({"valid": true}),
            Err(r) => json!({
                "valid": false, "reason": r.reason.as_str(), "field": r.field,
                "seq": r.seq, "stamp_ns": r.stamp_ns,
            }),
        };
        let _ = writeln!(out, "{v}");
    }
}
