#include "services/common/service.h"

#include <csignal>

namespace stitch {
namespace {

std::atomic<bool> g_stop_requested{false};

extern "C" void OnStopSignal(int) {
  g_stop_requested.store(true);
}

}  // namespace

const std::atomic<bool>& InstallStopSignals() {
  struct sigaction action {};
  action.sa_handler = OnStopSignal;
  sigemptyset(&action.sa_mask);
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);
  return g_stop_requested;
}

void ServiceCommandLine::Register(ArgParser* args) {
  args->AddOption("--lcm-url", &lcm_url, "URL", "LCM bus (udpm://group:port?ttl=0, or memq:// in one process)");
  args->AddOption("--agent", &agent, "NAME", "agent (aircraft) name; prefixes every channel");
  args->AddOption("--config", &config_path, "FILE", "YAML settings (see config/default.yaml)");
  args->AddOption("--set", &settings, "KEY=VALUE",
                  "a setting over the file, e.g. tracker.tracking.orb.num_features=1500");
  args->AddOption("--log-level", &log_level, "LEVEL", "debug, info, warning or error");
}

void ServiceCommandLine::Apply(const std::string& service_name) const {
  SetLogLevel(ParseLogLevel(log_level));
  bus::CheckAgentName(agent);
  SetLogTag(service_name + "@" + agent);
}

Heartbeat::Heartbeat(bus::Publisher* publisher, std::string service, std::function<Counts()> counts)
    : publisher_(publisher), service_(std::move(service)), counts_(std::move(counts)) {}

Heartbeat::~Heartbeat() {
  Stop();
}

void Heartbeat::SetState(int8_t state, const std::string& detail) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    state_ = state;
    detail_ = detail;
  }
  PublishNow();
}

void Heartbeat::PublishNow() {
  stitch::service_status_t status{};
  {
    std::lock_guard<std::mutex> lock(mutex_);
    status.state = state_;
    status.detail = detail_;
  }
  status.service = service_;
  const Counts counts = counts_();
  status.items_in = counts.items_in;
  status.items_out = counts.items_out;
  status.items_rejected = counts.items_rejected;
  publisher_->Publish(bus::Channel(publisher_->agent(), bus::kService), &status);
}

void Heartbeat::Start() {
  if (running_.exchange(true)) return;
  PublishNow();
  thread_ = std::thread([this] {
    int ticks = 0;
    while (running_.load()) {
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
      if (++ticks % 20 == 0) PublishNow();
    }
  });
}

void Heartbeat::Stop() {
  if (!running_.exchange(false)) return;
  if (thread_.joinable()) thread_.join();
}

}  // namespace stitch
