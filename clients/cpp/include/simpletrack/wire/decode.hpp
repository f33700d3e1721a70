// Decoders: bytes to a typed message, or the Rejection the service would report, with the
// checks in the order of schemas/README.md ("Validation order and reasons") and the same
// reason and dotted field as the reference decoder (simpletrack.wire.codec). They never throw.
#pragma once

#ifndef MSGPACK_NO_BOOST
#define MSGPACK_NO_BOOST
#endif
#include <msgpack.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <initializer_list>
#include <iterator>
#include <new>
#include <optional>
#include <string>
#include <string_view>
#include <type_traits>
#include <unordered_map>
#include <vector>

#include "simpletrack/wire/bytes.hpp"
#include "simpletrack/wire/encode.hpp"
#include "simpletrack/wire/messages.hpp"

namespace simpletrack::wire {

namespace detail {

using Obj = msgpack::object;
namespace mt = msgpack::type;

// Thrown inside a decoder at the first failing check, caught at its boundary.
struct Reject {
  Reason reason;
  std::optional<std::string> field;
  std::string detail;
};

[[noreturn]] inline void reject(Reason reason, std::optional<std::string> field,
                                std::string detail) {
  truncate_utf8(detail, 300);  // a detail is for people; a huge one only costs bandwidth
  if (field && field->empty()) field.reset();  // an unknown key "" names no field, as in Python
  throw Reject{reason, std::move(field), std::move(detail)};
}

inline std::string_view text_of(const Obj& o) {
  return {o.via.str.ptr, o.via.str.size};
}
inline std::string_view bytes_of(const Obj& o) {
  return {o.via.bin.ptr, o.via.bin.size};
}

// The name Python gives the decoded value's type (the reference decoder's details use it).
inline const char* type_name(const Obj& o) {
  switch (o.type) {
    case mt::NIL:
      return "NoneType";
    case mt::BOOLEAN:
      return "bool";
    case mt::POSITIVE_INTEGER:
    case mt::NEGATIVE_INTEGER:
      return "int";
    case mt::FLOAT32:
    case mt::FLOAT64:
      return "float";
    case mt::STR:
      return "str";
    case mt::BIN:
      return "bytes";
    case mt::ARRAY:
      return "list";
    case mt::MAP:
      return "dict";
    default:
      return "ExtType";
  }
}

// The reference decoder (Python's msgpack, strict) refuses the whole payload for a container
// nested 1024 deep, a str that is not UTF-8, a map key that is neither str nor bin, and a
// timestamp extension (type -1) it cannot read: all `malformed`, wherever they sit.
inline constexpr std::size_t kMaxDepth = 1024;

inline void check_timestamp(const Obj& o) {
  const std::size_t n = o.via.ext.size;
  const auto* p = reinterpret_cast<const unsigned char*>(o.via.ext.data());
  auto be32 = [](const unsigned char* q) {
    return (std::uint32_t{q[0]} << 24) | (std::uint32_t{q[1]} << 16) | (std::uint32_t{q[2]} << 8) |
           std::uint32_t{q[3]};
  };
  if (n == 4) return;
  if (n == 8) {
    if ((be32(p) >> 2) > 999999999U)
      reject(Reason::malformed, "payload", "not msgpack: timestamp nanoseconds over 999999999");
    return;
  }
  if (n == 12) {
    if (be32(p) > 999999999U)
      reject(Reason::malformed, "payload", "not msgpack: timestamp nanoseconds over 999999999");
    return;
  }
  reject(Reason::malformed, "payload",
         "not msgpack: invalid timestamp data (length " + std::to_string(n) + ")");
}

inline void check_tree(const Obj& o, std::size_t depth) {
  switch (o.type) {
    case mt::STR:
      if (!utf8_length(text_of(o)))
        reject(Reason::malformed, "payload", "not msgpack: a str is not UTF-8");
      return;
    case mt::EXT:
      if (o.via.ext.type() == -1) check_timestamp(o);
      return;
    case mt::ARRAY:
      if (depth >= kMaxDepth) reject(Reason::malformed, "payload", "not msgpack: nested too deep");
      for (std::uint32_t i = 0; i < o.via.array.size; ++i)
        check_tree(o.via.array.ptr[i], depth + 1);
      return;
    case mt::MAP:
      if (depth >= kMaxDepth) reject(Reason::malformed, "payload", "not msgpack: nested too deep");
      for (std::uint32_t i = 0; i < o.via.map.size; ++i) {
        const Obj& key = o.via.map.ptr[i].key;
        if (key.type != mt::STR && key.type != mt::BIN) {
          reject(Reason::malformed, "payload",
                 std::string("not msgpack: ") + type_name(key) + " is not allowed for map key");
        }
        check_tree(key, depth + 1);
        check_tree(o.via.map.ptr[i].val, depth + 1);
      }
      return;
    default:
      return;
  }
}

// Strings and bins point into the payload instead of being copied: the payload outlives the
// unpacked tree, which lives only inside a decoder.
inline bool reference_all(mt::object_type, std::size_t, void*) {
  return true;
}

inline msgpack::object_handle unpack(const void* data, std::size_t size,
                                     const DecodeLimits& limits) {
  if (size > limits.max_bytes) {
    reject(Reason::too_large, "payload",
           std::to_string(size) + " bytes exceeds the cap of " + std::to_string(limits.max_bytes));
  }
  // As Python's msgpack.unpackb: no container or string longer than the payload could hold,
  // so a forged length cannot make the unpacker allocate gigabytes.
  const msgpack::unpack_limit limit(size, size / 2, size, size, size, kMaxDepth + 1);
  std::size_t offset = 0;
  msgpack::object_handle handle;
  try {
    handle = msgpack::unpack(static_cast<const char*>(data), size, offset, reference_all, nullptr,
                             limit);
  } catch (const std::bad_alloc&) {
    throw;
  } catch (const std::exception& e) {
    reject(Reason::malformed, "payload", std::string("not msgpack: ") + e.what());
  }
  if (offset != size) {
    reject(Reason::malformed, "payload",
           "not msgpack: " + std::to_string(size - offset) + " trailing bytes");
  }
  check_tree(handle.get(), 0);
  if (handle.get().type != mt::MAP) {
    reject(Reason::malformed, "payload",
           std::string("expected a map, got ") + type_name(handle.get()));
  }
  return handle;
}

// One msgpack map as the reference decoder sees it: a repeated key keeps its first place
// and its last value, as a Python dict built from the pairs would.
class Fields {
 public:
  Fields(const Obj& map, std::string prefix) : prefix_(std::move(prefix)) {
    const auto& m = map.via.map;
    entries_.reserve(m.size);
    std::unordered_map<std::string_view, std::size_t> index[2];  // str keys, bin keys
    for (std::uint32_t i = 0; i < m.size; ++i) {
      const Obj& key = m.ptr[i].key;
      const bool bin = key.type == mt::BIN;
      const std::string_view name = bin ? bytes_of(key) : text_of(key);
      const auto [it, fresh] = index[bin].emplace(name, entries_.size());
      if (fresh) {
        entries_.push_back({bin, name, &m.ptr[i].val});
      } else {
        entries_[it->second].value = &m.ptr[i].val;
      }
    }
  }

