// The wire messages of schemas/README.md as plain C++17 structs, the reasons a message is
// refused, and the result type the decoders return.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <variant>
#include <vector>

namespace simpletrack::wire {

inline constexpr int kSchemaVersion = 1;
// TrackFrame version 2 added covariance and ages in seconds, version 3 the optional custody
// epoch; decode_track_frame reads 1 to 3 (schemas/README.md, "Versioning").
inline constexpr int kTrackSchemaVersion = 2;
inline constexpr int kTrackEpochSchemaVersion = 3;
// DetectionFrame version 2 adds the optional extrinsic; decode_detection_frame reads 1 and 2,
// encode writes 2 only for a frame with an extrinsic.
inline constexpr int kDetectionSchemaVersion = 2;
// VehicleTrackFrame, a vehicle's fused tracks, is a message of its own; its version 2 adds
// the optional custody epoch, and encode writes 2 only for a frame with one.
inline constexpr int kVehicleTrackSchemaVersion = 2;
// Where a sensor's name would be in a key, the chunk of a vehicle's fused stream
// (`<prefix>/<vehicle>/@vehicle/tracks`): verbatim, so `*` never matches it.
inline constexpr std::string_view kVehicleStream = "@vehicle";
inline constexpr std::size_t kMaxFusedSensors = 64;

// Ranges and caps of the contract ("DetectionFrame", "Bounds" in schemas/README.md).
inline constexpr std::uint64_t kInt64Max = 9223372036854775807ULL;
inline constexpr std::uint64_t kInt32Max = 2147483647ULL;
inline constexpr std::size_t kMaxClasses = 1024;
inline constexpr std::size_t kMaxNoticeSeqs = 1024;
inline constexpr double kMaxCoordinateM = 1e5;  // |x|, |y|, |z| of a centre, a pose's translation
inline constexpr double kMaxSizeM = 100.0;      // each of l, w, h
inline constexpr double kMaxYawRad = 1e4;
inline constexpr double kMaxSpeedMps = 200.0;   // |vx|, |vy|
inline constexpr double kPoseTolerance = 1e-4;  // rotation orthonormal to this, last row 0 0 0 1

// The `reason` values of a FrameError, in the order of simpletrack/wire/reasons.py (the strings
// travel).
enum class Reason {
  too_large,
  malformed,
  wrong_version,
  missing_field,
  extra_field,
  wrong_type,
  invalid_value,
  column_length,
  non_finite,
  non_positive_size,
  unknown_class,
  key_mismatch,
  out_of_order,
  seq_not_increasing,
  duplicate_seq,
  too_many_sensors,
  late,            // a fused sensor's frame older than the vehicle's re-processing history
  sensor_flagged,  // a fused sensor flagged for its clock or extrinsic: its frames kept out
  dropped_queue_full,
  dropped_shutdown,
  missed,
  internal_error,
};

inline constexpr std::array<std::string_view, 22> kReasonNames = {
    "too_large",    "malformed",          "wrong_version",      "missing_field",
    "extra_field",  "wrong_type",         "invalid_value",      "column_length",
    "non_finite",   "non_positive_size",  "unknown_class",      "key_mismatch",
    "out_of_order", "seq_not_increasing", "duplicate_seq",      "too_many_sensors",
    "late",         "sensor_flagged",     "dropped_queue_full", "dropped_shutdown",
    "missed",       "internal_error",
};

constexpr std::string_view to_string(Reason r) {
  return kReasonNames[static_cast<std::size_t>(r)];
}

// The enumerator E named `name` in `names` (E's values in order), or none.
template <class E, std::size_t N>
constexpr std::optional<E> parse_name(const std::array<std::string_view, N>& names,
                                      std::string_view name) {
  for (std::size_t i = 0; i < N; ++i) {
    if (names[i] == name) return static_cast<E>(i);
  }
  return std::nullopt;
}

inline std::optional<Reason> parse_reason(std::string_view name) {
  return parse_name<Reason>(kReasonNames, name);
}

// A fused sensor's condition (VehicleTrackFrame::sensor_state), in the order of
// simpletrack/wire/reasons.py's SensorCondition.
enum class SensorCondition {
  ok,
  probation,  // not yet verified against the others: updates tracks, starts none
  silent,     // no frame for a while
  clock,      // its stamps are off: its frames are kept out
  extrinsic,  // its detections are offset from the vehicle's tracks: kept out
  unseen,     // configured, never heard
};

inline constexpr std::array<std::string_view, 6> kSensorConditionNames = {
    "ok", "probation", "silent", "clock", "extrinsic", "unseen"};

constexpr std::string_view to_string(SensorCondition c) {
  return kSensorConditionNames[static_cast<std::size_t>(c)];
}

inline std::optional<SensorCondition> parse_sensor_condition(std::string_view name) {
  return parse_name<SensorCondition>(kSensorConditionNames, name);
}

// Codes of TrackColumns::state.
enum class TrackState : std::int32_t { tentative = 0, confirmed = 1, coasting = 2 };

using Vec2f = std::array<float, 2>;
using Vec3f = std::array<float, 3>;
using Pose = std::array<double, 16>;  // sensor -> world, 4x4 row-major

// N detection boxes, one vector per column; N is class_index.size() and every column must
// have N rows (the encoder refuses anything else).
struct BoxColumns {
  std::vector<std::string> classes;  // this frame's class table
  std::vector<std::int32_t> class_index;
  std::vector<Vec3f> center;  // x, y, z of the box's geometric centre, metres
  std::vector<Vec3f> size;    // l, w, h
  std::vector<float> yaw;     // heading about +z from +x, radians
  std::vector<double> score;
  std::optional<std::vector<Vec2f>> velocity;  // vx, vy in m/s

