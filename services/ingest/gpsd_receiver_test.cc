#include "services/ingest/gpsd_receiver.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <mutex>
#include <thread>

#include <gtest/gtest.h>

#include "services/common/bus.h"
#include "services/ingest/live_gnss.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/child_process.h"
#include "stitch/util/error.h"
#include "stitch/util/time.h"

namespace stitch {
namespace {

// What the receiver has handed over, waited for.
struct Received {
  std::mutex mutex;
  std::condition_variable changed;
  std::vector<GnssFix> fixes;

  GnssFixCallback Callback() {
    return [this](const GnssFix& fix) {
      std::lock_guard<std::mutex> lock(mutex);
      fixes.push_back(fix);
      changed.notify_all();
    };
  }
  bool WaitFor(size_t n, double seconds) {
    std::unique_lock<std::mutex> lock(mutex);
    return changed.wait_for(lock, std::chrono::duration<double>(seconds), [&] { return fixes.size() >= n; });
  }
};

// gpsd as its clients see it: JSON reports on TCP, one a line. Serves `lines` to each client that
// connects (after its ?WATCH), each `pauses_ms` after the one before (20 ms where not given), then
// closes the connection.
class FakeGpsd {
 public:
  explicit FakeGpsd(std::vector<std::string> lines, std::vector<int> pauses_ms = {})
      : lines_(std::move(lines)), pauses_ms_(std::move(pauses_ms)) {
    listener_ = socket(AF_INET, SOCK_STREAM, 0);
    const int yes = 1;
    setsockopt(listener_, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof(yes));
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    EXPECT_EQ(bind(listener_, reinterpret_cast<const sockaddr*>(&address), sizeof(address)), 0);
    socklen_t length = sizeof(address);
    getsockname(listener_, reinterpret_cast<sockaddr*>(&address), &length);
    port_ = ntohs(address.sin_port);
    listen(listener_, 4);
    thread_ = std::thread([this] { Serve(); });
  }
  ~FakeGpsd() {
    running_ = false;
    thread_.join();
    close(listener_);
  }
  int port() const { return port_; }
  int clients() const { return clients_.load(); }

