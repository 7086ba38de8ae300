#pragma once
// Running the project's programs from tests: exit status and combined output.

#include <atomic>
#include <csignal>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

namespace stitch::testing {

struct CommandResult {
  int exit_code = -1;  // or 128 + signal
  std::string output;  // stdout and stderr
};

// Runs `args[0]` with the rest as arguments, waits at most `timeout_s`, then kills it. With
// `signal_after_s` >= 0 it sends `signal` that many seconds after the start, or after the output
// first holds `signal_after_output` where that is given (a program's set-up takes its own time,
// several seconds under a sanitizer on a slow machine).
CommandResult RunProgram(const std::vector<std::string>& args, double timeout_s = 120, int signal_after_s = -1,
                         int signal = SIGINT, const std::string& signal_after_output = "");

// Path of a built program: STITCH_BIN_DIR/name.
std::string Bin(const std::string& name);

// The short synthetic flight the integration tests fly (tests/short_flight.yaml).
std::string ShortFlightConfig();
// A file of the source tree, e.g. "benchmarks/quality.yaml".
std::string SourceFile(const std::string& relative);

// A JSON file (report.json, run.json); throws on a missing or malformed file.
nlohmann::json ReadJson(const std::string& path);

// The whole of a file as it is now ("" when it cannot be read).
std::string ReadWholeFile(const std::string& path);

// Whether a program is on the PATH.
bool OnPath(const std::string& program);

// A TCP socket connected to 127.0.0.1:`port`, receiving with a 3 s timeout; -1 when nothing
// listens there. The caller closes it.
int ConnectToLocalPort(int port);
// Sends `request` (raw bytes) to 127.0.0.1:`port` over TCP and returns what comes back until the
// server closes, 3 s pass, or (with `until_close` false) the end of the reply's headers; "" when
// nothing listens there.
std::string HttpExchange(int port, const std::string& request, bool until_close = true);
// "GET `path`": the reply's body when the status is 200, else nullopt.
std::optional<std::string> HttpGet(int port, const std::string& path);

// Threads that spin while it lives: a loaded machine for a test.
class BusyLoops {
 public:
  explicit BusyLoops(int threads);
  ~BusyLoops();
  BusyLoops(const BusyLoops&) = delete;
  BusyLoops& operator=(const BusyLoops&) = delete;

 private:
  std::atomic<bool> busy_{true};
  std::vector<std::thread> loops_;
};

}  // namespace stitch::testing