  std::size_t count() const { return class_index.size(); }
};

// `<prefix>/<vehicle>/<sensor>/detections`
struct DetectionFrame {
  std::string vehicle;
  std::string sensor;
  std::uint64_t seq = 0;
  std::uint64_t stamp_ns = 0;
  std::string frame_id;
  std::optional<Pose> pose;
  bool key_frame = true;
  std::optional<std::uint64_t> session_id;
  BoxColumns boxes;
  // Version 2: the sensor's mounting, sensor -> vehicle, 4x4 row-major; a vehicle whose
  // sensors the service fuses needs it.
  std::optional<Pose> extrinsic;
  // What encode writes: nullopt = 2 with an extrinsic, else 1 (the bytes of before version
  // 2). decode_detection_frame sets the version it read, so a frame re-encodes as it came.
  std::optional<int> schema_version;

  // The version encode writes (what == compares: nullopt is the default for the content).
  int version() const { return schema_version.value_or(extrinsic ? 2 : 1); }
};

struct TrackColumns {
  std::vector<std::string> classes;  // the service's class table
  std::vector<std::int64_t> id;
  std::vector<std::int32_t> class_index;
  std::vector<Vec3f> center;
  std::vector<Vec3f> size;
  std::vector<float> yaw;
  std::vector<double> score;
  std::vector<Vec3f> velocity;      // vx, vy, vz
  std::vector<std::int32_t> state;  // TrackState codes
  std::vector<std::int32_t> hits;
  std::vector<std::int32_t> age;
  std::vector<std::int32_t> time_since_update;
  // Version 2. The covariance over x, y, z, vx, vy, vz as its upper triangle, row-major
  // ((0,0) (0,1) ... (0,5) (1,1) ... (5,5)); absent when the service's motion model keeps
  // none. Ages in seconds from birth and from the last update to stamp_ns.
  std::optional<std::vector<std::array<float, 21>>> covariance;
  std::optional<std::vector<double>> age_s;
  std::optional<std::vector<double>> time_since_update_s;
  // A vehicle's fused tracks only (VehicleTrackFrame; a TrackFrame's encoder leaves them
  // out): the probability in [0, 1] that the track is an object, and per track one value
  // per sensor of the frame's `sensors`, the stamp_ns of that sensor's last update of the
  // track, -1 when it never updated it.
  std::optional<std::vector<double>> existence;
  std::optional<std::vector<std::vector<std::int64_t>>> sensor_stamp_ns;

