//! Zenoh key expressions of the service (docs/SERVICE.md), under a prefix (default `fleet`).

pub const DEFAULT_PREFIX: &str = "fleet";
pub const SERVICE_CHUNK: &str = "@simpletrack";
/// Where a sensor's name would be, the chunk of a vehicle's fused stream: a verbatim chunk,
/// which `*` never matches (a `<prefix>/*/*/tracks` subscriber never hears fused tracks).
pub const VEHICLE_STREAM: &str = "@vehicle";

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Keys {
    pub prefix: String,
}

impl Default for Keys {
    fn default() -> Self {
        Self::new(DEFAULT_PREFIX)
    }
}

impl Keys {
    pub fn new(prefix: impl Into<String>) -> Self {
        Self {
            prefix: prefix.into(),
        }
    }

    /// `<prefix>/<vehicle>/<sensor>/detections` (`*` selects every vehicle or sensor).
    pub fn detections(&self, vehicle: &str, sensor: &str) -> String {
        format!("{}/{vehicle}/{sensor}/detections", self.prefix)
    }

    pub fn tracks(&self, vehicle: &str, sensor: &str) -> String {
        format!("{}/{vehicle}/{sensor}/tracks", self.prefix)
    }

    pub fn errors(&self, vehicle: &str, sensor: &str) -> String {
        format!("{}/{vehicle}/{sensor}/errors", self.prefix)
    }

    /// `<prefix>/<vehicle>/@vehicle/tracks`: the vehicle's fused tracks (`*`: every vehicle).
    pub fn vehicle_tracks(&self, vehicle: &str) -> String {
        format!("{}/{vehicle}/{VEHICLE_STREAM}/tracks", self.prefix)
    }

    /// The status queryable of `instance` (`*`: every instance).
    pub fn status(&self, instance: &str) -> String {
        format!("{}/{SERVICE_CHUNK}/{instance}/status", self.prefix)
    }

    /// (vehicle, sensor) of a `<prefix>/<vehicle>/<sensor>/<leaf>` key; a vehicle's fused
    /// stream gives (vehicle, `VEHICLE_STREAM`).
    pub fn sensor_of<'k>(&self, key: &'k str) -> Option<(&'k str, &'k str)> {
        let rest = key.strip_prefix(self.prefix.as_str())?.strip_prefix('/')?;
        let mut parts = rest.split('/');
        let (vehicle, sensor, _leaf) = (parts.next()?, parts.next()?, parts.next()?);
        parts.next().is_none().then_some((vehicle, sensor))
    }
}
