#include "tests/test_process.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <sys/wait.h>
#include <unistd.h>
#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <fstream>
#include <optional>
#include <thread>

namespace stitch::testing {

CommandResult RunProgram(const std::vector<std::string>& args, double timeout_s, int signal_after_s, int signal,
                         const std::string& signal_after_output) {
  int pipe_fds[2];
  if (pipe(pipe_fds) != 0) return {};
  std::vector<std::string> storage = args;
  std::vector<char*> argv;
  for (auto& a : storage) argv.push_back(a.data());
  argv.push_back(nullptr);
  const pid_t pid = _Fork();  // no fork handlers in the child, as stitch::ChildProcess
  if (pid == 0) {
    dup2(pipe_fds[1], STDOUT_FILENO);
    dup2(pipe_fds[1], STDERR_FILENO);
    close(pipe_fds[0]);
    close(pipe_fds[1]);
    execv(argv[0], argv.data());
    _exit(127);
  }
  close(pipe_fds[1]);
  fcntl(pipe_fds[0], F_SETFL, O_NONBLOCK);
  CommandResult result;
  const auto start = std::chrono::steady_clock::now();
  bool signalled = false;
  std::optional<double> signal_clock_from;  // when the output first held signal_after_output
  if (signal_after_output.empty()) signal_clock_from = 0;
  int status = 0;
  while (true) {
    char buffer[4096];
    pollfd fd{pipe_fds[0], POLLIN, 0};
    poll(&fd, 1, 50);
    ssize_t n;
    while ((n = read(pipe_fds[0], buffer, sizeof(buffer))) > 0) result.output.append(buffer, n);
    const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (!signal_clock_from && result.output.find(signal_after_output) != std::string::npos) {
      signal_clock_from = elapsed;
    }
    if (signal_after_s >= 0 && !signalled && signal_clock_from && elapsed - *signal_clock_from >= signal_after_s) {
      kill(pid, signal);
      signalled = true;
    }
    if (waitpid(pid, &status, WNOHANG) == pid) break;
    if (elapsed > timeout_s) {
      kill(pid, SIGKILL);
      waitpid(pid, &status, 0);
      result.output += "\n[killed after " + std::to_string(timeout_s) + " s]\n";
      break;
    }
  }
  char buffer[4096];
  ssize_t n;
  while ((n = read(pipe_fds[0], buffer, sizeof(buffer))) > 0) result.output.append(buffer, n);
  close(pipe_fds[0]);
  result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  return result;
}

std::string Bin(const std::string& name) {
  return std::string(STITCH_BIN_DIR) + "/" + name;
}

std::string ShortFlightConfig() {
  return SourceFile("tests/short_flight.yaml");
}

std::string SourceFile(const std::string& relative) {
  return std::string(STITCH_SOURCE_DIR) + "/" + relative;
}

nlohmann::json ReadJson(const std::string& path) {
  std::ifstream in(path);
  return nlohmann::json::parse(in);
}

std::string ReadWholeFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

bool OnPath(const std::string& program) {
  return std::system(("command -v " + program + " > /dev/null 2>&1").c_str()) == 0;
}

int ConnectToLocalPort(int port) {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_port = htons(static_cast<uint16_t>(port));
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  timeval timeout{3, 0};
  setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof(timeout));
  if (connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof(address)) != 0) {
    close(fd);
    return -1;
  }
  return fd;
}

std::string HttpExchange(int port, const std::string& request, bool until_close) {
  const int fd = ConnectToLocalPort(port);
  if (fd < 0) return "";
  size_t sent = 0;
  while (sent < request.size()) {
    const ssize_t n = send(fd, request.data() + sent, request.size() - sent, MSG_NOSIGNAL);
    if (n <= 0) break;
    sent += static_cast<size_t>(n);
  }
  std::string reply;
  char buffer[65536];
  while (true) {
    const ssize_t n = recv(fd, buffer, sizeof(buffer), 0);
    if (n <= 0) break;
    reply.append(buffer, static_cast<size_t>(n));
    if (!until_close && reply.find("\r\n\r\n") != std::string::npos) break;
  }
  close(fd);
  return reply;
}

std::optional<std::string> HttpGet(int port, const std::string& path) {
  const std::string reply = HttpExchange(port, "GET " + path + " HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n");
  const size_t body = reply.find("\r\n\r\n");
  if (reply.rfind("HTTP/1.1 200", 0) != 0 || body == std::string::npos) return std::nullopt;
  return reply.substr(body + 4);
}

BusyLoops::BusyLoops(int threads) {
  for (int i = 0; i < threads; ++i) {
    loops_.emplace_back([this] {
      volatile uint64_t spin = 0;
      while (busy_.load(std::memory_order_relaxed)) spin = spin + 1;
    });
  }
}

BusyLoops::~BusyLoops() {
  busy_ = false;
  for (auto& loop : loops_) loop.join();
}

}  // namespace stitch::testing
