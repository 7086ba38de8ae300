#pragma once
// Which counters of one sender have been taken: the newest, and a window of `size` behind it
// (WireGuard's and IPsec's sliding anti-replay window). A counter is taken once; one that fell
// behind the window is refused, as it can no longer be told from a replay. Used by the link's
// datagrams (services/link/link_auth.h) and the bus's authenticated messages (bus_auth.h).

#include <cstdint>
#include <vector>

namespace stitch {

class ReplayWindow {
 public:
  ReplayWindow() : ReplayWindow(4096) {}
  explicit ReplayWindow(uint64_t size) : seen_(size) {}

  // True where `counter` was not taken before and is not behind the window; it is taken then.
  bool Take(uint64_t counter) {
    const uint64_t size = seen_.size();
    if (any_) {
      if (counter + size <= newest_) return false;
      if (counter <= newest_ && seen_[counter % size]) return false;
    }
    if (!any_ || counter > newest_) {
      if (!any_ || counter - newest_ >= size) {
        seen_.assign(size, false);
      } else {
        for (uint64_t c = newest_ + 1; c < counter; ++c) seen_[c % size] = false;
      }
      newest_ = counter;
      any_ = true;
    }
    seen_[counter % size] = true;
    return true;
  }
  // Forgets every counter taken (a new session of the sender).
  void Reset() {
    any_ = false;
    newest_ = 0;
    seen_.assign(seen_.size(), false);
  }

 private:
  uint64_t newest_ = 0;
  bool any_ = false;
  std::vector<bool> seen_;
};

}  // namespace stitch
