#include "stitch/records/source_record.h"

#include <fstream>

#include <nlohmann/json.hpp>

#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace stitch {

void WriteSourceRecord(const std::string& path, const SourceRecord& record) {
  const nlohmann::json json = {{"frames_published", record.frames_published},
                               {"frames_late", record.frames_late},
                               {"most_late_s", record.most_late_s},
                               {"seconds", record.seconds}};
  WriteFileAtomically(path, json.dump(1) + "\n");
}

SourceRecord ReadSourceRecord(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw Error(path + ": cannot be read");
  try {
    const nlohmann::json json = nlohmann::json::parse(in);
    SourceRecord record;
    record.frames_published = json.at("frames_published");
    record.frames_late = json.at("frames_late");
    record.most_late_s = json.at("most_late_s");
    record.seconds = json.at("seconds");
    if (record.frames_published < 0 || record.frames_late < 0 || record.frames_late > record.frames_published) {
      throw Error(path + ": frames_late must be within [0, frames_published]");
    }
    return record;
  } catch (const nlohmann::json::exception& e) {
    throw Error(path + ": not a source record (" + e.what() + ")");
  }
}

}  // namespace stitch