  const Obj* get(std::string_view name) const {
    for (const auto& e : entries_) {
      if (!e.bin && e.name == name) return e.value;
    }
    return nullptr;
  }

  std::string path(std::string_view name) const { return prefix_ + std::string(name); }

  // Then unknown keys, in the map's order (a bin key is `invalid_value`).
  void refuse_unknown(std::initializer_list<std::string_view> names) const {
    for (const auto& e : entries_) {
      if (e.bin) reject(Reason::invalid_value, path(bytes_repr(e.name)), "Keys should be strings");
      bool known = false;
      for (const auto n : names) known = known || n == e.name;
      if (!known) reject(Reason::extra_field, path(e.name), "Extra inputs are not permitted");
    }
  }

 private:
  struct Entry {
    bool bin;
    std::string_view name;
    const Obj* value;
  };
  std::string prefix_;
  std::vector<Entry> entries_;
};

// --- one check per kind of field (simpletrack/wire/fields.py) -------------------------------

inline const Obj& required(const Fields& m, std::string_view name) {
  const Obj* v = m.get(name);
  if (!v) reject(Reason::missing_field, m.path(name), "Field required");
  return *v;
}

inline const Obj* optional(const Fields& m, std::string_view name) {
  const Obj* v = m.get(name);
  return v && v->type != mt::NIL ? v : nullptr;
}

inline std::uint64_t int_value(const Obj& v, const std::string& path, std::uint64_t hi) {
  if (v.type == mt::NEGATIVE_INTEGER) {
    reject(Reason::invalid_value, path, "Input should be greater than or equal to 0");
  }
  if (v.type != mt::POSITIVE_INTEGER)
    reject(Reason::wrong_type, path, "Input should be a valid integer");
  if (v.via.u64 > hi) {
    reject(Reason::invalid_value, path,
           "Input should be less than or equal to " + std::to_string(hi));
  }
  return v.via.u64;
}

inline std::uint64_t int64_field(const Fields& m, std::string_view name) {
  return int_value(required(m, name), m.path(name), kInt64Max);
}

inline std::optional<std::uint64_t> optional_int64_field(const Fields& m, std::string_view name) {
  const Obj* v = optional(m, name);
  if (!v) return std::nullopt;
  return int_value(*v, m.path(name), kInt64Max);
}

inline std::string_view str_value(const Obj& v, const std::string& path) {
  if (v.type != mt::STR) reject(Reason::wrong_type, path, "Input should be a valid string");
  return text_of(v);
}

// An enumeration's value (a string, or UTF-8 bytes, naming one of `names`); anything else is
// `invalid_value` listing the names as pydantic does.
template <class E, std::size_t N>
E enum_value(const Obj& v, const std::array<std::string_view, N>& names, const std::string& path) {
  std::optional<E> e;
  if (v.type == mt::STR) e = parse_name<E>(names, text_of(v));
  if (v.type == mt::BIN && utf8_length(bytes_of(v))) e = parse_name<E>(names, bytes_of(v));
  if (e) return *e;
  std::string expected;
  for (std::size_t i = 0; i < N; ++i) {
    expected += (i == 0 ? "'" : i + 1 == N ? " or '" : ", '");
    expected += std::string(names[i]) + "'";
  }
  reject(Reason::invalid_value, path, "Input should be " + expected);
}

inline std::string text_value(const Obj& v, const std::string& path, std::size_t lo,
                              std::size_t hi) {
  const std::string_view s = str_value(v, path);
  const std::size_t n = *utf8_length(s);  // the whole payload was checked to be UTF-8
  if (n < lo) {
    reject(Reason::invalid_value, path,
           "String should have at least " + std::to_string(lo) +
               (lo == 1 ? " character" : " characters"));
  }
  if (n > hi) {
    reject(Reason::invalid_value, path,
           "String should have at most " + std::to_string(hi) +
               (hi == 1 ? " character" : " characters"));
  }
  return std::string(s);
}

inline std::string name_field(const Fields& m, std::string_view name) {
  const std::string path = m.path(name);
  const std::string_view s = str_value(required(m, name), path);
  if (!is_name(s)) {
    reject(Reason::invalid_value, path,
           "String should match pattern '^[A-Za-z0-9_][A-Za-z0-9_.\\-]{0,63}$'");
  }
  return std::string(s);
}

inline bool bool_value(const Obj& v, const std::string& path) {
  if (v.type != mt::BOOLEAN) reject(Reason::wrong_type, path, "Input should be a valid boolean");
  return v.via.boolean;
}

inline void check_list(const Obj& v, const std::string& path, std::size_t max_items) {
  if (v.type != mt::ARRAY) reject(Reason::wrong_type, path, "Input should be a valid list");
  if (v.via.array.size > max_items) {
    reject(Reason::invalid_value, path,
           "List should have at most " + std::to_string(max_items) +
               " items after validation, not " + std::to_string(v.via.array.size));
  }
}

// A 4x4 transform's field (`pose`, `extrinsic`): nil or absent, else a list of 16 numbers.
inline std::optional<Pose> transform_field(const Fields& m, std::string_view name) {
  const Obj* v = optional(m, name);
  if (!v) return std::nullopt;
  const std::string path = m.path(name);
  check_list(*v, path, 16);
  Pose pose{};
  const auto& a = v->via.array;
  for (std::uint32_t i = 0; i < a.size; ++i) {
    const Obj& x = a.ptr[i];
    switch (x.type) {
      case mt::FLOAT32:
      case mt::FLOAT64:
        pose[i] = x.via.f64;
        break;
      case mt::POSITIVE_INTEGER:
        pose[i] = static_cast<double>(x.via.u64);
        break;
      case mt::NEGATIVE_INTEGER:
        pose[i] = static_cast<double>(x.via.i64);
        break;
      default:
        reject(Reason::wrong_type, path + "." + std::to_string(i),
               "Input should be a valid number");
    }
  }
  if (a.size < 16) {
    reject(Reason::invalid_value, path,
           "List should have at least 16 items after validation, not " + std::to_string(a.size));
  }
  return pose;
}

inline std::optional<Pose> pose_field(const Fields& m) {
  return transform_field(m, "pose");
}

inline std::vector<std::string> classes_field(const Fields& m) {
  const std::string path = m.path("classes");
  const Obj& v = required(m, "classes");
  check_list(v, path, kMaxClasses);
  std::vector<std::string> out;
  out.reserve(v.via.array.size);
  for (std::uint32_t i = 0; i < v.via.array.size; ++i) {
    out.push_back(text_value(v.via.array.ptr[i], path + "." + std::to_string(i), 1, 64));
  }
  return out;
}

inline std::string_view bin_value(const Obj& v, const std::string& path) {
  if (v.type != mt::BIN) reject(Reason::wrong_type, path, "Input should be a valid bytes");
  return bytes_of(v);
}

inline const Obj& map_field(const Fields& m, std::string_view name, std::string_view model) {
  const Obj& v = required(m, name);
  if (v.type != mt::MAP) {
    reject(Reason::wrong_type, m.path(name),
           "Input should be a valid dictionary or instance of " + std::string(model));
  }
  return v;
}

// --- columns ---------------------------------------------------------------------------------

template <class T>
bool finite(T v) {
  if constexpr (std::is_floating_point_v<T>) {
    return std::isfinite(v);
  } else {
    return true;
  }
}

// A column's bin is read once its field checks passed; its length and finiteness are checked
// here, column by column in table order (length, then NaN/inf, then the next column).
template <class T, std::size_t K>
std::vector<std::array<T, K>> rows_of(std::string_view buf, std::size_t count,
                                      const std::string& path) {
  const std::uint64_t row_bytes = sizeof(T) * K;
  if (buf.size() != std::uint64_t{count} * row_bytes) {
    reject(Reason::column_length, path,
           std::to_string(buf.size()) + " bytes, expected count " + std::to_string(count) + " x " +
               std::to_string(row_bytes) + " bytes");
  }
  std::vector<std::array<T, K>> rows(count);
  const auto* p = reinterpret_cast<const unsigned char*>(buf.data());
  for (std::size_t i = 0; i < count; ++i) {
    for (std::size_t k = 0; k < K; ++k, p += sizeof(T)) rows[i][k] = read_le<T>(p);
  }
  for (std::size_t i = 0; i < count; ++i) {
    for (const T v : rows[i]) {
      if (!finite(v)) reject(Reason::non_finite, path, "NaN or inf in row " + std::to_string(i));
    }
  }
  return rows;
}

template <class T>
std::vector<T> values_of(std::string_view buf, std::size_t count, const std::string& path) {
  std::vector<T> out;
  out.reserve(count);
  for (const auto& row : rows_of<T, 1>(buf, count, path)) out.push_back(row[0]);
  return out;
}

// Step 9: rows are values (yaw) or arrays of values (center, size, velocity).
template <class T>
void check_bound(const std::vector<T>& rows, double bound, const std::string& path,
                 const char* unit) {
  auto over = [bound](double v) { return std::fabs(v) > bound; };
  for (std::size_t i = 0; i < rows.size(); ++i) {
    bool bad = false;
    if constexpr (std::is_arithmetic_v<T>) {
      bad = over(static_cast<double>(rows[i]));
    } else {
      for (const auto v : rows[i]) bad = bad || over(static_cast<double>(v));
    }
    if (bad) {
      reject(Reason::invalid_value, path,
             "|value| over " + format_g(bound) + " " + unit + " in row " + std::to_string(i));
    }
  }
}

// Step 10: a pose (or an extrinsic, named by `field`) must be finite, a rigid transform, and
// translate within the bounds.
inline void check_pose(const Pose& p, const std::string& field = "pose") {
  for (const double v : p) {
    if (!std::isfinite(v)) reject(Reason::non_finite, field, "NaN or inf in the " + field);
  }
  double err =
      std::max({std::fabs(p[12]), std::fabs(p[13]), std::fabs(p[14]), std::fabs(p[15] - 1.0)});
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      double dot = 0;  // (R R^T)[i][j]
      for (int k = 0; k < 3; ++k) dot += p[4 * i + k] * p[4 * j + k];
      err = std::max(err, std::fabs(dot - (i == j ? 1.0 : 0.0)));
    }
  }
  const double det = p[0] * (p[5] * p[10] - p[6] * p[9]) - p[1] * (p[4] * p[10] - p[6] * p[8]) +
                     p[2] * (p[4] * p[9] - p[5] * p[8]);
  if (!(err <= kPoseTolerance) || !(det > 0)) {
    reject(Reason::invalid_value, field, "not a rigid transform (row-major 4x4)");
  }
  if (std::max({std::fabs(p[3]), std::fabs(p[7]), std::fabs(p[11])}) > kMaxCoordinateM) {
    reject(Reason::invalid_value, field, "translation over " + format_g(kMaxCoordinateM) + " m");
  }
}

