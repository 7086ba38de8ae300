#pragma once
// Clocks. Times are integers: nanoseconds for data, microseconds (LCM's utime) on the bus.

#include <time.h>

#include <chrono>
#include <cstdint>
#include <string>

namespace stitch {

// Wall clock, microseconds since the Unix epoch (for message headers).
inline int64_t WallUtime() {
  return std::chrono::duration_cast<std::chrono::microseconds>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

// Wall clock, nanoseconds since the Unix epoch (a live camera's frames, and the fixes that go with them).
inline int64_t WallClockNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

// Monotonic seconds, for measuring durations.
inline double MonotonicSeconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

// CPU time the calling thread has used, milliseconds (what a piece of work costs, whatever else
// the machine runs).
inline double ThreadCpuMs() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) * 1e3 + static_cast<double>(t.tv_nsec) * 1e-6;
}

class Stopwatch {
 public:
  Stopwatch() : start_(MonotonicSeconds()) {}
  double ElapsedSeconds() const { return MonotonicSeconds() - start_; }
  double ElapsedMs() const { return 1e3 * ElapsedSeconds(); }
  void Restart() { start_ = MonotonicSeconds(); }

 private:
  double start_;
};

// The local time now, formatted with strftime's `format` (folder names, run records).
std::string LocalTimestamp(const char* format);

// Formats t_ns as seconds with nine decimals, exactly ("1403715273.262142976").
std::string FormatSeconds(int64_t t_ns);
// Parses decimal seconds ("1305031229.528748", "12", "1.5e-3" is rejected) into nanoseconds
// exactly, without going through a double. Throws stitch::Error on anything else.
int64_t ParseSecondsToNs(const std::string& text);

}  // namespace stitch
