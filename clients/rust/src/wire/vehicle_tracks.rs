//! `VehicleTrackFrame` (`<prefix>/<vehicle>/@vehicle/tracks`): a vehicle's fused tracks, one
//! tracker fed by its sensors. Its columns are a `TrackFrame` version 2's plus `existence` and
//! `sensor_stamp_ns` (one value per sensor of `sensors`).
//!
//! Order of checks (schemas/README.md, "VehicleTrackFrame"): the payload, the version (1 or 2), the
//! fields in table order and unknown keys; `sensors` unique, `sensor_state` one per sensor,
//! `sensor` one of `sensors`; the row cap, each column's length and finiteness; `existence`
//! within [0, 1], `sensor_stamp_ns` at least -1.

use super::columns::{check_count, check_finite};
use super::fields::{array, int64, name, one_of, string, Fields, MAX_FRAME_ID, V};
use super::header::{
    check_int64_field, check_name_field, check_version_in, peek, pose_field, unpack_map,
    version_field, DecodeLimits,
};
use super::keys::VEHICLE_STREAM;
use super::pack::Packer;
use super::reasons::{ErrorReason, SensorCondition, VEHICLE_TRACK_SCHEMA_VERSION};
use super::rejection::{Checked, Invalid, Rejection};
use super::status::MAX_FUSED_SENSORS;
use super::tracks::{
    check_columns, epoch_field, raw_tracks, read_tracks, write_columns, Layout, TrackColumns,
};
use super::value::Map;

/// A `sensor_stamp_ns` value: that sensor never updated the track.
pub const NEVER_UPDATED: i64 = -1;

/// A vehicle's fused tracks after one of its sensors' frames.
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleTrackFrame {
    pub vehicle: String,
    /// The vehicle stream's message counter: +1 per message, kept across restarts and
    /// failovers; a repeat carries the same seq and stamp (with the vehicle: the key to
    /// drop repeats by).
    pub seq: u64,
    /// The time every box is at: the stamp of the input frame that produced this message.
    pub stamp_ns: u64,
    /// The sensor whose frame produced it, and that frame's seq.
    pub sensor: String,
    pub sensor_seq: u64,
    /// The world frame when the vehicle's frames carry poses, else the vehicle's frame.
    pub frame_id: String,
    /// The producing frame's pose, echoed.
    pub pose: Option<[f64; 16]>,
    pub instance: String,
    /// Service wall clock (Unix ns) at receipt of the producing frame.
    pub received_ns: u64,
    pub published_ns: u64,
    /// The vehicle's fused sensors, unique: the order of `sensor_state` and of each row of
    /// `tracks.sensor_stamp_ns`.
    pub sensors: Vec<String>,
    pub sensor_state: Vec<SensorCondition>,
    /// Every column of a `TrackFrame` version 2, and `existence` and `sensor_stamp_ns`
    /// (both `Some` in a decoded frame, and needed by the encoder).
    pub tracks: TrackColumns,
    /// Version 2: the vehicle stream's custody epoch (schemas/README.md, "Custody epoch
    /// (fencing)"); None when the frame carries none.
    pub epoch: Option<u64>,
}

impl VehicleTrackFrame {
    /// The version the encoder writes: 2 with an epoch, else 1 (the bytes of before it).
    pub fn schema_version(&self) -> u64 {
        if self.epoch.is_some() {
            VEHICLE_TRACK_SCHEMA_VERSION
        } else {
            1
        }
    }

    /// Track `i`'s fleet-unique id `<vehicle>/@vehicle/<id>` (schemas/README.md, "Track
    /// identity"); None when `i` is out of range.
    pub fn global_id(&self, i: usize) -> Option<String> {
        let id = self.tracks.id.get(i)?;
        Some(format!("{}/{VEHICLE_STREAM}/{id}", self.vehicle))
    }

    /// The `stamp_ns` of `sensor`'s last update of track `i`; None when that sensor never
    /// updated it, is not one of `sensors`, or `i` is out of range.
    pub fn last_update_ns(&self, i: usize, sensor: &str) -> Option<u64> {
        let j = self.sensors.iter().position(|s| s == sensor)?;
        let stamp = *self.tracks.sensor_stamp_ns.as_ref()?.get(i)?.get(j)?;
        u64::try_from(stamp).ok()
    }

    /// The number of tracks.
    pub fn count(&self) -> usize {
        self.tracks.count()
    }

    /// Every track's `global_id`, in column order.
    pub fn global_ids(&self) -> Vec<String> {
        let vehicle = &self.vehicle;
        let ids = self.tracks.id.iter();
        ids.map(|id| format!("{vehicle}/{VEHICLE_STREAM}/{id}"))
            .collect()
    }

    /// The probability in [0, 1] that track `i` is a real object; None when `i` is out of
    /// range (or the columns have no `existence`: a frame built by hand).
    pub fn existence(&self, i: usize) -> Option<f64> {
        self.tracks.existence.as_ref()?.get(i).copied()
    }