// The version read, one of [lo, hi] (every message but TrackFrame: just kSchemaVersion).
inline int check_version(const Fields& top, int lo = kSchemaVersion, int hi = kSchemaVersion) {
  const Obj* v = top.get("schema_version");
  if (!v) reject(Reason::missing_field, "schema_version", "field required");
  if (v->type != mt::POSITIVE_INTEGER && v->type != mt::NEGATIVE_INTEGER) {
    reject(Reason::wrong_type, "schema_version", "must be an integer");
  }
  if (v->type == mt::NEGATIVE_INTEGER || v->via.u64 < static_cast<std::uint64_t>(lo) ||
      v->via.u64 > static_cast<std::uint64_t>(hi)) {
    const std::string shown =
        v->type == mt::NEGATIVE_INTEGER ? std::to_string(v->via.i64) : std::to_string(v->via.u64);
    std::string speaks = std::to_string(lo);
    for (int k = lo + 1; k <= hi; ++k) speaks += ", " + std::to_string(k);
    reject(Reason::wrong_version, "schema_version",
           "version " + shown + " not supported (this service speaks " + speaks + ")");
  }
  return static_cast<int>(v->via.u64);
}

// seq and stamp_ns of a refused frame, when its map could be read and they are in range.
struct Peek {
  std::optional<std::uint64_t> seq, stamp_ns;
};

