#pragma once
// The tracker's state file (tracker.state_file, `stitch-tracker --state`): the number the next
// submap gets, kept across restarts so submap ids never repeat (docs/ids.md). One line,
// "next_submap_number N". Written by the tracker service after each new submap, read when it
// starts.

#include <string>

namespace stitch {

// 0 when the file does not exist. Throws stitch::Error for a file that exists but does not parse
// or holds a number outside 1..65535.
int ReadNextSubmapNumber(const std::string& path);
// Replaces the file as one act (WriteFileAtomically). Throws stitch::Error.
void WriteNextSubmapNumber(const std::string& path, int number);

}  // namespace stitch
