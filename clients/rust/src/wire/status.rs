//! `ServiceStatus`, the reply of a service's status queryable
//! (`<prefix>/@simpletrack/<instance>/status`), which a publisher reads to resume its seq.

use super::fields::{array, boolean, int64, name, nullable, number, string, Fields, V};
use super::header::{check_version, unpack_map, version_field, DecodeLimits};
use super::rejection::{Checked, Rejection};
use super::value::Map;

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

fn decode_checked(map: &Map<'_>, value: &V<'_>) -> Checked<ServiceStatus> {
    check_version(map)?;
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
