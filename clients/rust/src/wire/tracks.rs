//! `TrackFrame` (`<prefix>/<vehicle>/<sensor>/tracks`) and its `TrackColumns`.

use super::columns::{check_count, check_finite, from_bytes, to_bytes};
use super::fields::{
    binary, boolean, int64, integer, name, string, Fields, INT32_MAX, MAX_FRAME_ID, V,
};
use super::header::{
    check_classes, check_int64_field, check_name_field, check_version, classes, peek, pose_field,
    unpack_map, version_field, DecodeLimits,
};
use super::pack::Packer;
use super::reasons::{ErrorReason, TrackState, SCHEMA_VERSION};
use super::rejection::{Checked, Invalid, Rejection};
use super::value::Map;

/// N tracks, column by column; `class_index` indexes `classes`, the service's class table.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TrackColumns {
    pub classes: Vec<String>,
    /// Unique per (vehicle, sensor) stream, never reused, kept across service restarts.
    pub id: Vec<i64>,
    pub class_index: Vec<i32>,
    pub center: Vec<[f32; 3]>,
    pub size: Vec<[f32; 3]>,
    pub yaw: Vec<f32>,
    /// The matched detection's score; decays while coasting.
    pub score: Vec<f64>,
    /// vx, vy, vz of the motion model.
    pub velocity: Vec<[f32; 3]>,
    /// `TrackState` codes: 0 tentative, 1 confirmed, 2 coasting.
    pub state: Vec<i32>,
    /// Frames with an update since birth (1 at birth).
    pub hits: Vec<i32>,
    /// Frames since birth (0 at birth).
    pub age: Vec<i32>,
    pub time_since_update: Vec<i32>,
}

impl TrackColumns {
    pub fn count(&self) -> usize {
        self.id.len()
    }

    /// The class name of track `i`, None when its index is outside the table.
    pub fn class_name(&self, i: usize) -> Option<&str> {
        let index = usize::try_from(*self.class_index.get(i)?).ok()?;
        self.classes.get(index).map(String::as_str)
    }

    pub fn track_state(&self, i: usize) -> Option<TrackState> {
        TrackState::from_code(*self.state.get(i)?)
    }
}

/// The tracks after one detection frame.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackFrame {
    pub vehicle: String,
    pub sensor: String,
    /// The detection frame's.
    pub seq: u64,
    pub stamp_ns: u64,
    /// The service's world frame when the detections had a pose, else theirs.
    pub frame_id: String,
    pub pose: Option<[f64; 16]>,
    pub key_frame: bool,
    /// The service instance that tracked the frame.
    pub instance: String,
    /// Service wall clock (Unix ns) when the frame arrived.
    pub received_ns: u64,
    /// Service wall clock (Unix ns) when the tracks were published.
    pub published_ns: u64,
    pub tracks: TrackColumns,
}

struct RawTracks<'v> {
    count: usize,
    classes: Vec<String>,
    columns: [&'v [u8]; 11],
}

const COLUMNS: [&str; 11] = [
    "id",
    "class_index",
    "center",
    "size",
    "yaw",
    "score",
    "velocity",
    "state",
    "hits",
    "age",
    "time_since_update",
];

fn raw_tracks<'v>(v: &'v V<'v>) -> Checked<RawTracks<'v>> {
    let mut f = Fields::new(v, "TrackColumns")?;
    let count = f.required("count", |v| integer(v, 0, i128::from(INT32_MAX)))? as usize;
    let classes = f.required("classes", classes)?;
    let mut columns: [&[u8]; 11] = [&[]; 11];
    for (slot, name) in columns.iter_mut().zip(COLUMNS) {
        *slot = f.required(name, binary)?;
    }
    f.finish()?;
    Ok(RawTracks {
        count,
        classes,
        columns,
    })
}

fn decode_checked(map: &Map<'_>, value: &V<'_>, limits: &DecodeLimits) -> Checked<TrackFrame> {
    check_version(map)?;
    let mut f = Fields::new(value, "TrackFrame")?;
    version_field(&mut f)?;
    let vehicle = f.required("vehicle", name)?.to_owned();
    let sensor = f.required("sensor", name)?.to_owned();
    let seq = f.required("seq", int64)?;
    let stamp_ns = f.required("stamp_ns", int64)?;
    let frame_id = f
        .required("frame_id", |v| string(v, 1, Some(MAX_FRAME_ID)))?
        .to_owned();
    let pose = f.optional("pose", None, pose_field)?;
    let key_frame = f.optional("key_frame", true, boolean)?;
    let instance = f.required("instance", name)?.to_owned();
    let received_ns = f.required("received_ns", int64)?;
    let published_ns = f.required("published_ns", int64)?;
    let raw = f.required("tracks", raw_tracks)?;
    f.finish()?;

    let n = raw.count;
    if n > limits.max_boxes {
        return Err(Invalid::at(
            ErrorReason::TooLarge,
            "tracks.count",
            format!("{n} rows exceeds the cap of {}", limits.max_boxes),
        ));
    }
    let [id, class_index, center, size, yaw, score, velocity, state, hits, age, tsu] = raw.columns;
    let tracks = TrackColumns {
        id: from_bytes(id, n, "tracks.id")?,
        class_index: from_bytes(class_index, n, "tracks.class_index")?,
        center: from_bytes(center, n, "tracks.center")?,
        size: from_bytes(size, n, "tracks.size")?,
        yaw: from_bytes(yaw, n, "tracks.yaw")?,
        score: from_bytes(score, n, "tracks.score")?,
        velocity: from_bytes(velocity, n, "tracks.velocity")?,
        state: from_bytes(state, n, "tracks.state")?,
        hits: from_bytes(hits, n, "tracks.hits")?,
        age: from_bytes(age, n, "tracks.age")?,
        time_since_update: from_bytes(tsu, n, "tracks.time_since_update")?,
        classes: raw.classes,
    };
    Ok(TrackFrame {
        vehicle,
        sensor,
        seq,
        stamp_ns,
        frame_id,
        pose,
        key_frame,
        instance,
        received_ns,
        published_ns,
        tracks,
    })
}

