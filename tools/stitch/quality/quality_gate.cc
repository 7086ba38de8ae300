// stitch bench --quality: the quality gate (quality_gate.h).

#include "tools/stitch/quality/quality_gate.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <set>
#include <sstream>
#include <thread>

#include <yaml-cpp/yaml.h>

#include "stitch/eval/evaluation.h"
#include "stitch/records/frame_record.h"
#include "stitch/records/keyframe_record.h"
#include "stitch/tracking/tracking_result.h"
#include "stitch/util/args.h"
#include "stitch/util/child_process.h"
#include "stitch/util/error.h"
#include "stitch/util/statistics.h"
#include "stitch/util/text_file.h"
#include "stitch/util/time.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

// The figures, in table order, with what a reader needs to know of each.
struct Figure {
  const char* key;
  const char* heading;  // table column
  const char* format;   // printf format of one value
};
const Figure kFigures[] = {
    {"frames_in_largest_map", "frames in largest map", "%.0f"},
    {"completeness", "completeness", "%.3f"},
    {"submaps", "submaps", "%.0f"},
    {"submaps_merged", "merged", "%.0f"},
    {"ate_m", "ATE [m]", "%.4f"},
    {"worst_submap_ate_in_map_m", "worst submap in map [m]", "%.4f"},
    {"wrong_merges", "wrong merges", "%.0f"},
    {"on_earth_m", "on Earth [m]", "%.3f"},
    {"keyframes_created", "keyframes made", "%.0f"},
    {"keyframes_kept", "kept", "%.0f"},
    {"median_tracked_points", "tracked points (median)", "%.0f"},
    {"cpu_s_per_frame", "CPU s/frame", "%.4f"},
    {"wall_s", "wall [s]", "%.1f"},
    {"dropped_frames", "dropped", "%.0f"},
    {"source_late_frames", "sent late", "%.0f"},  // by the source itself (real time: ingest.json)
};

bool KnownFigure(const std::string& key) {
  return std::any_of(std::begin(kFigures), std::end(kFigures), [&](const Figure& f) { return key == f.key; });
}

std::string FormatFigure(const std::string& key, double value) {
  for (const Figure& f : kFigures) {
    if (key != f.key) continue;
    char text[32];
    std::snprintf(text, sizeof(text), f.format, value);
    return text;
  }
  return std::to_string(value);
}

Tolerance ReadTolerance(const YAML::Node& node, const std::string& where, Tolerance tolerance) {
  if (!node.IsMap()) throw Error(where + ": a tolerance is a map {relative, absolute, better}");
  for (const auto& item : node) {
    const std::string key = item.first.as<std::string>();
    if (key == "relative") {
      tolerance.relative = item.second.as<double>();
    } else if (key == "absolute") {
      tolerance.absolute = item.second.as<double>();
    } else if (key == "better") {
      const std::string better = item.second.as<std::string>();
      if (better != "higher" && better != "lower") throw Error(where + ".better: higher or lower");
      tolerance.higher_is_better = better == "higher";
    } else {
      throw Error(where + ": unknown key '" + key + "'");
    }
  }
  if (!(tolerance.relative >= 0 && tolerance.absolute >= 0)) throw Error(where + ": slack must be >= 0");
  return tolerance;
}

std::string Substitute(std::string text, const std::string& marker, const std::string& value) {
  for (size_t at = text.find(marker); at != std::string::npos; at = text.find(marker, at + value.size())) {
    text.replace(at, marker.size(), value);
  }
  return text;
}

}  // namespace

std::string ReadWholeFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return "";
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) throw Error(path + ": cannot read");
  return text.str();
}

std::string DefaultDatasetsDir() {
  if (const char* env = std::getenv("STITCH_DATASETS")) return env;
  return fs::path(STITCH_DATASETS_DIR).lexically_normal().string();
}

std::vector<std::string> CaseRunArguments(const QualityCase& c, const std::string& datasets_dir,
                                          const std::string& rendered, int repeat) {
  std::vector<std::string> args;
  for (const std::string& a : c.run) {
    args.push_back(Substitute(Substitute(a, "${datasets}", datasets_dir), "${rendered}", rendered));
  }
  if (repeat >= 0 && repeat < static_cast<int>(c.start_frames.size())) {
    args.push_back("--start-frame");
    args.push_back(std::to_string(c.start_frames[static_cast<size_t>(repeat)]));
  }
  return args;
}

std::string RenderCaseClip(const QualityCase& c, const std::string& dir) {
  fs::create_directories(dir);
  const std::string clip = (fs::path(dir) / (c.name + ".mp4")).string();
  std::vector<std::string> args{"render"};
  args.insert(args.end(), c.render.begin(), c.render.end());
  args.push_back("--out");
  args.push_back(clip);
  std::printf("rendering the clip of %s\n", c.name.c_str());
  std::fflush(stdout);
  ChildProcess render("render " + c.name, ExecutableDir() + "/stitch", args, clip + ".log");
  std::optional<int> status;
  while (!(status = render.Poll())) std::this_thread::sleep_for(std::chrono::milliseconds(200));
  if (*status != 0) {
    throw Error("case '" + c.name + "': stitch render exited with status " + std::to_string(*status) + ":\n" +
                render.LogTail(8));
  }
  return clip;
}

