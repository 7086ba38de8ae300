#include "tools/stitch/launch/run_services.h"

#include <algorithm>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <filesystem>

namespace fs = std::filesystem;

namespace stitch {

RunServices::RunServices(const LaunchPlan& plan, const SplitNetwork* network) : plan_(plan), network_(network) {}

std::unique_ptr<ChildProcess> RunServices::Start(const PlannedService& service, const std::string& log_name) const {
  if (network_) service.on_ground ? network_->EnterGround() : network_->EnterAircraft();
  auto child =
      std::make_unique<ChildProcess>(service.name, ExecutableDir() + "/" + service.program, service.args,
                                     (fs::path(plan_.out) / "logs" / (log_name + ".log")).string(), service.niceness);
  if (network_) network_->EnterAircraft();  // the launcher listens on the aircraft's side
  return child;
}

void RunServices::StartAll() {
  for (const PlannedService& service : plan_.services) children_.push_back(Start(service, service.name));
}

void RunServices::RestartViewer(std::unique_ptr<ChildProcess>* viewer) {
  const int status = *(*viewer)->Poll();
  const int restarts = static_cast<int>(ended_viewers_.size());
  std::string note =
      "the viewer exited unexpectedly (status " + std::to_string(status) + "; " + (*viewer)->log_path() + ")";
  const auto planned = std::find_if(plan_.services.begin(), plan_.services.end(),
                                    [](const PlannedService& s) { return s.name == "viewer"; });
  std::unique_ptr<ChildProcess> again;
  if (restarts < kViewerRestarts && planned != plan_.services.end()) {
    try {
      again = Start(*planned, "viewer-" + std::to_string(restarts + 2));
      note += "; started again, the flight goes on";
    } catch (const std::exception& e) {
      note += std::string("; cannot start it again (") + e.what() + "), the flight goes on without it";
    }
  } else {
    note += "; not started again (it ended " + std::to_string(restarts + 1) + " times), the flight goes on without it";
  }
  std::fprintf(stderr, "stitch run: %s\n", note.c_str());
  viewer_notes_.push_back(note);
  ended_viewers_.push_back(std::move(*viewer));
  *viewer = std::move(again);
}

ChildProcess* RunServices::Find(const std::string& name) const {
  for (const auto& child : children_) {
    if (child->name() == name) return child.get();
  }
  return nullptr;
}

std::string RunServices::Failure() {
  for (auto& child : children_) {
    if (child->name() == "viewer" && child->Poll()) RestartViewer(&child);
    if (!child) break;  // not started again: it is erased below
  }
  children_.erase(std::remove(children_.begin(), children_.end(), nullptr), children_.end());
  for (const auto& child : children_) {
    if (child->name() == "ingest" || child->name() == "viewer" || !child->Poll()) continue;
    return "the " + child->name() + " exited unexpectedly (status " + std::to_string(*child->Poll()) + "); end of " +
           child->log_path() + ":\n" + child->LogTail(8);
  }
  ChildProcess* ingest = Find("ingest");
  if (ingest && ingest->Poll() && *ingest->Poll() != 0) {
    return "ingest failed (status " + std::to_string(*ingest->Poll()) + "); end of " + ingest->log_path() + ":\n" +
           ingest->LogTail(8);
  }
  return "";
}

bool RunServices::IngestDone() {
  ChildProcess* ingest = Find("ingest");
  return ingest && ingest->Poll() && *ingest->Poll() == 0;
}

void RunServices::SampleMemory(double seconds, int frame) {
  if (!memory_samples_) {
    memory_samples_ = std::make_unique<std::ofstream>(fs::path(plan_.out) / "memory.tsv");
    *memory_samples_ << "seconds\tframe\tservice\trss_mb\n";
  }
  for (const auto& child : children_) {
    const double mb = child->ResidentMb();
    if (mb < 0) continue;
    char row[160];
    std::snprintf(row, sizeof(row), "%.1f\t%d\t%s\t%.1f\n", seconds, frame, child->name().c_str(), mb);
    *memory_samples_ << row;
  }
  memory_samples_->flush();
}

std::string RunServices::StopAll(bool keep_viewer, bool quiet_statuses) {
  std::string failure;
  for (auto it = children_.rbegin(); it != children_.rend(); ++it) {
    if ((*it)->name() == "viewer" && keep_viewer) continue;
    const double grace_s = StopGraceSeconds(plan_, (*it)->name());
    const int status = (*it)->Terminate(std::chrono::milliseconds(static_cast<int64_t>(grace_s * 1000)));
    if (status != 0 && status != 128 + SIGTERM && status != 130 && !quiet_statuses && failure.empty()) {
      failure = (*it)->name() + " ended with status " + std::to_string(status) + "; see " + (*it)->log_path();
    }
  }
  return failure;
}

void RunServices::Report(RunInfo* info) const {
  for (const auto& child : children_) {
    if (!child->Poll()) continue;
    info->peak_rss_mb[child->name()] = child->peak_resident_mb();
    info->cpu_s[child->name()] = child->cpu_seconds();
  }
  for (const auto& viewer : ended_viewers_) {  // a viewer that ended and was started again
    info->peak_rss_mb["viewer"] = std::max(info->peak_rss_mb["viewer"], viewer->peak_resident_mb());
    info->cpu_s["viewer"] += viewer->cpu_seconds();
  }
  info->notes.insert(info->notes.end(), viewer_notes_.begin(), viewer_notes_.end());
  for (const auto& child : children_) {
    if (child->name().rfind("link", 0) != 0) continue;
    const std::string tail = child->LogTail(3);
    const size_t said = tail.rfind("stopped: ");
    if (said != std::string::npos) {
      info->link_figures.push_back(child->name() + ": " + tail.substr(said + 9, tail.find('\n', said) - said - 9));
    }
  }
  // What a service logged as an error (a record it could not write on a full disk, updates it had
  // to drop) is said here too, not only in its log.
  for (const auto& child : children_) {
    int total = 0;
    const std::vector<std::string> errors = child->LogErrors(3, &total);
    for (const std::string& line : errors) {
      std::fprintf(stderr, "stitch run: the %s logged: %s\n", child->name().c_str(), line.c_str());
      info->notes.push_back("the " + child->name() + " logged: " + line);
    }
    if (total > static_cast<int>(errors.size())) {
      info->notes.push_back("the " + child->name() + " logged " + std::to_string(total) + " errors in all; see " +
                            child->log_path());
    }
  }
}

namespace {

// "mapper 148 MB, tracker 141 MB": each service's figure, formatted by `format`.
std::string PerService(const std::map<std::string, double>& figures, const char* format) {
  std::string text;
  for (const auto& [service, value] : figures) {
    char figure[32];
    std::snprintf(figure, sizeof(figure), format, value);
    text += (text.empty() ? "" : ", ") + service + " " + figure;
  }
  return text;
}

}  // namespace

void PrintRunSummary(const RunInfo& info, const std::string& evaluation_summary, const std::string& out,
                     int exit_code) {
  std::printf("%s in %.1f s\n%s", info.interrupted ? "interrupted" : (exit_code ? "failed" : "done"), info.wall_seconds,
              evaluation_summary.c_str());
  if (!info.peak_rss_mb.empty()) {
    std::printf("  peak memory       %s (memory.tsv: every 2 s)\n", PerService(info.peak_rss_mb, "%.0f MB").c_str());
  }
  if (!info.cpu_s.empty()) {
    double total = 0;
    for (const auto& item : info.cpu_s) total += item.second;
    std::printf("  CPU               %s; %.1f s in all (user + system)\n", PerService(info.cpu_s, "%.1f s").c_str(),
                total);
  }
  for (const auto& figures : info.link_figures) std::printf("%s\n", figures.c_str());
  for (const auto& figures : info.geo_figures) std::printf("%s\n", figures.c_str());
  for (const auto& note : info.notes) std::printf("note: %s\n", note.c_str());
  std::printf("outputs: %s/{trajectory.tum, map.ply, report.json, trajectory.png, logs/%s}\n", out.c_str(),
              info.geo_figures.empty()
                  ? ""
                  : ", geo/ (WGS84: CSV, GeoJSON, KML; map_enu.ply and colmap_enu/ in metres, map_utm.las in UTM)");
  std::printf(
      "  trajectory.tum and map.ply are in the largest map's frame: its largest submap's first camera (z along the "
      "optical axis), in units of that camera's median scene depth (not metres; ATE is in the ground truth's metres, "
      "after a Sim3 alignment); docs/frames-and-units.md\n");
}

}  // namespace stitch