inline std::optional<std::uint64_t> peek_int(const Fields& top, std::string_view name) {
  const Obj* v = top.get(name);
  if (v && v->type == mt::POSITIVE_INTEGER && v->via.u64 <= kInt64Max) return v->via.u64;
  return std::nullopt;
}

struct Header {
  std::string vehicle, sensor;
  std::uint64_t seq, stamp_ns;
  std::string frame_id;
  std::optional<Pose> pose;
  bool key_frame;
};

// The fields DetectionFrame and TrackFrame share, in their table order.
inline Header header_fields(const Fields& top) {
  Header h;
  h.vehicle = name_field(top, "vehicle");
  h.sensor = name_field(top, "sensor");
  h.seq = int64_field(top, "seq");
  h.stamp_ns = int64_field(top, "stamp_ns");
  h.frame_id = text_value(required(top, "frame_id"), "frame_id", 1, 128);
  h.pose = pose_field(top);
  const Obj* kf = top.get("key_frame");
  h.key_frame = kf ? bool_value(*kf, "key_frame") : true;
  return h;
}

// Which columns a `tracks` map holds: a TrackFrame's of version 1 or 2, or a vehicle's.
enum class Layout { v1, v2, vehicle };

// A `tracks` map once its fields passed: the bins, read into columns by read_tracks.
struct TrackBins {
  std::size_t count = 0;
  std::vector<std::string> classes;
  std::string_view columns[11];
  bool has_covariance = false;
  std::string_view covariance, age_s, time_since_update_s, existence, sensor_stamp_ns;
};

