// Every golden vector of schemas/vectors, both ways: decoding <name>.msgpack gives what
// <name>.json says (the message, or the refusal's reason and field), and encoding the JSON's
// message gives <name>.msgpack back byte for byte.
#include <simpletrack/wire.hpp>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "check.hpp"

namespace fs = std::filesystem;
namespace wire = simpletrack::wire;
using nlohmann::json;

namespace {

std::vector<std::uint8_t> read_bytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}

template <class T>
std::vector<T> values(const json& j) {
  std::vector<T> out;
  for (const auto& v : j) out.push_back(v.get<T>());
  return out;
}

template <std::size_t K>
std::vector<std::array<float, K>> rows(const json& j) {
  std::vector<std::array<float, K>> out;
  for (const auto& row : j) {
    std::array<float, K> r{};
    if (row.size() != K)
      throw std::runtime_error("row of " + std::to_string(row.size()) + " values");
    for (std::size_t k = 0; k < K; ++k) r[k] = static_cast<float>(row[k].get<double>());
    out.push_back(r);
  }
  return out;
}

std::optional<wire::Pose> pose(const json& j) {
  if (j.is_null()) return std::nullopt;
  wire::Pose p{};
  for (std::size_t i = 0; i < 16; ++i) p[i] = j.at(i).get<double>();
  return p;
}

template <class T>
std::optional<T> maybe(const json& j, const char* key) {
  if (!j.contains(key) || j[key].is_null()) return std::nullopt;
  return j[key].get<T>();
}

wire::DetectionFrame detection(const json& d) {
  wire::DetectionFrame f;
  f.vehicle = d.at("vehicle"), f.sensor = d.at("sensor"), f.frame_id = d.at("frame_id");
  f.seq = d.at("seq"), f.stamp_ns = d.at("stamp_ns");
  f.pose = pose(d.at("pose"));
  f.key_frame = d.at("key_frame");
  f.session_id = maybe<std::uint64_t>(d, "session_id");
  if (d.contains("extrinsic")) f.extrinsic = pose(d.at("extrinsic"));
  f.schema_version = d.at("schema_version").get<int>();
  const json& b = d.at("boxes");
  f.boxes.classes = values<std::string>(b.at("classes"));
  f.boxes.class_index = values<std::int32_t>(b.at("class_index"));
  f.boxes.center = rows<3>(b.at("center"));
  f.boxes.size = rows<3>(b.at("size"));
  f.boxes.yaw = values<float>(b.at("yaw"));
  f.boxes.score = values<double>(b.at("score"));
  if (!b.at("velocity").is_null()) f.boxes.velocity = rows<2>(b.at("velocity"));
  return f;
}

wire::TrackColumns track_columns(const json& t) {
  wire::TrackColumns c;
  c.classes = values<std::string>(t.at("classes"));
  c.id = values<std::int64_t>(t.at("id"));
  c.class_index = values<std::int32_t>(t.at("class_index"));
  c.center = rows<3>(t.at("center"));
  c.size = rows<3>(t.at("size"));
  c.yaw = values<float>(t.at("yaw"));
  c.score = values<double>(t.at("score"));
  c.velocity = rows<3>(t.at("velocity"));
  c.state = values<std::int32_t>(t.at("state"));
  c.hits = values<std::int32_t>(t.at("hits"));
  c.age = values<std::int32_t>(t.at("age"));
  c.time_since_update = values<std::int32_t>(t.at("time_since_update"));
  if (t.contains("covariance") && !t.at("covariance").is_null()) {
    c.covariance = rows<21>(t.at("covariance"));
  }
  if (t.contains("age_s")) c.age_s = values<double>(t.at("age_s"));
  if (t.contains("time_since_update_s")) {
    c.time_since_update_s = values<double>(t.at("time_since_update_s"));
  }
  if (t.contains("existence")) c.existence = values<double>(t.at("existence"));
  if (t.contains("sensor_stamp_ns")) {
    c.sensor_stamp_ns.emplace();
    for (const auto& row : t.at("sensor_stamp_ns")) {
      c.sensor_stamp_ns->push_back(values<std::int64_t>(row));
    }
  }
  return c;
}

wire::VehicleTrackFrame vehicle_track(const json& d) {
  wire::VehicleTrackFrame f;
  f.vehicle = d.at("vehicle"), f.sensor = d.at("sensor"), f.frame_id = d.at("frame_id");
  f.seq = d.at("seq"), f.stamp_ns = d.at("stamp_ns"), f.sensor_seq = d.at("sensor_seq");
  f.pose = pose(d.at("pose"));
  f.instance = d.at("instance");
  f.received_ns = d.at("received_ns"), f.published_ns = d.at("published_ns");
  f.sensors = values<std::string>(d.at("sensors"));
  for (const auto& s : d.at("sensor_state")) {
    const auto c = wire::parse_sensor_condition(s.get<std::string>());
    if (!c) throw std::runtime_error("unknown sensor state in the JSON");
    f.sensor_state.push_back(*c);
  }
  // An empty frame's stamps are [] in the JSON: no rows, whatever the number of sensors.
  f.tracks = track_columns(d.at("tracks"));
  f.epoch = maybe<std::uint64_t>(d, "epoch");
  return f;
}