QualityMatrix LoadQualityMatrix(const std::string& path) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::Exception& e) {
    throw Error(path + ": " + e.what());
  }
  QualityMatrix matrix;
  try {
    for (const auto& item : root) {
      const std::string key = item.first.as<std::string>();
      if (key != "tolerance" && key != "cases") throw Error("unknown key '" + key + "'");
    }
    for (const auto& item : root["tolerance"]) {
      const std::string figure = item.first.as<std::string>();
      if (!KnownFigure(figure)) throw Error("tolerance: unknown figure '" + figure + "'");
      matrix.tolerance[figure] = ReadTolerance(item.second, "tolerance." + figure, Tolerance());
    }
    std::set<std::string> names;
    for (const auto& node : root["cases"]) {
      QualityCase c;
      for (const auto& item : node) {
        const std::string key = item.first.as<std::string>();
        if (key == "name") {
          c.name = item.second.as<std::string>();
        } else if (key == "about") {
          c.about = item.second.as<std::string>();
        } else if (key == "run") {
          c.run = item.second.as<std::vector<std::string>>();
        } else if (key == "needs") {
          c.needs = item.second.as<std::string>();
        } else if (key == "render") {
          c.render = item.second.as<std::vector<std::string>>();
        } else if (key == "alone") {
          c.alone = item.second.as<bool>();
        } else if (key == "ci") {
          c.ci = item.second.as<bool>();
        } else if (key == "repeats") {
          c.repeats = item.second.as<int>();
        } else if (key == "start_frames") {
          c.start_frames = item.second.as<std::vector<int>>();
        } else if (key == "expect" || key == "expect_worst") {
          std::map<std::string, double>& expect = key == "expect" ? c.expect : c.expect_worst;
          for (const auto& e : item.second) expect[e.first.as<std::string>()] = e.second.as<double>();
        } else if (key == "tolerance") {
          continue;  // read below, over the defaults
        } else {
          throw Error("case '" + c.name + "': unknown key '" + key + "'");
        }
      }
      if (c.name.empty()) throw Error("a case without a name");
      if (!names.insert(c.name).second) throw Error("two cases named '" + c.name + "'");
      if (!c.start_frames.empty()) {
        if (node["repeats"] && c.repeats != static_cast<int>(c.start_frames.size())) {
          throw Error("case '" + c.name + "': start_frames runs once per start frame; leave repeats out");
        }
        if (std::any_of(c.start_frames.begin(), c.start_frames.end(), [](int f) { return f < 0; })) {
          throw Error("case '" + c.name + "': start_frames must be frame numbers (>= 0)");
        }
        c.repeats = static_cast<int>(c.start_frames.size());
      }
      if (c.repeats < 1 || c.repeats > 20) throw Error("case '" + c.name + "': repeats must be in [1, 20]");
      const bool plays_rendered = std::any_of(
          c.run.begin(), c.run.end(), [](const std::string& a) { return a.find("${rendered}") != std::string::npos; });
      if (plays_rendered != !c.render.empty()) {
        throw Error("case '" + c.name +
                    "': `render` makes the clip that `run` plays as ${rendered}; give both or neither");
      }
      if (!c.expect_worst.empty() && c.start_frames.empty()) {
        throw Error("case '" + c.name + "': expect_worst is the worst start's: it needs start_frames");
      }
      for (const auto* expect : {&c.expect, &c.expect_worst}) {
        for (const auto& [figure, value] : *expect) {
          if (!KnownFigure(figure)) throw Error("case '" + c.name + "': unknown figure '" + figure + "'");
          if (!matrix.tolerance.count(figure)) throw Error("case '" + c.name + "': no tolerance for '" + figure + "'");
        }
      }
      // A case's own tolerances start from the defaults.
      for (const auto& item : node["tolerance"]) {
        const std::string figure = item.first.as<std::string>();
        if (!matrix.tolerance.count(figure))
          throw Error("case '" + c.name + "': no default tolerance for '" + figure + "'");
        c.tolerance[figure] = ReadTolerance(item.second, c.name + ".tolerance." + figure, matrix.tolerance.at(figure));
      }
      matrix.cases.push_back(std::move(c));
    }
  } catch (const YAML::Exception& e) {
    throw Error(path + ": " + e.what());
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
  if (matrix.cases.empty()) throw Error(path + ": no cases");
  return matrix;
}

