//! What the examples share: a tiny argument parser and JSON of the wire's columns.

#![allow(dead_code)]

use std::collections::HashMap;
use std::process::exit;

use serde_json::{json, Value};
use simpletrack_client::wire::{BoxColumns, FrameError, TrackColumns};

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
