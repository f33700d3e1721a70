//! `ServiceStatus`, the reply of a service's status queryable
//! (`<prefix>/@simpletrack/<instance>/status`), which a publisher reads to resume its seq.
//! Versions 1 and 2 (version 2: the fused vehicles).

use super::fields::{array, boolean, int64, name, nullable, number, one_of, string, Fields, V};
use super::header::{check_version_in, unpack_map, version_field, DecodeLimits};
use super::reasons::{SensorCondition, SCHEMA_VERSION, STATUS_SCHEMA_VERSION};
use super::rejection::{Checked, Rejection};
use super::value::Map;

/// The most sensors one vehicle fuses.
pub const MAX_FUSED_SENSORS: usize = 64;

/// What an instance holds of one sensor.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorStatus {
    pub vehicle: String,
    pub sensor: String,
    /// The seq and stamp of the last frame it tracked (None before the first).
    pub last_seq: Option<u64>,
    pub last_stamp_ns: Option<u64>,
    pub frames: u64,
    pub active_tracks: u64,
    pub idle_s: f64,
    /// Frames tracked per second over the last 10 s (0 from a service without the field).
    pub rate_hz: f64,
    /// Tracker resets (gap, time_backwards, restart, non_finite) on this instance.
    pub resets: u64,
    /// Frames tracked with a plausibility warning (units, conventions) on this instance.
    pub implausible_frames: u64,
}

/// One sensor of a fused vehicle, as the vehicle's tracker sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct FusedSensorStatus {
    pub sensor: String,
    pub state: SensorCondition,
    pub last_seq: Option<u64>,
    pub last_stamp_ns: Option<u64>,
    /// Its frames applied to the vehicle's tracks.
    pub frames: u64,
    pub idle_s: Option<f64>,
    /// Median stamp → receipt over its recent frames.
    pub latency_s: Option<f64>,
    pub clock_offset_s: Option<f64>,
    /// Estimated x, y offset of its detections from the vehicle's tracks (m).
    pub offset_m: Option<[f64; 2]>,
    /// Its frames kept out (clock or extrinsic).
    pub flagged_frames: u64,
    /// Why it is flagged; empty when ok.
    pub detail: String,
}

