#include "stitch/util/child_process.h"

#include <fcntl.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>
#include <csignal>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <filesystem>
#include <fstream>
#include <thread>

#include "stitch/util/error.h"

namespace stitch {

ChildProcess::ChildProcess(std::string name, const std::string& program, const std::vector<std::string>& args,
                           const std::string& log_path, int niceness)
    : name_(std::move(name)), log_path_(log_path) {
  if (access(program.c_str(), X_OK) != 0)
    throw Error(program + ": not found or not executable (is the build complete?)");
  const int log_fd = open(log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (log_fd < 0) throw Error(log_path + ": cannot create log file: " + std::strerror(errno));
  std::vector<std::string> argv_storage{program};
  argv_storage.insert(argv_storage.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& a : argv_storage) argv.push_back(a.data());
  argv.push_back(nullptr);
  // The child runs only async-signal-safe calls until exec, and it is started by _Fork, which runs
  // no fork handlers: a library's handler (PROJ closes its database in the child) allocates, and
  // where another of the launcher's threads held the allocator's lock at the fork (AddressSanitizer's
  // allocator is not reset in the child) the child waited for it forever, never a service.
  const std::string exec_failed = "exec " + program + " failed\n";
  const pid_t launcher = getpid();
  pid_ = _Fork();
  if (pid_ < 0) {
    close(log_fd);
    throw Error("cannot start " + program + ": " + std::strerror(errno));
  }
  if (pid_ == 0) {
    // Child: ends with the launcher (SIGTERM, so a service still writes its outputs) even when the
    // launcher is killed outright; then output to the log, default signal dispositions, the program.
    prctl(PR_SET_PDEATHSIG, SIGTERM);
    if (getppid() != launcher) _exit(128 + SIGTERM);  // it died before the line above
    dup2(log_fd, STDOUT_FILENO);
    dup2(log_fd, STDERR_FILENO);
    signal(SIGINT, SIG_DFL);
    signal(SIGTERM, SIG_DFL);
    if (niceness > 0) (void)setpriority(PRIO_PROCESS, 0, niceness);  // best effort: it runs either way
    execv(program.c_str(), argv.data());
    (void)!write(STDERR_FILENO, exec_failed.data(), exec_failed.size());
    _exit(127);
  }
  close(log_fd);
}

ChildProcess::~ChildProcess() {
  if (!status_ && pid_ > 0) Terminate(std::chrono::milliseconds(2000));
}

std::optional<int> ChildProcess::Poll() {
  if (status_ || pid_ <= 0) return status_;
  int raw = 0;
  rusage usage{};
  const pid_t done = wait4(pid_, &raw, WNOHANG, &usage);
  if (done == pid_) {
    status_ = WIFEXITED(raw) ? WEXITSTATUS(raw) : 128 + WTERMSIG(raw);
    KeepUsage(usage);
  }
  return status_;
}

int ChildProcess::Terminate(std::chrono::milliseconds grace) {
  if (Poll()) return *status_;
  kill(pid_, SIGTERM);
  const auto deadline = std::chrono::steady_clock::now() + grace;
  while (std::chrono::steady_clock::now() < deadline) {
    if (Poll()) return *status_;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  kill(pid_, SIGKILL);
  int raw = 0;
  rusage usage{};
  wait4(pid_, &raw, 0, &usage);
  status_ = WIFEXITED(raw) ? WEXITSTATUS(raw) : 128 + WTERMSIG(raw);
  KeepUsage(usage);
  return *status_;
}

void ChildProcess::KeepUsage(const rusage& usage) {
  cpu_seconds_ =
      usage.ru_utime.tv_sec + usage.ru_utime.tv_usec * 1e-6 + usage.ru_stime.tv_sec + usage.ru_stime.tv_usec * 1e-6;
  peak_resident_mb_ = usage.ru_maxrss / 1024.0;  // kB on Linux
}

double ChildProcess::ResidentMb() const {
  if (status_ || pid_ <= 0) return -1;
  std::ifstream in("/proc/" + std::to_string(pid_) + "/status");
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("VmRSS:", 0) == 0) return std::atof(line.c_str() + 6) / 1024.0;  // "VmRSS:  1234 kB"
  }
  return -1;
}

std::string ChildProcess::LogTail(int lines) const {
  std::ifstream in(log_path_);
  std::deque<std::string> tail;
  std::string line;
  while (std::getline(in, line)) {
    tail.push_back(line);
    if (static_cast<int>(tail.size()) > lines) tail.pop_front();
  }
  std::string text;
  for (const auto& l : tail) text += "    " + l + "\n";
  return text;
}

std::vector<std::string> ChildProcess::LogErrors(int max_lines, int* total) const {
  std::ifstream in(log_path_);
  std::vector<std::string> errors;
  *total = 0;
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("E ", 0) != 0) continue;
    if (static_cast<int>(errors.size()) < max_lines) errors.push_back(line);
    ++*total;
  }
  return errors;
}

std::string ExecutableDir() {
  std::error_code error;
  const auto self = std::filesystem::read_symlink("/proc/self/exe", error);
  if (error) return ".";
  return self.parent_path().string();
}

}  // namespace stitch
