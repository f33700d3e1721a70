//! Every golden vector of schemas/vectors both ways: the decoder gives the vector's
//! `decoded` (or its refusal: reason and field), and re-encoding a valid one gives its bytes.

use std::fs;
use std::path::PathBuf;

use serde_json::{json, Value};
use simpletrack_client::wire::{
    decode_detection_frame, decode_frame_error, decode_track_frame, decode_vehicle_track_frame,
    encode_detection_frame, encode_frame_error, encode_track_frame, encode_vehicle_track_frame,
    BoxColumns, DecodeLimits, DetectionFrame, FrameError, Rejection, TrackColumns, TrackFrame,
    VehicleTrackFrame, SCHEMA_VERSION,
};

fn vectors_dir() -> PathBuf {
    // The running checkout's, as cargo test sets it: a test binary that a shared target dir
    // kept from another checkout's build must not read that checkout's vectors.
    let root = std::env::var("CARGO_MANIFEST_DIR").unwrap_or(env!("CARGO_MANIFEST_DIR").into());
    PathBuf::from(root).join("../../schemas/vectors")
}

fn rows<const K: usize, T: Copy + Into<f64>>(rows: &[[T; K]]) -> Value {
    Value::Array(
        rows.iter()
            .map(|r| Value::Array(r.iter().map(|&v| json!(v.into())).collect()))
            .collect(),
    )
}

fn floats<T: Copy + Into<f64>>(v: &[T]) -> Value {
    Value::Array(v.iter().map(|&x| json!(x.into())).collect())
}

fn pose(p: &Option<[f64; 16]>) -> Value {
    p.as_ref().map_or(Value::Null, |p| floats(p))
}

fn boxes_json(b: &BoxColumns) -> Value {
    json!({
        "count": b.count(),
        "classes": b.classes,
        "class_index": b.class_index,
        "center": rows(&b.center),
        "size": rows(&b.size),
        "yaw": floats(&b.yaw),
        "score": floats(&b.score),
        "velocity": b.velocity.as_ref().map_or(Value::Null, |v| rows(v)),
    })
}

fn detection_json(d: &DetectionFrame) -> Value {
    let mut v = json!({
        "schema_version": d.schema_version(),
        "vehicle": d.vehicle, "sensor": d.sensor, "seq": d.seq, "stamp_ns": d.stamp_ns,
        "frame_id": d.frame_id, "pose": pose(&d.pose), "key_frame": d.key_frame,
        "session_id": d.session_id, "boxes": boxes_json(&d.boxes),
    });
    if d.extrinsic.is_some() {
        v["extrinsic"] = pose(&d.extrinsic);
    }
    v
}

fn tracks_json(c: &TrackColumns, version: u64) -> Value {
    let mut v = json!({
        "count": c.count(), "classes": c.classes, "id": c.id, "class_index": c.class_index,
        "center": rows(&c.center), "size": rows(&c.size), "yaw": floats(&c.yaw),
        "score": floats(&c.score), "velocity": rows(&c.velocity), "state": c.state,
        "hits": c.hits, "age": c.age, "time_since_update": c.time_since_update,
    });
    if version >= 2 {
        v["covariance"] = c.covariance.as_ref().map_or(Value::Null, |m| rows(m));
        v["age_s"] = c.age_s.as_ref().map_or(Value::Null, |a| floats(a));
        v["time_since_update_s"] = c
            .time_since_update_s
            .as_ref()
            .map_or(Value::Null, |a| floats(a));
    }
    v
}

fn vehicle_track_frame_json(t: &VehicleTrackFrame) -> Value {
    let mut tracks = tracks_json(&t.tracks, 2);
    let c = &t.tracks;
    tracks["existence"] = c.existence.as_ref().map_or(Value::Null, |e| floats(e));
    tracks["sensor_stamp_ns"] = json!(c.sensor_stamp_ns);
    let states: Vec<&str> = t.sensor_state.iter().map(|s| s.as_str()).collect();
    let mut v = json!({
        "schema_version": t.schema_version(),
        "vehicle": t.vehicle, "seq": t.seq, "stamp_ns": t.stamp_ns, "sensor": t.sensor,
        "sensor_seq": t.sensor_seq, "frame_id": t.frame_id, "pose": pose(&t.pose),
        "instance": t.instance, "received_ns": t.received_ns, "published_ns": t.published_ns,
        "sensors": t.sensors, "sensor_state": states, "tracks": tracks,
    });
    if let Some(epoch) = t.epoch {
        v["epoch"] = json!(epoch);
    }
    v
}

fn track_frame_json(t: &TrackFrame) -> Value {
    let mut v = json!({
        "schema_version": t.schema_version,
        "vehicle": t.vehicle, "sensor": t.sensor, "seq": t.seq, "stamp_ns": t.stamp_ns,
        "frame_id": t.frame_id, "pose": pose(&t.pose), "key_frame": t.key_frame,
        "instance": t.instance, "received_ns": t.received_ns, "published_ns": t.published_ns,
        "tracks": tracks_json(&t.tracks, t.schema_version),
    });
    if let Some(epoch) = t.epoch {
        v["epoch"] = json!(epoch);
    }
    v
}