void SaveQualityMatrix(const QualityMatrix& matrix, const std::string& path) {
  const auto tolerance_text = [](const Tolerance& t) {
    std::ostringstream out;
    out << "{relative: " << t.relative << ", absolute: " << t.absolute
        << ", better: " << (t.higher_is_better ? "higher" : "lower") << "}";
    return out.str();
  };
  const auto quoted = [](const std::string& s) {
    YAML::Emitter e;
    e << YAML::DoubleQuoted << s;
    return std::string(e.c_str());
  };
  std::ostringstream out;
  out << "# The quality gate (`stitch bench --quality`, docs/testing.md): every case, what it must give\n"
         "# (`expect`, measured on the machine docs/benchmarks.md names, written by --update), and how far\n"
         "# each figure may move the worse way before `--check` calls it a regression. `run` holds\n"
         "# `stitch run` arguments (${datasets}: the real sequences' folder); `needs`: the sequence a\n"
         "# case plays (skipped where it is absent); `render`: `stitch render` arguments of the clip a\n"
         "# case plays as ${rendered} (rendered first); `alone`: nothing runs beside it (CPU, real\n"
         "# time, link timing); `ci`: in the subset ctest runs; `repeats`: runs of a case that varies\n"
         "# run to run (real time), checked on their median and on their worst; `start_frames`: one\n"
         "# run from each of these frames (--start-frame), the median held to `expect` and the worst\n"
         "# start to `expect_worst`.\n";
  out << "tolerance:\n";
  for (const auto& [figure, t] : matrix.tolerance) out << "  " << figure << ": " << tolerance_text(t) << "\n";
  out << "cases:\n";
  for (const QualityCase& c : matrix.cases) {
    out << "  - name: " << c.name << "\n";
    if (!c.about.empty()) out << "    about: " << quoted(c.about) << "\n";
    const auto write_list = [&](const char* key, const std::vector<std::string>& items) {
      out << "    " << key << ": [";
      for (size_t i = 0; i < items.size(); ++i) out << (i ? ", " : "") << quoted(items[i]);
      out << "]\n";
    };
    write_list("run", c.run);
    if (!c.render.empty()) write_list("render", c.render);
    if (!c.needs.empty()) out << "    needs: " << quoted(c.needs) << "\n";
    if (c.alone) out << "    alone: true\n";
    if (c.ci) out << "    ci: true\n";
    if (!c.start_frames.empty()) {
      out << "    start_frames: [";
      for (size_t i = 0; i < c.start_frames.size(); ++i) out << (i ? ", " : "") << c.start_frames[i];
      out << "]\n";
    } else if (c.repeats != 1) {
      out << "    repeats: " << c.repeats << "\n";
    }
    if (!c.tolerance.empty()) {
      out << "    tolerance:\n";
      for (const auto& [figure, t] : c.tolerance) out << "      " << figure << ": " << tolerance_text(t) << "\n";
    }
    const auto write_expect = [&](const char* key, const std::map<std::string, double>& expect) {
      if (expect.empty()) return;
      out << "    " << key << ": {";
      bool first = true;
      for (const Figure& f : kFigures) {
        const auto it = expect.find(f.key);
        if (it == expect.end()) continue;
        out << (first ? "" : ", ") << f.key << ": " << FormatFigure(f.key, it->second);
        first = false;
      }
      out << "}\n";
    };
    write_expect("expect", c.expect);
    write_expect("expect_worst", c.expect_worst);
  }
  WriteFileAtomically(path, out.str());
}

std::map<std::string, double> MeasureRun(const std::string& run_dir, double cpu_seconds, double wall_seconds) {
  const fs::path dir(run_dir);
  const Evaluation e = ReadReport((dir / "report.json").string());
  std::map<std::string, double> m;
  m["frames_in_largest_map"] = e.frames_localized;
  m["completeness"] = e.completeness;
  m["submaps"] = e.submaps;
  m["submaps_merged"] = e.submaps_merged;
  if (e.errors) m["ate_m"] = e.errors->ate_rmse_m;
  double worst = -1;
  for (const SubmapEvaluation& s : e.per_submap) {
    if (s.ate_in_map_m) worst = std::max(worst, *s.ate_in_map_m);
  }
  if (worst >= 0) m["worst_submap_ate_in_map_m"] = worst;
  m["wrong_merges"] = e.wrong_merges;
  // Placed on Earth by the GNSS fixes: the largest map's keyframes against the truth, unaligned.
  if (std::ifstream in(dir / "geo" / "georeference.json"); in) {
    const nlohmann::json geo = nlohmann::json::parse(in, nullptr, false);
    if (geo.is_object()) {
      for (const auto& map : geo.value("maps", nlohmann::json::array())) {
        if (map.value("largest", false) && map.contains("absolute")) {
          m["on_earth_m"] = map["absolute"].value("keyframe_horizontal_rms_m", 0.0);
        }
      }
    }
  }
  std::vector<FrameRecord> frames;
  if (fs::exists(dir / "frames.tsv")) frames = ReadFrameRecords((dir / "frames.tsv").string());
  int created = 0, dropped = 0;
  std::vector<double> tracked;
  for (const FrameRecord& f : frames) {
    created += f.is_keyframe;
    dropped += f.reason == static_cast<int>(TrackingReason::kDropped);
    if (f.state == "OK") tracked.push_back(f.tracked_points);
  }
  // Every keyframe the mapper received, culled or not (frames.tsv marks the reference frame of an
  // initialization, which becomes one, only where its frames are placed); the tracker's count
  // without a mapper.
  int kept = 0;
  if (fs::exists(dir / "keyframes.tsv")) {
    const std::vector<KeyframeRecord> keyframes = ReadKeyframeRecords((dir / "keyframes.tsv").string());
    for (const KeyframeRecord& k : keyframes) kept += !k.culled;
    created = std::max(created, static_cast<int>(keyframes.size()));
  }
  m["keyframes_created"] = created;
  m["keyframes_kept"] = kept;
  m["median_tracked_points"] = Median(tracked);
  m["cpu_s_per_frame"] = e.frames_total > 0 ? cpu_seconds / e.frames_total : 0;
  m["wall_s"] = wall_seconds;
  m["dropped_frames"] = dropped;
  m["source_late_frames"] = e.frames_late_at_source;
  m["frames_total"] = e.frames_total;
  return m;
}