  std::size_t count() const { return id.size(); }
};

// Element (r, c) of a 6x6 covariance kept as its upper triangle.
inline float covariance_at(const std::array<float, 21>& upper, int r, int c) {
  if (r > c) std::swap(r, c);
  return upper[static_cast<std::size_t>(r * 6 - r * (r - 1) / 2 + (c - r))];
}

// `<prefix>/<vehicle>/<sensor>/tracks`
struct TrackFrame {
  std::string vehicle;
  std::string sensor;
  std::uint64_t seq = 0;
  std::uint64_t stamp_ns = 0;
  std::string frame_id;
  std::optional<Pose> pose;
  bool key_frame = true;
  std::string instance;
  std::uint64_t received_ns = 0;
  std::uint64_t published_ns = 0;
  TrackColumns tracks;
  // Version 3: the stream's custody epoch (schemas/README.md, "Custody epoch (fencing)");
  // nullopt when the frame carries none. encode writes it in version 3 only.
  std::optional<std::uint64_t> epoch;
  // What encode writes: nullopt = 3 when the tracks have their ages in seconds and there is
  // an epoch, 2 with the ages only, else 1. decode_track_frame sets the version it read, so
  // a frame re-encodes as it came.
  std::optional<int> schema_version;

  // The track's fleet-unique id "<vehicle>/<sensor>/<id>" (schemas/README.md, "Track identity").
  std::string global_id(std::size_t i) const {
    return vehicle + "/" + sensor + "/" + std::to_string(tracks.id.at(i));
  }
};

// `<prefix>/<vehicle>/@vehicle/tracks`: a vehicle's fused tracks, one tracker fed by its
// sensors. (vehicle, seq, stamp_ns) identify a message: a repeat carries the same three.
struct VehicleTrackFrame {
  std::string vehicle;
  std::uint64_t seq = 0;       // the vehicle stream's counter, +1 per message
  std::uint64_t stamp_ns = 0;  // the time every box is at: the producing frame's stamp
  std::string sensor;          // the sensor whose frame produced this message
  std::uint64_t sensor_seq = 0;
  std::string
      frame_id;  // the world frame when the vehicle's frames carry poses, else the vehicle's
  std::optional<Pose> pose;  // the producing frame's, echoed
  std::string instance;
  std::uint64_t received_ns = 0;
  std::uint64_t published_ns = 0;
  std::vector<std::string> sensors;  // unique; the order of sensor_state and of each
                                     // tracks.sensor_stamp_ns row
  std::vector<SensorCondition> sensor_state;
  TrackColumns tracks;  // version 2's columns, existence and sensor_stamp_ns
  // Version 2: the vehicle stream's custody epoch; nullopt when the frame carries none.
  std::optional<std::uint64_t> epoch;

  // The version encode writes: 2 with an epoch, else 1 (the bytes of before it).
  int version() const { return epoch ? 2 : 1; }

  // The track's fleet-unique id "<vehicle>/@vehicle/<id>" (schemas/README.md, "Track identity").
  std::string global_id(std::size_t i) const {
    return vehicle + "/" + std::string(kVehicleStream) + "/" + std::to_string(tracks.id.at(i));
  }

  // stamp_ns of sensor `name`'s last update of track i; nullopt when it never updated it or is
  // not one of `sensors`.
  std::optional<std::uint64_t> last_update_ns(std::size_t i, std::string_view name) const {
    if (!tracks.sensor_stamp_ns) return std::nullopt;
    for (std::size_t j = 0; j < sensors.size(); ++j) {
      if (sensors[j] != name) continue;
      const std::int64_t stamp = tracks.sensor_stamp_ns->at(i).at(j);
      if (stamp < 0) return std::nullopt;
      return static_cast<std::uint64_t>(stamp);
    }
    return std::nullopt;
  }