// The `tracks` map's fields in table order, then its unknown keys.
inline TrackBins track_bins(const Fields& tracks, Layout layout) {
  static constexpr std::string_view kColumns[] = {
      "id",   "class_index", "center",           "size", "yaw", "score", "velocity", "state",
      "hits", "age",         "time_since_update"};
  TrackBins b;
  b.count = int_value(required(tracks, "count"), "tracks.count", kInt32Max);
  b.classes = classes_field(tracks);
  for (std::size_t i = 0; i < std::size(kColumns); ++i) {
    b.columns[i] = bin_value(required(tracks, kColumns[i]), tracks.path(kColumns[i]));
  }
  // Version 2's columns, checked after version 1's as the field table orders them.
  if (layout != Layout::v1) {
    if (const Obj* c = optional(tracks, "covariance")) {
      b.has_covariance = true;
      b.covariance = bin_value(*c, "tracks.covariance");
    }
    b.age_s = bin_value(required(tracks, "age_s"), "tracks.age_s");
    b.time_since_update_s =
        bin_value(required(tracks, "time_since_update_s"), "tracks.time_since_update_s");
  }
  if (layout == Layout::vehicle) {
    b.existence = bin_value(required(tracks, "existence"), "tracks.existence");
    b.sensor_stamp_ns = bin_value(required(tracks, "sensor_stamp_ns"), "tracks.sensor_stamp_ns");
  }
  switch (layout) {
    case Layout::v1:
      tracks.refuse_unknown({"count", "classes", "id", "class_index", "center", "size", "yaw",
                             "score", "velocity", "state", "hits", "age", "time_since_update"});
      break;
    case Layout::v2:
      tracks.refuse_unknown({"count", "classes", "id", "class_index", "center", "size", "yaw",
                             "score", "velocity", "state", "hits", "age", "time_since_update",
                             "covariance", "age_s", "time_since_update_s"});
      break;
    case Layout::vehicle:
      tracks.refuse_unknown({"count", "classes", "id", "class_index", "center", "size", "yaw",
                             "score", "velocity", "state", "hits", "age", "time_since_update",
                             "covariance", "age_s", "time_since_update_s", "existence",
                             "sensor_stamp_ns"});
      break;
  }
  return b;
}

