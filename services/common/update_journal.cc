#include "services/common/update_journal.h"

#include <algorithm>
#include <array>
#include <cstdio>
#include <filesystem>
#include <set>
#include <vector>

#include <sodium.h>

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
  if (sodium_init() < 0) throw Error("libsodium cannot be initialized");
}

namespace {

constexpr size_t kChecksumBytes = 16;

// BLAKE2b of a record's channel and bytes (the channel's terminating zero between them).
std::array<uint8_t, kChecksumBytes> RecordChecksum(const std::string& channel, const uint8_t* data, size_t size) {
  crypto_generichash_state state;
  crypto_generichash_init(&state, nullptr, 0, kChecksumBytes);
  crypto_generichash_update(&state, reinterpret_cast<const unsigned char*>(channel.c_str()), channel.size() + 1);
  crypto_generichash_update(&state, data, size);
  std::array<uint8_t, kChecksumBytes> checksum{};
  crypto_generichash_final(&state, checksum.data(), checksum.size());
  return checksum;
}

bool ChecksumMatches(const LcmLogRecord& record, const std::vector<uint8_t>& checksum) {
  const auto expected = RecordChecksum(record.channel, record.data.data(), record.data.size());
  return checksum.size() == expected.size() && std::equal(expected.begin(), expected.end(), checksum.begin());
}

}  // namespace

SubmapUpdateLogRead ReadSubmapUpdateLog(const std::string& path, const std::set<std::string>& channels,
                                        const std::function<void(const stitch::submap_update_t&)>& each,
                                        const std::function<void(const stitch::gnss_fix_t&)>& each_fix) {
  if (sodium_init() < 0) throw Error("libsodium cannot be initialized");
  LcmLogReader reader(path);
  SubmapUpdateLogRead read;
  std::set<std::string> gnss_channels;  // the same aircraft's fixes
  if (each_fix) {
    for (const std::string& channel : channels) {
      gnss_channels.insert(bus::Channel(channel.substr(0, channel.rfind('/')), bus::kGnss));
    }
  }
  std::vector<LcmLogDamage> mismatched;
  // A record is passed on once the next one shows whether a checksum follows it.
  std::optional<LcmLogRecord> waiting;
  const auto settle = [&](const LcmLogRecord& record, bool checked) {
    const bool update_record = channels.count(record.channel) > 0;
    if (!update_record && !gnss_channels.count(record.channel)) return;
    // Decodes the record as `message` and passes it to `to`, counting it in `count`.
    const auto pass_on = [&](auto message, const auto& to, int64_t* count) {
      const int length = static_cast<int>(record.data.size());
      if (message.decode(record.data.data(), 0, length) != length) {
        ++read.undecodable;
        return;
      }
      to(message);
      ++*count;
      if (!checked) ++read.unchecked;
    };
    if (update_record) {
      pass_on(stitch::submap_update_t(), each, &read.updates);
    } else {
      pass_on(stitch::gnss_fix_t(), each_fix, &read.gnss_fixes);
    }
  };
  while (std::optional<LcmLogRecord> record = reader.Next()) {
    if (record->channel != kJournalChecksumChannel) {
      if (waiting) settle(*waiting, false);
      waiting = std::move(record);
      continue;
    }
    const bool follows = waiting && waiting->end == record->offset;
    if (follows && ChecksumMatches(*waiting, record->data)) {
      settle(*waiting, true);
    } else {
      // The record before it (when it is right before it) and the checksum are set aside.
      if (waiting && !follows) settle(*waiting, false);
      const int64_t from = follows ? waiting->offset : record->offset;
      mismatched.push_back({from, record->end - from});
      ++read.checksum_mismatches;
    }
    waiting.reset();
  }
  if (waiting) settle(*waiting, false);
  // The reader's damage and the mismatched records, in file order, a stretch that ends where the
  // next begins joined to it (a record cut off from its checksum is one damaged stretch).
  std::vector<LcmLogDamage> damage = reader.damage();
  damage.insert(damage.end(), mismatched.begin(), mismatched.end());
  std::sort(damage.begin(), damage.end(),
            [](const LcmLogDamage& a, const LcmLogDamage& b) { return a.offset < b.offset; });
  for (const LcmLogDamage& stretch : damage) {
    if (!read.damage.empty() && read.damage.back().offset + read.damage.back().length == stretch.offset) {
      read.damage.back().length += stretch.length;
    } else {
      read.damage.push_back(stretch);
    }
  }
  if (read.undecodable > 0) {
    STITCH_LOG(WARNING) << path << ": skipped " << read.undecodable << " records that do not decode";
  }
  if (read.checksum_mismatches > 0) {
    STITCH_LOG(WARNING) << path << ": skipped " << read.checksum_mismatches
                        << " records whose checksum does not match their bytes (damaged on disk)";
  }
  return read;
}

int64_t UpdateJournal::Recover(const std::function<void(const stitch::submap_update_t&)>& each,
                               const std::function<void(const stitch::gnss_fix_t&)>& each_fix) {
  int64_t count = 0;
  if (std::filesystem::exists(path_)) {
    const SubmapUpdateLogRead read = ReadSubmapUpdateLog(path_, channels_, each, each_fix);
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
  std::lock_guard<std::mutex> lock(mutex_);
  writer_ = std::make_unique<lcm::LogFile>(path_, "a");
  if (!writer_->good()) throw Error(path_ + ": cannot append to the merger's journal");
  return count;
}

int64_t UpdateJournal::appended() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return appended_;
}

void UpdateJournal::Append(const stitch::submap_update_t& update) {
  std::vector<uint8_t> bytes(static_cast<size_t>(update.getEncodedSize()));
  update.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
  AppendRecord(bus::Channel(update.header.agent, bus::kSubmap), bytes);
}

void UpdateJournal::Append(const stitch::gnss_fix_t& fix) {
  std::vector<uint8_t> bytes(static_cast<size_t>(fix.getEncodedSize()));
  fix.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
  AppendRecord(bus::Channel(fix.header.agent, bus::kGnss), bytes);
}

void UpdateJournal::AppendRecord(const std::string& channel, const std::vector<uint8_t>& bytes) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!writer_) throw Error("UpdateJournal: appending before Recover");
  lcm::LogEvent event;
  event.eventnum = appended_;
  event.timestamp = WallUtime();
  event.channel = channel;
  event.datalen = static_cast<int32_t>(bytes.size());
  event.data = const_cast<uint8_t*>(bytes.data());
  auto checksum = RecordChecksum(event.channel, bytes.data(), bytes.size());
  lcm::LogEvent checksum_event;
  checksum_event.eventnum = appended_;
  checksum_event.timestamp = event.timestamp;
  checksum_event.channel = kJournalChecksumChannel;
  checksum_event.datalen = static_cast<int32_t>(checksum.size());
  checksum_event.data = checksum.data();
  if (writer_->writeEvent(&event) != 0 || writer_->writeEvent(&checksum_event) != 0 ||
      std::fflush(writer_->getFilePtr()) != 0) {
    throw Error(path_ + ": writing the merger's journal failed (disk full?)");
  }
  ++appended_;
}

}  // namespace stitch