std::string MarkdownOptionHelp(const char* begin, const char* end) {
  return std::string("also write the table as Markdown: in place of the lines between the markers ") + begin + " and " +
         end + " where FILE has them (docs/benchmarks.md), else as the whole file";
}

void WriteMarkdownTable(const std::string& path, const std::string& command,
                        const std::function<void(std::FILE*)>& print, const char* begin, const char* end) {
  char* text = nullptr;
  size_t size = 0;
  std::FILE* md = open_memstream(&text, &size);
  if (!md) throw Error("out of memory for the Markdown table");
  std::fprintf(md, "`%s`, %s:\n\n", command.c_str(), LocalTimestamp("%Y-%m-%d").c_str());
  print(md);
  std::fclose(md);
  const std::string table(text, size);
  std::free(text);
  WriteFileAtomically(path, PlaceMarkdownTable(ReadWholeFile(path), table, begin, end));
}

std::string PlaceMarkdownTable(const std::string& document, const std::string& table, const char* begin_marker,
                               const char* end_marker) {
  const size_t begin = document.find(begin_marker);
  const size_t end = begin == std::string::npos ? std::string::npos : document.find(end_marker, begin);
  if (end == std::string::npos) return table;
  const size_t after_begin = document.find('\n', begin);
  return document.substr(0, after_begin + 1) + table + document.substr(end);
}

std::string Regression::Describe() const {
  char text[256];
  std::snprintf(text, sizeof(text), "%s%s %s, expected %s (limit %s)", worst_run ? "worst run: " : "", figure.c_str(),
                std::isnan(measured) ? "missing" : FormatFigure(figure, measured).c_str(),
                FormatFigure(figure, expected).c_str(), FormatFigure(figure, limit).c_str());
  return text;
}

namespace {

// `figure`'s tolerance in case `c`: its own, else the default; nullptr when it has none.
const Tolerance* FindTolerance(const QualityMatrix& matrix, const QualityCase& c, const std::string& figure) {
  const auto own = c.tolerance.find(figure);
  if (own != c.tolerance.end()) return &own->second;
  const auto fallback = matrix.tolerance.find(figure);
  return fallback != matrix.tolerance.end() ? &fallback->second : nullptr;
}

}  // namespace

std::vector<Regression> CheckCase(const QualityMatrix& matrix, const QualityCase& c,
                                  const std::map<std::string, double>& measured, const std::set<std::string>& only,
                                  bool worst_run) {
  std::vector<Regression> regressions;
  const std::map<std::string, double>& expect = worst_run && !c.expect_worst.empty() ? c.expect_worst : c.expect;
  for (const auto& [figure, expected] : expect) {
    if (!only.empty() && !only.count(figure)) continue;
    const Tolerance& t = *FindTolerance(matrix, c, figure);  // LoadQualityMatrix holds every expectation to one
    const double slack = t.relative * std::abs(expected) + t.absolute;
    const double limit = t.higher_is_better ? expected - slack : expected + slack;
    const auto it = measured.find(figure);
    if (it == measured.end()) {
      regressions.push_back({figure, NAN, expected, limit, worst_run});
      continue;
    }
    const bool worse = t.higher_is_better ? it->second < limit : it->second > limit;
    if (worse) regressions.push_back({figure, it->second, expected, limit, worst_run});
  }
  return regressions;
}

RepeatedFigures CombineRuns(const QualityMatrix& matrix, const QualityCase& c,
                            const std::vector<std::map<std::string, double>>& runs) {
  std::set<std::string> keys;
  for (const auto& run : runs) {
    for (const auto& item : run) keys.insert(item.first);
  }
  RepeatedFigures combined;
  for (const std::string& key : keys) {
    std::vector<double> values;
    for (const auto& run : runs) {
      const auto it = run.find(key);
      if (it != run.end()) values.push_back(it->second);
    }
    if (2 * values.size() > runs.size()) combined.median[key] = Median(values);
    if (values.size() < runs.size()) continue;
    const Tolerance* t = FindTolerance(matrix, c, key);
    const bool higher_is_better = t != nullptr && t->higher_is_better;
    combined.worst[key] = higher_is_better ? *std::min_element(values.begin(), values.end())
                                           : *std::max_element(values.begin(), values.end());
  }
  return combined;
}

