//! What the examples share: a tiny argument parser and JSON of the wire's columns.

#![allow(dead_code)]

use std::collections::HashMap;
use std::process::exit;

use serde_json::{json, Map, Value};
use simpletrack_client::wire::{BoxColumns, FrameError, TrackColumns, VehicleTrackFrame};
use simpletrack_client::VehicleTrackMessage;

/// The bytes of a hex string (None: not hex, or an odd length).
pub fn unhex(s: &str) -> Option<Vec<u8>> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(s.get(i..i + 2)?, 16).ok())
        .collect()
}

/// `--name value` pairs and bare `--flag`s; exits with a one-line message on a bad one.
pub struct Args {
    values: HashMap<String, String>,
    usage: &'static str,
}

impl Args {
    pub fn parse(usage: &'static str, flags: &[&str]) -> Self {
        let mut values = HashMap::new();
        let mut it = std::env::args().skip(1);
        while let Some(arg) = it.next() {
            if arg == "-h" || arg == "--help" {
                println!("{usage}");
                exit(0);
            }
            let Some(name) = arg.strip_prefix("--") else {
                fail(usage, &format!("unexpected argument {arg:?}"))
            };
            if flags.contains(&name) {
                values.insert(name.to_owned(), "true".to_owned());
                continue;
            }
            match it.next() {
                Some(v) => values.insert(name.to_owned(), v),
                None => fail(usage, &format!("--{name} needs a value")),
            };
        }
        Self { values, usage }
    }

    pub fn get(&self, name: &str, default: &str) -> String {
        self.values
            .get(name)
            .cloned()
            .unwrap_or_else(|| default.to_owned())
    }

    pub fn flag(&self, name: &str) -> bool {
        self.values.contains_key(name)
    }

    pub fn number<T: std::str::FromStr>(&self, name: &str, default: T) -> T {
        match self.values.get(name) {
            None => default,
            Some(v) => v
                .parse()
                .unwrap_or_else(|_| fail(self.usage, &format!("--{name} {v:?} is not a number"))),
        }
    }

    pub fn optional<T: std::str::FromStr>(&self, name: &str) -> Option<T> {
        self.values.get(name).map(|v| {
            v.parse()
                .unwrap_or_else(|_| fail(self.usage, &format!("--{name} {v:?} is not a number")))
        })
    }
}

pub fn fail(usage: &str, msg: &str) -> ! {
    eprintln!("error: {msg}\n{usage}");
    exit(2)
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

pub fn boxes_json(b: &BoxColumns) -> Value {
    json!({
        "classes": b.classes, "class_index": b.class_index, "center": rows(&b.center),
        "size": rows(&b.size), "yaw": floats(&b.yaw), "score": floats(&b.score),
        "velocity": b.velocity.as_ref().map_or(Value::Null, |v| rows(v)),
    })
}

pub fn tracks_json(c: &TrackColumns) -> Value {
    json!({
        "classes": c.classes, "id": c.id, "class_index": c.class_index, "center": rows(&c.center),
        "size": rows(&c.size), "yaw": floats(&c.yaw), "score": floats(&c.score),
        "velocity": rows(&c.velocity), "state": c.state, "hits": c.hits, "age": c.age,
        "time_since_update": c.time_since_update,
    })
}

pub fn error_json(e: &FrameError) -> Value {
    json!({
        "vehicle": e.vehicle, "sensor": e.sensor, "seq": e.seq, "stamp_ns": e.stamp_ns,
        "reason": e.reason.as_str(), "field": e.field, "detail": e.detail, "seqs": e.seqs,
    })
}

fn optional_floats<T: Copy + Into<f64>>(v: &Option<Vec<T>>) -> Value {
    v.as_ref().map_or(Value::Null, |v| floats(v))
}

/// A `VehicleTrackFrame` as the golden vectors' `decoded` JSON writes it (schemas/vectors,
/// `decoded_json` of schemas/simpletrack/wire/generate.py): every field, the columns as
/// (nested) number lists, float32 values widened to float64.
pub fn vehicle_frame_json(t: &VehicleTrackFrame) -> Value {
    let c = &t.tracks;
    let tracks = json!({
        "count": c.count(), "classes": c.classes, "id": c.id, "class_index": c.class_index,
        "center": rows(&c.center), "size": rows(&c.size), "yaw": floats(&c.yaw),
        "score": floats(&c.score), "velocity": rows(&c.velocity), "state": c.state,
        "hits": c.hits, "age": c.age, "time_since_update": c.time_since_update,
        "covariance": c.covariance.as_ref().map_or(Value::Null, |m| rows(m)),
        "age_s": optional_floats(&c.age_s),
        "time_since_update_s": optional_floats(&c.time_since_update_s),
        "existence": optional_floats(&c.existence), "sensor_stamp_ns": c.sensor_stamp_ns,
    });
    let states: Vec<&str> = t.sensor_state.iter().map(|s| s.as_str()).collect();
    let mut v = json!({
        "schema_version": t.schema_version(),
        "vehicle": t.vehicle, "seq": t.seq, "stamp_ns": t.stamp_ns, "sensor": t.sensor,
        "sensor_seq": t.sensor_seq, "frame_id": t.frame_id,
        "pose": t.pose.as_ref().map_or(Value::Null, |p| floats(p)),
        "instance": t.instance, "received_ns": t.received_ns, "published_ns": t.published_ns,
        "sensors": t.sensors, "sensor_state": states, "tracks": tracks,
    });
    if let Some(epoch) = t.epoch {
        v["epoch"] = json!(epoch);
    }
    v
}

/// What a planner reads of a fused message through the accessors: each track's global id,
/// existence and contributors (sensor -> stamp of its last update), each sensor's state, the
/// input frame answered and the epoch.
pub fn walk_json(m: &VehicleTrackMessage) -> Value {
    let n = m.count();
    let contributors: Vec<Value> = (0..n)
        .map(|i| {
            let c = m.contributors(i).into_iter();
            Value::Object(
                c.map(|(s, t)| (s.to_owned(), json!(t)))
                    .collect::<Map<_, _>>(),
            )
        })
        .collect();
    let states = m.sensor_state().into_iter();
    let states: Map<String, Value> = states
        .map(|(s, c)| (s.to_owned(), json!(c.as_str())))
        .collect();
    let (sensor, sensor_seq) = m.source();
    json!({
        "global_ids": m.global_ids(),
        "existence": (0..n).map(|i| m.existence(i)).collect::<Vec<_>>(),
        "contributors": contributors, "sensor_state": states,
        "source": [sensor, sensor_seq], "epoch": m.epoch(),
    })
}
