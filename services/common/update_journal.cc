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

int64_t ReadSubmapUpdateLog(const std::string& path, const std::set<std::string>& channels,
                            const std::function<void(const stitch::submap_update_t&)>& each, long* whole_end) {
  lcm::LogFile reader(path, "r");
  if (!reader.good()) throw Error(path + ": cannot read this LCM log");
  int64_t count = 0, undecodable = 0;
  while (const lcm::LogEvent* event = reader.readNextEvent()) {
    if (whole_end) *whole_end = std::ftell(reader.getFilePtr());
    if (!channels.count(event->channel)) continue;
    stitch::submap_update_t update;
    if (update.decode(event->data, 0, static_cast<int>(event->datalen)) != static_cast<int>(event->datalen)) {
      ++undecodable;
      continue;
    }
    each(update);
    ++count;
  }
  if (undecodable > 0) {
    STITCH_LOG(WARNING) << path << ": skipped " << undecodable << " submap update records that do not decode";
  }
  return count;
}

int64_t UpdateJournal::Recover(const std::function<void(const stitch::submap_update_t&)>& each) {
  int64_t count = 0;
  if (std::filesystem::exists(path_)) {
    long whole_end = 0;  // file offset after the last whole record
    count = ReadSubmapUpdateLog(path_, channels_, each, &whole_end);
    const auto size = std::filesystem::file_size(path_);
    if (static_cast<uintmax_t>(whole_end) < size) {
      STITCH_LOG(WARNING) << path_ << ": cut " << size - whole_end << " bytes of a record left unfinished";
      std::filesystem::resize_file(path_, static_cast<uintmax_t>(whole_end));
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
