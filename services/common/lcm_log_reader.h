#pragma once
// Reads an LCM log file (LCM's event log format: per record a sync word 0xEDA1DA01, event
// number, timestamp, channel length, data length, all big-endian, then the channel and the data)
// without trusting a byte of it. A record is taken only when its header is plausible (a channel
// of 1-999 printable characters, a data length within the file) and its length does not run
// into another record: the bytes after it start the next record's sync word or end the file, or
// (that sync word damaged) no record that checks out starts inside it. Anything else is a
// damaged stretch, stepped over to the next record that checks out and reported, so the intact
// records after damage are all read. No length is allocated before it is checked against the bytes that remain, and
// nothing is read past the file's end. (liblcm's own reader stops at the first bad header and trusts the data length it
// reads.)

#include <cstdint>
#include <fstream>
#include <optional>
#include <string>
#include <vector>

namespace stitch {

struct LcmLogRecord {
  int64_t event_number = 0;
  int64_t utime = 0;
  std::string channel;
  std::vector<uint8_t> data;
  int64_t offset = 0;  // of its sync word in the file
  int64_t end = 0;     // the offset after it
};

struct LcmLogDamage {
  int64_t offset = 0;  // bytes of the file that hold no whole record
  int64_t length = 0;
};

// Bytes in all of `damage`.
int64_t DamagedBytes(const std::vector<LcmLogDamage>& damage);

class LcmLogReader {
 public:
  // Throws stitch::Error when the file cannot be opened.
  explicit LcmLogReader(const std::string& path);

  // The next whole record, damaged stretches stepped over; nullopt at the end of the file.
  std::optional<LcmLogRecord> Next();

  // The damaged stretches met so far, in file order.
  const std::vector<LcmLogDamage>& damage() const { return damage_; }
  int64_t size() const { return size_; }
  const std::string& path() const { return path_; }

 private:
  struct Header {
    int64_t event_number = 0, utime = 0;
    int32_t channel_length = 0, data_length = 0;
  };
  // Whether a whole record starts at `offset` (see the top of this file). `strict`: only when the
  // next record's sync word follows it.
  bool RecordStartsAt(int64_t offset, Header* header, bool strict = false);
  // The offset of the next record after `offset` and before `end`, or `end` when none.
  int64_t NextRecordAfter(int64_t offset, int64_t end, bool strict = false);
  // Reads `length` bytes at `offset`; false when the file has fewer.
  bool ReadAt(int64_t offset, void* bytes, int64_t length);

  std::string path_;
  std::ifstream file_;
  int64_t size_ = 0;
  int64_t position_ = 0;
  std::vector<LcmLogDamage> damage_;
};

// Copies the bytes of `path` outside `damage` (its whole records, byte for byte) to `path`, and
// the damaged bytes to `set_aside_path` (appended, one stretch after another), each file written
// and synced before the journal is replaced by an atomic rename. Throws stitch::Error on failure
// (the journal is then as it was).
void SetDamageAside(const std::string& path, const std::vector<LcmLogDamage>& damage,
                    const std::string& set_aside_path);

}  // namespace stitch