  // The number of tracks; track i's columns are tracks.<column>[i].
  std::size_t count() const { return tracks.count(); }

  // The probability in [0, 1] that track i is a real object (tracks.existence[i]; a decoded
  // frame always has the column). Throws std::out_of_range for an i past count().
  double existence(std::size_t i) const {
    if (!tracks.existence) throw std::out_of_range("VehicleTrackFrame without existence");
    return tracks.existence->at(i);
  }

  // The sensors that updated track i, each with the stamp_ns of its last update, in the
  // order of `sensors`. Throws std::out_of_range for an i past count().
  std::vector<std::pair<std::string, std::uint64_t>> contributors(std::size_t i) const {
    std::vector<std::pair<std::string, std::uint64_t>> out;
    if (!tracks.sensor_stamp_ns) return out;
    const std::vector<std::int64_t>& row = tracks.sensor_stamp_ns->at(i);
    for (std::size_t j = 0; j < sensors.size() && j < row.size(); ++j) {
      if (row[j] >= 0) out.emplace_back(sensors[j], static_cast<std::uint64_t>(row[j]));
    }
    return out;
  }

  // The condition of fused sensor `name`; nullopt when it is not one of `sensors`.
  std::optional<SensorCondition> condition(std::string_view name) const {
    for (std::size_t j = 0; j < sensors.size() && j < sensor_state.size(); ++j) {
      if (sensors[j] == name) return sensor_state[j];
    }
    return std::nullopt;
  }
};

// `<prefix>/<vehicle>/<sensor>/errors`
struct FrameError {
  std::string vehicle;
  std::string sensor;
  std::optional<std::uint64_t> seq;
  std::optional<std::uint64_t> stamp_ns;
  Reason reason = Reason::internal_error;
  std::optional<std::string> field;  // dotted path, e.g. "boxes.size"
  std::string detail;                // for people, not for parsing
  std::string instance;
  std::uint64_t received_ns = 0;
  // Drop notices only: the seq of every frame the notice stands for (nullopt: unreadable).
  std::optional<std::vector<std::optional<std::uint64_t>>> seqs;
};

inline bool operator==(const BoxColumns& a, const BoxColumns& b) {
  return a.classes == b.classes && a.class_index == b.class_index && a.center == b.center &&
         a.size == b.size && a.yaw == b.yaw && a.score == b.score && a.velocity == b.velocity;
}
inline bool operator==(const DetectionFrame& a, const DetectionFrame& b) {
  return a.vehicle == b.vehicle && a.sensor == b.sensor && a.seq == b.seq &&
         a.stamp_ns == b.stamp_ns && a.frame_id == b.frame_id && a.pose == b.pose &&
         a.key_frame == b.key_frame && a.session_id == b.session_id && a.boxes == b.boxes &&
         a.extrinsic == b.extrinsic && a.version() == b.version();
}
inline bool operator==(const TrackColumns& a, const TrackColumns& b) {
  return a.classes == b.classes && a.id == b.id && a.class_index == b.class_index &&
         a.center == b.center && a.size == b.size && a.yaw == b.yaw && a.score == b.score &&
         a.velocity == b.velocity && a.state == b.state && a.hits == b.hits && a.age == b.age &&
         a.time_since_update == b.time_since_update && a.covariance == b.covariance &&
         a.age_s == b.age_s && a.time_since_update_s == b.time_since_update_s &&
         a.existence == b.existence && a.sensor_stamp_ns == b.sensor_stamp_ns;
}
inline bool operator==(const TrackFrame& a, const TrackFrame& b) {
  return a.vehicle == b.vehicle && a.sensor == b.sensor && a.seq == b.seq &&
         a.stamp_ns == b.stamp_ns && a.frame_id == b.frame_id && a.pose == b.pose &&
         a.key_frame == b.key_frame && a.instance == b.instance && a.received_ns == b.received_ns &&
         a.published_ns == b.published_ns && a.tracks == b.tracks && a.epoch == b.epoch &&
         a.schema_version == b.schema_version;
}
inline bool operator==(const VehicleTrackFrame& a, const VehicleTrackFrame& b) {
  return a.vehicle == b.vehicle && a.seq == b.seq && a.stamp_ns == b.stamp_ns &&
         a.sensor == b.sensor && a.sensor_seq == b.sensor_seq && a.frame_id == b.frame_id &&
         a.pose == b.pose && a.instance == b.instance && a.received_ns == b.received_ns &&
         a.published_ns == b.published_ns && a.sensors == b.sensors &&
         a.sensor_state == b.sensor_state && a.tracks == b.tracks && a.epoch == b.epoch;
}
inline bool operator==(const FrameError& a, const FrameError& b) {
  return a.vehicle == b.vehicle && a.sensor == b.sensor && a.seq == b.seq &&
         a.stamp_ns == b.stamp_ns && a.reason == b.reason && a.field == b.field &&
         a.detail == b.detail && a.instance == b.instance && a.received_ns == b.received_ns &&
         a.seqs == b.seqs;
}
inline bool operator!=(const BoxColumns& a, const BoxColumns& b) {
  return !(a == b);
}
inline bool operator!=(const DetectionFrame& a, const DetectionFrame& b) {
  return !(a == b);
}
inline bool operator!=(const TrackColumns& a, const TrackColumns& b) {
  return !(a == b);
}
inline bool operator!=(const TrackFrame& a, const TrackFrame& b) {
  return !(a == b);
}
inline bool operator!=(const VehicleTrackFrame& a, const VehicleTrackFrame& b) {
  return !(a == b);
}
inline bool operator!=(const FrameError& a, const FrameError& b) {
  return !(a == b);
}

// Why a payload was refused: the reason and dotted field the service would report, and the
// frame's seq/stamp_ns when they could still be read (detection and track frames only).
struct Rejection {
  Reason reason = Reason::internal_error;
  std::optional<std::string> field;
  std::string detail;
  std::optional<std::uint64_t> seq;
  std::optional<std::uint64_t> stamp_ns;

