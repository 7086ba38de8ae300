#include "stitch/records/run_info.h"

#include <filesystem>
#include <fstream>

#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace fs = std::filesystem;

namespace stitch {

nlohmann::json RunInfo::ToJson() const {
  return {{"source", source},
          {"dataset", dataset},
          {"start_frame", start_frame},
          {"frames_total", frames_total},
          {"frames_unusable", frames_unusable},
          {"failures", failures},
          {"on_loss", on_loss},
          {"pacing", pacing},
          {"lcm_url", lcm_url},
          {"agent", agent},
          {"started_at", started_at},
          {"wall_seconds", wall_seconds},
          {"interrupted", interrupted},
          {"link", link},
          {"link_figures", link_figures},
          {"geo_figures", geo_figures},
          {"notes", notes},
          {"peak_rss_mb", peak_rss_mb},
          {"cpu_s", cpu_s}};
}

RunInfo RunInfo::FromJson(const nlohmann::json& j) {
  try {
    RunInfo info;
    info.source = j.at("source");
    info.dataset = j.at("dataset");
    info.start_frame = j.value("start_frame", 0);
    info.frames_total = j.at("frames_total");
    info.frames_unusable = j.at("frames_unusable");
    info.failures = j.at("failures");
    info.on_loss = j.at("on_loss");
    info.pacing = j.at("pacing");
    info.lcm_url = j.value("lcm_url", "");
    info.agent = j.value("agent", "");
    info.link = j.value("link", "");
    info.link_figures = j.value("link_figures", std::vector<std::string>{});
    info.geo_figures = j.value("geo_figures", std::vector<std::string>{});
    info.started_at = j.value("started_at", "");
    info.wall_seconds = j.value("wall_seconds", 0.0);
    info.interrupted = j.value("interrupted", false);
    info.notes = j.value("notes", std::vector<std::string>{});
    info.peak_rss_mb = j.value("peak_rss_mb", std::map<std::string, double>{});
    info.cpu_s = j.value("cpu_s", std::map<std::string, double>{});
    return info;
  } catch (const nlohmann::json::exception& e) {
    throw Error(std::string("run.json: ") + e.what());
  }
}

void SaveRunInfo(const RunInfo& info, const std::string& run_dir) {
  WriteFileAtomically((fs::path(run_dir) / "run.json").string(), info.ToJson().dump(2) + "\n");
}

RunInfo LoadRunInfo(const std::string& run_dir) {
  const fs::path path = fs::path(run_dir) / "run.json";
  std::ifstream in(path);
  if (!in) throw Error(path.string() + ": not found (is " + run_dir + " a stitch run folder?)");
  try {
    return RunInfo::FromJson(nlohmann::json::parse(in));
  } catch (const nlohmann::json::parse_error& e) {
    throw Error(path.string() + ": not valid JSON (" + e.what() + ")");
  }
}

}  // namespace stitch
