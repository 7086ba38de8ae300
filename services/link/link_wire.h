#pragma once
// What the two link bridges say to each other over UDP. Every datagram starts with a magic
// number, a version and a type; integers are little-endian. Three types:
//
//   DATA    one fragment of one LCM message: the sender's session, the message's number, the
//           fragment's index and count, its byte offset, the message's size and channel.
//   REPAIR  the receiver's list of what it lacks of the sender's session: per message, the
//           missing fragment indices (none listed: the whole message).
//   STATUS  how far the sender has sent: every message below `sent_end` has had all its
//           fragments sent once; messages below `retained_begin` can no longer be repaired.
//
// Parsing never trusts a length: a datagram that is short, long, or inconsistent is refused
// with the reason, never read past its end.

#include <cstdint>
#include <string>
#include <vector>

namespace stitch::link {

inline constexpr uint32_t kMagic = 0x314c5453;  // "STL1" on the wire
inline constexpr uint8_t kVersion = 1;
inline constexpr int kUdpIpHeaderBytes = 28;  // what each datagram costs the link beyond its payload

enum class DatagramType : uint8_t { kData = 1, kRepair = 2, kStatus = 3 };

struct DataFragment {
  uint64_t session = 0;
  uint64_t message = 0;
  uint16_t index = 0;
  uint16_t count = 0;
  uint32_t offset = 0;
  uint32_t message_bytes = 0;
  std::string channel;
  std::string payload;
};

struct RepairRequest {
  struct Wanted {
    uint64_t message = 0;
    std::vector<uint16_t> missing;  // empty: every fragment
  };
  uint64_t session = 0;  // the data sender's session these refer to
  std::vector<Wanted> wanted;
};

struct LinkStatus {
  uint64_t session = 0;
  uint64_t sent_end = 0;
  uint64_t retained_begin = 0;
};

// Bytes a DATA datagram spends besides the payload.
int DataHeaderBytes(const std::string& channel);

std::string Encode(const DataFragment& fragment);
std::string Encode(const RepairRequest& request);
std::string Encode(const LinkStatus& status);

// Number of fragments a message of `message_bytes` on `channel` takes (0: it cannot be sent:
// the channel leaves no room or it would need more than 65535).
int FragmentCount(const std::string& channel, size_t message_bytes, int max_datagram_bytes);
// Fragment `index` of a message (index < FragmentCount).
DataFragment MakeFragment(uint64_t session, uint64_t message, const std::string& channel, const std::string& bytes,
                          int max_datagram_bytes, int index);

// Splits a message into fragments of at most `max_datagram_bytes` each (at least one, also for
// an empty message). Returns no fragment when the channel leaves no room or more than 65535
// fragments would be needed.
std::vector<DataFragment> Fragment(uint64_t session, uint64_t message, const std::string& channel,
                                   const std::string& bytes, int max_datagram_bytes);

struct Datagram {
  DatagramType type = DatagramType::kData;
  DataFragment data;
  RepairRequest repair;
  LinkStatus status;
};

// Decodes one datagram; false with `why` set when it is not a well-formed one of ours.
bool Decode(const uint8_t* bytes, size_t size, Datagram* out, std::string* why);

// Repair requests for many messages split over datagrams of at most `max_datagram_bytes`.
std::vector<RepairRequest> SplitRepair(const RepairRequest& request, int max_datagram_bytes);

}  // namespace stitch::link