// The row cap, then each column's length and finiteness in table order; a vehicle's
// sensor_stamp_ns holds `sensors` values per row.
inline TrackColumns read_tracks(const TrackBins& b, Layout layout, const DecodeLimits& limits,
                                std::size_t sensors) {
  const std::size_t count = b.count;
  if (count > limits.max_boxes) {
    reject(Reason::too_large, "tracks.count",
           std::to_string(count) + " rows exceeds the cap of " + std::to_string(limits.max_boxes));
  }
  TrackColumns t;
  t.classes = b.classes;
  t.id = values_of<std::int64_t>(b.columns[0], count, "tracks.id");
  t.class_index = values_of<std::int32_t>(b.columns[1], count, "tracks.class_index");
  t.center = rows_of<float, 3>(b.columns[2], count, "tracks.center");
  t.size = rows_of<float, 3>(b.columns[3], count, "tracks.size");
  t.yaw = values_of<float>(b.columns[4], count, "tracks.yaw");
  t.score = values_of<double>(b.columns[5], count, "tracks.score");
  t.velocity = rows_of<float, 3>(b.columns[6], count, "tracks.velocity");
  t.state = values_of<std::int32_t>(b.columns[7], count, "tracks.state");
  t.hits = values_of<std::int32_t>(b.columns[8], count, "tracks.hits");
  t.age = values_of<std::int32_t>(b.columns[9], count, "tracks.age");
  t.time_since_update = values_of<std::int32_t>(b.columns[10], count, "tracks.time_since_update");
  if (b.has_covariance) t.covariance = rows_of<float, 21>(b.covariance, count, "tracks.covariance");
  if (layout != Layout::v1) {
    t.age_s = values_of<double>(b.age_s, count, "tracks.age_s");
    t.time_since_update_s =
        values_of<double>(b.time_since_update_s, count, "tracks.time_since_update_s");
  }
  if (layout == Layout::vehicle) {
    t.existence = values_of<double>(b.existence, count, "tracks.existence");
    // count is capped and sensors at most 64: the product cannot overflow.
    const auto flat =
        values_of<std::int64_t>(b.sensor_stamp_ns, count * sensors, "tracks.sensor_stamp_ns");
    t.sensor_stamp_ns.emplace(count);
    for (std::size_t i = 0; i < count; ++i) {
      const auto row = flat.begin() + static_cast<std::ptrdiff_t>(i * sensors);
      (*t.sensor_stamp_ns)[i].assign(row, row + static_cast<std::ptrdiff_t>(sensors));
    }
  }
  return t;
}

inline Rejection internal_error(const char* what) {
  std::string detail = std::string("decoder bug: ") + what;
  truncate_utf8(detail, 300);
  return Rejection{Reason::internal_error, std::nullopt, detail, std::nullopt, std::nullopt};
}

}  // namespace detail

