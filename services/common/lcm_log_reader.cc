#include "services/common/lcm_log_reader.h"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>

#include "services/common/big_endian.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

constexpr uint8_t kSync[4] = {0xED, 0xA1, 0xDA, 0x01};
constexpr int64_t kHeaderBytes = 4 + 8 + 8 + 4 + 4;
constexpr int32_t kMaxChannelLength = 999;  // as liblcm's reader
constexpr int64_t kScanChunk = 1 << 16;

}  // namespace

LcmLogReader::LcmLogReader(const std::string& path) : path_(path), file_(path, std::ios::binary) {
  std::error_code error;
  const auto size = std::filesystem::file_size(path, error);
  if (!file_ || error) throw Error(path + ": cannot read this LCM log" + (error ? " (" + error.message() + ")" : ""));
  size_ = static_cast<int64_t>(size);
}

bool LcmLogReader::ReadAt(int64_t offset, void* bytes, int64_t length) {
  if (offset < 0 || length < 0 || offset + length > size_) return false;
  file_.clear();
  file_.seekg(offset);
  file_.read(static_cast<char*>(bytes), length);
  return file_.gcount() == length;
}

bool LcmLogReader::RecordStartsAt(int64_t offset, Header* header, bool strict) {
  uint8_t bytes[kHeaderBytes];
  if (!ReadAt(offset, bytes, kHeaderBytes) || std::memcmp(bytes, kSync, 4) != 0) return false;
  header->event_number = BigEndian(bytes + 4, 8);
  header->utime = BigEndian(bytes + 12, 8);
  header->channel_length = static_cast<int32_t>(BigEndian(bytes + 20, 4));
  header->data_length = static_cast<int32_t>(BigEndian(bytes + 24, 4));
  const int64_t body = offset + kHeaderBytes;
  if (header->channel_length < 1 || header->channel_length > kMaxChannelLength || header->data_length < 0 ||
      body + header->channel_length + header->data_length > size_) {
    return false;
  }
  char channel[kMaxChannelLength];
  if (!ReadAt(body, channel, header->channel_length)) return false;
  for (int i = 0; i < header->channel_length; ++i) {
    if (channel[i] < 0x21 || channel[i] > 0x7e) return false;
  }
  // What follows is the next record's sync word (as much of it as the file holds: a record
  // whose successor was cut short by a kill is whole) or the end of the file.
  const int64_t end = body + header->channel_length + header->data_length;
  const int64_t following = std::min<int64_t>(4, size_ - end);
  uint8_t next[4];
  if (following == 0 || (ReadAt(end, next, following) && std::memcmp(next, kSync, following) == 0)) return true;
  // Else that sync word is damaged, or the length is: a length that runs into the next records
  // has one of them start inside it.
  return !strict && NextRecordAfter(offset, end, /*strict=*/true) == end;
}

int64_t LcmLogReader::NextRecordAfter(int64_t offset, int64_t end, bool strict) {
  std::vector<uint8_t> chunk(kScanChunk + 3);
  for (int64_t start = offset + 1; start < end; start += kScanChunk) {
    const int64_t length = std::min<int64_t>(kScanChunk + 3, size_ - start);
    if (!ReadAt(start, chunk.data(), length)) break;
    for (int64_t i = 0; i + 4 <= length && i < kScanChunk && start + i < end; ++i) {
      Header header;
      if (std::memcmp(chunk.data() + i, kSync, 4) == 0 && RecordStartsAt(start + i, &header, strict)) return start + i;
    }
  }
  return end;
}

std::optional<LcmLogRecord> LcmLogReader::Next() {
  while (position_ < size_) {
    Header header;
    if (!RecordStartsAt(position_, &header)) {
      const int64_t next = NextRecordAfter(position_, size_);
      damage_.push_back({position_, next - position_});
      position_ = next;
      continue;
    }
    LcmLogRecord record;
    record.event_number = header.event_number;
    record.utime = header.utime;
    record.offset = position_;
    record.channel.resize(static_cast<size_t>(header.channel_length));
    record.data.resize(static_cast<size_t>(header.data_length));
    const int64_t body = position_ + kHeaderBytes;
    if (!ReadAt(body, record.channel.data(), header.channel_length) ||
        !ReadAt(body + header.channel_length, record.data.data(), header.data_length)) {
      throw Error(path_ + ": read failed at offset " + std::to_string(body));
    }
    record.end = body + header.channel_length + header.data_length;
    position_ = record.end;
    return record;
  }
  return std::nullopt;
}

int64_t DamagedBytes(const std::vector<LcmLogDamage>& damage) {
  int64_t total = 0;
  for (const LcmLogDamage& d : damage) total += d.length;
  return total;
}

namespace {

// Appends bytes [offset, offset + length) of `in` to `out`; false on a read or write failure.
bool CopyRange(std::FILE* in, int64_t offset, int64_t length, std::FILE* out) {
  if (std::fseek(in, offset, SEEK_SET) != 0) return false;
  std::vector<char> buffer(1 << 16);
  while (length > 0) {
    const size_t n = static_cast<size_t>(std::min<int64_t>(length, static_cast<int64_t>(buffer.size())));
    if (std::fread(buffer.data(), 1, n, in) != n || std::fwrite(buffer.data(), 1, n, out) != n) return false;
    length -= static_cast<int64_t>(n);
  }
  return true;
}

bool FlushAndSync(std::FILE* file) {
  return std::fflush(file) == 0 && ::fsync(fileno(file)) == 0;
}

}  // namespace

void SetDamageAside(const std::string& path, const std::vector<LcmLogDamage>& damage,
                    const std::string& set_aside_path) {
  std::FILE* in = std::fopen(path.c_str(), "rb");
  if (!in) throw Error(path + ": cannot read (" + std::strerror(errno) + ")");
  const int64_t size = static_cast<int64_t>(std::filesystem::file_size(path));
  const std::string temporary = path + ".partial";
  std::FILE* aside = std::fopen(set_aside_path.c_str(), "ab");
  std::FILE* intact = aside ? std::fopen(temporary.c_str(), "wb") : nullptr;
  bool ok = aside && intact;
  int64_t at = 0;
  for (const LcmLogDamage& d : damage) {
    if (!ok) break;
    ok = d.offset >= at && d.offset + d.length <= size && CopyRange(in, at, d.offset - at, intact) &&
         CopyRange(in, d.offset, d.length, aside);
    at = d.offset + d.length;
  }
  ok = ok && CopyRange(in, at, size - at, intact) && FlushAndSync(aside) && FlushAndSync(intact);
  const int error = errno;
  std::fclose(in);
  if (aside) std::fclose(aside);
  if (intact) std::fclose(intact);
  if (!ok || std::rename(temporary.c_str(), path.c_str()) != 0) {
    std::remove(temporary.c_str());
    throw Error(path + ": cannot set its damaged bytes aside in " + set_aside_path + " (" +
                std::strerror(ok ? errno : error) + ")");
  }
}

}  // namespace stitch
