#pragma once
// Minimal leveled logging to stderr, one line per call, safe from several threads.
//   STITCH_LOG(INFO) << "tracker: frame " << i << " lost (" << why << ")";
// The threshold is process-wide and meant to be set once by main() (SetLogLevel).

#include <sstream>
#include <string>

namespace stitch {

enum class LogLevel { kDebug = 0, kInfo = 1, kWarning = 2, kError = 3 };

void SetLogLevel(LogLevel level);
LogLevel GetLogLevel();
// Parses "debug", "info", "warning", "error"; throws stitch::Error otherwise.
LogLevel ParseLogLevel(const std::string& name);
// Prefix for every line of this process, e.g. "tracker". Set once by main().
void SetLogTag(const std::string& tag);

class LogLine {
 public:
  LogLine(LogLevel level, const char* file, int line);
  ~LogLine();
  std::ostream& stream() { return stream_; }

 private:
  LogLevel level_;
  std::ostringstream stream_;
};

}  // namespace stitch

#define STITCH_LOG_DEBUG ::stitch::LogLevel::kDebug
#define STITCH_LOG_INFO ::stitch::LogLevel::kInfo
#define STITCH_LOG_WARNING ::stitch::LogLevel::kWarning
#define STITCH_LOG_ERROR ::stitch::LogLevel::kError
#define STITCH_LOG(level)                             \
  if (STITCH_LOG_##level < ::stitch::GetLogLevel()) { \
  } else                                              \
    ::stitch::LogLine(STITCH_LOG_##level, __FILE__, __LINE__).stream()