 private:
  void Serve() {
    while (running_.load()) {
      pollfd ready{listener_, POLLIN, 0};
      if (poll(&ready, 1, 50) != 1) continue;
      const int client = accept(listener_, nullptr, nullptr);
      if (client < 0) continue;
      ++clients_;
      const auto say = [&](const std::string& line) {
        const std::string text = line + "\r\n";
        send(client, text.data(), text.size(), MSG_NOSIGNAL);
      };
      say(R"({"class":"VERSION","release":"3.22","rev":"3.22","proto_major":3,"proto_minor":14})");
      // The client's ?WATCH={...}; then the reports.
      char request[512];
      pollfd asked{client, POLLIN, 0};
      if (poll(&asked, 1, 2000) == 1) (void)recv(client, request, sizeof(request), 0);
      say(R"({"class":"DEVICES","devices":[{"class":"DEVICE","path":"/dev/ttyACM0","driver":"u-blox"}]})");
      say(R"({"class":"WATCH","enable":true,"json":true})");
      for (size_t i = 0; i < lines_.size(); ++i) {
        if (i < pauses_ms_.size()) std::this_thread::sleep_for(std::chrono::milliseconds(pauses_ms_[i]));
        say(lines_[i]);
        if (i >= pauses_ms_.size()) std::this_thread::sleep_for(std::chrono::milliseconds(20));
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
      close(client);
    }
  }

  std::vector<std::string> lines_;
  std::vector<int> pauses_ms_;
  int listener_ = -1, port_ = 0;
  std::atomic<int> clients_{0};
  std::atomic<bool> running_{true};
  std::thread thread_;
};

TEST(GpsdReceiver, TakesEachTpvWithAFixAndConnectsAgainWhenGpsdGoes) {
  FakeGpsd gpsd({
      R"({"class":"TPV","device":"/dev/ttyACM0","mode":1,"status":0})",  // no fix yet
      R"({"class":"SKY","device":"/dev/ttyACM0","hdop":0.9,"satellites":[]})",
      R"({"class":"TPV","device":"/dev/ttyACM0","mode":3,"status":2,"time":"2026-11-30T06:30:00.000Z",)"
      R"("lat":47.3684230,"lon":8.5390540,"altHAE":507.120,"altMSL":459.870,"epx":1.5,"epy":1.9,"epv":4.0})",
      R"({"class":"TPV","device":"/dev/ttyACM0","mode":2,"status":1,"time":"2026-11-30T06:30:00.200Z",)"
      R"("lat":47.3684240,"lon":8.5390550})",
  });
  Received received;
  const int64_t before = WallClockNs();
  GpsdReceiver receiver("127.0.0.1", std::to_string(gpsd.port()), 0.1, received.Callback());
  ASSERT_TRUE(received.WaitFor(2, 10)) << receiver.Describe();
  {
    std::lock_guard<std::mutex> lock(received.mutex);
    const GnssFix& dgps = received.fixes[0];
    EXPECT_EQ(dgps.type, GnssFixType::kDgps);
    EXPECT_NEAR(dgps.position.latitude_deg, 47.368423, 1e-9);
    EXPECT_NEAR(dgps.position.longitude_deg, 8.539054, 1e-9);
    EXPECT_NEAR(dgps.position.height_m, 507.12, 1e-9) << "above the ellipsoid";
    EXPECT_NEAR(dgps.horizontal_accuracy_m, 0.95, 1e-9) << "the larger of epx and epy, at 95%, as one sigma";
    EXPECT_NEAR(dgps.vertical_accuracy_m, 2.0, 1e-9);
    EXPECT_GE(dgps.t_ns, before - 100'000'000) << "its arrival on the wall clock, less the latency";
    EXPECT_LE(dgps.t_ns, WallClockNs() - 100'000'000);
    const GnssFix& flat = received.fixes[1];
    EXPECT_EQ(flat.type, GnssFixType::k2d);
    EXPECT_GT(flat.t_ns, dgps.t_ns);
    EXPECT_EQ(flat.horizontal_accuracy_m, 3.0) << "gpsd stated none";
  }
  // gpsd closes the connection after its reports: the receiver connects again and reads them anew.
  ASSERT_TRUE(received.WaitFor(4, 10)) << receiver.Describe();
  EXPECT_GE(gpsd.clients(), 2);
  EXPECT_NE(receiver.Describe().find("reports without a usable fix"), std::string::npos);
}

// #42: a fix keeps the receiver's time. Reports 100 ms apart by the receiver's clock arrive 20
// and 180 ms apart (every other one held up 80 ms, as a busy gpsd or serial line may): stamped on
// arrival they would be 80 ms off; by the receiver's time they are 100 ms apart.
TEST(GpsdReceiver, AFixKeepsTheReceiversTimeWhateverItsArrivalJitters) {
  std::vector<std::string> lines;
  std::vector<int> pauses_ms;
  for (int i = 0; i < 10; ++i) {
    char line[256];
    std::snprintf(line, sizeof(line),
                  R"({"class":"TPV","device":"/dev/ttyACM0","mode":3,"time":"2026-11-30T06:30:0%d.%d00Z",)"
                  R"("lat":47.36842%02d,"lon":8.5390540,"altHAE":507.1})",
                  i / 10, i % 10, i);
    lines.push_back(line);
    pauses_ms.push_back(i == 0 ? 0 : i % 2 == 1 ? 180 : 20);
  }
  FakeGpsd gpsd(lines, pauses_ms);
  Received received;
  std::vector<int64_t> arrivals;
  GpsdReceiver receiver("127.0.0.1", std::to_string(gpsd.port()), 0.0, [&](const GnssFix& fix) {
    std::lock_guard<std::mutex> lock(received.mutex);
    arrivals.push_back(WallClockNs());
    received.fixes.push_back(fix);
    received.changed.notify_all();
  });
  ASSERT_TRUE(received.WaitFor(10, 10)) << receiver.Describe();
  std::lock_guard<std::mutex> lock(received.mutex);
  // The mean distance of the spacings from 100 ms: a machine's own delay (a sanitizer, a busy CI)
  // moves a spacing or two, not the mean.
  double stamped_off_ms = 0, arrival_off_ms = 0;
  for (size_t i = 1; i < 10; ++i) {
    stamped_off_ms += std::abs((received.fixes[i].t_ns - received.fixes[i - 1].t_ns) * 1e-6 - 100.0) / 9;
    arrival_off_ms += std::abs((arrivals[i] - arrivals[i - 1]) * 1e-6 - 100.0) / 9;
  }
  EXPECT_LT(stamped_off_ms, 25.0) << "stamped on arrival, the spacings would be 80 ms off";
  EXPECT_GT(arrival_off_ms, 50.0) << "the reports did not arrive with the jitter the test means";
  // On the wall clock: never later than its arrival.
  for (size_t i = 0; i < 10; ++i) EXPECT_LE(received.fixes[i].t_ns, arrivals[i]);
}

TEST(GpsdReceiver, WaitsForAGpsdThatIsNotThereYet) {
  const int port = bus::UnusedTcpPort();
  Received received;
  GpsdReceiver receiver("127.0.0.1", std::to_string(port), 0, received.Callback());
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  EXPECT_EQ(receiver.fixes(), 0);
  EXPECT_NE(receiver.Describe().find("0 connections"), std::string::npos) << receiver.Describe();
}

TEST(LiveGnss, OpensTheReceiverItsSettingNames) {
  Received received;
  EXPECT_THROW(OpenLiveGnssReceiver("serial:/dev/ttyACM0", 0, received.Callback()), Error);
  EXPECT_THROW(OpenLiveGnssReceiver("mavlink:14550", 0, received.Callback()), Error) << "no port";
  EXPECT_THROW(OpenLiveGnssReceiver("mavlink-serial:/dev/no-such-controller:57600", 0, received.Callback()), Error);
  EXPECT_THROW(OpenLiveGnssReceiver("mavlink-serial:/dev/ttyACM0:fast", 0, received.Callback()), Error);
  const auto mavlink = OpenLiveGnssReceiver("mavlink:127.0.0.1:0", 0, received.Callback());
  EXPECT_NE(mavlink->Describe().find("from MAVLink"), std::string::npos);
  const auto gpsd =
      OpenLiveGnssReceiver("gpsd:127.0.0.1:" + std::to_string(bus::UnusedTcpPort()), 0, received.Callback());
  EXPECT_NE(gpsd->Describe().find("from gpsd at 127.0.0.1:"), std::string::npos);
  EXPECT_NE(OpenLiveGnssReceiver("gpsd", 0, received.Callback())->Describe().find("localhost:2947"), std::string::npos);
  // A MAVLink signing key: a MAVLink receiver checks signatures; gpsd's fixes carry none.
  const Secret key = RandomSecret();
  EXPECT_NE(OpenLiveGnssReceiver("mavlink:127.0.0.1:0", 0, received.Callback(), key)->Describe().find("0 unsigned"),
            std::string::npos);
  EXPECT_THROW(OpenLiveGnssReceiver("gpsd", 0, received.Callback(), key), Error);
}

// The real gpsd, fed an NMEA log by gpsfake (Debian's gpsd-clients) as a receiver on a serial port
// would feed it: its GGA fixes reach the receiver with their places and heights.
TEST(GpsdReceiver, ReadsTheFixesGpsdMakesOfARealReceiversNmea) {
  if (std::system("command -v gpsfake > /dev/null 2>&1") != 0) {
    GTEST_SKIP() << "gpsfake is not installed (Debian: gpsd gpsd-clients python3-gps)";
  }
  testing::TempDir dir;
  const std::string log = dir / "receiver.nmea";
  {
    std::ofstream out(log);
    const auto sentence = [&](const std::string& body) {
      unsigned char sum = 0;
      for (char c : body) sum ^= static_cast<unsigned char>(c);
      char tail[8];
      std::snprintf(tail, sizeof(tail), "*%02X", sum);
      out << "$" << body << tail << "\r\n";
    };
    for (int i = 0; i < 30; ++i) {
      char time[16], minutes[16];
      std::snprintf(time, sizeof(time), "0630%02d.00", i);
      std::snprintf(minutes, sizeof(minutes), "%07.4f", 22.1054 + 0.0001 * i);  // 47 deg 22.1054' N, moving north
      sentence(std::string("GPGGA,") + time + ",47" + minutes + ",N,00832.3432,E,1,09,0.9,459.870,M,47.250,M,,");
      sentence(std::string("GPRMC,") + time + ",A,47" + minutes + ",N,00832.3432,E,0.5,0.0,301126,,,A");
    }
  }
  const int port = bus::UnusedTcpPort();
  ChildProcess gpsfake("gpsfake", "/usr/bin/gpsfake", {"-q", "-c", "0.05", "-P", std::to_string(port), log},
                       dir / "gpsfake.log");
  Received received;
  GpsdReceiver receiver("127.0.0.1", std::to_string(port), 0, received.Callback());
  if (!received.WaitFor(5, 30)) {
    std::ifstream said(dir / "gpsfake.log");
    FAIL() << receiver.Describe() << "\ngpsfake: " << std::string(std::istreambuf_iterator<char>(said), {});
  }
  std::lock_guard<std::mutex> lock(received.mutex);
  int with_height = 0;
  for (const GnssFix& fix : received.fixes) {
    EXPECT_NEAR(fix.position.latitude_deg, 47.0 + 22.1054 / 60, 0.0001);
    EXPECT_NEAR(fix.position.longitude_deg, 8.0 + 32.3432 / 60, 1e-6);
    // gpsd reports a 2D fix where an epoch's RMC came before its GGA (the log's start): no height.
    if (fix.type == GnssFixType::k2d) continue;
    ++with_height;
    EXPECT_NEAR(fix.position.height_m, 459.87 + 47.25, 0.01) << "the height above the ellipsoid: MSL plus the geoid";
  }
  EXPECT_GE(with_height, 3);
}

}  // namespace
}  // namespace stitch
