// Encoders: a message as the msgpack map that travels, keys in the reference encoder's order
// (simpletrack.wire.codec), so that re-encoding a golden vector gives it back byte for byte.
// A message the decoders would refuse by its structure throws EncodeError; its values
// (finite, positive sizes, bounds, a rigid pose) are the decoders' business: validate() runs
// the full check on an encoded frame.
#pragma once

#ifndef MSGPACK_NO_BOOST
#define MSGPACK_NO_BOOST
#endif
#include <msgpack.hpp>

#include <array>
#include <cstdint>
#include <cstring>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "simpletrack/wire/bytes.hpp"
#include "simpletrack/wire/messages.hpp"

namespace simpletrack::wire {

namespace detail {

// msgpack-c++'s packer writes through any object with write(const char*, size_t).
struct VectorStream {
  std::vector<std::uint8_t>* out;
  void write(const char* p, std::size_t n) { out->insert(out->end(), p, p + n); }
};

class Writer {
 public:
  Writer() : stream_{&bytes_}, pk_(stream_) {}

  Writer& map(std::size_t n) {
    pk_.pack_map(static_cast<std::uint32_t>(n));
    return *this;
  }
  Writer& array(std::size_t n) {
    pk_.pack_array(static_cast<std::uint32_t>(n));
    return *this;
  }
  Writer& nil() {
    pk_.pack_nil();
    return *this;
  }
  Writer& boolean(bool v) {
    v ? pk_.pack_true() : pk_.pack_false();
    return *this;
  }
  Writer& uint(std::uint64_t v) {  // the shortest form, as Python's msgpack writes it
    pk_.pack_uint64(v);
    return *this;
  }
  Writer& str(std::string_view s) {
    pk_.pack_str(static_cast<std::uint32_t>(s.size()));
    pk_.pack_str_body(s.data(), static_cast<std::uint32_t>(s.size()));
    return *this;
  }
  Writer& key(std::string_view s) { return str(s); }
  // Always `float 64`: msgpack-c++ 4 packs a double holding an integer (a pose's 0.0, 1.0) as
  // an int, which decoders accept but which would not re-encode the golden vectors exactly.
  Writer& f64(double v) {
    std::uint64_t bits;
    std::memcpy(&bits, &v, sizeof bits);
    bytes_.push_back(0xcb);
    for (int shift = 56; shift >= 0; shift -= 8) {
      bytes_.push_back(static_cast<std::uint8_t>(bits >> shift));
    }
    return *this;
  }
  Writer& bin(const std::vector<std::uint8_t>& b) {
    pk_.pack_bin(static_cast<std::uint32_t>(b.size()));
    pk_.pack_bin_body(reinterpret_cast<const char*>(b.data()),
                      static_cast<std::uint32_t>(b.size()));
    return *this;
  }
  template <class T>
  Writer& column(const std::vector<T>& rows) {
    std::vector<std::uint8_t> b;
    b.reserve(rows.size() * sizeof(T));
    for (const T& v : rows) append_le(b, v);
    return bin(b);
  }
  template <class T, std::size_t K>
  Writer& column(const std::vector<std::array<T, K>>& rows) {
    std::vector<std::uint8_t> b;
    b.reserve(rows.size() * sizeof(T) * K);
    for (const auto& row : rows) {
      for (const T& v : row) append_le(b, v);
    }
    return bin(b);
  }
  Writer& pose(const std::optional<Pose>& p) {
    if (!p) return nil();
    array(16);
    for (double v : *p) f64(v);
    return *this;
  }
  Writer& classes(const std::vector<std::string>& names) {
    array(names.size());
    for (const auto& n : names) str(n);
    return *this;
  }
  std::vector<std::uint8_t> take() { return std::move(bytes_); }

