#pragma once
// Child processes of the launcher: one per service, output to a log file. Each gets SIGTERM when
// the thread that started it ends (PR_SET_PDEATHSIG: start them from the launcher's main
// thread), so a launcher killed outright leaves no service running.

#include <chrono>
#include <optional>
#include <string>
#include <vector>

#include <sys/resource.h>
#include <sys/types.h>

namespace stitch {

class ChildProcess {
 public:
  // Starts `program` with `args` (not including argv[0]); stdout and stderr go to `log_path`;
  // `niceness` above 0 gives it a lower scheduling priority (setpriority). Throws stitch::Error if
  // it cannot be started.
  ChildProcess(std::string name, const std::string& program, const std::vector<std::string>& args,
               const std::string& log_path, int niceness = 0);
  ~ChildProcess();  // kills the process if it still runs
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  const std::string& name() const { return name_; }
  const std::string& log_path() const { return log_path_; }
  pid_t pid() const { return pid_; }
  // The exit status once the process has ended: its exit code, or 128 + signal number.
  std::optional<int> Poll();
  // SIGTERM, then SIGKILL if it has not ended after `grace`. Returns the exit status.
  int Terminate(std::chrono::milliseconds grace);
  // The last `lines` lines of its log (for error messages).
  std::string LogTail(int lines) const;
  // The lines its log holds at ERROR level (stitch's log format: they begin "E "), the first
  // `max_lines` of them, and how many there are in all.
  std::vector<std::string> LogErrors(int max_lines, int* total) const;
  // Once it has ended: the CPU seconds (user + system) it and the children it waited for used.
  double cpu_seconds() const { return cpu_seconds_; }
  // Its resident memory now, in MB (VmRSS in /proc); -1 once it has ended or where /proc cannot say.
  double ResidentMb() const;
  // Once it has ended: its peak resident memory in MB (the kernel's ru_maxrss).
  double peak_resident_mb() const { return peak_resident_mb_; }

 private:
  void KeepUsage(const rusage& usage);

  std::string name_;
  std::string log_path_;
  pid_t pid_ = -1;
  std::optional<int> status_;
  double cpu_seconds_ = 0;
  double peak_resident_mb_ = 0;
};

// Folder of the running executable (to find the service programs beside `stitch`).
std::string ExecutableDir();

}  // namespace stitch
