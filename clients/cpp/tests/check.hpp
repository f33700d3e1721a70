// A minimal test harness: CHECK records a failure and goes on, summary() prints the
// closing line and gives the exit code.
#pragma once

#include <cstdio>
#include <string>

namespace check {

inline int passed = 0;
inline int failed = 0;

inline void record(bool ok, const char* expr, const char* file, int line, const std::string& what) {
  if (ok) {
    ++passed;
    return;
  }
  ++failed;
  std::fprintf(stderr, "FAIL %s:%d: %s%s%s\n", file, line, expr, what.empty() ? "" : " -- ",
               what.c_str());
}

inline int summary(const char* suite) {
  std::printf("%s: %d passed, %d failed\n", suite, passed, failed);
  return failed == 0 && passed > 0 ? 0 : 1;
}

}  // namespace check

#define CHECK(expr) ::check::record(static_cast<bool>(expr), #expr, __FILE__, __LINE__, "")
#define CHECK_MSG(expr, what) \
  ::check::record(static_cast<bool>(expr), #expr, __FILE__, __LINE__, (what))
