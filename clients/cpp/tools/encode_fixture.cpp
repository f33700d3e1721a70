// Prints the shared fixture frame (3 boxes, Car/Pedestrian, with velocity) as hex msgpack, so
// that tests can hold the C++ encoder to the Python one. The boxes come from
// tests/native/fixture_boxes.json when it exists (the Rust client's tests read the same file),
// else from the same values built in here.
//
//   encode_fixture [fixture.json]
#include <simpletrack/wire.hpp>

#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <string>

namespace wire = simpletrack::wire;
using nlohmann::json;

namespace {

wire::DetectionFrame built_in() {
  wire::DetectionFrame f;
  f.vehicle = "veh-fixture";
  f.sensor = "lidar";
  f.seq = 7;
  f.stamp_ns = 1'700'000'000'000'000'000ULL;
  f.frame_id = "base_link";
  f.boxes.classes = {"Car", "Pedestrian"};
  f.boxes.class_index = {0, 1, 0};
  f.boxes.center = {{10.0f, 2.0f, 0.8f}, {6.0f, -3.0f, 0.9f}, {25.0f, 4.0f, 0.8f}};
  f.boxes.size = {{4.5f, 1.9f, 1.6f}, {0.8f, 0.7f, 1.8f}, {4.2f, 1.8f, 1.5f}};
  f.boxes.yaw = {0.1f, 1.5f, -0.2f};
  f.boxes.score = {0.9, 0.7, 0.6};
  f.boxes.velocity = std::vector<wire::Vec2f>{{5.0f, 0.0f}, {1.0f, 0.5f}, {-3.0f, 0.2f}};
  return f;
}

template <std::size_t K>
std::vector<std::array<float, K>> rows(const json& j, const char* key) {
  std::vector<std::array<float, K>> out;
  for (const auto& row : j.at(key)) {
    if (row.size() != K) {
      throw std::runtime_error(std::string(key) + ": a row of " + std::to_string(row.size()) +
                               " values, expected " + std::to_string(K));
    }
    std::array<float, K> r{};
    for (std::size_t k = 0; k < K; ++k)
      r[k] = static_cast<float>(row[k].get<double>());  // as numpy's float32 cast
    out.push_back(r);
  }
  return out;
}

wire::DetectionFrame from_file(const std::string& path) {
  json j;
  std::ifstream(path) >> j;
  static const std::set<std::string> known = {"vehicle",  "sensor",  "seq",         "stamp_ns",
                                              "frame_id", "classes", "class_index", "center",
                                              "size",     "yaw",     "score",       "velocity"};
  for (const auto& item : j.items()) {
    // A key this tool does not reproduce would make the comparison silently unfair.
    if (!known.count(item.key())) throw std::runtime_error("unknown key '" + item.key() + "'");
  }
  wire::DetectionFrame f;
  f.vehicle = j.at("vehicle"), f.sensor = j.at("sensor"), f.frame_id = j.at("frame_id");
  f.seq = j.at("seq"), f.stamp_ns = j.at("stamp_ns");
  f.boxes.classes = j.at("classes").get<std::vector<std::string>>();
  f.boxes.class_index = j.at("class_index").get<std::vector<std::int32_t>>();
  f.boxes.center = rows<3>(j, "center");
  f.boxes.size = rows<3>(j, "size");
  for (const auto& v : j.at("yaw")) f.boxes.yaw.push_back(static_cast<float>(v.get<double>()));
  f.boxes.score = j.at("score").get<std::vector<double>>();
  if (j.contains("velocity") && !j["velocity"].is_null()) f.boxes.velocity = rows<2>(j, "velocity");
  return f;
}

}  // namespace

int main(int argc, char** argv) {
  const std::string path = argc > 1 ? argv[1] : SIMPLETRACK_FIXTURE_JSON;
  try {
    const bool file = std::ifstream(path).good();
    const wire::DetectionFrame frame = file ? from_file(path) : built_in();
    std::fprintf(stderr, "encode_fixture: boxes from %s\n",
                 file ? path.c_str() : "built-in constants");
    for (const std::uint8_t b : wire::encode(frame)) std::printf("%02x", b);
    std::printf("\n");
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "encode_fixture: %s: %s\n", path.c_str(), e.what());
    return 1;
  }
}
