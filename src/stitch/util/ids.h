#pragma once
// Typed identifiers (docs/ids.md). A submap id packs the agent number (16 bits) and the submap
// number (16 bits) in its high half; keyframe and map point ids add a 32-bit index within the
// submap. -1 is invalid. Ids never collide across agents, submaps or tracker restarts (as long
// as submap numbers are not reused, which the tracker ensures).

#include <cstdint>
#include <functional>
#include <ostream>
#include <string>

namespace stitch {

template <class Tag>
struct Id {
  int64_t value = -1;

  constexpr Id() = default;
  constexpr explicit Id(int64_t v) : value(v) {}
  constexpr bool valid() const { return value >= 0; }
  constexpr bool operator==(const Id& o) const { return value == o.value; }
  constexpr bool operator!=(const Id& o) const { return value != o.value; }
  constexpr bool operator<(const Id& o) const { return value < o.value; }
};

template <class Tag>
std::ostream& operator<<(std::ostream& out, const Id<Tag>& id) {
  return out << id.value;
}

using SubmapId = Id<struct SubmapTag>;
using KeyframeId = Id<struct KeyframeTag>;
using MapPointId = Id<struct MapPointTag>;

constexpr SubmapId MakeSubmapId(int agent_number, int submap_number) {
  return SubmapId((static_cast<int64_t>(agent_number & 0x7fff) << 48) |
                  (static_cast<int64_t>(submap_number & 0xffff) << 32));
}
constexpr KeyframeId MakeKeyframeId(SubmapId submap, uint32_t index) {
  return KeyframeId(submap.value | static_cast<int64_t>(index));
}
constexpr MapPointId MakeMapPointId(SubmapId submap, uint32_t index) {
  return MapPointId(submap.value | static_cast<int64_t>(index));
}
template <class Tag>
constexpr SubmapId SubmapOf(Id<Tag> id) {
  return SubmapId(id.value & ~int64_t{0xffffffff});
}
template <class Tag>
constexpr uint32_t IndexOf(Id<Tag> id) {
  return static_cast<uint32_t>(id.value & 0xffffffff);
}
constexpr int SubmapNumber(SubmapId id) {
  return static_cast<int>((id.value >> 32) & 0xffff);
}
constexpr int AgentNumber(SubmapId id) {
  return static_cast<int>((id.value >> 48) & 0x7fff);
}

// The agent number of maps loaded from a file (`stitch run --map`, docs/map-file.md): no aircraft
// has it (tracker.tracking.agent_number stops below it).
constexpr int kSavedMapAgent = 0x7fff;
constexpr bool IsSavedMap(SubmapId id) {
  return id.valid() && AgentNumber(id) == kSavedMapAgent;
}

// "agent:submap" (e.g. "0:3") for logs and people; ids stay int64 everywhere else.
inline std::string SubmapName(SubmapId id) {
  return id.valid() ? std::to_string(AgentNumber(id)) + ":" + std::to_string(SubmapNumber(id)) : std::string("-");
}

}  // namespace stitch

namespace std {
template <class Tag>
struct hash<stitch::Id<Tag>> {
  size_t operator()(const stitch::Id<Tag>& id) const noexcept { return std::hash<int64_t>()(id.value); }
};
}  // namespace std