wire::TrackFrame track(const json& d) {
  wire::TrackFrame f;
  f.vehicle = d.at("vehicle"), f.sensor = d.at("sensor"), f.frame_id = d.at("frame_id");
  f.seq = d.at("seq"), f.stamp_ns = d.at("stamp_ns");
  f.pose = pose(d.at("pose"));
  f.key_frame = d.at("key_frame");
  f.instance = d.at("instance");
  f.received_ns = d.at("received_ns"), f.published_ns = d.at("published_ns");
  f.schema_version = d.at("schema_version").get<int>();
  f.tracks = track_columns(d.at("tracks"));
  f.epoch = maybe<std::uint64_t>(d, "epoch");
  return f;
}

wire::FrameError frame_error(const json& d) {
  wire::FrameError e;
  e.vehicle = d.at("vehicle"), e.sensor = d.at("sensor");
  e.seq = maybe<std::uint64_t>(d, "seq"), e.stamp_ns = maybe<std::uint64_t>(d, "stamp_ns");
  const auto reason = wire::parse_reason(d.at("reason").get<std::string>());
  if (!reason) throw std::runtime_error("unknown reason in the JSON");
  e.reason = *reason;
  e.field = maybe<std::string>(d, "field");
  e.detail = d.at("detail"), e.instance = d.at("instance"), e.received_ns = d.at("received_ns");
  if (d.contains("seqs") && !d["seqs"].is_null()) {
    e.seqs.emplace();
    for (const auto& s : d["seqs"]) {
      e.seqs->push_back(s.is_null() ? std::nullopt
                                    : std::optional<std::uint64_t>(s.get<std::uint64_t>()));
    }
  }
  return e;
}

std::string show(const wire::Rejection& r) {
  return r.message();
}

// Decode, compare with the JSON, and re-encode both the JSON's message and the decoded one.
template <class Message, class Decode, class FromJson>
void check_vector(const std::string& name, const json& j, const std::vector<std::uint8_t>& bytes,
                  Decode decode, FromJson from_json) {
  const wire::Result<Message> got = decode(bytes);
  if (!j.at("valid").get<bool>()) {
    const std::string reason = j.at("reason");
    const std::optional<std::string> field =
        j.at("field").is_null() ? std::nullopt : std::optional<std::string>(j.at("field"));
    CHECK_MSG(!got.ok(), name + ": decoded, expected " + reason);
    if (got.ok()) return;
    CHECK_MSG(std::string(wire::to_string(got.error().reason)) == reason,
              name + ": got " + show(got.error()) + ", expected " + reason);
    CHECK_MSG(got.error().field == field, name + ": field " + got.error().field.value_or("null") +
                                              ", expected " + field.value_or("null"));
    return;
  }
  CHECK_MSG(got.ok(), name + ": refused: " + (got.ok() ? "" : show(got.error())));
  if (!got.ok()) return;
  const Message expected = from_json(j.at("decoded"));
  CHECK_MSG(got.value() == expected, name + ": decoded message differs from the JSON");
  CHECK_MSG(wire::encode(expected) == bytes, name + ": encoding the JSON's message differs");
  CHECK_MSG(wire::encode(got.value()) == bytes, name + ": re-encoding the decoded message differs");
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: golden_vectors <schemas/vectors directory>\n");
    return 2;
  }
  const fs::path dir = argv[1];
  std::vector<fs::path> jsons;
  if (fs::is_directory(dir)) {
    for (const auto& e : fs::directory_iterator(dir)) {
      if (e.path().extension() == ".json") jsons.push_back(e.path());
    }
  }
  std::sort(jsons.begin(), jsons.end());
  CHECK_MSG(!jsons.empty(), "no golden vectors in " + dir.string());
  int valid = 0;
  for (const auto& path : jsons) {
    const std::string name = path.stem().string();
    try {
      json j;
      std::ifstream(path) >> j;
      const auto bytes = read_bytes(fs::path(path).replace_extension(".msgpack"));
      const std::string message = j.at("message");
      valid += j.at("valid").get<bool>() ? 1 : 0;
      if (message == "DetectionFrame") {
        check_vector<wire::DetectionFrame>(
            name, j, bytes, [](const auto& b) { return wire::decode_detection_frame(b); },
            detection);
      } else if (message == "TrackFrame") {
        check_vector<wire::TrackFrame>(
            name, j, bytes, [](const auto& b) { return wire::decode_track_frame(b); }, track);
      } else if (message == "VehicleTrackFrame") {
        check_vector<wire::VehicleTrackFrame>(
            name, j, bytes, [](const auto& b) { return wire::decode_vehicle_track_frame(b); },
            vehicle_track);
      } else if (message == "FrameError") {
        check_vector<wire::FrameError>(
            name, j, bytes, [](const auto& b) { return wire::decode_frame_error(b); }, frame_error);
      } else {
        CHECK_MSG(false, name + ": message type " + message + " has no C++ decoder");
      }
    } catch (const std::exception& e) {
      CHECK_MSG(false, name + ": " + e.what());
    }
  }
  std::printf("checked %zu golden vectors (%d valid, %zu invalid) in %s\n", jsons.size(), valid,
              jsons.size() - static_cast<std::size_t>(valid), dir.string().c_str());
  return check::summary("golden_vectors");
}
