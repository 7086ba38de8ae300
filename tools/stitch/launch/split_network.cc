#include "tools/stitch/launch/split_network.h"

#include <fcntl.h>
#include <sched.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <sstream>
#include <thread>
#include <vector>

#include "stitch/util/child_process.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

std::string FindIp() {
  for (const char* path : {"/usr/sbin/ip", "/sbin/ip", "/usr/bin/ip", "/bin/ip"}) {
    if (access(path, X_OK) == 0) return path;
  }
  throw Error("`ip` (iproute2) is not installed");
}

}  // namespace

SplitNetwork::SplitNetwork(const std::string& log_path) : ip_(FindIp()), log_path_(log_path) {
  if (geteuid() != 0) throw Error("network namespaces need root (run as root, or leave out --netns)");
  const std::string tag = "stitch-" + std::to_string(getpid());
  aircraft_ = tag + "-air";
  ground_ = tag + "-gnd";
  Ip("netns add " + aircraft_);
  created_aircraft_ = true;
  Ip("netns add " + ground_);
  created_ground_ = true;
  const std::string air_link = "st" + std::to_string(getpid()) + "a",
                    ground_link = "st" + std::to_string(getpid()) + "g";
  Ip("link add " + air_link + " netns " + aircraft_ + " type veth peer name " + ground_link + " netns " + ground_);
  for (const auto& [side, link, address] : {std::tuple(aircraft_, air_link, std::string(kAircraftAddress)),
                                            std::tuple(ground_, ground_link, std::string(kGroundAddress))}) {
    Ip("-n " + side + " addr add " + address + "/30 dev " + link);
    Ip("-n " + side + " link set " + link + " up");
    Ip("-n " + side + " link set lo up");
    Ip("-n " + side + " link set lo multicast on");
    Ip("-n " + side + " route add 224.0.0.0/4 dev lo");  // each side's LCM bus stays on its loopback
  }
}

SplitNetwork::~SplitNetwork() {
  for (const auto& [created, name] : {std::pair(created_aircraft_, aircraft_), std::pair(created_ground_, ground_)}) {
    if (!created) continue;
    try {
      Ip("netns delete " + name);  // the veth pair goes with it
    } catch (const Error&) {
      // Reported in the log; nothing else to do while unwinding.
    }
  }
}

void SplitNetwork::Ip(const std::string& arguments) const {
  std::vector<std::string> args;
  std::istringstream words(arguments);
  for (std::string word; words >> word;) args.push_back(word);
  ChildProcess ip("ip", ip_, args, log_path_ + ".tmp");
  std::optional<int> status;
  for (int i = 0; i < 500 && !(status = ip.Poll()); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  const std::string output = ip.LogTail(4);
  {
    FILE* log = std::fopen(log_path_.c_str(), "a");
    if (log) {
      std::fprintf(log, "ip %s -> %d\n%s", arguments.c_str(), status.value_or(-1), output.c_str());
      std::fclose(log);
    }
  }
  std::remove((log_path_ + ".tmp").c_str());
  if (status.value_or(-1) != 0) {
    throw Error("`ip " + arguments + "` failed" + (output.empty() ? std::string() : ":\n" + output) +
                "(are network namespaces permitted here?)");
  }
}

void SplitNetwork::Enter(const std::string& name) const {
  const std::string path = "/run/netns/" + name;
  const int fd = open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw Error("cannot open " + path + ": " + std::strerror(errno));
  const int status = setns(fd, CLONE_NEWNET);
  const int error = errno;
  close(fd);
  if (status != 0) throw Error("cannot enter network namespace " + name + ": " + std::strerror(error));
}

std::string SplitNetwork::Describe() const {
  return "aircraft in netns " + aircraft_ + " (" + kAircraftAddress + "), ground in netns " + ground_ + " (" +
         kGroundAddress + "), joined by a veth pair";
}

}  // namespace stitch