    /// The sensors that updated track `i`, each with the `stamp_ns` of its last update, in
    /// the order of `sensors`; empty when `i` is out of range.
    pub fn contributors(&self, i: usize) -> Vec<(&str, u64)> {
        let Some(row) = self.tracks.sensor_stamp_ns.as_ref().and_then(|s| s.get(i)) else {
            return Vec::new();
        };
        self.sensors
            .iter()
            .zip(row)
            .filter_map(|(s, &stamp)| Some((s.as_str(), u64::try_from(stamp).ok()?)))
            .collect()
    }

    /// The condition of fused sensor `sensor`; None when it is not one of `sensors`.
    pub fn condition(&self, sensor: &str) -> Option<SensorCondition> {
        let j = self.sensors.iter().position(|s| s == sensor)?;
        self.sensor_state.get(j).copied()
    }
}

fn condition(v: &V<'_>) -> Checked<SensorCondition> {
    one_of(v, &SensorCondition::ALL, SensorCondition::as_str)
}

fn check_sensors(sensor: &str, sensors: &[String], states: usize) -> Checked<()> {
    for (i, s) in sensors.iter().enumerate() {
        if sensors[..i].contains(s) {
            return Err(Invalid::at(
                ErrorReason::InvalidValue,
                "sensors",
                format!("'{s}' repeated at {i}"),
            ));
        }
    }
    if states != sensors.len() {
        return Err(Invalid::at(
            ErrorReason::InvalidValue,
            "sensor_state",
            format!("{states} states for {} sensors", sensors.len()),
        ));
    }
    if !sensors.iter().any(|s| s == sensor) {
        return Err(Invalid::at(
            ErrorReason::InvalidValue,
            "sensor",
            format!("'{sensor}' is not one of sensors"),
        ));
    }
    Ok(())
}

fn check_values(existence: &[f64], stamps: &[Vec<i64>]) -> Checked<()> {
    if let Some(row) = existence.iter().position(|e| !(0.0..=1.0).contains(e)) {
        return Err(Invalid::at(
            ErrorReason::InvalidValue,
            "tracks.existence",
            format!("outside [0, 1] in row {row}"),
        ));
    }
    if let Some(row) = stamps
        .iter()
        .position(|r| r.iter().any(|&s| s < NEVER_UPDATED))
    {
        return Err(Invalid::at(
            ErrorReason::InvalidValue,
            "tracks.sensor_stamp_ns",
            format!("below {NEVER_UPDATED} in row {row}"),
        ));
    }
    Ok(())
}

fn decode_checked(
    map: &Map<'_>,
    value: &V<'_>,
    limits: &DecodeLimits,
) -> Checked<VehicleTrackFrame> {
    let version = check_version_in(map, 1, VEHICLE_TRACK_SCHEMA_VERSION)?;
    let mut f = Fields::new(value, "VehicleTrackFrame")?;
    version_field(&mut f)?;
    let vehicle = f.required("vehicle", name)?.to_owned();
    let seq = f.required("seq", int64)?;
    let stamp_ns = f.required("stamp_ns", int64)?;
    let sensor = f.required("sensor", name)?.to_owned();
    let sensor_seq = f.required("sensor_seq", int64)?;
    let frame_id = f
        .required("frame_id", |v| string(v, 1, Some(MAX_FRAME_ID)))?
        .to_owned();
    let pose = f.optional("pose", None, pose_field)?;
    let instance = f.required("instance", name)?.to_owned();
    let received_ns = f.required("received_ns", int64)?;
    let published_ns = f.required("published_ns", int64)?;
    let sensors = f.required("sensors", |v| {
        array(v, 1, Some(MAX_FUSED_SENSORS), |s| {
            name(s).map(str::to_owned)
        })
    })?;
    let sensor_state = f.required("sensor_state", |v| {
        array(v, 0, Some(MAX_FUSED_SENSORS), condition)
    })?;
    let raw = f.required("tracks", |v| raw_tracks(v, Layout::Vehicle))?;
    let epoch = epoch_field(&mut f, version >= VEHICLE_TRACK_SCHEMA_VERSION)?;
    f.finish()?;

    check_sensors(&sensor, &sensors, sensor_state.len())?;
    let tracks = read_tracks(raw, limits, sensors.len())?;
    if let (Some(e), Some(s)) = (&tracks.existence, &tracks.sensor_stamp_ns) {
        check_values(e, s)?;
    }
    Ok(VehicleTrackFrame {
        vehicle,
        seq,
        stamp_ns,
        sensor,
        sensor_seq,
        frame_id,
        pose,
        instance,
        received_ns,
        published_ns,
        sensors,
        sensor_state,
        tracks,
        epoch,
    })
}