/// A fused vehicle: one tracker fed by its sensors (status version 2).
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleStatus {
    pub vehicle: String,
    /// Seq of its last `VehicleTrackFrame`.
    pub seq: Option<u64>,
    pub last_stamp_ns: Option<u64>,
    pub active_tracks: u64,
    /// Input frames applied.
    pub frames: u64,
    pub late_frames: u64,
    pub reprocessed_frames: u64,
    pub sensors: Vec<FusedSensorStatus>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct ServiceStatus {
    pub instance: String,
    pub version: String,
    pub preset: String,
    /// The tracker configuration's classes.
    pub classes: Vec<String>,
    pub config_digest: String,
    pub started_ns: u64,
    pub ready: bool,
    pub queue_depth: u64,
    pub sensors: Vec<SensorStatus>,
    pub members: Vec<String>,
    pub standby_sensors: u64,
    pub handoffs_in: u64,
    pub handoffs_out: u64,
    pub failovers: u64,
    /// Version 2: the fused vehicles this instance holds (empty from version 1).
    pub vehicles: Vec<VehicleStatus>,
}

fn owned(v: &V<'_>) -> Checked<String> {
    string(v, 0, None).map(str::to_owned)
}

fn sensor_status(v: &V<'_>) -> Checked<SensorStatus> {
    let mut f = Fields::new(v, "SensorStatus")?;
    let s = SensorStatus {
        vehicle: f.required("vehicle", name)?.to_owned(),
        sensor: f.required("sensor", name)?.to_owned(),
        last_seq: f.required("last_seq", |v| nullable(v, int64))?,
        last_stamp_ns: f.required("last_stamp_ns", |v| nullable(v, int64))?,
        frames: f.required("frames", int64)?,
        active_tracks: f.required("active_tracks", int64)?,
        idle_s: f.required("idle_s", number)?,
        rate_hz: f.optional("rate_hz", 0.0, number)?,
        resets: f.optional("resets", 0, int64)?,
        implausible_frames: f.optional("implausible_frames", 0, int64)?,
    };
    f.finish()?;
    Ok(s)
}

fn fused_sensor(v: &V<'_>) -> Checked<FusedSensorStatus> {
    let mut f = Fields::new(v, "FusedSensorStatus")?;
    let s = FusedSensorStatus {
        sensor: f.required("sensor", name)?.to_owned(),
        state: f.required("state", |v| {
            one_of(v, &SensorCondition::ALL, SensorCondition::as_str)
        })?,
        last_seq: f.required("last_seq", |v| nullable(v, int64))?,
        last_stamp_ns: f.required("last_stamp_ns", |v| nullable(v, int64))?,
        frames: f.required("frames", int64)?,
        idle_s: f.required("idle_s", |v| nullable(v, number))?,
        latency_s: f.required("latency_s", |v| nullable(v, number))?,
        clock_offset_s: f.required("clock_offset_s", |v| nullable(v, number))?,
        offset_m: f.required("offset_m", |v| {
            nullable(v, |v| array(v, 2, Some(2), number).map(|xy| [xy[0], xy[1]]))
        })?,
        flagged_frames: f.required("flagged_frames", int64)?,
        detail: f
            .optional("detail", "", |v| string(v, 0, Some(256)))?
            .to_owned(),
    };
    f.finish()?;
    Ok(s)
}

fn vehicle_status(v: &V<'_>) -> Checked<VehicleStatus> {
    let mut f = Fields::new(v, "VehicleStatus")?;
    let s = VehicleStatus {
        vehicle: f.required("vehicle", name)?.to_owned(),
        seq: f.required("seq", |v| nullable(v, int64))?,
        last_stamp_ns: f.required("last_stamp_ns", |v| nullable(v, int64))?,
        active_tracks: f.required("active_tracks", int64)?,
        frames: f.required("frames", int64)?,
        late_frames: f.required("late_frames", int64)?,
        reprocessed_frames: f.required("reprocessed_frames", int64)?,
        sensors: f.required("sensors", |v| {
            array(v, 0, Some(MAX_FUSED_SENSORS), fused_sensor)
        })?,
    };
    f.finish()?;
    Ok(s)
}

fn decode_checked(map: &Map<'_>, value: &V<'_>) -> Checked<ServiceStatus> {
    let version = check_version_in(map, SCHEMA_VERSION, STATUS_SCHEMA_VERSION)?;
    let mut f = Fields::new(value, "ServiceStatus")?;
    version_field(&mut f)?;
    let s = ServiceStatus {
        instance: f.required("instance", name)?.to_owned(),
        version: f.required("version", owned)?,
        preset: f.required("preset", owned)?,
        classes: f.required("classes", |v| array(v, 0, None, owned))?,
        config_digest: f.required("config_digest", owned)?,
        started_ns: f.required("started_ns", int64)?,
        ready: f.required("ready", boolean)?,
        queue_depth: f.required("queue_depth", int64)?,
        sensors: f.required("sensors", |v| array(v, 0, None, sensor_status))?,
        members: f.optional("members", Vec::new(), |v| {
            array(v, 0, None, |m| name(m).map(str::to_owned))
        })?,
        standby_sensors: f.optional("standby_sensors", 0, int64)?,
        handoffs_in: f.optional("handoffs_in", 0, int64)?,
        handoffs_out: f.optional("handoffs_out", 0, int64)?,
        failovers: f.optional("failovers", 0, int64)?,
        vehicles: match version {
            1 => Vec::new(), // then a vehicles key is an unknown one, as to a version-1 reader
            _ => f.optional("vehicles", Vec::new(), |v| {
                array(v, 0, None, vehicle_status)
            })?,
        },
    };
    f.finish()?;
    Ok(s)
}

pub fn decode_service_status(
    payload: &[u8],
    limits: &DecodeLimits,
) -> Result<ServiceStatus, Rejection> {
    let value = unpack_map(payload, limits.max_bytes).map_err(|e| e.into_rejection(None, None))?;
    let map = Map::of_value(&value);
    decode_checked(&map, &value).map_err(|e| e.into_rejection(None, None))
}
