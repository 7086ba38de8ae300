#include "services/link/link_wire.h"

#include <algorithm>
#include <cstring>

namespace stitch::link {
namespace {

constexpr size_t kPrefixBytes = 4 + 1 + 1;  // magic, version, type
constexpr size_t kDataFixedBytes = 8 + 8 + 2 + 2 + 4 + 4 + 1;
constexpr size_t kMaxChannelBytes = 255;

class Writer {
 public:
  explicit Writer(DatagramType type) {
    U32(kMagic);
    U8(kVersion);
    U8(static_cast<uint8_t>(type));
  }
  void U8(uint8_t v) { bytes_.push_back(static_cast<char>(v)); }
  void U16(uint16_t v) { Little(v, 2); }
  void U32(uint32_t v) { Little(v, 4); }
  void U64(uint64_t v) { Little(v, 8); }
  void Bytes(const std::string& s) { bytes_ += s; }
  std::string Take() { return std::move(bytes_); }

 private:
  void Little(uint64_t v, int n) {
    for (int i = 0; i < n; ++i) bytes_.push_back(static_cast<char>((v >> (8 * i)) & 0xff));
  }
  std::string bytes_;
};

class Reader {
 public:
  Reader(const uint8_t* bytes, size_t size) : bytes_(bytes), size_(size) {}
  bool U8(uint8_t* v) { return Little(v, 1); }
  bool U16(uint16_t* v) { return Little(v, 2); }
  bool U32(uint32_t* v) { return Little(v, 4); }
  bool U64(uint64_t* v) { return Little(v, 8); }
  bool Bytes(size_t n, std::string* out) {
    if (n > size_ - at_) return false;
    out->assign(reinterpret_cast<const char*>(bytes_ + at_), n);
    at_ += n;
    return true;
  }
  size_t left() const { return size_ - at_; }