// Decode and validate a DetectionFrame (all eleven steps of the README's validation order).
// `accepted_classes`, when given, lists the class names the receiver tracks or ignores: a box
// of any other class is `unknown_class` (step 11), as the service would report it.
inline Result<DetectionFrame> decode_detection_frame(
    const void* data, std::size_t size, const DecodeLimits& limits = {},
    const std::vector<std::string>* accepted_classes = nullptr) {
  using namespace detail;
  Peek peek;
  try {
    const msgpack::object_handle handle = unpack(data, size, limits);
    const Fields top(handle.get(), "");
    peek = {peek_int(top, "seq"), peek_int(top, "stamp_ns")};
    const int version = check_version(top, kSchemaVersion, kDetectionSchemaVersion);
    DetectionFrame f;
    f.schema_version = version;
    Header h = header_fields(top);
    f.vehicle = std::move(h.vehicle), f.sensor = std::move(h.sensor);
    f.seq = h.seq, f.stamp_ns = h.stamp_ns, f.frame_id = std::move(h.frame_id);
    f.pose = h.pose, f.key_frame = h.key_frame;
    f.session_id = optional_int64_field(top, "session_id");

    const Fields boxes(map_field(top, "boxes", "BoxColumns"), "boxes.");
    const std::size_t count = int_value(required(boxes, "count"), "boxes.count", kInt32Max);
    BoxColumns& b = f.boxes;
    b.classes = classes_field(boxes);
    const auto class_index = bin_value(required(boxes, "class_index"), "boxes.class_index");
    const auto center = bin_value(required(boxes, "center"), "boxes.center");
    const auto size_ = bin_value(required(boxes, "size"), "boxes.size");
    const auto yaw = bin_value(required(boxes, "yaw"), "boxes.yaw");
    const auto score = bin_value(required(boxes, "score"), "boxes.score");
    const Obj* velocity = optional(boxes, "velocity");
    const std::string_view velocity_bin = velocity ? bin_value(*velocity, "boxes.velocity") : "";
    boxes.refuse_unknown(
        {"count", "classes", "class_index", "center", "size", "yaw", "score", "velocity"});
    if (version == 2) {
      f.extrinsic = transform_field(top, "extrinsic");
      top.refuse_unknown({"schema_version", "vehicle", "sensor", "seq", "stamp_ns", "frame_id",
                          "pose", "key_frame", "session_id", "boxes", "extrinsic"});
    } else {  // then an extrinsic is an unknown key, as to a version-1 reader
      top.refuse_unknown({"schema_version", "vehicle", "sensor", "seq", "stamp_ns", "frame_id",
                          "pose", "key_frame", "session_id", "boxes"});
    }

    if (count > limits.max_boxes) {
      reject(
          Reason::too_large, "boxes.count",
          std::to_string(count) + " rows exceeds the cap of " + std::to_string(limits.max_boxes));
    }
    b.class_index = values_of<std::int32_t>(class_index, count, "boxes.class_index");
    b.center = rows_of<float, 3>(center, count, "boxes.center");
    b.size = rows_of<float, 3>(size_, count, "boxes.size");
    b.yaw = values_of<float>(yaw, count, "boxes.yaw");
    b.score = values_of<double>(score, count, "boxes.score");
    if (velocity) b.velocity = rows_of<float, 2>(velocity_bin, count, "boxes.velocity");

    for (const std::int32_t i : b.class_index) {
      if (i < 0 || static_cast<std::size_t>(i) >= b.classes.size()) {
        reject(Reason::invalid_value, "boxes.class_index",
               "index outside the class table of " + std::to_string(b.classes.size()) + " entries");
      }
    }
    for (std::size_t i = 0; i < count; ++i) {
      for (const float v : b.size[i]) {
        if (!(v > 0))
          reject(Reason::non_positive_size, "boxes.size", "size <= 0 in row " + std::to_string(i));
      }
    }
    check_bound(b.center, kMaxCoordinateM, "boxes.center", "m");
    check_bound(b.size, kMaxSizeM, "boxes.size", "m");
    check_bound(b.yaw, kMaxYawRad, "boxes.yaw", "rad");
    if (b.velocity) check_bound(*b.velocity, kMaxSpeedMps, "boxes.velocity", "m/s");
    if (f.pose) check_pose(*f.pose);
    if (f.extrinsic) check_pose(*f.extrinsic, "extrinsic");

    if (accepted_classes) {
      for (const std::int32_t i : b.class_index) {
        const std::string& name = b.classes[static_cast<std::size_t>(i)];
        bool known = false;
        for (const auto& a : *accepted_classes) known = known || a == name;
        if (!known) {
          std::string listed;
          for (const auto& a : *accepted_classes) listed += (listed.empty() ? "" : ", ") + a;
          reject(Reason::unknown_class, "boxes.classes." + std::to_string(i),
                 "class '" + name + "' is not tracked here; known: " + listed);
        }
      }
    }
    return f;
  } catch (const Reject& r) {
    return Rejection{r.reason, r.field, r.detail, peek.seq, peek.stamp_ns};
  } catch (const std::exception& e) {
    return internal_error(e.what());
  }
}

