// Decodes a stream of payloads and prints one verdict per payload, for tests that compare
// this decoder with the Python one (tests/native/test_cpp_codec.py).
//
// stdin: records of [kind: 1 byte][length: 4 bytes little-endian][payload], kind one of
//   'd' DetectionFrame, 'D' DetectionFrame accepting only Car and Pedestrian,
//   't' TrackFrame, 'v' VehicleTrackFrame, 'e' FrameError.
// stdout: per record one line, tab-separated:
//   ok <hex of the decoded message re-encoded>
//   no <reason> <field or None> <seq or None> <stamp_ns or None>
#include <simpletrack/wire.hpp>

#include <cstdio>
#include <iostream>
#include <iterator>
#include <string>
#include <vector>

namespace wire = simpletrack::wire;

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
  const wire::Rejection& e = r.error();
  std::cout << "no\t" << wire::to_string(e.reason) << "\t" << show(e.field) << "\t" << show(e.seq)
            << "\t" << show(e.stamp_ns) << "\n";
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
      default:
        std::cerr << "wire_decode: unknown kind '" << kind << "'\n";
        return 2;
    }
  }
  return 0;
}
