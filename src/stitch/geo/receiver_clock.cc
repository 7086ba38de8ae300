#include "stitch/geo/receiver_clock.h"

#include <algorithm>
#include <cmath>

namespace stitch {

ReceiverClock::ReceiverClock(double window_s, double max_jump_s, double max_delay_s)
    : window_ns_(static_cast<int64_t>(std::llround(window_s * 1e9))),
      max_jump_ns_(static_cast<int64_t>(std::llround(max_jump_s * 1e9))),
      max_delay_ns_(static_cast<int64_t>(std::llround(max_delay_s * 1e9))) {}

int64_t ReceiverClock::Stamp(int64_t receiver_t_ns, int64_t arrived_t_ns) {
  // Held within +-2^61 ns (73 years either side of the clocks' epochs), so that no difference or
  // sum below overflows whatever a receiver sends.
  constexpr int64_t kBound = int64_t{1} << 61;
  receiver_t_ns = std::clamp(receiver_t_ns, -kBound, kBound);
  arrived_t_ns = std::clamp(arrived_t_ns, -kBound, kBound);
  const int64_t offset = arrived_t_ns - receiver_t_ns;
  // A receiver time that jumped against the local clock starts over.
  if (!smallest_.empty() &&
      (offset < smallest_.front().second - max_jump_ns_ || offset > smallest_.front().second + max_delay_ns_)) {
    smallest_.clear();
    ++restarts_;
  }
  while (!smallest_.empty() && smallest_.back().second >= offset) smallest_.pop_back();
  smallest_.emplace_back(arrived_t_ns, offset);
  while (smallest_.front().first < arrived_t_ns - window_ns_) smallest_.pop_front();
  return receiver_t_ns + smallest_.front().second;
}

}  // namespace stitch
