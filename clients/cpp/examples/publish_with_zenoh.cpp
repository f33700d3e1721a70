// A vehicle publishing detection frames: encode with simpletrack::wire, hand the bytes to
// zenoh-cpp with the encoding `application/msgpack`, one frame per sample.
//
// Built with -DSIMPLETRACK_WITH_ZENOH=ON it talks to a real Zenoh network:
//   publish_with_zenoh [--connect tcp/127.0.0.1:7447] [--frames N]
// Built without (the default, where zenoh-cpp is not installed) the same code "puts" into
// files through a stand-in with the same shape, so the codec side is compiled and run:
//   publish_with_zenoh --out DIR [--frames N]      (writes DIR/<n>.msgpack)
#include <simpletrack/wire.hpp>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>
#include <vector>

#ifdef SIMPLETRACK_WITH_ZENOH
#include "zenoh.hxx"
#else
#include <filesystem>
#include <fstream>
#endif

namespace wire = simpletrack::wire;

namespace {

constexpr const char* kVehicle = "veh-1";
constexpr const char* kSensor = "lidar";

// What a detector would hand over; here two boxes drifting along +x.
wire::DetectionFrame detect(std::uint64_t seq, std::uint64_t stamp_ns) {
  wire::DetectionFrame f;
  f.vehicle = kVehicle;
  f.sensor = kSensor;
  f.seq = seq;
  f.stamp_ns = stamp_ns;
  f.frame_id = "base_link";
  const float x = 10.0f + 0.5f * static_cast<float>(seq);
  f.boxes.classes = {"Car", "Pedestrian"};
  f.boxes.class_index = {0, 1};
  f.boxes.center = {{x, 2.0f, 0.8f}, {6.0f, -3.0f, 0.9f}};
  f.boxes.size = {{4.5f, 1.9f, 1.6f}, {0.8f, 0.7f, 1.8f}};
  f.boxes.yaw = {0.1f, 1.5f};
  f.boxes.score = {0.9, 0.7};
  f.boxes.velocity = std::vector<wire::Vec2f>{{5.0f, 0.0f}, {1.0f, 0.5f}};
  return f;
}

#ifdef SIMPLETRACK_WITH_ZENOH

class Publisher {
 public:
  explicit Publisher(const std::string& connect) : session_(open(connect)) {}

  void put(const std::string& key, std::vector<std::uint8_t> bytes) {
    zenoh::Session::PutOptions options;
    options.encoding = zenoh::Encoding("application/msgpack");
    session_.put(zenoh::KeyExpr(key), zenoh::Bytes(std::move(bytes)), std::move(options));
  }

 private:
  static zenoh::Session open(const std::string& connect) {
    zenoh::Config config = zenoh::Config::create_default();
    if (!connect.empty()) config.insert_json5("connect/endpoints", "[\"" + connect + "\"]");
    return zenoh::Session::open(std::move(config));
  }
  zenoh::Session session_;
};

#else

// Stand-in for zenoh::Session::put: same arguments, the sample lands in a file.
class Publisher {
 public:
  explicit Publisher(std::filesystem::path dir) : dir_(std::move(dir)) {
    std::filesystem::create_directories(dir_);
  }

  void put(const std::string& key, std::vector<std::uint8_t> bytes) {
    const std::string encoding = "application/msgpack";
    const auto path = dir_ / (std::to_string(puts_++) + ".msgpack");
    std::ofstream(path, std::ios::binary)
        .write(reinterpret_cast<const char*>(bytes.data()),
               static_cast<std::streamsize>(bytes.size()));
    std::printf("put %s (%s, %zu bytes) -> %s\n", key.c_str(), encoding.c_str(), bytes.size(),
                path.string().c_str());
  }

 private:
  std::filesystem::path dir_;
  int puts_ = 0;
};

#endif

std::uint64_t now_ns() {
  return static_cast<std::uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                        std::chrono::system_clock::now().time_since_epoch())
                                        .count());
}

int run(int argc, char** argv) {
  std::string target;  // --connect endpoint, or --out directory
  int frames = 10;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string flag = argv[i];
    if (flag == "--frames") {
      frames = std::atoi(argv[i + 1]);
    } else if (flag == "--connect" || flag == "--out") {
      target = argv[i + 1];
    } else {
      std::fprintf(stderr, "publish_with_zenoh: unknown option %s\n", flag.c_str());
      return 2;
    }
  }
#ifndef SIMPLETRACK_WITH_ZENOH
  if (target.empty()) {
    std::fprintf(stderr, "publish_with_zenoh: built without zenoh-cpp; give --out DIR\n");
    return 2;
  }
#endif
  Publisher publisher(target);
  const std::string key = std::string("fleet/") + kVehicle + "/" + kSensor + "/detections";
  for (int i = 0; i < frames; ++i) {
    const wire::DetectionFrame frame = detect(static_cast<std::uint64_t>(i), now_ns());
    // Refusing locally what the service would refuse saves a round trip to its error topic.
    if (const auto problem = wire::validate(frame)) {
      std::fprintf(stderr, "publish_with_zenoh: frame %d not sent: %s\n", i,
                   problem->message().c_str());
      continue;
    }
    publisher.put(key, wire::encode(frame));
    std::this_thread::sleep_for(std::chrono::milliseconds(100));  // a 10 Hz sensor
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const std::exception& e) {  // zenoh::ZException is a std::runtime_error
    std::fprintf(stderr, "publish_with_zenoh: %s\n", e.what());
    return 1;
  }
}