 private:
  std::vector<std::uint8_t> bytes_;
  VectorStream stream_;
  msgpack::packer<VectorStream> pk_;
};

[[noreturn]] inline void refuse(std::string_view where, const std::string& why) {
  throw EncodeError(std::string(where) + ": " + why);
}

inline void check_name(std::string_view where, const std::string& v) {
  if (!is_name(v)) refuse(where, "'" + v + "' does not match ^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}$");
}

inline void check_int64(std::string_view where, std::uint64_t v) {
  if (v > kInt64Max) refuse(where, std::to_string(v) + " is over 2^63-1");
}

inline void check_text(std::string_view where, const std::string& v, std::size_t lo,
                       std::size_t hi) {
  const auto n = utf8_length(v);
  if (!n) refuse(where, "not UTF-8");
  if (*n < lo || *n > hi) {
    refuse(where, std::to_string(*n) + " characters, expected " + std::to_string(lo) + " to " +
                      std::to_string(hi));
  }
}

inline void check_classes(std::string_view where, const std::vector<std::string>& classes) {
  if (classes.size() > kMaxClasses) {
    refuse(where, std::to_string(classes.size()) + " names, at most 1024");
  }
  for (std::size_t i = 0; i < classes.size(); ++i) {
    check_text(std::string(where) + "." + std::to_string(i), classes[i], 1, 64);
  }
}

template <class Column>
void check_rows(std::string_view where, const Column& column, std::size_t count) {
  if (column.size() != count) {
    refuse(where, std::to_string(column.size()) + " rows, expected " + std::to_string(count));
  }
}

inline void check_header(std::string_view message, const std::string& vehicle,
                         const std::string& sensor, std::uint64_t seq, std::uint64_t stamp_ns,
                         const std::string& frame_id) {
  const std::string m(message);
  check_name(m + ".vehicle", vehicle);
  check_name(m + ".sensor", sensor);
  check_int64(m + ".seq", seq);
  check_int64(m + ".stamp_ns", stamp_ns);
  check_text(m + ".frame_id", frame_id, 1, 128);
}

}  // namespace detail

inline std::vector<std::uint8_t> encode(const DetectionFrame& f) {
  using namespace detail;
  const BoxColumns& b = f.boxes;
  const std::size_t n = b.count();
  check_header("DetectionFrame", f.vehicle, f.sensor, f.seq, f.stamp_ns, f.frame_id);
  if (f.session_id) check_int64("DetectionFrame.session_id", *f.session_id);
  if (n > kInt32Max) refuse("DetectionFrame.boxes.count", std::to_string(n) + " is over 2^31-1");
  check_classes("DetectionFrame.boxes.classes", b.classes);
  check_rows("DetectionFrame.boxes.center", b.center, n);
  check_rows("DetectionFrame.boxes.size", b.size, n);
  check_rows("DetectionFrame.boxes.yaw", b.yaw, n);
  check_rows("DetectionFrame.boxes.score", b.score, n);
  if (b.velocity) check_rows("DetectionFrame.boxes.velocity", *b.velocity, n);
  const int version = f.version();
  if (version != 1 && version != 2) {
    refuse("DetectionFrame.schema_version", std::to_string(version) + " is not one of 1, 2");
  }
  if (version == 1 && f.extrinsic) {
    refuse("DetectionFrame.extrinsic", "a version 1 DetectionFrame has no extrinsic");
  }

  Writer w;
  // The reference encoder puts the optional pose, session_id and extrinsic after boxes.
  w.map(8 + (f.pose ? 1 : 0) + (f.session_id ? 1 : 0) + (f.extrinsic ? 1 : 0));
  w.key("schema_version").uint(static_cast<std::uint64_t>(version));
  w.key("vehicle").str(f.vehicle);
  w.key("sensor").str(f.sensor);
  w.key("seq").uint(f.seq);
  w.key("stamp_ns").uint(f.stamp_ns);
  w.key("frame_id").str(f.frame_id);
  w.key("key_frame").boolean(f.key_frame);
  w.key("boxes");
  w.map(7 + (b.velocity ? 1 : 0));
  w.key("count").uint(n);
  w.key("classes").classes(b.classes);
  w.key("class_index").column(b.class_index);
  w.key("center").column(b.center);
  w.key("size").column(b.size);
  w.key("yaw").column(b.yaw);
  w.key("score").column(b.score);
  if (b.velocity) w.key("velocity").column(*b.velocity);
  if (f.pose) w.key("pose").pose(f.pose);
  if (f.session_id) w.key("session_id").uint(*f.session_id);
  if (f.extrinsic) w.key("extrinsic").pose(f.extrinsic);
  return w.take();
}

namespace detail {

// The row counts of a `tracks` map built in memory (version 2's columns when `v2`), each named
// `<message>.tracks.<column>` in a refusal.
inline void check_track_columns(const std::string& message, const TrackColumns& t, bool v2) {
  const std::size_t n = t.count();
  const std::string m = message + ".tracks.";
  if (n > kInt32Max) refuse(m + "count", std::to_string(n) + " is over 2^31-1");
  check_classes(m + "classes", t.classes);
  check_rows(m + "class_index", t.class_index, n);
  check_rows(m + "center", t.center, n);
  check_rows(m + "size", t.size, n);
  check_rows(m + "yaw", t.yaw, n);
  check_rows(m + "score", t.score, n);
  check_rows(m + "velocity", t.velocity, n);
  check_rows(m + "state", t.state, n);
  check_rows(m + "hits", t.hits, n);
  check_rows(m + "age", t.age, n);
  check_rows(m + "time_since_update", t.time_since_update, n);
  if (!v2) return;
  if (!t.age_s || !t.time_since_update_s) refuse(m + "age_s", "version 2 columns need both ages");
  check_rows(m + "age_s", *t.age_s, n);
  check_rows(m + "time_since_update_s", *t.time_since_update_s, n);
  if (t.covariance) check_rows(m + "covariance", *t.covariance, n);
}

// The columns of a `tracks` map in the reference encoder's order, after a map header for them
// and `extra` more entries the caller writes: version 1's, then version 2's when `v2`
// (covariance only when present).
inline void write_track_columns(Writer& w, const TrackColumns& t, bool v2, std::size_t extra) {
  w.map(13 + (v2 ? (t.covariance ? 3 : 2) : 0) + extra);
  w.key("count").uint(t.count());
  w.key("classes").classes(t.classes);
  w.key("id").column(t.id);
  w.key("class_index").column(t.class_index);
  w.key("center").column(t.center);
  w.key("size").column(t.size);
  w.key("yaw").column(t.yaw);
  w.key("score").column(t.score);
  w.key("velocity").column(t.velocity);
  w.key("state").column(t.state);
  w.key("hits").column(t.hits);
  w.key("age").column(t.age);
  w.key("time_since_update").column(t.time_since_update);
  if (v2) {  // version 1 leaves them out: the bytes a version-1 reader takes
    if (t.covariance) w.key("covariance").column(*t.covariance);
    w.key("age_s").column(*t.age_s);
    w.key("time_since_update_s").column(*t.time_since_update_s);
  }
}

}  // namespace detail

// A sensor's TrackFrame; a vehicle's columns (existence, sensor_stamp_ns) are not part of it
// and are left out.
inline std::vector<std::uint8_t> encode(const TrackFrame& f) {
  using namespace detail;
  const TrackColumns& t = f.tracks;
  check_header("TrackFrame", f.vehicle, f.sensor, f.seq, f.stamp_ns, f.frame_id);
  check_name("TrackFrame.instance", f.instance);
  check_int64("TrackFrame.received_ns", f.received_ns);
  check_int64("TrackFrame.published_ns", f.published_ns);
  const bool has_ages = t.age_s && t.time_since_update_s;
  const int newest = f.epoch ? kTrackEpochSchemaVersion : kTrackSchemaVersion;
  const int version = f.schema_version.value_or(has_ages ? newest : 1);
  if (version < 1 || version > kTrackEpochSchemaVersion) {
    refuse("TrackFrame.schema_version", std::to_string(version) + " is not one of 1, 2, 3");
  }
  if (version >= 2 && !has_ages) {
    refuse("TrackFrame.tracks.age_s",
           "a version " + std::to_string(version) + " TrackFrame needs both ages");
  }
  check_track_columns("TrackFrame", t, version >= 2);
  if (f.epoch) check_int64("TrackFrame.epoch", *f.epoch);
  // An earlier version has no such field: left out, the bytes a reader of that version takes.
  const bool with_epoch = f.epoch && version >= kTrackEpochSchemaVersion;

  Writer w;
  w.map(12 + (with_epoch ? 1 : 0));
  w.key("schema_version").uint(static_cast<std::uint64_t>(version));
  w.key("vehicle").str(f.vehicle);
  w.key("sensor").str(f.sensor);
  w.key("seq").uint(f.seq);
  w.key("stamp_ns").uint(f.stamp_ns);
  w.key("frame_id").str(f.frame_id);
  w.key("pose").pose(f.pose);
  w.key("key_frame").boolean(f.key_frame);
  w.key("instance").str(f.instance);
  w.key("received_ns").uint(f.received_ns);
  w.key("published_ns").uint(f.published_ns);
  w.key("tracks");
  write_track_columns(w, t, version >= 2, 0);
  if (with_epoch) w.key("epoch").uint(*f.epoch);
  return w.take();
}

inline std::vector<std::uint8_t> encode(const FrameError& e) {
  using namespace detail;
  check_name("FrameError.vehicle", e.vehicle);
  check_name("FrameError.sensor", e.sensor);
  if (e.seq) check_int64("FrameError.seq", *e.seq);
  if (e.stamp_ns) check_int64("FrameError.stamp_ns", *e.stamp_ns);
  if (e.field) check_text("FrameError.field", *e.field, 0, 256);
  check_text("FrameError.detail", e.detail, 0, 1024);
  check_name("FrameError.instance", e.instance);
  check_int64("FrameError.received_ns", e.received_ns);
  if (e.seqs) {
    if (e.seqs->size() > kMaxNoticeSeqs) {
      refuse("FrameError.seqs", std::to_string(e.seqs->size()) + " items, at most 1024");
    }
    for (std::size_t i = 0; i < e.seqs->size(); ++i) {
      if ((*e.seqs)[i]) check_int64("FrameError.seqs." + std::to_string(i), *(*e.seqs)[i]);
    }
  }

  Writer w;
  // seqs is left out when absent, so that every other notice stays byte for byte as before.
  w.map(10 + (e.seqs ? 1 : 0));
  w.key("schema_version").uint(kSchemaVersion);
  w.key("vehicle").str(e.vehicle);
  w.key("sensor").str(e.sensor);
  w.key("seq");
  e.seq ? w.uint(*e.seq) : w.nil();
  w.key("stamp_ns");
  e.stamp_ns ? w.uint(*e.stamp_ns) : w.nil();
  w.key("reason").str(to_string(e.reason));
  w.key("field");
  e.field ? w.str(*e.field) : w.nil();
  w.key("detail").str(e.detail);
  w.key("instance").str(e.instance);
  w.key("received_ns").uint(e.received_ns);
  if (e.seqs) {
    w.key("seqs");
    w.array(e.seqs->size());
    for (const auto& s : *e.seqs) s ? w.uint(*s) : w.nil();
  }
  return w.take();
}

}  // namespace simpletrack::wire
