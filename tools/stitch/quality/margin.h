#pragma once
// stitch bench --realtime: a case's margin in real time, the highest playback speed
// (ingest.speed) at which it still drops at most a given share of its frames. A machine half as
// fast as this one sees the camera at speed 2, so a margin of 2 is what keeps a case in real time
// there. docs/benchmarks.md, "Margin".

#include <functional>
#include <map>
#include <string>
#include <vector>

namespace stitch {

struct MarginOptions {
  double max_dropped_share = 0.01;  // of the frames, at most this many dropped to keep up
  double lowest_speed = 0.25;       // slowest speed tried (below it the margin is 0)
  double highest_speed = 8;         // fastest tried (a case keeping up there has at least this margin)
  double resolution = 0.1;          // the search stops when its bracket is within this ratio (1.1)
};

// One play of the case at one speed.
struct MarginTrial {
  double speed = 0;
  double dropped_share = 0;               // dropped frames of all frames
  std::map<std::string, double> figures;  // the quality gate's (MeasureRun) and frames_total
  bool kept_up = false;                   // dropped_share <= max_dropped_share
};

struct Margin {
  double speed = 0;                 // the highest speed tried that kept up; 0 when none did
  bool capped = false;              // it kept up at the highest speed tried: the margin is at least that
  std::vector<MarginTrial> trials;  // in the order played
};

// Plays at 1, then doubles (or halves) until the case stops (or starts) keeping up, then bisects
// the bracket (geometrically) down to the resolution. `play` plays the case at a speed and
// returns the trial with its dropped share and figures; FindMargin sets kept_up.
Margin FindMargin(const std::function<MarginTrial(double speed)>& play, const MarginOptions& options);

int MarginCommand(int argc, char** argv);  // stitch bench --realtime

}  // namespace stitch
