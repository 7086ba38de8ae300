// stitch campaign: many randomized flights, each merge scored against ground truth
// (docs/benchmarks.md, "The merge campaign").

#include "tools/stitch/quality/campaign.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>

#include <nlohmann/json.hpp>

#include "stitch/util/args.h"
#include "stitch/util/error.h"
#include "stitch/util/rng.h"
#include "stitch/util/text_file.h"
#include "stitch/util/time.h"
#include "tools/stitch/commands.h"
#include "tools/stitch/quality/quality_gate.h"

namespace fs = std::filesystem;

namespace stitch {

CampaignFlight DrawCampaignFlight(const CampaignOptions& options, int index) {
  Rng rng(static_cast<uint64_t>(options.seed) * 1000003ULL + static_cast<uint64_t>(index));
  CampaignFlight f;
  f.world_seed = rng.UniformInt(1, 10000);
  f.frames = rng.UniformInt(options.min_frames, options.max_frames);
  // Gusts: 0-4, each 6-20 frames, at least 40 frames from the start, the end and each other.
  const int wanted = rng.UniformInt(0, 4);
  for (int tries = 0; tries < 50 && static_cast<int>(f.gusts.size()) < wanted; ++tries) {
    const int length = rng.UniformInt(6, 20);
    const int start = rng.UniformInt(40, std::max(40, f.frames - 40 - length));
    const bool clear = std::all_of(f.gusts.begin(), f.gusts.end(), [&](const std::pair<int, int>& g) {
      return start + length + 40 <= g.first || g.first + g.second + 40 <= start;
    });
    if (clear && start + length + 40 <= f.frames) f.gusts.push_back({start, length});
  }
  std::sort(f.gusts.begin(), f.gusts.end());
  f.link = rng.Uniform() < options.link_share;
  if (f.link) {
    f.loss = std::round(rng.Uniform(0, 0.25) * 100) / 100;
    f.delay_ms = rng.UniformInt(0, 150);
    f.jitter_ms = rng.UniformInt(0, 50);
    static const int kBudgets[] = {100000, 250000, 500000, 0};
    f.budget = kBudgets[rng.UniformInt(0, 3)];
    f.link_seed = rng.UniformInt(1, 10000);
  }
  return f;
}

std::vector<std::string> CampaignRunArguments(const CampaignFlight& f) {
  std::vector<std::string> args = {"--set", "synthetic.seed=" + std::to_string(f.world_seed)};
  if (f.frames > 1000) {
    // A longer survey at the default flight's speed: more strips.
    args.insert(args.end(), {"--set", "synthetic.flight.num_frames=" + std::to_string(f.frames), "--set",
                             "synthetic.flight.num_strips=" + std::to_string((4 * f.frames + 500) / 1000)});
  } else {
    args.insert(args.end(), {"--max-frames", std::to_string(f.frames)});
  }
  std::string failures;
  for (const auto& [start, length] : f.gusts) {
    failures += (failures.empty() ? "" : ",") + std::to_string(start) + ":" + std::to_string(length);
  }
  args.insert(args.end(), {"--failures", failures.empty() ? "none" : failures});
  if (f.link) {
    char loss[16];
    std::snprintf(loss, sizeof(loss), "%.2f", f.loss);
    args.insert(args.end(),
                {"--link", "--link-loss", loss, "--link-delay-ms", std::to_string(f.delay_ms), "--link-budget",
                 std::to_string(f.budget), "--set", "link.jitter_ms=" + std::to_string(f.jitter_ms), "--set",
                 "link.seed=" + std::to_string(f.link_seed)});
  }
  return args;
}

namespace {

// One flight's outcome as the campaign reports it.
struct FlightOutcome {
  std::string name, command;
  bool failed = false;
  std::string why;
  std::map<std::string, double> figures;
};

std::string GustsText(const CampaignFlight& f) {
  std::string gusts;
  for (const auto& [start, length] : f.gusts) {
    gusts += (gusts.empty() ? "" : ",") + std::to_string(start) + ":" + std::to_string(length);
  }
  return gusts.empty() ? "-" : gusts;
}

std::string LinkText(const CampaignFlight& f) {
  if (!f.link) return "-";
  char text[80];
  std::snprintf(text, sizeof(text), "%.0f%% %dms+%d %s", 100 * f.loss, f.delay_ms, f.jitter_ms,
                f.budget > 0 ? (std::to_string(f.budget / 1000) + "kB/s").c_str() : "unlimited");
  return text;
}

double Figure(const FlightOutcome& o, const char* key) {
  const auto it = o.figures.find(key);
  return it == o.figures.end() ? NAN : it->second;
}

// One row per flight, the totals, and each wrong merge with its command; as text or Markdown.
void PrintCampaign(std::FILE* out, const CampaignOptions& options, const std::vector<CampaignFlight>& flights,
                   const std::vector<FlightOutcome>& outcomes, bool markdown) {
  if (markdown) {
    std::fprintf(out,
                 "| flight | frames | gusts (frame:length) | link (loss, delay+jitter, budget) | submaps | in largest "
                 "map | wrong merges | ATE [m] | worst submap in map [m] |\n|---|---|---|---|---|---|---|---|---|\n");
  } else {
    std::fprintf(out, "%-11s %6s %-30s %-28s %7s %6s %5s %9s %9s\n", "flight", "frames", "gusts", "link", "submaps",
                 "merged", "wrong", "ATE [m]", "worst [m]");
  }
  int submaps = 0, merged = 0, wrong = 0, failed = 0;
  for (size_t i = 0; i < outcomes.size(); ++i) {
    const FlightOutcome& o = outcomes[i];
    const CampaignFlight& f = flights[i];
    if (o.failed) {
      ++failed;
      std::fprintf(out, markdown ? "| %s | %d | failed: %s |\n" : "%-11s %6d FAILED: %s\n", o.name.c_str(), f.frames,
                   o.why.c_str());
      continue;
    }
    submaps += static_cast<int>(Figure(o, "submaps"));
    merged += static_cast<int>(Figure(o, "submaps_merged"));
    wrong += static_cast<int>(Figure(o, "wrong_merges"));
    std::fprintf(out,
                 markdown ? "| %s | %d | %s | %s | %.0f | %.0f | %.0f | %.4f | %.4f |\n"
                          : "%-11s %6d %-30s %-28s %7.0f %6.0f %5.0f %9.4f %9.4f\n",
                 o.name.c_str(), f.frames, GustsText(f).c_str(), LinkText(f).c_str(), Figure(o, "submaps"),
                 Figure(o, "submaps_merged"), Figure(o, "wrong_merges"), Figure(o, "ate_m"),
                 Figure(o, "worst_submap_ate_in_map_m"));
  }
  std::fprintf(out,
               "\n%d flights (seed %d): %d submaps, %d of them in their flight's largest merged map (%.1f%%), %d wrong "
               "merges, %d failed\n",
               static_cast<int>(outcomes.size()), options.seed, submaps, merged,
               submaps > 0 ? 100.0 * merged / submaps : 0.0, wrong, failed);
  for (const FlightOutcome& o : outcomes) {
    if (!o.failed && Figure(o, "wrong_merges") > 0) {
      std::fprintf(out, markdown ? "\n- wrong merge in %s: `%s`\n" : "  wrong merge in %s: %s\n", o.name.c_str(),
                   o.command.c_str());
    }
  }
}

// " --set K=V" for each setting, as the command line takes them.
std::string SettingsText(const std::vector<std::string>& settings) {
  std::string text;
  for (const std::string& setting : settings) text += " --set " + setting;
  return text;
}

}  // namespace

int CampaignCommand(int argc, char** argv) {
  CampaignOptions options;
  std::string out_dir, markdown_path, from_path;
  int jobs = 1;
  std::string frames = "200:1500";
  bool list = false;
  std::vector<std::string> settings;
  ArgParser args("stitch campaign",
                 "The merge campaign: N randomized synthetic flights (world, length, gusts: how many, where, how "
                 "long; on some, the radio link with loss, delay, jitter that reorders, and a bandwidth budget), "
                 "each a `stitch run`, each merge scored against ground truth. A wrong merge: a submap whose ATE in "
                 "the merged map is more than 3x its own and above 0.5% of the flight's extent. Prints one row per "
                 "flight, the totals, and every flight with a wrong merge with the command that reproduces it; "
                 "exits 1 when there is one. The same --seed draws the same flights.");
  args.AddOption("--runs", &options.runs, "N", "flights (default: 60, the benchmark)");
  args.AddOption("--seed", &options.seed, "S", "draws the flights (default: 1)");
  args.AddOption("--frames", &frames, "MIN:MAX", "flight lengths, frames (default: 200:1500)");
  args.AddOption("--link-share", &options.link_share, "P", "share of the flights behind the radio link (default: 0.5)");
  args.AddOption("--jobs", &jobs, "N", "flights side by side (those behind the link run alone)");
  args.AddOption("--out", &out_dir, "DIR",
                 "the flights' run folders and campaign.json (default: runs/campaign-<time>)");
  args.AddOption("--set", &settings, "KEY=VALUE",
                 "a setting for every flight, after the flight's own (repeat for several), e.g. "
                 "merger.merged_map.gnss_in_adjustment=false");
  args.AddFlag("--list", &list, "print each flight's `stitch run` command and run nothing");
  args.AddOption("--markdown", &markdown_path, "FILE", MarkdownOptionHelp(kCampaignBegin, kCampaignEnd));
  args.AddOption("--from", &from_path, "FILE",
                 "run nothing: table an earlier campaign's campaign.json (its seed, runs, frames and link share)");
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    std::vector<FlightOutcome> outcomes;
    if (!from_path.empty()) {
      std::ifstream in(from_path);
      if (!in) throw Error(from_path + ": cannot open (give an earlier campaign's campaign.json)");
      try {
        const nlohmann::json json = nlohmann::json::parse(in);
        options.seed = json.at("seed").get<int>();
        options.runs = json.at("runs").get<int>();
        options.min_frames = json.value("min_frames", options.min_frames);
        options.max_frames = json.value("max_frames", options.max_frames);
        options.link_share = json.value("link_share", options.link_share);
        for (const auto& flight : json.at("flights")) {
          outcomes.push_back({flight.at("flight").get<std::string>(), flight.at("command").get<std::string>(),
                              flight.at("failed").get<bool>(), flight.at("why").get<std::string>(),
                              flight.at("figures").get<std::map<std::string, double>>()});
        }
      } catch (const nlohmann::json::exception& e) {
        throw Error(from_path + ": not a campaign.json (" + e.what() + ")");
      }
      if (static_cast<int>(outcomes.size()) != options.runs) throw Error(from_path + ": runs and flights disagree");
    } else {
      if (std::sscanf(frames.c_str(), "%d:%d", &options.min_frames, &options.max_frames) != 2 ||
          options.min_frames < 100 || options.max_frames < options.min_frames || options.max_frames > 5000) {
        throw Error("--frames must be MIN:MAX with 100 <= MIN <= MAX <= 5000 (got '" + frames + "')");
      }
    }
    if (options.runs < 1 || options.runs > 10000) throw Error("--runs must be in [1, 10000]");
    if (!(options.link_share >= 0 && options.link_share <= 1)) throw Error("--link-share must be in [0, 1]");

    // The flights as quality-gate cases whose one expectation is no wrong merge.
    QualityMatrix matrix;
    matrix.tolerance["wrong_merges"] = Tolerance{0, 0, false};
    std::vector<CampaignFlight> flights;
    for (int i = 0; i < options.runs; ++i) {
      flights.push_back(DrawCampaignFlight(options, i));
      QualityCase c;
      char name[32];
      std::snprintf(name, sizeof(name), "flight-%03d", i);
      c.name = name;
      c.run = CampaignRunArguments(flights.back());
      for (const std::string& setting : settings) c.run.insert(c.run.end(), {"--set", setting});
      c.alone = flights.back().link;
      c.expect["wrong_merges"] = 0;
      matrix.cases.push_back(c);
    }
    if (list) {
      for (const QualityCase& c : matrix.cases) {
        std::printf("%s  %s\n", c.name.c_str(), ReproduceCommand(c, "").c_str());
      }
      return 0;
    }
    if (from_path.empty()) {
      if (out_dir.empty()) out_dir = "runs/campaign-" + LocalTimestamp("%Y%m%d-%H%M%S");
      std::vector<const QualityCase*> chosen;
      for (const QualityCase& c : matrix.cases) chosen.push_back(&c);
      std::printf("stitch campaign: %d flights (seed %d) into %s\n", options.runs, options.seed, out_dir.c_str());
      RunCasesOptions run_options;
      run_options.out_dir = out_dir;
      run_options.jobs = jobs;
      for (const CaseResult& r : RunCases(matrix, chosen, run_options)) {
        outcomes.push_back({r.c->name, ReproduceCommand(*r.c, ""), r.failed, r.why, r.figures});
      }
      nlohmann::json json = nlohmann::json::array();
      for (const FlightOutcome& o : outcomes) {
        json.push_back(
            {{"flight", o.name}, {"command", o.command}, {"failed", o.failed}, {"why", o.why}, {"figures", o.figures}});
      }
      int wrong = 0, submaps = 0, merged = 0, failed = 0;
      for (const FlightOutcome& o : outcomes) {
        failed += o.failed;
        if (o.failed) continue;
        wrong += static_cast<int>(Figure(o, "wrong_merges"));
        submaps += static_cast<int>(Figure(o, "submaps"));
        merged += static_cast<int>(Figure(o, "submaps_merged"));
      }
      const nlohmann::json summary{{"seed", options.seed},
                                   {"runs", options.runs},
                                   {"min_frames", options.min_frames},
                                   {"max_frames", options.max_frames},
                                   {"link_share", options.link_share},
                                   {"submaps", submaps},
                                   {"submaps_merged", merged},
                                   {"wrong_merges", wrong},
                                   {"failed", failed},
                                   {"flights", json}};
      WriteFileAtomically((fs::path(out_dir) / "campaign.json").string(), summary.dump(2) + "\n");
      std::printf("\n");
    }
    PrintCampaign(stdout, options, flights, outcomes, /*markdown=*/false);
    if (from_path.empty()) std::printf("wrote %s/campaign.json\n", out_dir.c_str());
    if (!markdown_path.empty()) {
      WriteMarkdownTable(
          markdown_path,
          "build/bin/stitch campaign --runs " + std::to_string(options.runs) + " --seed " +
              std::to_string(options.seed) + SettingsText(settings),
          [&](std::FILE* md) { PrintCampaign(md, options, flights, outcomes, /*markdown=*/true); }, kCampaignBegin,
          kCampaignEnd);
    }
    const bool any_wrong = std::any_of(outcomes.begin(), outcomes.end(), [](const FlightOutcome& o) {
      return o.failed || Figure(o, "wrong_merges") > 0;
    });
    return any_wrong ? 1 : 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch campaign: %s\n", e.what());
    return 2;
  }
}

}  // namespace stitch
