#pragma once
// The merger's store on disk: every submap update it has accepted (and every GNSS fix, on its
// <agent>/GNSS channel), appended in LCM's log format
// and flushed one by one, so a merger killed at any moment (SIGKILL included) and restarted with
// the same folder reads them back and carries on with nothing lost. Being an LCM log, the journal
// can also be replayed with lcm-logplayer into another merger, or kept as the run's record.
//
// Each update record is followed by a checksum record (channel kJournalChecksumChannel: a 16-byte
// BLAKE2b hash of the update's channel and bytes), so damage inside a record that still decodes
// (a flipped bit in a point) is found, set aside and counted, never taken silently. A record
// without one (an lcm-logger recording, a journal cut between the two) is read unchecked.

#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <vector>

#include <lcm/lcm-cpp.hpp>

#include "services/common/lcm_log_reader.h"
#include "stitch/gnss_fix_t.hpp"
#include "stitch/submap_update_t.hpp"

namespace stitch {

// The channel of the journal's checksum records (no service subscribes to it).
inline constexpr char kJournalChecksumChannel[] = "STITCH_JOURNAL_CHECKSUM";

// What reading a log of submap updates found.
struct SubmapUpdateLogRead {
  int64_t updates = 0;      // passed on
  int64_t gnss_fixes = 0;   // passed on (with a `each_fix`)
  int64_t unchecked = 0;    // of those, read without a checksum record after them
  int64_t undecodable = 0;  // records on the channels that do not decode (skipped)
  // Records whose checksum does not match their bytes, or a checksum record with no record
  // before it: stepped over, their bytes in `damage`.
  int64_t checksum_mismatches = 0;
  std::vector<LcmLogDamage> damage;  // stretches of the file that hold no whole, intact record
  bool lost_anything() const { return undecodable > 0 || !damage.empty(); }
};

// Reads the submap updates on `channels` (<agent>/SUBMAP of each aircraft) from an LCM log (the
// journal, or an lcm-logger recording of a flight, whose other channels are passed over) and
// calls `each` with them in order; with `each_fix`, also the GNSS fixes of those aircraft
// (<agent>/GNSS), in their place among the updates. Damaged stretches are stepped over (LcmLogReader), and so is
// a record whose checksum record does not match it: every intact record after them is read.
// Throws stitch::Error when the file cannot be read.
SubmapUpdateLogRead ReadSubmapUpdateLog(const std::string& path, const std::set<std::string>& channels,
                                        const std::function<void(const stitch::submap_update_t&)>& each,
                                        const std::function<void(const stitch::gnss_fix_t&)>& each_fix = {});

class UpdateJournal {
 public:
  // Opens (creating) `dir`/submap_updates.lcmlog for the updates on `channels` (<agent>/SUBMAP of
  // each aircraft). Throws stitch::Error when it cannot.
  UpdateJournal(const std::string& dir, std::set<std::string> channels);

  // Calls `each` with every update already in the journal, in order, and returns how many. A
  // record cut short by a kill mid-write, or any other damaged stretch (a disk's error, an
  // overwritten length), is stepped over with every intact record after it kept: the damaged
  // bytes are moved to `path()`.damaged (appended, never deleted) and the journal rewritten
  // without them, so appending goes on after its last whole record. A record that does not
  // decode is skipped with a warning.
  int64_t Recover(const std::function<void(const stitch::submap_update_t&)>& each,
                  const std::function<void(const stitch::gnss_fix_t&)>& each_fix = {});

  // Appends one update (on <its header's agent>/SUBMAP) and its checksum record, and flushes them
  // to the operating system. Throws stitch::Error on a write failure (a full disk): the caller
  // must know the store is no longer complete.
  void Append(const stitch::submap_update_t& update);
  // The same for a GNSS fix (on <its header's agent>/GNSS). Either may be called from any thread.
  void Append(const stitch::gnss_fix_t& fix);

  const std::string& path() const { return path_; }
  int64_t appended() const;

 private:
  void AppendRecord(const std::string& channel, const std::vector<uint8_t>& bytes);

  std::string path_;
  std::set<std::string> channels_;
  mutable std::mutex mutex_;  // the writer and the count
  std::unique_ptr<lcm::LogFile> writer_;
  int64_t appended_ = 0;
};

}  // namespace stitch