std::string ReproduceCommand(const QualityCase& c, const std::string& datasets_dir,
                             const std::vector<std::string>& settings) {
  const auto quoted = [](const std::string& a) {
    const bool plain = !a.empty() && a.find_first_of(" \t'\"$*?()[]{};&|<>") == std::string::npos;
    return plain ? a : "'" + a + "'";
  };
  std::string command;
  const std::string clip = c.name + ".mp4";
  if (!c.render.empty()) {
    command = "build/bin/stitch render";
    for (const std::string& a : c.render) command += " " + quoted(a);
    command += " --out " + clip + " && ";
  }
  std::vector<std::string> args = CaseRunArguments(c, datasets_dir, clip);
  for (const std::string& setting : settings) {
    args.push_back("--set");
    args.push_back(setting);
  }
  command += "build/bin/stitch run";
  for (const std::string& a : args) command += " " + quoted(a);
  if (c.start_frames.size() > 1) {
    command += "  # and with --start-frame";
    for (size_t i = 1; i < c.start_frames.size(); ++i)
      command += (i > 1 ? ", " : " ") + std::to_string(c.start_frames[i]);
  }
  return command;
}

namespace {

using Result = CaseResult;

// One running case.
struct Running {
  const QualityCase* c;
  size_t index;  // into the planned runs
  std::unique_ptr<ChildProcess> process;
  Stopwatch clock;
  std::string run_dir;
};

// Figures of an earlier run (its quality.json): case -> its figures (a repeated case's median)
// and its worst run's.
struct EarlierCase {
  std::map<std::string, double> figures, worst;
  std::vector<std::map<std::string, double>> runs;  // a repeated case's
};
using Figures = std::map<std::string, EarlierCase>;

Figures ReadFigures(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw Error(path + ": cannot open (give the quality.json of an earlier run)");
  Figures figures;
  try {
    const nlohmann::json json = nlohmann::json::parse(in);
    for (const auto& c : json) {
      if (c.at("skipped").get<bool>() || c.at("failed").get<bool>()) continue;
      EarlierCase& earlier = figures[c.at("case").get<std::string>()];
      earlier.figures = c.at("figures").get<std::map<std::string, double>>();
      if (c.contains("worst")) earlier.worst = c.at("worst").get<std::map<std::string, double>>();
      if (c.contains("runs")) earlier.runs = c.at("runs").get<std::vector<std::map<std::string, double>>>();
    }
  } catch (const nlohmann::json::exception& e) {
    throw Error(path + ": not a quality.json (" + e.what() + ")");
  }
  return figures;
}

// One table; with `before`, a figure that moved shows as "before -> now". A repeated case has a
// second row, its worst run.
void PrintTable(const std::vector<Result>& results, bool markdown, std::FILE* out, const Figures& before = {}) {
  const std::string separator = markdown ? " | " : "  ";
  std::string header = markdown ? "| case" : "case";
  std::string rule = markdown ? "|---" : "";
  for (const Figure& f : kFigures) {
    header += separator + f.heading;
    rule += "|---";
  }
  std::fprintf(out, "%s%s\n", header.c_str(), markdown ? " |" : "");
  if (markdown) std::fprintf(out, "%s|\n", rule.c_str());
  const auto print_row = [&](const Result& r, bool worst_row) {
    const std::map<std::string, double>& figures = worst_row ? r.worst : r.figures;
    std::string row = (markdown ? "| " : "") + r.c->name;
    if (r.runs.size() > 1) {
      row += worst_row ? " (worst)"
                       : " (median of " + std::to_string(r.runs.size()) +
                             (r.c->start_frames.empty() ? std::string(")") : std::string(" start frames)"));
    }
    const auto was = before.find(r.c->name);
    for (const Figure& f : kFigures) {
      const auto it = figures.find(f.key);
      std::string cell = r.skipped ? "-" : it == figures.end() ? "n/a" : FormatFigure(f.key, it->second);
      if (!r.skipped && was != before.end()) {
        const auto& earlier = worst_row ? was->second.worst : was->second.figures;
        const auto old = earlier.find(f.key);
        const std::string old_cell = old == earlier.end() ? "n/a" : FormatFigure(f.key, old->second);
        if (old_cell != cell) cell = old_cell + " -> " + cell;
      }
      const bool regressed = std::any_of(r.regressions.begin(), r.regressions.end(), [&](const Regression& g) {
        return g.figure == f.key && g.worst_run == worst_row;
      });
      if (regressed) cell = markdown ? "**" + cell + "**" : cell + "!";
      row += separator + cell;
    }
    if (r.skipped) row += separator + "(skipped: " + r.why + ")";
    std::fprintf(out, "%s%s\n", row.c_str(), markdown && !r.skipped ? " |" : "");
  };
  for (const Result& r : results) {
    print_row(r, /*worst_row=*/false);
    if (!r.worst.empty()) print_row(r, /*worst_row=*/true);
  }
}

// A case's regressions: its figures', and a repeated case's worst run's.
std::vector<Regression> CheckResult(const QualityMatrix& matrix, const Result& r, const std::set<std::string>& only) {
  std::vector<Regression> regressions = CheckCase(matrix, *r.c, r.figures, only);
  if (r.worst.empty()) return regressions;
  for (const Regression& g : CheckCase(matrix, *r.c, r.worst, only, /*worst_run=*/true)) regressions.push_back(g);
  return regressions;
}

}  // namespace

