#pragma once
// A GNSS receiver's fixes on the local clock by the receiver's own time of each fix. A fix
// reaches the computer some time after its epoch, and that delay varies (a serial port's
// sentences, a busy gpsd, a telemetry link's queue): stamped on arrival, a fix of an aircraft at
// 12 m/s moves by a metre per 80 ms of jitter. The receiver states when each fix was taken; the
// offset between its clock and the local one is the smallest (arrival - receiver time) over the
// last `window_s` (the fix that came quickest), so every fix keeps the receiver's spacing and
// only the quickest delay is left (what ingest.gnss_latency_s states). The window lets the offset
// follow a local clock that drifts or is stepped. A receiver time that jumps against the local
// clock starts the offset over: ahead by more than `max_jump_s` (no delay is that much shorter
// than the quickest), or behind by more than `max_delay_s` (a receiver restarted, counting from
// its boot again; a longer delay than the quickest by less is a queue, and waits out the window).

#include <cstdint>
#include <deque>
#include <utility>

namespace stitch {

class ReceiverClock {
 public:
  explicit ReceiverClock(double window_s = 30.0, double max_jump_s = 2.0, double max_delay_s = 10.0);

  // The fix the receiver took at `receiver_t_ns` (its clock: UTC, or since its boot) and that
  // arrived at `arrived_t_ns` (the local clock), on the local clock.
  int64_t Stamp(int64_t receiver_t_ns, int64_t arrived_t_ns);

  // Times the offset started over (a receiver time that jumped).
  int restarts() const { return restarts_; }

 private:
  int64_t window_ns_, max_jump_ns_, max_delay_ns_;
  // (arrival, arrival - receiver time) of the fixes within the window whose offset is smaller
  // than every later one's: the front is the window's smallest.
  std::deque<std::pair<int64_t, int64_t>> smallest_;
  int restarts_ = 0;
};

}  // namespace stitch
