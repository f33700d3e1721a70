// Vehicle fusion on the wire: a detection frame's extrinsic (DetectionFrame version 2), a
// vehicle's fused tracks (VehicleTrackFrame) and the reasons that come with them.
#include <simpletrack/wire.hpp>

#include <cstdint>
#include <cstring>
#include <functional>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "check.hpp"

namespace wire = simpletrack::wire;
using Bytes = std::vector<std::uint8_t>;

namespace {

const wire::Pose kRear{-1, 0, 0, -3.5, 0, -1, 0, 0, 0, 0, 1, 0.5, 0, 0, 0, 1};

wire::DetectionFrame radar_frame() {
  wire::DetectionFrame f;
  f.vehicle = "veh-1", f.sensor = "radar", f.seq = 3, f.frame_id = "radar";
  f.stamp_ns = 1'700'000'000'000'000'000ULL;
  f.boxes.classes = {"Car"};
  f.boxes.class_index = {0};
  f.boxes.center = {{1.0f, 2.0f, 0.5f}};
  f.boxes.size = {{4.0f, 2.0f, 1.5f}};
  f.boxes.yaw = {0.1f};
  f.boxes.score = {0.9};
  return f;
}

// A msgpack map re-packed with one entry's value replaced (or added) by `write`.
Bytes with_entry(const Bytes& payload, const std::string& key,
                 const std::function<void(msgpack::packer<msgpack::sbuffer>&)>& write,
                 const std::string& inside = "") {
  const msgpack::object_handle h =
      msgpack::unpack(reinterpret_cast<const char*>(payload.data()), payload.size());
  msgpack::sbuffer sb;
  msgpack::packer<msgpack::sbuffer> pk(sb);
  std::function<void(const msgpack::object&, bool)> copy = [&](const msgpack::object& m,
                                                               bool target) {
    const auto& map = m.via.map;
    bool present = false;
    for (std::uint32_t i = 0; i < map.size; ++i) {
      present = present || (target && map.ptr[i].key.as<std::string>() == key);
    }
    pk.pack_map(map.size + (target && !present ? 1 : 0));
    for (std::uint32_t i = 0; i < map.size; ++i) {
      const std::string k = map.ptr[i].key.as<std::string>();
      pk.pack(k);
      if (target && k == key) {
        write(pk);
      } else if (!inside.empty() && !target && k == inside) {
        copy(map.ptr[i].val, true);
      } else {
        pk.pack(map.ptr[i].val);
      }
    }
    if (target && !present) {
      pk.pack(key);
      write(pk);
    }
  };
  copy(h.get(), inside.empty());
  return Bytes(sb.data(), sb.data() + sb.size());
}

void an_extrinsic_makes_version_2() {
  wire::DetectionFrame f = radar_frame();
  CHECK(wire::encode(f)[16] == 1);  // schema_version, right after its key
  f.extrinsic = kRear;
  const Bytes b = wire::encode(f);
  CHECK(b[16] == 2);
  const auto back = wire::decode_detection_frame(b);
  CHECK_MSG(back.ok(), back.ok() ? "" : back.error().message());
  CHECK(back.ok() && back.value() == f && back.value().schema_version == 2);
  CHECK(back.ok() && wire::encode(back.value()) == b);

  // An extrinsic under version 1 is an unknown key, as to a version-1 reader.
  const Bytes v1 = with_entry(b, "schema_version", [](auto& pk) { pk.pack(1); });
  const auto r1 = wire::decode_detection_frame(v1);
  CHECK(!r1.ok() && r1.error().reason == wire::Reason::extra_field &&
        r1.error().field == std::string("extrinsic"));
  wire::Pose scaled = kRear;
  scaled[0] = -2;
  const Bytes bad = with_entry(b, "extrinsic", [&](auto& pk) {
    pk.pack_array(16);
    for (const double v : scaled) pk.pack_double(v);
  });
  const auto r2 = wire::decode_detection_frame(bad);
  CHECK(!r2.ok() && r2.error().reason == wire::Reason::invalid_value &&
        r2.error().field == std::string("extrinsic"));
  f.extrinsic = scaled;
  CHECK(wire::validate(f) && wire::validate(f)->field == std::string("extrinsic"));
  f.extrinsic = kRear;
  f.schema_version = 1;
  bool threw = false;
  try {
    (void)wire::encode(f);
  } catch (const wire::EncodeError&) {
    threw = true;
  }
  CHECK(threw);
}

wire::VehicleTrackFrame fused() {
  wire::VehicleTrackFrame f;
  f.vehicle = "veh-1", f.seq = 100, f.stamp_ns = 2000, f.sensor = "lidar", f.sensor_seq = 7;
  f.frame_id = "base_link", f.instance = "svc", f.received_ns = 3000, f.published_ns = 4000;
  f.sensors = {"lidar", "radar"};
  f.sensor_state = {wire::SensorCondition::ok, wire::SensorCondition::extrinsic};
  wire::TrackColumns& t = f.tracks;
  t.classes = {"Car"};
  t.id = {7, std::int64_t{1} << 40};
  t.class_index = {0, 0};
  t.center = {{1, 2, 0.5f}, {3, 4, 0.5f}};
  t.size = {{4, 2, 1.5f}, {4, 2, 1.5f}};
  t.yaw = {0, 0.5f};
  t.score = {0.9, 0.5};
  t.velocity = {{0, 0, 0}, {1, 0, 0}};
  t.state = {1, 0}, t.hits = {3, 1}, t.age = {4, 0}, t.time_since_update = {0, 0};
  t.age_s = std::vector<double>{0.4, 0.0};
  t.time_since_update_s = std::vector<double>{0.0, 0.0};
  t.existence = std::vector<double>{1.0, 0.25};
  t.sensor_stamp_ns = std::vector<std::vector<std::int64_t>>{{2000, 1950}, {2000, -1}};
  return f;
}

void a_vehicle_frame_round_trips() {
  const wire::VehicleTrackFrame f = fused();
  const Bytes b = wire::encode(f);
  const auto back = wire::decode_vehicle_track_frame(b);
  CHECK_MSG(back.ok(), back.ok() ? "" : back.error().message());
  CHECK(back.ok() && back.value() == f && wire::encode(back.value()) == b);
  CHECK(f.global_id(1) == "veh-1/@vehicle/1099511627776");
  CHECK(f.last_update_ns(0, "radar") == std::optional<std::uint64_t>(1950));
  CHECK(!f.last_update_ns(1, "radar") && !f.last_update_ns(0, "camera"));
  CHECK(!wire::validate_vehicle_tracks(f));
  CHECK(!wire::decode_track_frame(b).ok());  // not a sensor's TrackFrame
}

void a_vehicle_frame_is_walked_by_track_and_sensor() {
  const auto back = wire::decode_vehicle_track_frame(wire::encode(fused()));
  CHECK(back.ok());
  if (!back.ok()) return;
  const wire::VehicleTrackFrame& f = back.value();
  CHECK(f.count() == 2);
  CHECK(f.existence(0) == 1.0 && f.existence(1) == 0.25);
  using Contributors = std::vector<std::pair<std::string, std::uint64_t>>;
  CHECK(f.contributors(0) == (Contributors{{"lidar", 2000}, {"radar", 1950}}));
  CHECK(f.contributors(1) == (Contributors{{"lidar", 2000}}));
  CHECK(f.condition("radar") == wire::SensorCondition::extrinsic);
  CHECK(f.condition("lidar") == wire::SensorCondition::ok);
  CHECK(!f.condition("camera"));
  bool threw = false;
  try {
    (void)f.existence(2);
  } catch (const std::out_of_range&) {
    threw = true;
  }
  CHECK(threw);
}

// The cases of the Python StreamFilter's tests (tests/client/test_epoch_fencing.py).
void the_stream_filter_drops_repeats_and_fenced_holders() {
  using simpletrack::Verdict;
  const std::string k = "fleet/car-1/@vehicle/tracks";
  simpletrack::StreamFilter f;
  CHECK(f.admit(k, 0, 100, 1) == Verdict::deliver);
  CHECK(f.admit(k, 1, 200, 2) == Verdict::deliver);
  CHECK(f.admit(k, 2, 300, 1) == Verdict::stale);  // a fenced holder, whatever its seq
  CHECK(f.admit(k, 1, 200, 2) == Verdict::repeat);  // same epoch, same (seq, stamp)
  CHECK(f.admit(k, 1, 250, 2) == Verdict::deliver);  // same epoch, a new stamp
  CHECK(f.admit(k, 0, 900, 2) == Verdict::deliver);  // a rebooted vehicle's seq 0 again
  CHECK(f.stale() == 1 && f.repeats() == 1 && f.highest_epoch(k) == 2u);
  CHECK(f.admit("fleet/car-1/lidar/tracks", 1, 200, 1) == Verdict::deliver);  // its own stream

  simpletrack::StreamFilter n;  // no epoch: the repeat rule only, the highest kept
  CHECK(n.admit(k, 0, 100, std::nullopt) == Verdict::deliver && !n.highest_epoch(k));
  CHECK(n.admit(k, 1, 200, 6) == Verdict::deliver);
  CHECK(n.admit(k, 2, 300, std::nullopt) == Verdict::deliver);
  CHECK(n.admit(k, 2, 300, std::nullopt) == Verdict::repeat);
  CHECK(n.admit(k, 3, 400, 0) == Verdict::stale);  // epoch 0 is an epoch, lower than 6

  simpletrack::StreamFilter t;  // a new holder's repeat raises the epoch all the same
  CHECK(t.admit(k, 7, 700, 3) == Verdict::deliver);
  CHECK(t.admit(k, 7, 700, 4) == Verdict::repeat);
  CHECK(t.admit(k, 8, 800, 3) == Verdict::stale && t.highest_epoch(k) == 4u);

  // After a partition the taker replays from far back: each frame once all the same.
  simpletrack::StreamFilter p(4);
  bool all = true;
  for (std::uint64_t q = 0; q < 40; ++q) all = all && p.admit(k, q, q * 100, 1) == Verdict::deliver;
  CHECK(all);
  std::vector<Verdict> replay;
  for (std::uint64_t q = 10; q < 45; ++q) replay.push_back(p.admit(k, q, q * 100, 2));
  std::vector<Verdict> want(30, Verdict::repeat);
  want.insert(want.end(), 5, Verdict::deliver);
  CHECK(replay == want);
  CHECK(p.admit(k, 45, 4500, 1) == Verdict::stale);
  CHECK(p.admit(k, 0, 50, 2) == Verdict::deliver);  // caught up: a stamp going back is new

  // A fused vehicle's lidar and camera frames can share a stamp: two messages, 75 and 76.
  simpletrack::StreamFilter v;
  CHECK(v.admit(k, 74, 2900, 1) == Verdict::deliver && v.admit(k, 75, 3000, 1) == Verdict::deliver);
  CHECK(v.admit(k, 75, 3000, 2) == Verdict::repeat);
  CHECK(v.admit(k, 76, 3000, 2) == Verdict::deliver && v.admit(k, 77, 3067, 2) == Verdict::deliver);
  simpletrack::StreamFilter w(1);  // out of the window: by (stamp, seq)
  CHECK(w.admit(k, 75, 3000, 1) == Verdict::deliver && w.admit(k, 76, 3000, 1) == Verdict::deliver);
  CHECK(w.admit(k, 75, 3000, 2) == Verdict::repeat && w.admit(k, 76, 3000, 2) == Verdict::repeat);

  simpletrack::StreamFilter b(2, 2);  // bounded: a third stream forgets the first two
  CHECK(b.admit("a", 0, 0, 5) == Verdict::deliver && b.admit("b", 0, 0, 5) == Verdict::deliver);
  CHECK(b.admit("c", 0, 0, 5) == Verdict::deliver && !b.highest_epoch("a"));
  CHECK(b.admit("a", 1, 1, 1) == Verdict::deliver);
  CHECK(b.admit("c", 1, 1, 5) == Verdict::deliver && b.admit("c", 2, 2, 5) == Verdict::deliver);
  CHECK(b.admit("c", 0, 0, 5) == Verdict::deliver);  // out of the window of the 2 newest
}

wire::Rejection refusal(const Bytes& b) {
  const auto r = wire::decode_vehicle_track_frame(b);
  CHECK_MSG(!r.ok(), "accepted");
  return r.ok() ? wire::Rejection{} : r.error();
}

bool is(const wire::Rejection& r, wire::Reason reason, const std::string& field) {
  return r.reason == reason && r.field == field && r.seq == std::optional<std::uint64_t>(100);
}

template <class T>
void pack_column(msgpack::packer<msgpack::sbuffer>& pk, const std::vector<T>& values) {
  std::vector<std::uint8_t> bytes;
  for (const T v : values) wire::detail::append_le(bytes, v);
  pk.pack_bin(static_cast<std::uint32_t>(bytes.size()));
  pk.pack_bin_body(reinterpret_cast<const char*>(bytes.data()),
                   static_cast<std::uint32_t>(bytes.size()));
}

void a_vehicle_frame_breaking_its_rules_is_refused() {
  const Bytes b = wire::encode(fused());
  auto column = [&](const std::string& name, auto values) {
    return with_entry(b, name, [&](auto& pk) { pack_column(pk, values); }, "tracks");
  };
  auto top = [&](const std::string& name, std::vector<std::string> values) {
    return with_entry(b, name, [&](auto& pk) { pk.pack(values); });
  };
  CHECK(is(refusal(column("sensor_stamp_ns", std::vector<std::int64_t>{2000, 2000})),
           wire::Reason::column_length, "tracks.sensor_stamp_ns"));
  CHECK(is(refusal(column("existence", std::vector<double>{0.5, 1.5})), wire::Reason::invalid_value,
           "tracks.existence"));
  CHECK(is(refusal(column("sensor_stamp_ns", std::vector<std::int64_t>{2000, -2, 0, 0})),
           wire::Reason::invalid_value, "tracks.sensor_stamp_ns"));
  CHECK(is(refusal(top("sensors", {"lidar", "lidar"})), wire::Reason::invalid_value, "sensors"));
  CHECK(
      is(refusal(top("sensors", {"lidar", "@vehicle"})), wire::Reason::invalid_value, "sensors.1"));
  CHECK(is(refusal(top("sensor_state", {"ok"})), wire::Reason::invalid_value, "sensor_state"));
  CHECK(is(refusal(top("sensor_state", {"ok", "asleep"})), wire::Reason::invalid_value,
           "sensor_state.1"));
  CHECK(is(refusal(with_entry(b, "sensor", [](auto& pk) { pk.pack(std::string("camera")); })),
           wire::Reason::invalid_value, "sensor"));
  CHECK(is(refusal(with_entry(b, "schema_version", [](auto& pk) { pk.pack(3); })),
           wire::Reason::wrong_version, "schema_version"));
  CHECK(is(refusal(with_entry(b, "key_frame", [](auto& pk) { pk.pack(true); })),
           wire::Reason::extra_field, "key_frame"));
}

void a_vehicle_frame_with_an_epoch_is_version_2() {
  wire::VehicleTrackFrame f = fused();
  CHECK(wire::encode(f)[16] == 1);  // without an epoch: version 1, the bytes of before
  f.epoch = (std::uint64_t{1} << 32) + 1;
  const Bytes b = wire::encode(f);
  CHECK(b[16] == 2);
  const auto back = wire::decode_vehicle_track_frame(b);
  CHECK(back.ok() && back.value() == f && back.value().version() == 2);
  CHECK(back.ok() && wire::encode(back.value()) == b);
  // An epoch in a frame that says version 1 is refused, as a version-1 reader would.
  CHECK(is(refusal(with_entry(b, "schema_version", [](auto& pk) { pk.pack(1); })),
           wire::Reason::extra_field, "epoch"));
  CHECK(is(refusal(with_entry(b, "epoch", [](auto& pk) { pk.pack(-1); })),
           wire::Reason::invalid_value, "epoch"));
}

bool encode_throws(const std::function<void(wire::VehicleTrackFrame&)>& mutate) {
  wire::VehicleTrackFrame f = fused();
  mutate(f);
  try {
    (void)wire::encode(f);
  } catch (const wire::EncodeError&) {
    return true;
  }
  return false;
}

void the_vehicle_encoder_refuses_what_the_decoder_would() {
  CHECK(encode_throws([](auto& f) { f.tracks.sensor_stamp_ns = {{{1}, {1}}}; }));
  CHECK(encode_throws([](auto& f) { f.tracks.existence.reset(); }));
  CHECK(encode_throws([](auto& f) { f.sensor_state.pop_back(); }));
  CHECK(encode_throws([](auto& f) { f.sensors[1] = "lidar"; }));
  CHECK(encode_throws([](auto& f) { f.sensor = "camera"; }));
  CHECK(encode_throws([](auto& f) { f.tracks.age_s.reset(); }));
  // Values are the decoder's business, as for every message: validate_vehicle_tracks says so.
  wire::VehicleTrackFrame f = fused();
  (*f.tracks.existence)[0] = 1.5;
  const auto r = wire::validate_vehicle_tracks(f);
  CHECK(r && r->field == std::string("tracks.existence"));
}

void the_fusion_reasons() {
  CHECK(wire::parse_reason("late") == wire::Reason::late);
  CHECK(wire::parse_reason("sensor_flagged") == wire::Reason::sensor_flagged);
  CHECK(wire::to_string(wire::Reason::internal_error) == "internal_error");
  CHECK(wire::parse_sensor_condition("unseen") == wire::SensorCondition::unseen);
  CHECK(!wire::detail::is_name(wire::kVehicleStream));
}

}  // namespace

int main() {
  an_extrinsic_makes_version_2();
  a_vehicle_frame_round_trips();
  a_vehicle_frame_is_walked_by_track_and_sensor();
  the_stream_filter_drops_repeats_and_fenced_holders();
  a_vehicle_frame_breaking_its_rules_is_refused();
  the_vehicle_encoder_refuses_what_the_decoder_would();
  a_vehicle_frame_with_an_epoch_is_version_2();
  the_fusion_reasons();
  return check::summary("fusion_cases");
}
