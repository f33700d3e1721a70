//! `TrackFrame` (`<prefix>/<vehicle>/<sensor>/tracks`) and its `TrackColumns`.

use super::columns::{check_count, check_finite, from_bytes, to_bytes};
use super::fields::{
    binary, boolean, int64, integer, name, nullable, string, Fields, INT32_MAX, MAX_FRAME_ID, V,
};
use super::header::{
    check_classes, check_int64_field, check_name_field, check_version_in, classes, peek,
    pose_field, unpack_map, version_field, DecodeLimits,
};
use super::pack::Packer;
use super::reasons::{ErrorReason, TrackState, TRACK_EPOCH_SCHEMA_VERSION};
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
    /// Version 2: the filter's covariance over x, y, z, vx, vy, vz as its upper triangle,
    /// row-major ((0,0) (0,1) … (0,5) (1,1) … (5,5)); None from version 1 or when the
    /// service's motion model keeps none. An estimate for ranking and gating, not metres
    /// of error (schemas/README.md).
    pub covariance: Option<Vec<[f32; 21]>>,
    /// Version 2: seconds from birth to the frame's `stamp_ns`.
    pub age_s: Option<Vec<f64>>,
    /// Version 2: seconds from the last update to the frame's `stamp_ns`.
    pub time_since_update_s: Option<Vec<f64>>,
    /// A vehicle's fused tracks only (`VehicleTrackFrame`): the probability in [0, 1] that
    /// the track is an object. None in a sensor's `TrackFrame` (whose encoder ignores it).
    pub existence: Option<Vec<f64>>,
    /// A vehicle's fused tracks only: per track, one value per sensor of the frame's
    /// `sensors` (in that order), the `stamp_ns` of that sensor's last update of the track,
    /// -1 when it never updated it.
    pub sensor_stamp_ns: Option<Vec<Vec<i64>>>,
}

/// Element (r, c), each 0 … 5, of a covariance kept as its upper triangle.
pub fn covariance_at(upper: &[f32; 21], r: usize, c: usize) -> f32 {
    let (r, c) = if r <= c { (r, c) } else { (c, r) };
    upper[r * 6 - r * r.saturating_sub(1) / 2 + (c - r)]
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
    /// 1, 2 or 3: what the frame was decoded from, and what `encode_track_frame` writes.
    pub schema_version: u64,
    /// Version 3: the stream's custody epoch (schemas/README.md, "Custody epoch (fencing)");
    /// None when the frame carries none. The encoder writes it in version 3 only.
    pub epoch: Option<u64>,
}

impl TrackFrame {
    /// Track `i`'s fleet-unique id `<vehicle>/<sensor>/<id>` (schemas/README.md, "Track
    /// identity"); None when `i` is out of range.
    pub fn global_id(&self, i: usize) -> Option<String> {
        let id = self.tracks.id.get(i)?;
        Some(format!("{}/{}/{id}", self.vehicle, self.sensor))
    }
}

/// Which columns a `tracks` map holds: a TrackFrame's of version 1 or 2, or a vehicle's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Layout {
    V1,
    V2,
    Vehicle,
}

