#include "stitch/util/log.h"

#include <atomic>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <mutex>

#include "stitch/util/error.h"

namespace stitch {
namespace {

// Process-wide logging settings: written once by main(), read by every thread.
std::atomic<int> g_level{static_cast<int>(LogLevel::kInfo)};
std::mutex g_tag_mutex;
std::string& Tag() {
  static std::string tag;
  return tag;
}

const char* LevelLetter(LogLevel level) {
  switch (level) {
    case LogLevel::kDebug:
      return "D";
    case LogLevel::kInfo:
      return "I";
    case LogLevel::kWarning:
      return "W";
    case LogLevel::kError:
      return "E";
  }
  return "?";
}

}  // namespace

void SetLogLevel(LogLevel level) {
  g_level = static_cast<int>(level);
}
LogLevel GetLogLevel() {
  return static_cast<LogLevel>(g_level.load());
}

LogLevel ParseLogLevel(const std::string& name) {
  if (name == "debug") return LogLevel::kDebug;
  if (name == "info") return LogLevel::kInfo;
  if (name == "warning") return LogLevel::kWarning;
  if (name == "error") return LogLevel::kError;
  throw Error("unknown log level '" + name + "' (use debug, info, warning or error)");
}

void SetLogTag(const std::string& tag) {
  std::lock_guard<std::mutex> lock(g_tag_mutex);
  Tag() = tag;
}

LogLine::LogLine(LogLevel level, const char* /*file*/, int /*line*/) : level_(level) {}

LogLine::~LogLine() {
  const auto now = std::chrono::system_clock::now();
  const std::time_t seconds = std::chrono::system_clock::to_time_t(now);
  const int millis =
      static_cast<int>(std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch()).count() % 1000);
  std::tm local{};
  localtime_r(&seconds, &local);
  char stamp[32];
  std::strftime(stamp, sizeof(stamp), "%H:%M:%S", &local);
  std::string tag;
  {
    std::lock_guard<std::mutex> lock(g_tag_mutex);
    tag = Tag();
  }
  char millis_text[8];
  std::snprintf(millis_text, sizeof(millis_text), ".%03d", millis);
  const std::string line = std::string(LevelLetter(level_)) + " " + stamp + millis_text + (tag.empty() ? "" : " ") +
                           tag + "] " + stream_.str() + "\n";
  // One write per line keeps lines from different threads whole. Not fprintf: on the unbuffered
  // stderr it formats into an 8 kB buffer on the stack, too much for a library thread's small
  // stack under AddressSanitizer.
  std::fwrite(line.data(), 1, line.size(), stderr);
}

}  // namespace stitch
