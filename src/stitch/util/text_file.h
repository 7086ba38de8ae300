#pragma once
// Line-oriented text files (trajectories, dataset lists, records).

#include <functional>
#include <string>

namespace stitch {

// Calls `on_line(line, line_number)` for every line that is neither blank nor a '#' comment,
// with a trailing '\r' (CRLF files) removed. Throws stitch::Error "<path>: cannot open<hint>"
// when the file cannot be read.
void ForEachDataLine(const std::string& path, const std::function<void(const std::string&, int)>& on_line,
                     const std::string& open_hint = "");

// Replaces the file at `path` with `text` as one act: written to a temporary file beside it,
// flushed, then renamed over it, so a reader (or a crash) never sees half a file. Throws
// stitch::Error naming the file on any failure (a full disk among them); the old file stays.
void WriteFileAtomically(const std::string& path, const std::string& text);

// The whole file's bytes. Throws stitch::Error "cannot open" or "cannot read" (without the path:
// callers name the file).
std::string ReadFileBytes(const std::string& path);

}  // namespace stitch