// Decode a TrackFrame: its fields, then each column's length and finiteness.
inline Result<TrackFrame> decode_track_frame(const void* data, std::size_t size,
                                             const DecodeLimits& limits = {}) {
  using namespace detail;
  Peek peek;
  try {
    const msgpack::object_handle handle = unpack(data, size, limits);
    const Fields top(handle.get(), "");
    peek = {peek_int(top, "seq"), peek_int(top, "stamp_ns")};
    const int version = check_version(top, 1, kTrackEpochSchemaVersion);
    TrackFrame f;
    f.schema_version = version;
    Header h = header_fields(top);
    f.vehicle = std::move(h.vehicle), f.sensor = std::move(h.sensor);
    f.seq = h.seq, f.stamp_ns = h.stamp_ns, f.frame_id = std::move(h.frame_id);
    f.pose = h.pose, f.key_frame = h.key_frame;
    f.instance = name_field(top, "instance");
    f.received_ns = int64_field(top, "received_ns");
    f.published_ns = int64_field(top, "published_ns");

    const Layout layout = version == 1 ? Layout::v1 : Layout::v2;
    const Fields tracks(map_field(top, "tracks", "TrackColumns"), "tracks.");
    const TrackBins bins = track_bins(tracks, layout);
    if (version >= kTrackEpochSchemaVersion) {
      f.epoch = optional_int64_field(top, "epoch");
      top.refuse_unknown({"schema_version", "vehicle", "sensor", "seq", "stamp_ns", "frame_id",
                          "pose", "key_frame", "instance", "received_ns", "published_ns", "tracks",
                          "epoch"});
    } else {  // then an epoch is an unknown key, as to a reader of that version
      top.refuse_unknown({"schema_version", "vehicle", "sensor", "seq", "stamp_ns", "frame_id",
                          "pose", "key_frame", "instance", "received_ns", "published_ns",
                          "tracks"});
    }
    f.tracks = read_tracks(bins, layout, limits, 0);
    return f;
  } catch (const Reject& r) {
    return Rejection{r.reason, r.field, r.detail, peek.seq, peek.stamp_ns};
  } catch (const std::exception& e) {
    return internal_error(e.what());
  }
}

// Decode a FrameError. A reason this library does not know is `invalid_value` (field
// `reason`): a newer service's notice is refused rather than misread.
inline Result<FrameError> decode_frame_error(const void* data, std::size_t size,
                                             const DecodeLimits& limits = {}) {
  using namespace detail;
  try {
    const msgpack::object_handle handle = unpack(data, size, limits);
    const Fields top(handle.get(), "");
    check_version(top);
    FrameError e;
    e.vehicle = name_field(top, "vehicle");
    e.sensor = name_field(top, "sensor");
    e.seq = optional_int64_field(top, "seq");
    e.stamp_ns = optional_int64_field(top, "stamp_ns");
    e.reason = enum_value<Reason>(required(top, "reason"), kReasonNames, "reason");
    if (const Obj* field = optional(top, "field")) e.field = text_value(*field, "field", 0, 256);
    e.detail = text_value(required(top, "detail"), "detail", 0, 1024);
    e.instance = name_field(top, "instance");
    e.received_ns = int64_field(top, "received_ns");
    if (const Obj* seqs = optional(top, "seqs")) {
      check_list(*seqs, "seqs", kMaxNoticeSeqs);
      e.seqs.emplace();
      for (std::uint32_t i = 0; i < seqs->via.array.size; ++i) {
        const Obj& s = seqs->via.array.ptr[i];
        if (s.type == mt::NIL) {
          e.seqs->push_back(std::nullopt);
        } else {
          e.seqs->push_back(int_value(s, "seqs." + std::to_string(i), kInt64Max));
        }
      }
    }
    top.refuse_unknown({"schema_version", "vehicle", "sensor", "seq", "stamp_ns", "reason", "field",
                        "detail", "instance", "received_ns", "seqs"});
    return e;
  } catch (const Reject& r) {
    return Rejection{r.reason, r.field, r.detail, std::nullopt, std::nullopt};
  } catch (const std::exception& e) {
    return internal_error(e.what());
  }
}

// The same decoders over a byte vector or string.
inline Result<DetectionFrame> decode_detection_frame(
    const std::vector<std::uint8_t>& payload, const DecodeLimits& limits = {},
    const std::vector<std::string>* accepted_classes = nullptr) {
  return decode_detection_frame(payload.data(), payload.size(), limits, accepted_classes);
}
inline Result<TrackFrame> decode_track_frame(const std::vector<std::uint8_t>& payload,
                                             const DecodeLimits& limits = {}) {
  return decode_track_frame(payload.data(), payload.size(), limits);
}
inline Result<FrameError> decode_frame_error(const std::vector<std::uint8_t>& payload,
                                             const DecodeLimits& limits = {}) {
  return decode_frame_error(payload.data(), payload.size(), limits);
}

// Everything the service checks of a frame that this side can check: nullopt when the frame
// would be accepted (unknown_class only when `accepted_classes` is given). A frame that
// cannot even be encoded throws EncodeError, as encode() does.
inline std::optional<Rejection> validate(
    const DetectionFrame& frame, const DecodeLimits& limits = {},
    const std::vector<std::string>* accepted_classes = nullptr) {
  auto decoded = decode_detection_frame(encode(frame), limits, accepted_classes);
  if (decoded) return std::nullopt;
  return decoded.error();
}

}  // namespace simpletrack::wire
