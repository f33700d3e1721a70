// Decodes a stream of payloads and prints one verdict per payload, for tests that compare
// this decoder with the Python one (tests/native/test_cpp_codec.py,
// tests/native/test_fused_frame_every_client.py).
//
// stdin: records of [kind: 1 byte][length: 4 bytes little-endian][payload], kind one of
//   'd' DetectionFrame, 'D' DetectionFrame accepting only Car and Pedestrian,
//   't' TrackFrame, 'v' VehicleTrackFrame, 'e' FrameError,
//   'j' VehicleTrackFrame, printed as JSON.
// stdout: per record one line, tab-separated:
//   ok <hex of the decoded message re-encoded>
//   ok <JSON> (kind 'j'): {"decoded": the golden vectors' form of the frame (schemas/vectors),
//      "walk": what a planner reads through the accessors: each track's global_id, existence
//      and contributors (sensor: stamp of its last update), each sensor's state, the source
//      (sensor, sensor_seq) and the epoch}
//   no <reason> <field or None> <seq or None> <stamp_ns or None>
#include <simpletrack/wire.hpp>

#include <cstdio>
#include <iostream>
#include <iterator>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

namespace wire = simpletrack::wire;
using nlohmann::json;

namespace {

template <class T>
std::string show(const std::optional<T>& v) {
  if (!v) return "None";
  if constexpr (std::is_same_v<T, std::string>) {
    return *v;
  } else {
    return std::to_string(*v);
  }
}

template <class T>
json floats(const std::vector<T>& v) {
  json out = json::array();
  for (const T x : v) out.push_back(static_cast<double>(x));  // float32 widened, as Python
  return out;
}

template <class T, std::size_t K>
json rows(const std::vector<std::array<T, K>>& v) {
  json out = json::array();
  for (const auto& row : v) {
    json r = json::array();
    for (const T x : row) r.push_back(static_cast<double>(x));
    out.push_back(r);
  }
  return out;
}

template <class T>
json optional_floats(const std::optional<std::vector<T>>& v) {
  return v ? floats(*v) : json(nullptr);
}

// The golden vectors' `decoded` form of a VehicleTrackFrame (schemas/vectors/*.json).
json decoded_json(const wire::VehicleTrackFrame& f) {
  const wire::TrackColumns& t = f.tracks;
  json tracks = {
      {"count", t.count()},
      {"classes", t.classes},
      {"id", t.id},
      {"class_index", t.class_index},
      {"center", rows(t.center)},
      {"size", rows(t.size)},
      {"yaw", floats(t.yaw)},
      {"score", floats(t.score)},
      {"velocity", rows(t.velocity)},
      {"state", t.state},
      {"hits", t.hits},
      {"age", t.age},
      {"time_since_update", t.time_since_update},
      {"covariance", t.covariance ? rows(*t.covariance) : json(nullptr)},
      {"age_s", optional_floats(t.age_s)},
      {"time_since_update_s", optional_floats(t.time_since_update_s)},
      {"existence", optional_floats(t.existence)},
      {"sensor_stamp_ns", t.sensor_stamp_ns ? json(*t.sensor_stamp_ns) : json(nullptr)},
  };
  json states = json::array();
  for (const wire::SensorCondition c : f.sensor_state) states.push_back(wire::to_string(c));
  json out = {
      {"schema_version", f.version()},
      {"vehicle", f.vehicle},
      {"seq", f.seq},
      {"stamp_ns", f.stamp_ns},
      {"sensor", f.sensor},
      {"sensor_seq", f.sensor_seq},
      {"frame_id", f.frame_id},
      {"pose", f.pose ? json(*f.pose) : json(nullptr)},
      {"instance", f.instance},
      {"received_ns", f.received_ns},
      {"published_ns", f.published_ns},
      {"sensors", f.sensors},
      {"sensor_state", states},
      {"tracks", tracks},
  };
  if (f.epoch) out["epoch"] = *f.epoch;
  return out;
}

// What a planner reads of the frame through its accessors.
json walk_json(const wire::VehicleTrackFrame& f) {
  json ids = json::array(), existence = json::array(), contributors = json::array();
  for (std::size_t i = 0; i < f.count(); ++i) {
    ids.push_back(f.global_id(i));
    existence.push_back(f.existence(i));
    json by_sensor = json::object();
    for (const auto& [sensor, stamp] : f.contributors(i)) by_sensor[sensor] = stamp;
    contributors.push_back(by_sensor);
  }
  json states = json::object();
  for (const std::string& s : f.sensors) states[s] = wire::to_string(*f.condition(s));
  return {
      {"global_ids", ids},
      {"existence", existence},
      {"contributors", contributors},
      {"sensor_state", states},
      {"source", json::array({f.sensor, f.sensor_seq})},
      {"epoch", f.epoch ? json(*f.epoch) : json(nullptr)},
  };
}

void print_rejection(const wire::Rejection& e) {
  std::cout << "no\t" << wire::to_string(e.reason) << "\t" << show(e.field) << "\t" << show(e.seq)
            << "\t" << show(e.stamp_ns) << "\n";
}

void print_json(const wire::Result<wire::VehicleTrackFrame>& r) {
  if (!r) {
    print_rejection(r.error());
    return;
  }
  const json line = {{"decoded", decoded_json(r.value())}, {"walk", walk_json(r.value())}};
  std::cout << "ok\t" << line.dump() << "\n";
}

template <class Message>
void print(const wire::Result<Message>& r) {
  if (r) {
    std::string hex;
    char byte[3];
    for (const std::uint8_t b : wire::encode(r.value())) {
      std::snprintf(byte, sizeof byte, "%02x", b);
      hex += byte;
    }
    std::cout << "ok\t" << hex << "\n";
    return;
  }
  print_rejection(r.error());
}

}  // namespace

int main() {
  std::ios::sync_with_stdio(false);
  const std::vector<unsigned char> in((std::istreambuf_iterator<char>(std::cin)), {});
  const std::vector<std::string> accepted = {"Car", "Pedestrian"};
  std::size_t at = 0;
  while (at < in.size()) {
    if (in.size() - at < 5) {
      std::cerr << "wire_decode: truncated record header at byte " << at << "\n";
      return 2;
    }
    const char kind = static_cast<char>(in[at]);
    const std::size_t n = wire::detail::read_le<std::uint32_t>(&in[at + 1]);
    at += 5;
    if (in.size() - at < n) {
      std::cerr << "wire_decode: truncated payload at byte " << at << "\n";
      return 2;
    }
    const unsigned char* p = in.data() + at;
    at += n;
    switch (kind) {
      case 'd':
        print(wire::decode_detection_frame(p, n));
        break;
      case 'D':
        print(wire::decode_detection_frame(p, n, {}, &accepted));
        break;
      case 't':
        print(wire::decode_track_frame(p, n));
        break;
      case 'v':
        print(wire::decode_vehicle_track_frame(p, n));
        break;
      case 'e':
        print(wire::decode_frame_error(p, n));
        break;
      case 'j':
        print_json(wire::decode_vehicle_track_frame(p, n));
        break;
      default:
        std::cerr << "wire_decode: unknown kind '" << kind << "'\n";
        return 2;
    }
  }
  return 0;
}
