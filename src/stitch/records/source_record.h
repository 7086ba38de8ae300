#pragma once
// ingest.json: how the source kept the camera's pace (`stitch-ingest --record FILE`, written when
// it ends; `stitch run` keeps it beside the run's outputs). In real-time playback of a recorded
// sequence each frame goes out at its time; a frame the source (decoding, reducing, rendering)
// had ready more than one frame period after its time went out late, and the run then played
// slower than the camera: its figures say nothing of the camera's own pace.

#include <string>

namespace stitch {

struct SourceRecord {
  int frames_published = 0;
  int frames_late = 0;     // real-time playback: sent more than one frame period after their time
  double most_late_s = 0;  // how far behind its time the latest of them went out, seconds
  double seconds = 0;      // the playback, from its start to the last frame sent
};

// Replaces `path` as one act (WriteFileAtomically). Throws stitch::Error.
void WriteSourceRecord(const std::string& path, const SourceRecord& record);
// Throws stitch::Error naming the file when it cannot be read or is not such a record.
SourceRecord ReadSourceRecord(const std::string& path);

}  // namespace stitch
