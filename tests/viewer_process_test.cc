// stitch-viewer as a process, under clients that break the rules (issue #45): its HTTP and
// WebSocket server must outlive any byte stream. In one process with a test's threads the server
// did not show the failure below (less of its threads' stacks taken by thread-local storage), so
// these start the real program.

#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <thread>

#include <gtest/gtest.h>

#include "services/common/bus.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/child_process.h"
#include "stitch/util/rng.h"
#include "tests/test_process.h"

namespace stitch {
namespace {

using namespace std::chrono_literals;
using testing::Bin;

struct RunningViewer {
  int port = bus::UnusedTcpPort();
  testing::TempDir dir;
  ChildProcess process{"viewer",
                       Bin("stitch-viewer"),
                       {"--lcm-url", "memq://", "--port", std::to_string(port), "--set", "viewer.max_pages=64"},
                       dir / "viewer.log"};

  RunningViewer() {
    for (int i = 0; i < 200 && !testing::HttpGet(port, "/state.json"); ++i) std::this_thread::sleep_for(25ms);
  }
  // Alive and serving the page.
  bool Serves() {
    if (process.Poll()) return false;
    const std::string reply = testing::HttpExchange(port, "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n");
    return reply.rfind("HTTP/1.1 200 OK", 0) == 0;
  }
  // Sends `bytes` on a new connection (after a WebSocket handshake when `upgrade`) and closes it.
  void Send(const std::string& bytes, bool upgrade) {
    const int fd = testing::ConnectToLocalPort(port);
    if (fd < 0) return;
    std::string out;
    if (upgrade) {
      out = "GET /live HTTP/1.1\r\nHost: 127.0.0.1:" + std::to_string(port) +
            "\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
            "Sec-WebSocket-Version: 13\r\nOrigin: http://127.0.0.1:" +
            std::to_string(port) + "\r\n\r\n";
    }
    out += bytes;
    send(fd, out.data(), out.size(), MSG_NOSIGNAL);
    close(fd);
  }
};

// A masked client frame header (binary, final) claiming `length` bytes of payload.
std::string FrameHeader(uint64_t length) {
  std::string frame = {'\x82'};
  if (length < 126) {
    frame += static_cast<char>(0x80 | length);
  } else if (length < 65536) {
    frame += static_cast<char>(0x80 | 126);
    for (int shift = 8; shift >= 0; shift -= 8) frame += static_cast<char>((length >> shift) & 0xff);
  } else {
    frame += static_cast<char>(0x80 | 127);
    for (int shift = 56; shift >= 0; shift -= 8) frame += static_cast<char>((length >> shift) & 0xff);
  }
  return frame + "\x01\x02\x03\x04";  // the mask
}

// A WebSocket frame whose header claims more than its client sends before it goes: the reading
// thread gives up, and civetweb's error path ran past the end of its 100 kB stack (the viewer
// died within 2 s, 13 of 13 tries from outside). Every length form, claims up to 2^64 - 1.
TEST(ViewerProcess, SurvivesWebSocketFramesCutOffByTheirClients) {
  RunningViewer viewer;
  ASSERT_TRUE(viewer.Serves()) << viewer.process.LogTail(10);
  for (const uint64_t claimed :
       {uint64_t{100}, uint64_t{3000}, uint64_t{100000}, uint64_t{1} << 31, (uint64_t{1} << 63) - 1, ~uint64_t{0}}) {
    for (const size_t sent : {size_t{0}, size_t{10}, size_t{1000}}) {
      if (sent < claimed) viewer.Send(FrameHeader(claimed) + std::string(sent, 'x'), /*upgrade=*/true);
    }
  }
  std::this_thread::sleep_for(3s);  // the readers give up as their clients go
  EXPECT_TRUE(viewer.Serves()) << viewer.process.LogTail(10);
}

// Arbitrary bytes: random streams, and requests and frames cut at random points, for a few
// seconds (the acceptance fuzzes for 10 minutes from outside).
TEST(ViewerProcess, SurvivesArbitraryBytes) {
  RunningViewer viewer;
  ASSERT_TRUE(viewer.Serves()) << viewer.process.LogTail(10);
  Rng rng(45);
  const std::string request = "GET /state.json HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n";
  // STITCH_VIEWER_FUZZ_S: how long (4 s by default; docs/security.md's figure: 600).
  const char* fuzz_s = std::getenv("STITCH_VIEWER_FUZZ_S");
  const auto duration = std::chrono::duration<double>(fuzz_s ? std::atof(fuzz_s) : 4.0);
  const auto start = std::chrono::steady_clock::now();
  int streams = 0;
  while (std::chrono::steady_clock::now() - start < duration) {
    std::string bytes;
    const int kind = static_cast<int>(rng.Uniform(0, 3));
    if (kind == 0) {  // noise
      bytes.resize(static_cast<size_t>(rng.Uniform(1, 3000)));
      for (char& c : bytes) c = static_cast<char>(rng.Uniform(0, 256));
      viewer.Send(bytes, rng.Uniform(0, 1) < 0.5);
    } else if (kind == 1) {  // a request cut off, or with a byte changed
      bytes = request.substr(0, static_cast<size_t>(rng.Uniform(0, request.size())));
      if (!bytes.empty() && rng.Uniform(0, 1) < 0.5)
        bytes[static_cast<size_t>(rng.Uniform(0, bytes.size()))] = static_cast<char>(rng.Uniform(0, 256));
      viewer.Send(bytes, false);
    } else {  // frames: random lengths and opcodes, payload cut at random
      for (int f = 0; f < 3; ++f) {
        std::string frame = FrameHeader(static_cast<uint64_t>(rng.Uniform(0, 1e6)));
        frame[0] = static_cast<char>(rng.Uniform(0, 256));
        bytes += frame + std::string(static_cast<size_t>(rng.Uniform(0, 500)), 'y');
      }
      viewer.Send(bytes, true);
    }
    ++streams;
  }
  std::this_thread::sleep_for(3s);
  EXPECT_TRUE(viewer.Serves()) << streams << " streams; " << viewer.process.LogTail(10);
}

}  // namespace
}  // namespace stitch