pub(crate) struct RawTracks<'v> {
    count: usize,
    classes: Vec<String>,
    columns: [&'v [u8]; 11],
    // Version 2's: covariance (optional), age_s, time_since_update_s.
    covariance: Option<&'v [u8]>,
    ages: Option<(&'v [u8], &'v [u8])>,
    // A vehicle's: existence, sensor_stamp_ns.
    fused: Option<(&'v [u8], &'v [u8])>,
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

/// The `tracks` map's fields in table order, then its unknown keys.
pub(crate) fn raw_tracks<'v>(v: &'v V<'v>, layout: Layout) -> Checked<RawTracks<'v>> {
    let type_name = match layout {
        Layout::V1 => "TrackColumnsV1",
        Layout::V2 => "TrackColumns",
        Layout::Vehicle => "VehicleTrackColumns",
    };
    let mut f = Fields::new(v, type_name)?;
    let count = f.required("count", |v| integer(v, 0, i128::from(INT32_MAX)))? as usize;
    let classes = f.required("classes", classes)?;
    let mut columns: [&[u8]; 11] = [&[]; 11];
    for (slot, name) in columns.iter_mut().zip(COLUMNS) {
        *slot = f.required(name, binary)?;
    }
    let (mut covariance, mut ages, mut fused) = (None, None, None);
    if layout != Layout::V1 {
        covariance = f.optional("covariance", None, |v| nullable(v, binary))?;
        let age_s = f.required("age_s", binary)?;
        ages = Some((age_s, f.required("time_since_update_s", binary)?));
    }
    if layout == Layout::Vehicle {
        let existence = f.required("existence", binary)?;
        fused = Some((existence, f.required("sensor_stamp_ns", binary)?));
    }
    f.finish()?;
    Ok(RawTracks {
        count,
        classes,
        columns,
        covariance,
        ages,
        fused,
    })
}

/// The row cap, then each column's length and finiteness in table order; a vehicle's
/// `sensor_stamp_ns` is `sensors` values wide.
pub(crate) fn read_tracks(
    raw: RawTracks<'_>,
    limits: &DecodeLimits,
    sensors: usize,
) -> Checked<TrackColumns> {
    let n = raw.count;
    if n > limits.max_boxes {
        return Err(Invalid::at(
            ErrorReason::TooLarge,
            "tracks.count",
            format!("{n} rows exceeds the cap of {}", limits.max_boxes),
        ));
    }
    let [id, class_index, center, size, yaw, score, velocity, state, hits, age, tsu] = raw.columns;
    let mut tracks = TrackColumns {
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
        covariance: None,
        age_s: None,
        time_since_update_s: None,
        existence: None,
        sensor_stamp_ns: None,
        classes: raw.classes,
    };
    if let Some(c) = raw.covariance {
        tracks.covariance = Some(from_bytes(c, n, "tracks.covariance")?);
    }
    if let Some((a, t)) = raw.ages {
        tracks.age_s = Some(from_bytes(a, n, "tracks.age_s")?);
        tracks.time_since_update_s = Some(from_bytes(t, n, "tracks.time_since_update_s")?);
    }
    if let Some((e, stamps)) = raw.fused {
        tracks.existence = Some(from_bytes(e, n, "tracks.existence")?);
        // n is capped and sensors at most 64: the product cannot overflow.
        let flat: Vec<i64> = from_bytes(stamps, n * sensors, "tracks.sensor_stamp_ns")?;
        tracks.sensor_stamp_ns = Some(match sensors {
            0 => vec![Vec::new(); n],
            s => flat.chunks_exact(s).map(<[i64]>::to_vec).collect(),
        });
    }
    Ok(tracks)
}

/// The optional `epoch` of a tracks message of a version that has it (else absent: an `epoch`
/// key is then an unknown one, as to a reader of that version).
pub(crate) fn epoch_field(f: &mut Fields<'_>, has_epoch: bool) -> Checked<Option<u64>> {
    if !has_epoch {
        return Ok(None);
    }
    f.optional("epoch", None, |v| nullable(v, int64))
}

fn decode_checked(map: &Map<'_>, value: &V<'_>, limits: &DecodeLimits) -> Checked<TrackFrame> {
    let schema_version = check_version_in(map, 1, TRACK_EPOCH_SCHEMA_VERSION)?;
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
    let layout = if schema_version == 1 {
        Layout::V1
    } else {
        Layout::V2
    };
    let raw = f.required("tracks", |v| raw_tracks(v, layout))?;
    let epoch = epoch_field(&mut f, schema_version >= TRACK_EPOCH_SCHEMA_VERSION)?;
    f.finish()?;
    let tracks = read_tracks(raw, limits, 0)?;
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
        schema_version,
        epoch,
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

/// A columns map built in memory, checked as the decoder would: class table, row counts and
/// finiteness (version 2's columns when `v2`).
pub(crate) fn check_columns(c: &TrackColumns, v2: bool) -> Checked<()> {
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
    if !v2 {
        return Ok(());
    }
    let (Some(age_s), Some(tsu_s)) = (&c.age_s, &c.time_since_update_s) else {
        return Err(Invalid::at(
            ErrorReason::MissingField,
            "tracks.age_s",
            "version 2 columns need age_s and time_since_update_s",
        ));
    };
    check_count(age_s, n, "tracks.age_s")?;
    check_count(tsu_s, n, "tracks.time_since_update_s")?;
    check_finite(age_s, "tracks.age_s")?;
    check_finite(tsu_s, "tracks.time_since_update_s")?;
    if let Some(cov) = &c.covariance {
        check_count(cov, n, "tracks.covariance")?;
        check_finite(cov, "tracks.covariance")?;
    }
    Ok(())
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
    match t.schema_version {
        1..=3 => check_columns(&t.tracks, t.schema_version >= 2)?,
        v => {
            return Err(Invalid::at(
                ErrorReason::WrongVersion,
                "schema_version",
                format!("version {v} not supported (this client speaks 1, 2, 3)"),
            ))
        }
    }
    if let Some(epoch) = t.epoch {
        check_int64_field("epoch", epoch)?;
    }
    if let Some(p) = &t.pose {
        check_finite(p.as_slice(), "pose")?;
    }
    Ok(())
}

/// The `tracks` map: its keys in the reference encoder's order, version 2's (covariance only
/// when present) after version 1's, then `extra` more (a vehicle's) the caller writes.
pub(crate) fn write_columns(p: &mut Packer, c: &TrackColumns, v2: bool, extra: usize) {
    let added = if v2 {
        2 + usize::from(c.covariance.is_some())
    } else {
        0
    };
    p.map(13 + added + extra);
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
    if v2 {
        // Version 1 leaves them out: the bytes a version-1 reader takes.
        if let Some(cov) = &c.covariance {
            p.key("covariance").bin(&to_bytes(cov));
        }
        if let (Some(a), Some(s)) = (&c.age_s, &c.time_since_update_s) {
            p.key("age_s").bin(&to_bytes(a));
            p.key("time_since_update_s").bin(&to_bytes(s));
        }
    }
}

/// The frame as msgpack, byte for byte what the service writes (`pose` always present, nil
/// when absent). Mostly for tests and tools: the service is what publishes tracks. A vehicle's
/// columns (`existence`, `sensor_stamp_ns`) are not part of a TrackFrame and are left out; so
/// is `epoch` from a version before 3, which has no such field.
pub fn encode_track_frame(t: &TrackFrame) -> Result<Vec<u8>, Rejection> {
    check_frame(t).map_err(|e| e.into_rejection(Some(t.seq), Some(t.stamp_ns)))?;
    let c = &t.tracks;
    let epoch = t
        .epoch
        .filter(|_| t.schema_version >= TRACK_EPOCH_SCHEMA_VERSION);
    let mut p = Packer::new(512 + c.count() * 88);
    p.map(12 + usize::from(epoch.is_some()));
    p.key("schema_version").uint(t.schema_version);
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
    p.key("tracks");
    write_columns(&mut p, c, t.schema_version >= 2, 0);
    if let Some(epoch) = epoch {
        p.key("epoch").uint(epoch);
    }
    Ok(p.finish())
}
