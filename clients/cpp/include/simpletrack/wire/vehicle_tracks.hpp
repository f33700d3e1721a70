// VehicleTrackFrame (`<prefix>/<vehicle>/@vehicle/tracks`), a vehicle's fused tracks: its
// decoder and encoder. Order of checks (schemas/README.md, "VehicleTrackFrame"): the payload,
// the version (1 or 2), the fields in table order and unknown keys; `sensors` unique,
// `sensor_state` one per sensor, `sensor` one of `sensors`; the row cap, each column's length
// (sensor_stamp_ns: count x sensors values) and finiteness; existence within [0, 1] and
// sensor_stamp_ns at least -1.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "simpletrack/wire/decode.hpp"
#include "simpletrack/wire/encode.hpp"
#include "simpletrack/wire/messages.hpp"

namespace simpletrack::wire {

// A sensor_stamp_ns value: that sensor never updated the track.
inline constexpr std::int64_t kNeverUpdated = -1;

namespace detail {

inline std::vector<std::string> sensors_field(const Fields& top) {
  const Obj& v = required(top, "sensors");
  check_list(v, "sensors", kMaxFusedSensors);
  std::vector<std::string> out;
  for (std::uint32_t i = 0; i < v.via.array.size; ++i) {
    const std::string path = "sensors." + std::to_string(i);
    const std::string_view s = str_value(v.via.array.ptr[i], path);
    if (!is_name(s)) {
      reject(Reason::invalid_value, path,
             "String should match pattern '^[A-Za-z0-9_][A-Za-z0-9_.\\-]{0,63}$'");
    }
    out.emplace_back(s);
  }
  if (out.empty()) {
    reject(Reason::invalid_value, "sensors",
           "List should have at least 1 item after validation, not 0");
  }
  return out;
}

inline std::vector<SensorCondition> sensor_state_field(const Fields& top) {
  const Obj& v = required(top, "sensor_state");
  check_list(v, "sensor_state", kMaxFusedSensors);
  std::vector<SensorCondition> out;
  for (std::uint32_t i = 0; i < v.via.array.size; ++i) {
    out.push_back(enum_value<SensorCondition>(v.via.array.ptr[i], kSensorConditionNames,
                                              "sensor_state." + std::to_string(i)));
  }
  return out;
}

// Across fields: sensors unique, one state per sensor, the producing sensor among them.
inline void check_sensors(const std::string& sensor, const std::vector<std::string>& sensors,
                          std::size_t states) {
  for (std::size_t i = 0; i < sensors.size(); ++i) {
    for (std::size_t j = 0; j < i; ++j) {
      if (sensors[j] == sensors[i]) {
        reject(Reason::invalid_value, "sensors",
               "'" + sensors[i] + "' repeated at " + std::to_string(i));
      }
    }
  }
  if (states != sensors.size()) {
    reject(Reason::invalid_value, "sensor_state",
           std::to_string(states) + " states for " + std::to_string(sensors.size()) + " sensors");
  }
  bool found = false;
  for (const auto& s : sensors) found = found || s == sensor;
  if (!found) reject(Reason::invalid_value, "sensor", "'" + sensor + "' is not one of sensors");
}

inline void check_fused_values(const TrackColumns& t) {
  const auto& existence = *t.existence;
  for (std::size_t i = 0; i < existence.size(); ++i) {
    if (!(existence[i] >= 0.0 && existence[i] <= 1.0)) {
      reject(Reason::invalid_value, "tracks.existence",
             "outside [0, 1] in row " + std::to_string(i));
    }
  }
  const auto& stamps = *t.sensor_stamp_ns;
  for (std::size_t i = 0; i < stamps.size(); ++i) {
    for (const std::int64_t s : stamps[i]) {
      if (s < kNeverUpdated) {
        reject(Reason::invalid_value, "tracks.sensor_stamp_ns",
               "below -1 in row " + std::to_string(i));
      }
    }
  }
}

}  // namespace detail

// Decode and validate a VehicleTrackFrame: its structure, its sensors, every column's length
// and finiteness, then existence's and sensor_stamp_ns's values.
inline Result<VehicleTrackFrame> decode_vehicle_track_frame(const void* data, std::size_t size,
                                                            const DecodeLimits& limits = {}) {
  using namespace detail;
  Peek peek;
  try {
    const msgpack::object_handle handle = unpack(data, size, limits);
    const Fields top(handle.get(), "");
    peek = {peek_int(top, "seq"), peek_int(top, "stamp_ns")};
    const int version = check_version(top, 1, kVehicleTrackSchemaVersion);
    VehicleTrackFrame f;
    f.vehicle = name_field(top, "vehicle");
    f.seq = int64_field(top, "seq");
    f.stamp_ns = int64_field(top, "stamp_ns");
    f.sensor = name_field(top, "sensor");
    f.sensor_seq = int64_field(top, "sensor_seq");
    f.frame_id = text_value(required(top, "frame_id"), "frame_id", 1, 128);
    f.pose = pose_field(top);
    f.instance = name_field(top, "instance");
    f.received_ns = int64_field(top, "received_ns");
    f.published_ns = int64_field(top, "published_ns");
    f.sensors = sensors_field(top);
    f.sensor_state = sensor_state_field(top);
    const Fields tracks(map_field(top, "tracks", "VehicleTrackColumns"), "tracks.");
    const TrackBins bins = track_bins(tracks, Layout::vehicle);
    if (version >= 2) {
      f.epoch = optional_int64_field(top, "epoch");
      top.refuse_unknown({"schema_version", "vehicle", "seq", "stamp_ns", "sensor", "sensor_seq",
                          "frame_id", "pose", "instance", "received_ns", "published_ns",
                          "sensors", "sensor_state", "tracks", "epoch"});
    } else {  // then an epoch is an unknown key, as to a version-1 reader
      top.refuse_unknown({"schema_version", "vehicle", "seq", "stamp_ns", "sensor", "sensor_seq",
                          "frame_id", "pose", "instance", "received_ns", "published_ns",
                          "sensors", "sensor_state", "tracks"});
    }

    check_sensors(f.sensor, f.sensors, f.sensor_state.size());
    f.tracks = read_tracks(bins, Layout::vehicle, limits, f.sensors.size());
    check_fused_values(f.tracks);
    return f;
  } catch (const Reject& r) {
    return Rejection{r.reason, r.field, r.detail, peek.seq, peek.stamp_ns};
  } catch (const std::exception& e) {
    return internal_error(e.what());
  }
}

inline Result<VehicleTrackFrame> decode_vehicle_track_frame(
    const std::vector<std::uint8_t>& payload, const DecodeLimits& limits = {}) {
  return decode_vehicle_track_frame(payload.data(), payload.size(), limits);
}

// The frame as msgpack, byte for byte what the service writes (pose always present, nil when
// absent; covariance only when present). Throws EncodeError for a frame the decoder would
// refuse by its structure (names, row counts, sensors and states, a row of sensor_stamp_ns
// not one value per sensor); validate_vehicle_tracks() runs the decoder's full check.
inline std::vector<std::uint8_t> encode(const VehicleTrackFrame& f) {
  using namespace detail;
  const TrackColumns& t = f.tracks;
  const std::size_t n = t.count();
  check_name("VehicleTrackFrame.vehicle", f.vehicle);
  check_int64("VehicleTrackFrame.seq", f.seq);
  check_int64("VehicleTrackFrame.stamp_ns", f.stamp_ns);
  check_name("VehicleTrackFrame.sensor", f.sensor);
  check_int64("VehicleTrackFrame.sensor_seq", f.sensor_seq);
  check_text("VehicleTrackFrame.frame_id", f.frame_id, 1, 128);
  check_name("VehicleTrackFrame.instance", f.instance);
  check_int64("VehicleTrackFrame.received_ns", f.received_ns);
  check_int64("VehicleTrackFrame.published_ns", f.published_ns);
  if (f.sensors.empty() || f.sensors.size() > kMaxFusedSensors) {
    refuse("VehicleTrackFrame.sensors", std::to_string(f.sensors.size()) + " sensors, 1 to 64");
  }
  for (std::size_t i = 0; i < f.sensors.size(); ++i) {
    check_name("VehicleTrackFrame.sensors." + std::to_string(i), f.sensors[i]);
  }
  try {
    check_sensors(f.sensor, f.sensors, f.sensor_state.size());
  } catch (const Reject& r) {
    refuse("VehicleTrackFrame." + r.field.value_or(""), r.detail);
  }
  check_track_columns("VehicleTrackFrame", t, true);
  if (!t.existence || !t.sensor_stamp_ns) {
    refuse("VehicleTrackFrame.tracks.existence", "needs existence and sensor_stamp_ns");
  }
  check_rows("VehicleTrackFrame.tracks.existence", *t.existence, n);
  check_rows("VehicleTrackFrame.tracks.sensor_stamp_ns", *t.sensor_stamp_ns, n);
  for (std::size_t i = 0; i < n; ++i) {
    check_rows("VehicleTrackFrame.tracks.sensor_stamp_ns." + std::to_string(i),
               (*t.sensor_stamp_ns)[i], f.sensors.size());
  }
  if (f.epoch) check_int64("VehicleTrackFrame.epoch", *f.epoch);

  Writer w;
  w.map(14 + (f.epoch ? 1 : 0));
  w.key("schema_version").uint(static_cast<std::uint64_t>(f.version()));
  w.key("vehicle").str(f.vehicle);
  w.key("seq").uint(f.seq);
  w.key("stamp_ns").uint(f.stamp_ns);
  w.key("sensor").str(f.sensor);
  w.key("sensor_seq").uint(f.sensor_seq);
  w.key("frame_id").str(f.frame_id);
  w.key("pose").pose(f.pose);
  w.key("instance").str(f.instance);
  w.key("received_ns").uint(f.received_ns);
  w.key("published_ns").uint(f.published_ns);
  w.key("sensors").classes(f.sensors);
  w.key("sensor_state").array(f.sensor_state.size());
  for (const SensorCondition c : f.sensor_state) w.str(to_string(c));
  w.key("tracks");
  write_track_columns(w, t, true, 2);
  w.key("existence").column(*t.existence);
  std::vector<std::int64_t> flat;
  flat.reserve(n * f.sensors.size());
  for (const auto& row : *t.sensor_stamp_ns) flat.insert(flat.end(), row.begin(), row.end());
  w.key("sensor_stamp_ns").column(flat);
  if (f.epoch) w.key("epoch").uint(*f.epoch);
  return w.take();
}

// Everything the decoder checks of a frame, on its encoded bytes: nullopt when it would be
// accepted. A frame that cannot even be encoded throws EncodeError, as encode() does.
inline std::optional<Rejection> validate_vehicle_tracks(const VehicleTrackFrame& frame,
                                                        const DecodeLimits& limits = {}) {
  auto decoded = decode_vehicle_track_frame(encode(frame), limits);
  if (decoded) return std::nullopt;
  return decoded.error();
}

}  // namespace simpletrack::wire