std::vector<CaseResult> RunCases(const QualityMatrix& matrix, const std::vector<const QualityCase*>& chosen,
                                 const RunCasesOptions& options) {
  if (options.jobs < 1 || options.jobs > 64) throw Error("--jobs must be in [1, 64]");
  const std::string& out_dir = options.out_dir;
  if (fs::exists(out_dir) && !fs::is_empty(out_dir))
    throw Error(out_dir + " exists and is not empty; give a new --out");
  fs::create_directories(out_dir);
  const std::string stitch = ExecutableDir() + "/stitch";
  std::vector<CaseResult> results(chosen.size());
  // One run each: the cases in order, a repeated case's runs one after the other.
  struct PlannedRun {
    size_t index;
    int repeat;
  };
  std::vector<PlannedRun> planned;
  for (size_t i = 0; i < chosen.size(); ++i) {
    results[i].c = chosen[i];
    const QualityCase& c = *chosen[i];
    if (!c.needs.empty() && !fs::exists(fs::path(options.datasets_dir) / c.needs)) {
      results[i].skipped = true;
      results[i].why = c.needs + " is not in " + options.datasets_dir;
      continue;
    }
    if (!c.render.empty()) {
      try {
        results[i].rendered = RenderCaseClip(c, (fs::path(out_dir) / "clips").string());
      } catch (const Error& e) {
        results[i].failed = true;
        results[i].why = e.what();
        continue;
      }
    }
    for (int repeat = 0; repeat < c.repeats; ++repeat) planned.push_back({i, repeat});
  }
  std::vector<int> runs_left(chosen.size());
  for (const PlannedRun& p : planned) ++runs_left[p.index];
  std::vector<Running> running;
  size_t next = 0, done = 0;
  // The running line is for a terminal; a log gets one line per run.
  const bool terminal = isatty(fileno(stdout));
  const auto progress = [&]() {
    if (!terminal) return;
    std::string line = "\r[" + std::to_string(done) + "/" + std::to_string(planned.size()) + "] ";
    for (const Running& r : running) {
      line += r.c->name + " " + std::to_string(static_cast<int>(r.clock.ElapsedSeconds())) + " s  ";
    }
    std::printf("%-110s", line.c_str());
    std::fflush(stdout);
  };
  // A repeated case is checked once its last run has ended: its median and its worst run.
  const auto finish_case = [&](CaseResult& result) {
    const QualityCase& c = *result.c;
    if (result.failed) return;
    if (result.runs.size() == 1) {
      result.figures = result.runs.front();
    } else {
      RepeatedFigures combined = CombineRuns(matrix, c, result.runs);
      result.figures = std::move(combined.median);
      result.worst = std::move(combined.worst);
    }
    result.regressions = CheckResult(matrix, result, options.figures);
  };
  const Stopwatch total;
  while (done < planned.size()) {
    // Start what may start: a case marked alone only when nothing runs, nothing beside it.
    while (next < planned.size()) {
      const QualityCase& c = *chosen[planned[next].index];
      const bool alone_running =
          std::any_of(running.begin(), running.end(), [](const Running& r) { return r.c->alone; });
      if (alone_running || static_cast<int>(running.size()) >= options.jobs || (c.alone && !running.empty())) break;
      const int repeat = planned[next].repeat;
      const std::string name = repeat == 0 ? c.name : c.name + "-" + std::to_string(repeat + 1);
      Running r{&c, next, nullptr, Stopwatch(), (fs::path(out_dir) / name).string()};
      std::vector<std::string> run_args{"run", "--quiet", "--out", r.run_dir};
      const std::vector<std::string> case_args =
          CaseRunArguments(c, options.datasets_dir, results[planned[next].index].rendered, repeat);
      run_args.insert(run_args.end(), case_args.begin(), case_args.end());
      for (const std::string& setting : options.settings) {
        run_args.push_back("--set");
        run_args.push_back(setting);
      }
      r.process = std::make_unique<ChildProcess>(name, stitch, run_args, r.run_dir + ".log");
      running.push_back(std::move(r));
      ++next;
    }
    progress();
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    for (auto it = running.begin(); it != running.end();) {
      const std::optional<int> status = it->process->Poll();
      if (!status) {
        ++it;
        continue;
      }
      const PlannedRun& p = planned[it->index];
      CaseResult& result = results[p.index];
      const double wall = it->clock.ElapsedSeconds();
      if (*status != 0) {
        result.failed = true;
        result.why = "stitch run exited with status " + std::to_string(*status) + ":\n" + it->process->LogTail(8);
      } else if (!result.failed) {
        try {
          result.runs.push_back(MeasureRun(it->run_dir, it->process->cpu_seconds(), wall));
        } catch (const Error& e) {
          result.failed = true;
          result.why = e.what();
        }
      }
      const bool case_done = --runs_left[p.index] == 0;
      if (case_done) finish_case(result);
      const std::string run_name =
          result.c->repeats == 1 ? result.c->name
          : !result.c->start_frames.empty()
              ? result.c->name + " (from frame " + std::to_string(result.c->start_frames[p.repeat]) + ")"
              : result.c->name + " (run " + std::to_string(p.repeat + 1) + " of " + std::to_string(result.c->repeats) +
                    ")";
      const std::string outcome = *status != 0    ? "FAILED"
                                  : !case_done    ? "ran"
                                  : result.failed ? "FAILED"
                                  : !result.regressions.empty()
                                      ? std::to_string(result.regressions.size()) + " regressed"
                                      : "ok";
      if (terminal) std::printf("\r%-110s\r", "");
      std::printf("[%zu/%zu] %-36s %5.0f s  %s\n", done + 1, planned.size(), run_name.c_str(), wall, outcome.c_str());
      std::fflush(stdout);
      ++done;
      it = running.erase(it);
    }
  }
  if (terminal) std::printf("\r%-110s\r", "");
  std::printf("%zu cases, %zu runs in %.0f s\n", chosen.size(), planned.size(), total.ElapsedSeconds());
  return results;
}