  // One line for a log: "invalid_value at boxes.center: |value| over 100000 m in row 2".
  std::string message() const {
    std::string out(to_string(reason));
    if (field) out += " at " + *field;
    return out + ": " + detail;
  }
};

struct DecodeLimits {
  std::size_t max_bytes = std::size_t{8} << 20;  // the service's default payload cap
  std::size_t max_boxes = 10000;                 // the service's default max_boxes
};

// What a decoder returns: the message, or why it was refused. Never both, never neither.
template <class T>
class Result {
 public:
  Result(T value) : v_(std::move(value)) {}          // NOLINT: implicit on purpose
  Result(Rejection error) : v_(std::move(error)) {}  // NOLINT
  bool ok() const { return v_.index() == 0; }
  explicit operator bool() const { return ok(); }
  const T& value() const& { return ok() ? std::get<0>(v_) : fail(); }
  T value() && {
    if (!ok()) fail();
    return std::get<0>(std::move(v_));
  }
  const T* operator->() const { return &value(); }
  const Rejection& error() const {
    if (ok()) throw std::logic_error("Result::error() on a decoded message");
    return std::get<1>(v_);
  }

 private:
  [[noreturn]] const T& fail() const {
    throw std::logic_error("Result::value() on a rejected message: " + std::get<1>(v_).message());
  }
  std::variant<T, Rejection> v_;
};

// The encoders' complaint about a message the decoders would refuse by its structure
// (a bad id, mismatched column lengths, an overlong class table ...).
class EncodeError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

}  // namespace simpletrack::wire
