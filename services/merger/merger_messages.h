#pragma once
// The merger's messages from its session's values: the merged maps (<agent>/GLOBAL_MAP) and
// their points (<agent>/MAP_CLOUD).

#include <map>
#include <optional>
#include <string>
#include <vector>

#include "stitch/global_map_t.hpp"
#include "stitch/map_cloud_t.hpp"
#include "stitch/merging/merge_session.h"

namespace stitch {

// Every submap's placement (its aircraft from `agent_of`, else `default_agent`), every edge of
// the graph, the refined keyframe poses, the last `log_lines` lines of the merge log and, with
// `enu_origin` (MergeSession::gnss_origin), where the fixes place each merged map on Earth. The
// revision is left to the caller.
stitch::global_map_t ToGlobalMapMessage(const Merger::Graph& graph, const std::map<SubmapId, SubmapReplica>& submaps,
                                        const std::map<SubmapId, std::string>& agent_of,
                                        const std::string& default_agent, const std::vector<MergeLogRecord>& log,
                                        size_t log_lines, const std::optional<GeodeticPoint>& enu_origin);

stitch::map_cloud_t ToMessage(const MergeSession::MapCloud& cloud);

}  // namespace stitch