 private:
  template <class T>
  bool Little(T* v, int n) {
    if (static_cast<size_t>(n) > size_ - at_) return false;
    uint64_t value = 0;
    for (int i = 0; i < n; ++i) value |= static_cast<uint64_t>(bytes_[at_ + i]) << (8 * i);
    at_ += n;
    *v = static_cast<T>(value);
    return true;
  }
  const uint8_t* bytes_;
  size_t size_;
  size_t at_ = 0;
};

bool Fail(std::string* why, const std::string& reason) {
  if (why) *why = reason;
  return false;
}

}  // namespace

int DataHeaderBytes(const std::string& channel) {
  return static_cast<int>(kPrefixBytes + kDataFixedBytes + channel.size());
}

std::string Encode(const DataFragment& f) {
  Writer w(DatagramType::kData);
  w.U64(f.session);
  w.U64(f.message);
  w.U16(f.index);
  w.U16(f.count);
  w.U32(f.offset);
  w.U32(f.message_bytes);
  w.U8(static_cast<uint8_t>(f.channel.size()));
  w.Bytes(f.channel);
  w.Bytes(f.payload);
  return w.Take();
}

std::string Encode(const RepairRequest& r) {
  Writer w(DatagramType::kRepair);
  w.U64(r.session);
  w.U16(static_cast<uint16_t>(r.wanted.size()));
  for (const auto& wanted : r.wanted) {
    w.U64(wanted.message);
    w.U16(static_cast<uint16_t>(wanted.missing.size()));
    for (uint16_t index : wanted.missing) w.U16(index);
  }
  return w.Take();
}

std::string Encode(const LinkStatus& s) {
  Writer w(DatagramType::kStatus);
  w.U64(s.session);
  w.U64(s.sent_end);
  w.U64(s.retained_begin);
  return w.Take();
}

int FragmentCount(const std::string& channel, size_t message_bytes, int max_datagram_bytes) {
  if (channel.empty() || channel.size() > kMaxChannelBytes || message_bytes > UINT32_MAX) return 0;
  const int room = max_datagram_bytes - DataHeaderBytes(channel);
  if (room < 1) return 0;
  const size_t count = std::max<size_t>(1, (message_bytes + room - 1) / room);
  return count > 65535 ? 0 : static_cast<int>(count);
}

DataFragment MakeFragment(uint64_t session, uint64_t message, const std::string& channel, const std::string& bytes,
                          int max_datagram_bytes, int index) {
  const size_t room = static_cast<size_t>(max_datagram_bytes - DataHeaderBytes(channel));
  DataFragment f;
  f.session = session;
  f.message = message;
  f.index = static_cast<uint16_t>(index);
  f.count = static_cast<uint16_t>(FragmentCount(channel, bytes.size(), max_datagram_bytes));
  f.offset = static_cast<uint32_t>(index * room);
  f.message_bytes = static_cast<uint32_t>(bytes.size());
  f.channel = channel;
  f.payload = bytes.substr(std::min<size_t>(f.offset, bytes.size()), room);
  return f;
}

std::vector<DataFragment> Fragment(uint64_t session, uint64_t message, const std::string& channel,
                                   const std::string& bytes, int max_datagram_bytes) {
  const int count = FragmentCount(channel, bytes.size(), max_datagram_bytes);
  std::vector<DataFragment> fragments;
  fragments.reserve(count);
  for (int i = 0; i < count; ++i) {
    fragments.push_back(MakeFragment(session, message, channel, bytes, max_datagram_bytes, i));
  }
  return fragments;
}

bool Decode(const uint8_t* bytes, size_t size, Datagram* out, std::string* why) {
  Reader r(bytes, size);
  uint32_t magic = 0;
  uint8_t version = 0, type = 0;
  if (!r.U32(&magic) || !r.U8(&version) || !r.U8(&type)) return Fail(why, "shorter than a header");
  if (magic != kMagic) return Fail(why, "not a stitch link datagram (wrong magic)");
  if (version != kVersion) return Fail(why, "link protocol version " + std::to_string(version) + ", this is 1");
  switch (static_cast<DatagramType>(type)) {
    case DatagramType::kData: {
      out->type = DatagramType::kData;
      DataFragment& f = out->data;
      uint8_t channel_bytes = 0;
      if (!r.U64(&f.session) || !r.U64(&f.message) || !r.U16(&f.index) || !r.U16(&f.count) || !r.U32(&f.offset) ||
          !r.U32(&f.message_bytes) || !r.U8(&channel_bytes) || !r.Bytes(channel_bytes, &f.channel)) {
        return Fail(why, "data header truncated");
      }
      if (f.channel.empty()) return Fail(why, "data without a channel");
      if (f.count == 0 || f.index >= f.count) return Fail(why, "fragment index out of range");
      r.Bytes(r.left(), &f.payload);
      if (static_cast<uint64_t>(f.offset) + f.payload.size() > f.message_bytes) {
        return Fail(why, "fragment reaches past its message's end");
      }
      if (f.index + 1 < f.count && f.payload.empty()) return Fail(why, "empty fragment inside a message");
      return true;
    }
    case DatagramType::kRepair: {
      out->type = DatagramType::kRepair;
      RepairRequest& q = out->repair;
      q.wanted.clear();
      uint16_t n = 0;
      if (!r.U64(&q.session) || !r.U16(&n)) return Fail(why, "repair request truncated");
      if (n > r.left() / 10) return Fail(why, "repair request lists more messages than it holds");
      q.wanted.resize(n);
      for (auto& wanted : q.wanted) {
        uint16_t m = 0;
        if (!r.U64(&wanted.message) || !r.U16(&m) || m > r.left() / 2) return Fail(why, "repair request truncated");
        wanted.missing.resize(m);
        for (uint16_t& index : wanted.missing) r.U16(&index);
      }
      if (r.left() != 0) return Fail(why, "bytes after a repair request");
      return true;
    }
    case DatagramType::kStatus: {
      out->type = DatagramType::kStatus;
      LinkStatus& s = out->status;
      if (!r.U64(&s.session) || !r.U64(&s.sent_end) || !r.U64(&s.retained_begin)) return Fail(why, "status truncated");
      if (r.left() != 0) return Fail(why, "bytes after a status");
      if (s.retained_begin > s.sent_end) return Fail(why, "status retains past what it sent");
      return true;
    }
  }
  return Fail(why, "unknown datagram type " + std::to_string(type));
}

std::vector<RepairRequest> SplitRepair(const RepairRequest& request, int max_datagram_bytes) {
  std::vector<RepairRequest> out;
  const size_t budget = static_cast<size_t>(max_datagram_bytes) - (kPrefixBytes + 8 + 2);
  RepairRequest current{request.session, {}};
  size_t used = 0;
  for (const auto& wanted : request.wanted) {
    // One message's list may itself be too long: split it (each part names the message again).
    size_t from = 0;
    bool named = false;
    while (!named || from < wanted.missing.size()) {
      const size_t room = budget - used;
      if (room < 10 + 2 || current.wanted.size() == 65535) {
        out.push_back(std::move(current));
        current = RepairRequest{request.session, {}};
        used = 0;
        continue;
      }
      const size_t take = std::min(wanted.missing.size() - from, (room - 10) / 2);
      RepairRequest::Wanted part{wanted.message, {}};
      part.missing.assign(wanted.missing.begin() + from, wanted.missing.begin() + from + take);
      from += take;
      used += 10 + 2 * take;
      named = true;
      current.wanted.push_back(std::move(part));
    }
  }
  if (!current.wanted.empty()) out.push_back(std::move(current));
  return out;
}

}  // namespace stitch::link
