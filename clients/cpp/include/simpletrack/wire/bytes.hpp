// Byte-level helpers shared by the encoders and decoders: little-endian column values built
// and read with shifts (so the host's byte order never matters), strict UTF-8, id patterns.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <optional>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

namespace simpletrack::wire::detail {

// The unsigned integer of a column item's size; floats travel as their IEEE-754 bits.
template <class T>
using Bits = std::conditional_t<sizeof(T) == 8, std::uint64_t, std::uint32_t>;

static_assert(sizeof(float) == 4 && sizeof(double) == 8, "IEEE-754 float and double expected");

template <class T>
void append_le(std::vector<std::uint8_t>& out, T value) {
  static_assert(sizeof(T) == 4 || sizeof(T) == 8);
  Bits<T> bits;
  std::memcpy(&bits, &value, sizeof bits);  // reinterpret, same width: no conversion
  for (std::size_t i = 0; i < sizeof bits; ++i) {
    out.push_back(static_cast<std::uint8_t>(bits >> (8 * i)));
  }
}

template <class T>
T read_le(const unsigned char* p) {
  static_assert(sizeof(T) == 4 || sizeof(T) == 8);
  Bits<T> bits = 0;
  for (std::size_t i = 0; i < sizeof bits; ++i) {
    bits |= static_cast<Bits<T>>(p[i]) << (8 * i);
  }
  T value;
  std::memcpy(&value, &bits, sizeof value);
  return value;
}

// Code points of a strict UTF-8 string (no overlongs, no surrogates, nothing past U+10FFFF:
// what Python's decoder accepts), or nullopt when it is not UTF-8.
inline std::optional<std::size_t> utf8_length(std::string_view s) {
  std::size_t n = 0;
  const auto* p = reinterpret_cast<const unsigned char*>(s.data());
  const auto* end = p + s.size();
  while (p < end) {
    const unsigned c = *p;
    std::size_t len = 0;
    unsigned lo = 0x80, hi = 0xBF;  // allowed range of the second byte
    if (c < 0x80) {
      len = 1;
    } else if (c >= 0xC2 && c <= 0xDF) {
      len = 2;
    } else if (c >= 0xE0 && c <= 0xEF) {
      len = 3;
      if (c == 0xE0) lo = 0xA0;  // overlong
      if (c == 0xED) hi = 0x9F;  // surrogates
    } else if (c >= 0xF0 && c <= 0xF4) {
      len = 4;
      if (c == 0xF0) lo = 0x90;  // overlong
      if (c == 0xF4) hi = 0x8F;  // beyond U+10FFFF
    } else {
      return std::nullopt;
    }
    if (static_cast<std::size_t>(end - p) < len) return std::nullopt;
    for (std::size_t i = 1; i < len; ++i) {
      const unsigned b = p[i];
      if (i == 1 ? (b < lo || b > hi) : (b < 0x80 || b > 0xBF)) return std::nullopt;
    }
    p += len;
    ++n;
  }
  return n;
}

// Cut a UTF-8 string to at most `max_bytes` without splitting a character.
inline void truncate_utf8(std::string& s, std::size_t max_bytes) {
  if (s.size() <= max_bytes) return;
  std::size_t end = max_bytes;
  while (end > 0 && (static_cast<unsigned char>(s[end]) & 0xC0) == 0x80) --end;
  s.resize(end);
}

// `^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}$`: a vehicle, sensor or instance id (one Zenoh key chunk).
inline bool is_name(std::string_view s) {
  if (s.empty() || s.size() > 64) return false;
  for (std::size_t i = 0; i < s.size(); ++i) {
    const char c = s[i];
    const bool word =
        (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_';
    if (!word && (i == 0 || (c != '.' && c != '-'))) return false;
  }
  return true;
}

// Python's repr() of a bytes key, which is how the reference decoder names a `bin` map key
// in a rejection's field (e.g. "b'speed'").
inline std::string bytes_repr(std::string_view b) {
  const bool dq = b.find('\'') != std::string_view::npos && b.find('"') == std::string_view::npos;
  const char quote = dq ? '"' : '\'';
  std::string out = "b";
  out += quote;
  for (const char ch : b) {
    const auto c = static_cast<unsigned char>(ch);
    if (ch == quote || ch == '\\') {
      out += '\\';
      out += ch;
    } else if (ch == '\t') {
      out += "\\t";
    } else if (ch == '\n') {
      out += "\\n";
    } else if (ch == '\r') {
      out += "\\r";
    } else if (c < 0x20 || c >= 0x7F) {
      char hex[5];
      std::snprintf(hex, sizeof hex, "\\x%02x", c);
      out += hex;
    } else {
      out += ch;
    }
  }
  out += quote;
  return out;
}

// printf's %g, as the reference decoder formats bounds in its details.
inline std::string format_g(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

}  // namespace simpletrack::wire::detail