/// Decode and validate a `VehicleTrackFrame`: its structure, its sensors, then every
/// column's length and finiteness, then `existence` and `sensor_stamp_ns`'s values.
pub fn decode_vehicle_track_frame(
    payload: &[u8],
    limits: &DecodeLimits,
) -> Result<VehicleTrackFrame, Rejection> {
    let value = unpack_map(payload, limits.max_bytes).map_err(|e| e.into_rejection(None, None))?;
    let map = Map::of_value(&value);
    let (seq, stamp_ns) = peek(&map);
    decode_checked(&map, &value, limits).map_err(|e| e.into_rejection(seq, stamp_ns))
}

fn check_frame(t: &VehicleTrackFrame) -> Checked<()> {
    check_name_field("vehicle", &t.vehicle)?;
    check_int64_field("seq", t.seq)?;
    check_int64_field("stamp_ns", t.stamp_ns)?;
    check_name_field("sensor", &t.sensor)?;
    check_int64_field("sensor_seq", t.sensor_seq)?;
    super::fields::check_length(&t.frame_id, 1, Some(MAX_FRAME_ID))
        .map_err(|e| e.within("frame_id"))?;
    check_name_field("instance", &t.instance)?;
    check_int64_field("received_ns", t.received_ns)?;
    check_int64_field("published_ns", t.published_ns)?;
    if t.sensors.is_empty() || t.sensors.len() > MAX_FUSED_SENSORS {
        return Err(Invalid::at(
            ErrorReason::InvalidValue,
            "sensors",
            format!("1 to {MAX_FUSED_SENSORS} sensors, not {}", t.sensors.len()),
        ));
    }
    for (i, s) in t.sensors.iter().enumerate() {
        super::fields::check_name(s).map_err(|e| e.within(i).within("sensors"))?;
    }
    check_sensors(&t.sensor, &t.sensors, t.sensor_state.len())?;
    let c = &t.tracks;
    check_columns(c, true)?;
    let n = c.count();
    let (Some(existence), Some(stamps)) = (&c.existence, &c.sensor_stamp_ns) else {
        return Err(Invalid::at(
            ErrorReason::MissingField,
            "tracks.existence",
            "a VehicleTrackFrame needs existence and sensor_stamp_ns",
        ));
    };
    check_count(existence, n, "tracks.existence")?;
    check_finite(existence, "tracks.existence")?;
    check_count(stamps, n, "tracks.sensor_stamp_ns")?;
    if let Some(row) = stamps.iter().position(|r| r.len() != t.sensors.len()) {
        return Err(Invalid::at(
            ErrorReason::ColumnLength,
            "tracks.sensor_stamp_ns",
            format!(
                "row {row} has {} values, expected one per sensor",
                stamps[row].len()
            ),
        ));
    }
    check_values(existence, stamps)?;
    if let Some(p) = &t.pose {
        check_finite(p.as_slice(), "pose")?;
    }
    if let Some(epoch) = t.epoch {
        check_int64_field("epoch", epoch)?;
    }
    Ok(())
}

/// The frame as msgpack, byte for byte what the service writes (`pose` always present, nil
/// when absent; `covariance` only when present). A frame the decoder would refuse is refused.
pub fn encode_vehicle_track_frame(t: &VehicleTrackFrame) -> Result<Vec<u8>, Rejection> {
    check_frame(t).map_err(|e| e.into_rejection(Some(t.seq), Some(t.stamp_ns)))?;
    let c = &t.tracks;
    let mut p = Packer::new(768 + c.count() * (104 + 8 * t.sensors.len()));
    p.map(14 + usize::from(t.epoch.is_some()));
    p.key("schema_version").uint(t.schema_version());
    p.key("vehicle").str(&t.vehicle);
    p.key("seq").uint(t.seq);
    p.key("stamp_ns").uint(t.stamp_ns);
    p.key("sensor").str(&t.sensor);
    p.key("sensor_seq").uint(t.sensor_seq);
    p.key("frame_id").str(&t.frame_id);
    match &t.pose {
        Some(pose) => p.key("pose").f64s(pose),
        None => p.key("pose").nil(),
    };
    p.key("instance").str(&t.instance);
    p.key("received_ns").uint(t.received_ns);
    p.key("published_ns").uint(t.published_ns);
    p.key("sensors").strs(&t.sensors);
    p.key("sensor_state").array(t.sensor_state.len());
    for s in &t.sensor_state {
        p.str(s.as_str());
    }
    p.key("tracks");
    write_columns(&mut p, c, true, 2);
    if let (Some(existence), Some(stamps)) = (&c.existence, &c.sensor_stamp_ns) {
        p.key("existence").bin(&super::columns::to_bytes(existence));
        let flat: Vec<i64> = stamps.iter().flatten().copied().collect();
        p.key("sensor_stamp_ns")
            .bin(&super::columns::to_bytes(&flat));
    }
    if let Some(epoch) = t.epoch {
        p.key("epoch").uint(epoch);
    }
    Ok(p.finish())
}
