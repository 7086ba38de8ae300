// stitch spy: lcm-spy with stitch's message types, or a recorded log decoded with them.

#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>

#include "services/common/bus.h"
#include "stitch/util/args.h"
#include "stitch/util/child_process.h"
#include "stitch/util/error.h"
#include "tools/stitch/commands.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

constexpr char kLcmJar[] = "/usr/share/java/lcm.jar";
constexpr char kChartJar[] = "/usr/share/java/jchart2d.jar";  // lcm-spy's plots

// stitch-lcmtypes.jar: beside the programs in a build (build/bin/../share/java), or installed
// (<prefix>/bin/../share/java).
std::string TypesJar() {
  const fs::path jar = (fs::path(ExecutableDir()) / ".." / "share" / "java" / "stitch-lcmtypes.jar").lexically_normal();
  if (!fs::exists(jar)) {
    throw Error(jar.string() +
                " not found: stitch was built without its Java types (install Debian's default-jdk-headless and "
                "liblcm-java, then build again)");
  }
  if (!fs::exists(kLcmJar)) throw Error(std::string(kLcmJar) + " not found (Debian package liblcm-java)");
  return jar.string();
}

[[noreturn]] void ExecJava(std::vector<std::string> command) {
  std::vector<char*> argv;
  for (std::string& s : command) argv.push_back(s.data());
  argv.push_back(nullptr);
  std::fflush(stdout);
  execvp("java", argv.data());
  throw Error(std::string("cannot run java (Debian package default-jre-headless): ") + std::strerror(errno));
}

}  // namespace

int SpyCommand(int argc, char** argv) {
  std::string lcm_url = bus::DefaultLcmUrl(), log;
  bool classpath = false;
  ArgParser args("stitch spy",
                 "lcm-spy with stitch's message types: every channel of a live bus decoded, field by field (a window; "
                 "needs a display). Debian's lcm-spy wrapper passes a JVM flag Java 17 refuses and offers no types; "
                 "this starts the same program with both mended. With --log, decodes a recorded log (stitch record, "
                 "lcm-logger) instead, one line per channel, without a display.");
  args.AddOption("--lcm-url", &lcm_url, "URL", "the bus to watch");
  args.AddOption("--log", &log, "FILE", "decode this LCM log and print, per channel, its type, messages decoded, bytes and bytes per second");
  args.AddFlag("--classpath", &classpath,
               "print the Java class path holding stitch's types (for your own Java tools) and exit");
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    const std::string jar = TypesJar();
    std::string path = std::string(kLcmJar) + ":" + jar;
    // lcm-spy's plots; lcm.jar's own classes that use them cannot load without it.
    if (fs::exists(kChartJar)) path += std::string(":") + kChartJar;
    if (classpath) {
      std::printf("%s\n", path.c_str());
      return 0;
    }
    if (!log.empty()) {
      if (!fs::is_regular_file(log)) throw Error(log + ": no such log file");
      ExecJava({"java", "-Xmx256m", "-cp", path, "stitch.tools.DecodeLog", log});
    }
    if (!std::getenv("DISPLAY") && !std::getenv("WAYLAND_DISPLAY")) {
      throw Error(
          "lcm-spy opens a window and there is no display (DISPLAY is not set); use --log FILE on a "
          "recording, or run it where there is a desktop");
    }
    ExecJava(
        {"java", "-Djava.net.preferIPv4Stack=true", "-Xmx128m", "-cp", path, "lcm.spy.Spy", "--lcm-url=" + lcm_url});
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch spy: %s\n", e.what());
    return 1;
  }
}

}  // namespace stitch
