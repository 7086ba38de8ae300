#pragma once
// A disk that fills up after `bytes` more bytes of any one file, for this test process: the
// file size limit (RLIMIT_FSIZE) makes write() fail (EFBIG) past it, as a full disk makes it
// fail (ENOSPC), and SIGXFSZ, which would end the process instead, is ignored while it lasts.
// For tests only: one at a time, and only in a test whose process writes nothing else meanwhile.

#include <sys/resource.h>

#include <csignal>
#include <cstdlib>

namespace stitch::testing {

class FullDiskAfter {
 public:
  explicit FullDiskAfter(rlim_t bytes) {
    if (getrlimit(RLIMIT_FSIZE, &before_) != 0) std::abort();
    previous_handler_ = std::signal(SIGXFSZ, SIG_IGN);
    rlimit limited = before_;
    limited.rlim_cur = bytes;
    if (setrlimit(RLIMIT_FSIZE, &limited) != 0) std::abort();
  }
  ~FullDiskAfter() {
    setrlimit(RLIMIT_FSIZE, &before_);
    std::signal(SIGXFSZ, previous_handler_);
  }
  FullDiskAfter(const FullDiskAfter&) = delete;
  FullDiskAfter& operator=(const FullDiskAfter&) = delete;

 private:
  rlimit before_{};
  void (*previous_handler_)(int) = SIG_DFL;
};

}  // namespace stitch::testing
