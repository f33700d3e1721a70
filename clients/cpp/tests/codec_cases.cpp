// Cases the golden vectors do not show: the byte layout of columns, what the encoder refuses,
// and the decoder's corners (repeated and bin keys, bad UTF-8 anywhere, nesting, poses,
// class tables, caps). tests/native/test_cpp_codec.py also holds the decoder to the
// Python decoder's verdicts on thousands of mutated payloads.
#include <simpletrack/wire.hpp>

#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "check.hpp"

namespace wire = simpletrack::wire;
using Bytes = std::vector<std::uint8_t>;
using Packer = msgpack::packer<msgpack::sbuffer>;

namespace {

wire::DetectionFrame two_boxes() {
  wire::DetectionFrame f;
  f.vehicle = "veh-1";
  f.sensor = "lidar";
  f.seq = 42;
  f.stamp_ns = 1'700'000'000'000'000'000ULL;
  f.frame_id = "base_link";
  f.boxes.classes = {"Car", "Pedestrian"};
  f.boxes.class_index = {0, 1};
  f.boxes.center = {{1.0f, -2.0f, 0.5f}, {3.0f, 4.0f, 0.5f}};
  f.boxes.size = {{4.5f, 1.9f, 1.6f}, {0.8f, 0.7f, 1.8f}};
  f.boxes.yaw = {0.25f, -1.5f};
  f.boxes.score = {0.9, 0.7};
  return f;
}

// A valid frame's map with `extra_entries` more key/value pairs written by `extra`.
Bytes frame_with(int extra_entries, const std::function<void(Packer&)>& extra) {
  const Bytes base = wire::encode(two_boxes());
  msgpack::sbuffer sb;
  Packer pk(sb);
  // The encoder writes a fixmap; keep its entries and append ours after them.
  const std::uint8_t n = static_cast<std::uint8_t>((base[0] & 0x0f) + extra_entries);
  pk.pack_map(n);
  sb.write(reinterpret_cast<const char*>(base.data()) + 1, base.size() - 1);
  extra(pk);
  return Bytes(sb.data(), sb.data() + sb.size());
}

void key(Packer& pk, const std::string& k) {
  const auto n = static_cast<std::uint32_t>(k.size());
  pk.pack_str(n).pack_str_body(k.data(), n);
}

wire::Rejection refusal(const Bytes& b, const std::vector<std::string>* accepted = nullptr) {
  auto r = wire::decode_detection_frame(b, {}, accepted);
  if (r)
    return wire::Rejection{wire::Reason::internal_error, std::string("<accepted>"), "", {}, {}};
  return r.error();
}

bool is(const wire::Rejection& r, wire::Reason reason, const std::optional<std::string>& field) {
  return r.reason == reason && r.field == field;
}

std::string got(const wire::Rejection& r) {
  return "got " + r.message();
}

// The bin of `column` in the encoded boxes map (found by its key; the bin follows it).
Bytes column_bytes(const Bytes& frame, const std::string& column) {
  const std::string needle = std::string(1, static_cast<char>(0xa0 | column.size())) + column;
  const std::string s(frame.begin(), frame.end());
  const auto at = s.find(needle);
  if (at == std::string::npos) return {};
  const std::size_t bin = at + needle.size();
  const std::size_t len = frame[bin + 1];  // bin 8: 0xc4, one length byte
  return Bytes(frame.begin() + static_cast<long>(bin + 2),
               frame.begin() + static_cast<long>(bin + 2 + len));
}

void columns_are_little_endian() {
  wire::DetectionFrame f = two_boxes();
  f.boxes.class_index = {0, -1};  // two's complement on the wire, refused by the decoder
  f.boxes.center[0] = {1.0f, -2.0f, 0.5f};
  const Bytes b = wire::encode(f);
  CHECK(column_bytes(b, "class_index") == (Bytes{0, 0, 0, 0, 0xff, 0xff, 0xff, 0xff}));
  const Bytes center = column_bytes(b, "center");
  CHECK(center.size() == 24);
  CHECK(Bytes(center.begin(), center.begin() + 12) ==
        (Bytes{0x00, 0x00, 0x80, 0x3f, 0x00, 0x00, 0x00, 0xc0, 0x00, 0x00, 0x00, 0x3f}));
  const Bytes score = column_bytes(b, "score");  // 0.9 = 0x3FECCCCCCCCCCCCD
  CHECK(Bytes(score.begin(), score.begin() + 8) ==
        (Bytes{0xcd, 0xcc, 0xcc, 0xcc, 0xcc, 0xcc, 0xec, 0x3f}));
  CHECK_MSG(is(refusal(b), wire::Reason::invalid_value, "boxes.class_index"), got(refusal(b)));
}

void round_trip_with_every_optional_field() {
  wire::DetectionFrame f = two_boxes();
  f.pose = wire::Pose{0, -1, 0, 100, 1, 0, 0, -50, 0, 0, 1, 2, 0, 0, 0, 1};
  f.key_frame = false;
  f.session_id = 9'000'000'000ULL;
  f.boxes.velocity = std::vector<wire::Vec2f>{{5.0f, 0.0f}, {-1.0f, 0.5f}};
  const auto back = wire::decode_detection_frame(wire::encode(f));
  CHECK_MSG(back.ok(), back.ok() ? "" : back.error().message());
  CHECK(back.ok() && back.value() == f);
  CHECK(!wire::validate(f));

  wire::FrameError e;
  e.vehicle = "veh-1", e.sensor = "lidar", e.reason = wire::Reason::dropped_queue_full;
  e.detail = "shed", e.instance = "simpletrack-a", e.received_ns = 5;
  e.seqs = std::vector<std::optional<std::uint64_t>>{3, std::nullopt, 5};
  const auto err = wire::decode_frame_error(wire::encode(e));
  CHECK(err.ok() && err.value() == e);
}

template <class F>
std::string encode_error(F mutate) {
  wire::DetectionFrame f = two_boxes();
  mutate(f);
  try {
    wire::encode(f);
  } catch (const wire::EncodeError& e) {
    return e.what();
  }
  return "<encoded>";
}

bool starts(const std::string& s, const std::string& prefix) {
  return s.rfind(prefix, 0) == 0;
}

void encoder_refuses_what_decoders_refuse() {
  std::string m = encode_error([](auto& f) { f.vehicle = "veh/1"; });
  CHECK_MSG(starts(m, "DetectionFrame.vehicle: "), m);
  m = encode_error([](auto& f) { f.boxes.yaw.pop_back(); });
  CHECK_MSG(m == "DetectionFrame.boxes.yaw: 1 rows, expected 2", m);
  m = encode_error([](auto& f) { f.boxes.velocity = std::vector<wire::Vec2f>(3); });
  CHECK_MSG(starts(m, "DetectionFrame.boxes.velocity: "), m);
  m = encode_error([](auto& f) { f.boxes.classes.push_back(""); });
  CHECK_MSG(starts(m, "DetectionFrame.boxes.classes.2: "), m);
  m = encode_error([](auto& f) { f.boxes.classes.assign(1025, "Car"); });
  CHECK_MSG(starts(m, "DetectionFrame.boxes.classes: "), m);
  m = encode_error([](auto& f) { f.frame_id = ""; });
  CHECK_MSG(starts(m, "DetectionFrame.frame_id: "), m);
  m = encode_error([](auto& f) { f.frame_id = "\xff"; });
  CHECK_MSG(m == "DetectionFrame.frame_id: not UTF-8", m);
  m = encode_error([](auto& f) { f.seq = wire::kInt64Max + 1; });
  CHECK_MSG(starts(m, "DetectionFrame.seq: "), m);
}

void map_corners() {
  // A repeated key keeps its last value (a Python dict built from the pairs).
  auto r = wire::decode_detection_frame(frame_with(1, [](Packer& pk) {
    key(pk, "seq");
    pk.pack_uint64(43);
  }));
  CHECK(r.ok() && r.value().seq == 43);
  Bytes b = frame_with(1, [](Packer& pk) {
    key(pk, "seq");
    pk.pack_int64(-1);
  });
  CHECK_MSG(is(refusal(b), wire::Reason::invalid_value, "seq"), got(refusal(b)));
  CHECK(!refusal(b).seq && refusal(b).stamp_ns == 1'700'000'000'000'000'000ULL);
  // A bin key is named as the reference decoder names it.
  b = frame_with(1, [](Packer& pk) {
    pk.pack_bin(5).pack_bin_body("speed", 5);
    pk.pack_nil();
  });
  CHECK_MSG(is(refusal(b), wire::Reason::invalid_value, "b'speed'"), got(refusal(b)));
  CHECK(refusal(b).seq == 42u);
  // Bad UTF-8 or an int key anywhere, even in a value nobody reads, spoils the payload.
  b = frame_with(1, [](Packer& pk) {
    key(pk, "note");
    pk.pack_str(2).pack_str_body("\xed\xa0", 2);
  });
  CHECK_MSG(is(refusal(b), wire::Reason::malformed, "payload"), got(refusal(b)));
  CHECK(!refusal(b).seq);
  b = frame_with(1, [](Packer& pk) {
    key(pk, "note");
    pk.pack_map(1).pack_uint8(1).pack_nil();
  });
  CHECK_MSG(is(refusal(b), wire::Reason::malformed, "payload"), got(refusal(b)));
  b = wire::encode(two_boxes());
  b.push_back(0xc0);
  CHECK_MSG(is(refusal(b), wire::Reason::malformed, "payload"), got(refusal(b)));
  b = Bytes{0x93, 0x01, 0x02, 0x03};
  CHECK_MSG(is(refusal(b), wire::Reason::malformed, "payload"), got(refusal(b)));
  CHECK_MSG(is(refusal(Bytes{}), wire::Reason::malformed, "payload"), got(refusal(Bytes{})));
}

void nesting_limit() {
  // 1023 nested lists under the map still decode (then: an unknown key); 1024 do not.
  for (const int depth : {1023, 1024}) {
    const Bytes b = frame_with(1, [depth](Packer& pk) {
      key(pk, "deep");
      for (int i = 0; i < depth; ++i) pk.pack_array(1);
      pk.pack_nil();
    });
    const auto want = depth == 1023 ? wire::Reason::extra_field : wire::Reason::malformed;
    CHECK_MSG(refusal(b).reason == want, std::to_string(depth) + ": " + got(refusal(b)));
  }
}

void pose_checks() {
  auto with_pose = [](wire::Pose p) {
    wire::DetectionFrame f = two_boxes();
    f.pose = p;
    return wire::encode(f);
  };
  const wire::Pose eye{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  auto r = wire::decode_detection_frame(with_pose(eye));
  CHECK(r.ok());
  wire::Pose p = eye;
  p[10] = -1;  // a reflection
  CHECK_MSG(is(refusal(with_pose(p)), wire::Reason::invalid_value, "pose"),
            got(refusal(with_pose(p))));
  p = eye;
  p[3] = 2e5;
  CHECK_MSG(is(refusal(with_pose(p)), wire::Reason::invalid_value, "pose"),
            got(refusal(with_pose(p))));
  p = eye;
  p[5] = std::numeric_limits<double>::quiet_NaN();
  CHECK_MSG(is(refusal(with_pose(p)), wire::Reason::non_finite, "pose"),
            got(refusal(with_pose(p))));
  // float32 and int entries are numbers too (msgpack-c++ packs the integral ones as ints).
  const float c = 0.6f, s = 0.8f;
  const float rot[16] = {c, -s, 0, 0.5f, s, c, 0, -0.25f, 0, 0, 1, 2, 0, 0, 0, 1};
  Bytes b = frame_with(1, [&rot](Packer& pk) {
    key(pk, "pose");
    pk.pack_array(16);
    for (const float v : rot) pk.pack_float(v);
  });
  r = wire::decode_detection_frame(b);
  CHECK_MSG(r.ok(), got(refusal(b)));
  CHECK(r.ok() && r.value().pose->at(0) == static_cast<double>(c) && r.value().pose->at(15) == 1.0);
  b = frame_with(1, [](Packer& pk) {
    key(pk, "pose");
    pk.pack_array(15);
    for (int i = 0; i < 15; ++i) pk.pack_double(0.5);
  });
  CHECK_MSG(is(refusal(b), wire::Reason::invalid_value, "pose"), got(refusal(b)));
  b = frame_with(1, [](Packer& pk) {
    key(pk, "pose");
    pk.pack_array(16);
    for (int i = 0; i < 16; ++i)
      i == 4 ? pk.pack_str(1).pack_str_body("x", 1) : pk.pack_double(0.5);
  });
  CHECK_MSG(is(refusal(b), wire::Reason::wrong_type, "pose.4"), got(refusal(b)));
}

void class_tables() {
  const std::vector<std::string> cars_only{"Car"};
  Bytes b = wire::encode(two_boxes());
  CHECK_MSG(is(refusal(b, &cars_only), wire::Reason::unknown_class, "boxes.classes.1"),
            got(refusal(b, &cars_only)));
  wire::DetectionFrame f = two_boxes();
  f.boxes.class_index = {0, 0};  // Pedestrian is in the table but no box uses it
  CHECK(wire::decode_detection_frame(wire::encode(f), {}, &cars_only).ok());
  CHECK(!wire::validate(f, {}, &cars_only));
  f = two_boxes();
  f.boxes.size[1][2] = 0.0f;
  CHECK_MSG(is(*wire::validate(f), wire::Reason::non_positive_size, "boxes.size"),
            got(*wire::validate(f)));
  f = two_boxes();
  f.boxes.yaw[0] = 2e4f;
  CHECK_MSG(is(*wire::validate(f), wire::Reason::invalid_value, "boxes.yaw"),
            got(*wire::validate(f)));
  f = two_boxes();
  f.boxes.velocity = std::vector<wire::Vec2f>{{0, 0}, {0, std::numeric_limits<float>::infinity()}};
  CHECK_MSG(is(*wire::validate(f), wire::Reason::non_finite, "boxes.velocity"),
            got(*wire::validate(f)));
}

void caps() {
  const Bytes b = wire::encode(two_boxes());
  auto r = wire::decode_detection_frame(b, wire::DecodeLimits{b.size() - 1, 10000});
  CHECK(!r.ok() && is(r.error(), wire::Reason::too_large, "payload"));
  r = wire::decode_detection_frame(b, wire::DecodeLimits{1 << 20, 1});
  CHECK(!r.ok() && is(r.error(), wire::Reason::too_large, "boxes.count"));
}

void frame_errors() {
  wire::FrameError e;
  e.vehicle = "veh-1", e.sensor = "lidar", e.reason = wire::Reason::missed;
  e.detail = "3 frames", e.instance = "simpletrack-a", e.received_ns = 5;
  Bytes b = wire::encode(e);
  // A reason from a newer service is refused, not misread.
  const std::string missed =
      "\xa6"
      "missed";
  std::string s(b.begin(), b.end());
  s.replace(s.find(missed), missed.size(),
            "\xa6"
            "future");
  const auto r = wire::decode_frame_error(Bytes(s.begin(), s.end()));
  CHECK(!r.ok() && is(r.error(), wire::Reason::invalid_value, "reason"));
  // A Result holds one or the other, loudly.
  bool threw = false;
  try {
    (void)r.value();
  } catch (const std::logic_error&) {
    threw = true;
  }
  CHECK(threw);
}

wire::TrackFrame two_tracks() {
  wire::TrackFrame f;
  f.vehicle = "veh-1", f.sensor = "lidar", f.seq = 3, f.stamp_ns = 9, f.frame_id = "world";
  f.instance = "svc", f.received_ns = 10, f.published_ns = 11;
  wire::TrackColumns& t = f.tracks;
  t.classes = {"Car"};
  t.id = {7, std::int64_t{1} << 40};
  t.class_index = {0, 0};
  t.center = {{1.0f, 2.0f, 0.5f}, {3.0f, 4.0f, 0.5f}};
  t.size = {{4.0f, 2.0f, 1.5f}, {4.0f, 2.0f, 1.5f}};
  t.yaw = {0.0f, 0.5f};
  t.score = {0.9, 0.5};
  t.velocity = {{0.0f, 0.0f, 0.0f}, {1.0f, 0.0f, 0.0f}};
  t.state = {1, 0}, t.hits = {3, 1}, t.age = {4, 0}, t.time_since_update = {0, 0};
  return f;
}

void track_versions() {
  wire::TrackFrame v1 = two_tracks();
  const auto d1 = wire::decode_track_frame(wire::encode(v1));  // no ages: version 1
  CHECK(d1.ok() && d1.value().schema_version == 1 && !d1.value().tracks.age_s);
  wire::TrackFrame v2 = two_tracks();
  std::array<float, 21> upper{};
  for (std::size_t i = 0; i < upper.size(); ++i) upper[i] = static_cast<float>(i);
  v2.tracks.covariance = std::vector<std::array<float, 21>>{upper, upper};
  v2.tracks.age_s = std::vector<double>{0.4, 12.5};
  v2.tracks.time_since_update_s = std::vector<double>{0.0, 0.1};
  const Bytes b2 = wire::encode(v2);
  const auto d2 = wire::decode_track_frame(b2);
  CHECK(d2.ok() && d2.value().schema_version == 2);
  if (d2.ok()) {
    CHECK(d2.value().tracks.covariance == v2.tracks.covariance);
    CHECK(d2.value().tracks.age_s == v2.tracks.age_s);
    CHECK(wire::encode(d2.value()) == b2);
  }
  // Asked for version 1, the encoder leaves version 2's columns out.
  v2.schema_version = 1;
  const auto back = wire::decode_track_frame(wire::encode(v2));
  CHECK(back.ok() && !back.value().tracks.covariance && !back.value().tracks.age_s);
  // Version 2 needs its ages; no version 4.
  wire::TrackFrame bad = two_tracks();
  bad.schema_version = 2;
  bool threw = false;
  try {
    (void)wire::encode(bad);
  } catch (const wire::EncodeError&) {
    threw = true;
  }
  CHECK(threw);
  wire::TrackFrame v4 = v2;
  v4.schema_version = 4;
  threw = false;
  try {
    (void)wire::encode(v4);
  } catch (const wire::EncodeError&) {
    threw = true;
  }
  CHECK(threw);
  // The custody epoch: version 3 with the ages; an earlier version leaves it out.
  wire::TrackFrame v3 = v2;
  v3.schema_version.reset();
  v3.epoch = std::uint64_t{1} << 40;
  const Bytes b3 = wire::encode(v3);
  const auto d3 = wire::decode_track_frame(b3);
  CHECK(d3.ok() && d3.value().schema_version == 3 && d3.value().epoch == v3.epoch);
  CHECK(d3.ok() && wire::encode(d3.value()) == b3);
  wire::TrackFrame pinned = v3;
  pinned.schema_version = 2;
  wire::TrackFrame plain = v3;
  plain.schema_version = 2, plain.epoch.reset();
  CHECK(wire::encode(pinned) == wire::encode(plain));
  const auto d2e = wire::decode_track_frame(wire::encode(pinned));
  CHECK(d2e.ok() && !d2e.value().epoch);
  wire::TrackFrame huge = v3;
  huge.epoch = std::uint64_t{1} << 63;
  threw = false;
  try {
    (void)wire::encode(huge);
  } catch (const wire::EncodeError&) {
    threw = true;
  }
  CHECK(threw);
  CHECK(wire::covariance_at(upper, 0, 5) == 5.0f && wire::covariance_at(upper, 1, 1) == 6.0f);
  CHECK(wire::covariance_at(upper, 4, 1) == 9.0f && wire::covariance_at(upper, 5, 5) == 20.0f);
  CHECK(v1.global_id(1) == "veh-1/lidar/1099511627776");
}

void epoch_filter() {
  simpletrack::EpochFilter f;
  const std::string k = "fleet/car-1/lidar/tracks";
  CHECK(f.accept(k, std::nullopt) && !f.highest(k));  // a service of before epochs
  CHECK(f.accept(k, 1) && f.accept(k, 2));
  CHECK(!f.accept(k, 1));  // the fenced holder, late
  CHECK(f.accept(k, 2));   // equal: the repeat rule decides
  CHECK(f.accept(k, std::nullopt) && f.highest(k) == std::optional<std::uint64_t>(2));
  CHECK(!f.accept(k, 0));
  CHECK(f.accept("fleet/car-1/@vehicle/tracks", 0));  // each stream on its own
  for (std::size_t i = 0; i < simpletrack::EpochFilter::kMaxKeys; ++i) {
    (void)f.accept(std::to_string(i), 5);
  }
  CHECK(f.size() <= simpletrack::EpochFilter::kMaxKeys);
  CHECK(!f.highest(k) && f.accept(k, 1));  // forgotten: bounded memory
}

}  // namespace

int main() {
  columns_are_little_endian();
  round_trip_with_every_optional_field();
  encoder_refuses_what_decoders_refuse();
  map_corners();
  nesting_limit();
  pose_checks();
  class_tables();
  caps();
  frame_errors();
  track_versions();
  epoch_filter();
  return check::summary("codec_cases");
}