fn error_json(e: &FrameError) -> Value {
    let mut v = json!({
        "schema_version": SCHEMA_VERSION,
        "vehicle": e.vehicle, "sensor": e.sensor, "seq": e.seq, "stamp_ns": e.stamp_ns,
        "reason": e.reason.as_str(), "field": e.field, "detail": e.detail,
        "instance": e.instance, "received_ns": e.received_ns,
    });
    if let Some(seqs) = &e.seqs {
        v["seqs"] = json!(seqs);
    }
    v
}

/// (decoded JSON, re-encoded bytes) of a valid payload, or its refusal.
fn decode(kind: &str, payload: &[u8]) -> Result<(Value, Vec<u8>), Rejection> {
    let limits = DecodeLimits::default();
    Ok(match kind {
        "DetectionFrame" => {
            let d = decode_detection_frame(payload, &limits)?;
            (detection_json(&d), encode_detection_frame(&d)?)
        }
        "TrackFrame" => {
            let t = decode_track_frame(payload, &limits)?;
            (track_frame_json(&t), encode_track_frame(&t)?)
        }
        "VehicleTrackFrame" => {
            let t = decode_vehicle_track_frame(payload, &limits)?;
            (
                vehicle_track_frame_json(&t),
                encode_vehicle_track_frame(&t)?,
            )
        }
        "FrameError" => {
            let e = decode_frame_error(payload, &limits)?;
            (error_json(&e), encode_frame_error(&e)?)
        }
        other => panic!("vector of an unknown message type {other}"),
    })
}

struct Vector {
    name: String,
    spec: Value,
    payload: Vec<u8>,
}

fn vectors() -> Vec<Vector> {
    let mut out: Vec<Vector> = fs::read_dir(vectors_dir())
        .expect("schemas/vectors is readable")
        .filter_map(|e| {
            let path = e.ok()?.path();
            (path.extension()? == "json").then_some(path)
        })
        .map(|path| {
            let name = path.file_stem().unwrap().to_string_lossy().into_owned();
            let spec: Value = serde_json::from_str(&fs::read_to_string(&path).unwrap()).unwrap();
            let payload = fs::read(path.with_extension("msgpack")).unwrap();
            Vector {
                name,
                spec,
                payload,
            }
        })
        .collect();
    out.sort_by(|a, b| a.name.cmp(&b.name));
    out
}

#[test]
fn there_are_vectors_of_every_kind() {
    let all = vectors();
    let valid = all
        .iter()
        .filter(|v| v.spec["valid"] == json!(true))
        .count();
    assert!(valid >= 5, "{valid} valid vectors");
    assert!(
        all.len() - valid >= 10,
        "{} invalid vectors",
        all.len() - valid
    );
}

#[test]
fn valid_vectors_decode_to_their_json_and_reencode_byte_exact() {
    for v in vectors().iter().filter(|v| v.spec["valid"] == json!(true)) {
        let kind = v.spec["message"].as_str().unwrap();
        let (decoded, bytes) =
            decode(kind, &v.payload).unwrap_or_else(|r| panic!("{}: refused: {r}", v.name));
        assert_eq!(decoded, v.spec["decoded"], "{}: decoded differs", v.name);
        assert_eq!(
            bytes, v.payload,
            "{}: re-encoding is not byte-exact",
            v.name
        );
    }
}

#[test]
fn invalid_vectors_are_refused_with_their_reason_and_field() {
    let mut seen = 0;
    for v in vectors().iter().filter(|v| v.spec["valid"] == json!(false)) {
        let kind = v.spec["message"].as_str().unwrap();
        let r = match decode(kind, &v.payload) {
            Ok(_) => panic!("{}: accepted", v.name),
            Err(r) => r,
        };
        assert_eq!(r.reason.as_str(), v.spec["reason"], "{}: {r}", v.name);
        assert_eq!(json!(r.field), v.spec["field"], "{}: {r}", v.name);
        seen += 1;
    }
    assert!(seen >= 10);
}

#[test]
fn a_refused_frame_still_names_its_seq_and_stamp_when_readable() {
    let v = vectors()
        .into_iter()
        .find(|v| v.name == "invalid_non_finite")
        .unwrap();
    let r = decode_detection_frame(&v.payload, &DecodeLimits::default()).unwrap_err();
    assert_eq!(
        (r.seq, r.stamp_ns),
        (Some(42), Some(1_700_000_000_100_000_000))
    );
    let v = vectors()
        .into_iter()
        .find(|v| v.name == "invalid_malformed")
        .unwrap();
    let r = decode_detection_frame(&v.payload, &DecodeLimits::default()).unwrap_err();
    assert_eq!((r.seq, r.stamp_ns), (None, None));
}