/// Decode and validate a `TrackFrame`: the message's structure, then every column's length
/// and finiteness.
pub fn decode_track_frame(payload: &[u8], limits: &DecodeLimits) -> Result<TrackFrame, Rejection> {
    let value = unpack_map(payload, limits.max_bytes).map_err(|e| e.into_rejection(None, None))?;
    let map = Map::of_value(&value);
    let (seq, stamp_ns) = peek(&map);
    decode_checked(&map, &value, limits).map_err(|e| e.into_rejection(seq, stamp_ns))
}

fn check_frame(t: &TrackFrame) -> Checked<()> {
    check_name_field("vehicle", &t.vehicle)?;
    check_name_field("sensor", &t.sensor)?;
    check_int64_field("seq", t.seq)?;
    check_int64_field("stamp_ns", t.stamp_ns)?;
    super::fields::check_length(&t.frame_id, 1, Some(MAX_FRAME_ID))
        .map_err(|e| e.within("frame_id"))?;
    check_name_field("instance", &t.instance)?;
    check_int64_field("received_ns", t.received_ns)?;
    check_int64_field("published_ns", t.published_ns)?;
    let c = &t.tracks;
    check_classes(&c.classes).map_err(|e| e.within("tracks"))?;
    let n = c.count();
    check_count(&c.class_index, n, "tracks.class_index")?;
    check_count(&c.center, n, "tracks.center")?;
    check_count(&c.size, n, "tracks.size")?;
    check_count(&c.yaw, n, "tracks.yaw")?;
    check_count(&c.score, n, "tracks.score")?;
    check_count(&c.velocity, n, "tracks.velocity")?;
    check_count(&c.state, n, "tracks.state")?;
    check_count(&c.hits, n, "tracks.hits")?;
    check_count(&c.age, n, "tracks.age")?;
    check_count(&c.time_since_update, n, "tracks.time_since_update")?;
    check_finite(&c.center, "tracks.center")?;
    check_finite(&c.size, "tracks.size")?;
    check_finite(&c.yaw, "tracks.yaw")?;
    check_finite(&c.score, "tracks.score")?;
    check_finite(&c.velocity, "tracks.velocity")?;
    if let Some(p) = &t.pose {
        check_finite(p.as_slice(), "pose")?;
    }
    Ok(())
}

/// The frame as msgpack, byte for byte what the service writes (`pose` always present, nil
/// when absent). Mostly for tests and tools: the service is what publishes tracks.
pub fn encode_track_frame(t: &TrackFrame) -> Result<Vec<u8>, Rejection> {
    check_frame(t).map_err(|e| e.into_rejection(Some(t.seq), Some(t.stamp_ns)))?;
    let c = &t.tracks;
    let mut p = Packer::new(512 + c.count() * 88);
    p.map(12);
    p.key("schema_version").uint(SCHEMA_VERSION);
    p.key("vehicle").str(&t.vehicle);
    p.key("sensor").str(&t.sensor);
    p.key("seq").uint(t.seq);
    p.key("stamp_ns").uint(t.stamp_ns);
    p.key("frame_id").str(&t.frame_id);
    match &t.pose {
        Some(pose) => p.key("pose").f64s(pose),
        None => p.key("pose").nil(),
    };
    p.key("key_frame").bool(t.key_frame);
    p.key("instance").str(&t.instance);
    p.key("received_ns").uint(t.received_ns);
    p.key("published_ns").uint(t.published_ns);
    p.key("tracks").map(13);
    p.key("count").uint(c.count() as u64);
    p.key("classes").strs(&c.classes);
    p.key("id").bin(&to_bytes(&c.id));
    p.key("class_index").bin(&to_bytes(&c.class_index));
    p.key("center").bin(&to_bytes(&c.center));
    p.key("size").bin(&to_bytes(&c.size));
    p.key("yaw").bin(&to_bytes(&c.yaw));
    p.key("score").bin(&to_bytes(&c.score));
    p.key("velocity").bin(&to_bytes(&c.velocity));
    p.key("state").bin(&to_bytes(&c.state));
    p.key("hits").bin(&to_bytes(&c.hits));
    p.key("age").bin(&to_bytes(&c.age));
    p.key("time_since_update")
        .bin(&to_bytes(&c.time_since_update));
    Ok(p.finish())
}
