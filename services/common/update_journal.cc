#include "services/common/update_journal.h"

#include <cstdio>
#include <filesystem>
#include <vector>

#include "services/common/bus.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"
#include "stitch/util/time.h"

namespace stitch {

UpdateJournal::UpdateJournal(const std::string& dir, std::set<std::string> channels)
    : path_((std::filesystem::path(dir) / "submap_updates.lcmlog").string()), channels_(std::move(channels)) {
  std::error_code error;
  std::filesystem::create_directories(dir, error);
  if (error) throw Error("merger state folder " + dir + ": " + error.message());
}

SubmapUpdateLogRead ReadSubmapUpdateLog(const std::string& path, const std::set<std::string>& channels,
                                        const std::function<void(const stitch::submap_update_t&)>& each) {
  LcmLogReader reader(path);
  SubmapUpdateLogRead read;
  while (std::optional<LcmLogRecord> record = reader.Next()) {
    if (!channels.count(record->channel)) continue;
    stitch::submap_update_t update;
    const int length = static_cast<int>(record->data.size());
    if (update.decode(record->data.data(), 0, length) != length) {
      ++read.undecodable;
      continue;
    }
    each(update);
    ++read.updates;
  }
  read.damage = reader.damage();
  if (read.undecodable > 0) {
    STITCH_LOG(WARNING) << path << ": skipped " << read.undecodable << " submap update records that do not decode";
  }
  return read;
}

int64_t UpdateJournal::Recover(const std::function<void(const stitch::submap_update_t&)>& each) {
  int64_t count = 0;
  if (std::filesystem::exists(path_)) {
    const SubmapUpdateLogRead read = ReadSubmapUpdateLog(path_, channels_, each);
    count = read.updates;
    if (!read.damage.empty()) {
      const std::string aside = path_ + ".damaged";
      const LcmLogDamage& last = read.damage.back();
      const bool only_an_unfinished_tail =
          read.damage.size() == 1 &&
          last.offset + last.length == static_cast<int64_t>(std::filesystem::file_size(path_));
      SetDamageAside(path_, read.damage, aside);
      if (only_an_unfinished_tail) {
        STITCH_LOG(WARNING) << path_ << ": cut " << last.length << " bytes of a record left unfinished (moved to "
                            << aside << ")";
      } else {
        STITCH_LOG(WARNING) << path_ << ": " << read.damage.size() << " damaged stretches, "
                            << DamagedBytes(read.damage) << " bytes, the first at offset " << read.damage.front().offset
                            << "; the intact records around them kept (" << count
                            << " submap updates), the damaged bytes moved to " << aside;
      }
    }
  }
  writer_ = std::make_unique<lcm::LogFile>(path_, "a");
  if (!writer_->good()) throw Error(path_ + ": cannot append to the merger's journal");
  return count;
}

void UpdateJournal::Append(const stitch::submap_update_t& update) {
  if (!writer_) throw Error("UpdateJournal::Append before Recover");
  std::vector<uint8_t> bytes(static_cast<size_t>(update.getEncodedSize()));
  update.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
  lcm::LogEvent event;
  event.eventnum = appended_;
  event.timestamp = WallUtime();
  event.channel = bus::Channel(update.header.agent, bus::kSubmap);
  event.datalen = static_cast<int32_t>(bytes.size());
  event.data = bytes.data();
  if (writer_->writeEvent(&event) != 0 || std::fflush(writer_->getFilePtr()) != 0) {
    throw Error(path_ + ": writing the merger's journal failed (disk full?)");
  }
  ++appended_;
}

}  // namespace stitch