int QualityCommand(int argc, char** argv) {
  std::string expected_path = std::string(STITCH_SOURCE_DIR) + "/benchmarks/quality.yaml";
  std::string cases_list, figures_list, out_dir, markdown_path, before_path, from_path,
      datasets_dir = DefaultDatasetsDir();
  std::vector<std::string> settings;
  int jobs = 1;
  bool check = false, update = false, ci_only = false, quality = false;
  ArgParser args("stitch bench --quality",
                 "The quality gate: runs each case of the matrix (stitch run, as separate processes) and prints one "
                 "table: frames in the largest map, completeness, submaps and how many merged, ATE, the worst "
                 "submap's ATE in the merged map, wrong merges (a submap whose ATE in the merged map is more than 3x "
                 "its own and above 0.5% of the extent), keyframes made and kept, median tracked points per frame, "
                 "CPU seconds of all services per frame, wall time, frames dropped. With --check, exits 1 on any "
                 "figure worse than its expectation beyond its tolerance, naming it and the command that "
                 "reproduces it.");
  args.AddFlag("--quality", &quality, "(this mode of stitch bench)");
  args.AddOption("--expected", &expected_path, "FILE", "the matrix and its expected figures");
  args.AddOption("--cases", &cases_list, "A,B,...", "only these cases (default: all)");
  args.AddFlag("--ci", &ci_only, "only the cases marked ci (the subset ctest runs)");
  args.AddFlag("--check", &check, "exit 1 when a figure regressed beyond its tolerance");
  args.AddOption("--figures", &figures_list, "A,B,...",
                 "check only these figures (default: all; e.g. leave out cpu_s_per_frame and dropped_frames on "
                 "a machine other than the one the expectations were measured on)");
  args.AddFlag("--update", &update,
               "write the measured figures (of this run, or of --from's) into --expected as the new expectations; with "
               "--figures, only those (e.g. the machine-independent ones)");
  args.AddOption("--out", &out_dir, "DIR", "where the cases' run folders go (default: runs/quality-<time>)");
  args.AddOption("--markdown", &markdown_path, "FILE", MarkdownOptionHelp(kMarkdownBegin, kMarkdownEnd));
  args.AddOption("--before", &before_path, "FILE",
                 "the quality.json of an earlier run: the tables show each figure that moved as before -> now");
  args.AddOption("--from", &from_path, "FILE[,FILE...]",
                 "run nothing: table (and --check) the figures of earlier runs' quality.json (several: each case "
                 "from the last that has it, e.g. a whole gate's and a later run of some of its cases)");
  args.AddOption("--jobs", &jobs, "N", "cases run side by side (those marked alone always run alone)");
  args.AddOption("--set", &settings, "KEY=VALUE",
                 "a setting for every case's run (to try a change against the expectations)");
  args.AddOption("--datasets", &datasets_dir, "DIR",
                 "the real sequences' folder (default: $STITCH_DATASETS or ../shared/datasets)");
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    if (jobs < 1 || jobs > 64) throw Error("--jobs must be in [1, 64]");
    QualityMatrix matrix = LoadQualityMatrix(expected_path);
    const Figures before = before_path.empty() ? Figures() : ReadFigures(before_path);
    std::vector<const QualityCase*> chosen;
    std::set<std::string> wanted;
    std::stringstream list(cases_list);
    for (std::string name; std::getline(list, name, ',');) {
      if (!name.empty()) wanted.insert(name);
    }
    std::set<std::string> figures;
    std::stringstream figure_list(figures_list);
    for (std::string figure; std::getline(figure_list, figure, ',');) {
      if (figure.empty()) continue;
      if (!KnownFigure(figure)) throw Error("--figures: no figure named '" + figure + "'");
      figures.insert(figure);
    }
    for (const std::string& name : wanted) {
      if (std::none_of(matrix.cases.begin(), matrix.cases.end(),
                       [&](const QualityCase& c) { return c.name == name; })) {
        throw Error("--cases: no case named '" + name + "' in " + expected_path);
      }
    }
    for (const QualityCase& c : matrix.cases) {
      if ((wanted.empty() || wanted.count(c.name)) && (!ci_only || c.ci)) chosen.push_back(&c);
    }
    if (chosen.empty()) throw Error("no case chosen");
    std::vector<Result> results;
    if (!from_path.empty()) {
      // Nothing runs: the figures of an earlier run, tabled and checked as if just measured.
      Figures earlier;
      std::string last;
      for (std::stringstream files(from_path); std::getline(files, last, ',');) {
        for (auto& [name, figures] : ReadFigures(last)) earlier[name] = std::move(figures);
      }
      results.resize(chosen.size());
      for (size_t i = 0; i < chosen.size(); ++i) {
        results[i].c = chosen[i];
        const auto it = earlier.find(chosen[i]->name);
        if (it == earlier.end()) {
          results[i].skipped = true;
          results[i].why = "not in " + from_path;
          continue;
        }
        results[i].figures = it->second.figures;
        results[i].worst = it->second.worst;
        results[i].runs = it->second.runs;
        results[i].regressions = CheckResult(matrix, results[i], figures);
      }
      out_dir = fs::path(last).parent_path().string();
    } else {
      if (out_dir.empty()) out_dir = "runs/quality-" + LocalTimestamp("%Y%m%d-%H%M%S");
      RunCasesOptions run_options;
      run_options.out_dir = out_dir;
      run_options.datasets_dir = datasets_dir;
      run_options.jobs = jobs;
      run_options.settings = settings;
      run_options.figures = figures;
      results = RunCases(matrix, chosen, run_options);
    }
    std::printf("\nquality gate: %zu cases (%s)\n\n", chosen.size(), out_dir.c_str());
    PrintTable(results, /*markdown=*/false, stdout, before);

    nlohmann::json json = nlohmann::json::array();
    int regressed = 0, failed = 0;
    for (const Result& r : results) {
      nlohmann::json j{{"case", r.c->name},    {"skipped", r.skipped},
                       {"failed", r.failed},   {"why", r.why},
                       {"figures", r.figures}, {"command", ReproduceCommand(*r.c, datasets_dir, settings)}};
      if (r.runs.size() > 1) {
        j["runs"] = r.runs;
        j["worst"] = r.worst;
      }
      for (const Regression& g : r.regressions) j["regressions"].push_back(g.Describe());
      json.push_back(j);
      if (r.failed) {
        ++failed;
        std::printf("\nFAILED %s: %s\n  reproduce: %s\n", r.c->name.c_str(), r.why.c_str(),
                    ReproduceCommand(*r.c, datasets_dir, settings).c_str());
      } else if (!r.regressions.empty()) {
        ++regressed;
        std::printf("\nREGRESSION %s:\n", r.c->name.c_str());
        for (const Regression& g : r.regressions) std::printf("  %s\n", g.Describe().c_str());
        std::printf("  reproduce: %s\n", ReproduceCommand(*r.c, datasets_dir, settings).c_str());
      }
    }
    if (from_path.empty()) WriteFileAtomically((fs::path(out_dir) / "quality.json").string(), json.dump(2) + "\n");
    if (!markdown_path.empty()) {
      WriteMarkdownTable(markdown_path, "build/bin/stitch bench --quality",
                         [&](std::FILE* md) { PrintTable(results, /*markdown=*/true, md, before); });
    }
    if (update) {
      for (const Result& r : results) {
        if (r.skipped || r.failed) continue;
        for (QualityCase& c : matrix.cases) {
          if (c.name != r.c->name) continue;
          const auto record = [&](const std::map<std::string, double>& measured,
                                  std::map<std::string, double>* expect) {
            for (const auto& [figure, value] : measured) {
              if (matrix.tolerance.count(figure) && (figures.empty() || figures.count(figure)))
                (*expect)[figure] = value;
            }
          };
          record(r.figures, &c.expect);
          if (!c.start_frames.empty()) record(r.worst, &c.expect_worst);  // the worst start: a figure of its own
        }
      }
      SaveQualityMatrix(matrix, expected_path);
      std::printf("\nwrote the measured figures to %s\n", expected_path.c_str());
    }
    const int skipped =
        static_cast<int>(std::count_if(results.begin(), results.end(), [](const Result& r) { return r.skipped; }));
    std::printf("\n%d ok, %d regressed, %d failed, %d skipped\n",
                static_cast<int>(results.size()) - regressed - failed - skipped, regressed, failed, skipped);
    return check && (regressed > 0 || failed > 0) ? 1 : 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch bench --quality: %s\n", e.what());
    return 2;
  }
}

}  // namespace stitch
