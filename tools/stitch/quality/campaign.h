#pragma once
// `stitch campaign`: the merge campaign (docs/benchmarks.md, "The merge campaign"). Randomized
// synthetic flights, each a `stitch run` through the quality gate's runner, each merge scored
// against ground truth; a wrong merge fails the campaign.

#include <string>
#include <utility>
#include <vector>

namespace stitch {

struct CampaignOptions {
  int runs = 60;
  int seed = 1;
  int min_frames = 200, max_frames = 1500;
  double link_share = 0.5;  // flights behind the rehearsed radio link
};

// One drawn flight; the same options and index draw the same flight.
struct CampaignFlight {
  int world_seed = 1;
  int frames = 0;
  std::vector<std::pair<int, int>> gusts;  // (first frame, length), in order, apart
  bool link = false;
  double loss = 0;
  int delay_ms = 0, jitter_ms = 0;
  int budget = 0;  // bytes/s; 0: none
  int link_seed = 1;
};
CampaignFlight DrawCampaignFlight(const CampaignOptions& options, int index);
// The `stitch run` arguments that fly it.
std::vector<std::string> CampaignRunArguments(const CampaignFlight& flight);

}  // namespace stitch
