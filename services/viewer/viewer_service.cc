#include "services/viewer/viewer_service.h"

#include <chrono>

#include "stitch/frame_pose_t.hpp"
#include "stitch/global_map_t.hpp"
#include "stitch/link_status_t.hpp"
#include "stitch/map_cloud_t.hpp"
#include "stitch/tracking_status_t.hpp"
#include "stitch/util/log.h"
#include "stitch/util/time.h"

namespace stitch {

ViewerService::ViewerService(lcm::LCM* lcm, bus::Publisher* publisher, const ViewerOptions& options,
                             std::vector<std::string> agents)
    : options_(options), state_(options.max_page_points), subscriber_(lcm, publisher->authenticator()) {
  if (agents.empty()) agents.push_back(publisher->agent());
  // Each handler checks what the bus's decode cannot (ViewerState) and refuses the rest, counted.
  const auto take = [this](const std::string& channel, bool taken, const std::string& why) {
    ++received_;
    if (!taken) subscriber_.Reject(channel, why);
  };
  const std::string station = publisher->agent();
  subscriber_.Subscribe<stitch::global_map_t>(
      bus::Channel(station, bus::kGlobalMap),
      [this, take](std::unique_ptr<stitch::global_map_t> m, const std::string& on) {
        std::string why;
        take(on, state_.OnGlobalMap(*m, &why), why);
      });
  subscriber_.Subscribe<stitch::map_cloud_t>(
      bus::Channel(station, bus::kMapCloud),
      [this, take](std::unique_ptr<stitch::map_cloud_t> m, const std::string& on) {
        std::string why;
        take(on, state_.OnMapCloud(*m, &why), why);
      });
  subscriber_.Subscribe<stitch::mosaic_tile_t>(
      bus::Channel(station, bus::kMosaicTile),
      [this, take](std::unique_ptr<stitch::mosaic_tile_t> m, const std::string& on) {
        std::string why;
        take(on, state_.OnMosaicTile(*m, WallUtime(), &why), why);
      });
  for (const std::string& agent : agents) {
    subscriber_.Subscribe<stitch::tracking_status_t>(
        bus::Channel(agent, bus::kTrackingStatus),
        [this, take](std::unique_ptr<stitch::tracking_status_t> m, const std::string& on) {
          std::string why;
          take(on, state_.OnTrackingStatus(*m, MonotonicSeconds(), &why), why);
        });
    subscriber_.Subscribe<stitch::frame_pose_t>(
        bus::Channel(agent, bus::kPose), [this, take](std::unique_ptr<stitch::frame_pose_t> m, const std::string& on) {
          std::string why;
          take(on, state_.OnPose(*m, &why), why);
        });
    subscriber_.Subscribe<stitch::link_status_t>(
        bus::Channel(agent, bus::kLinkStatus),
        [this, take](std::unique_ptr<stitch::link_status_t> m, const std::string& on) {
          std::string why;
          take(on, state_.OnLinkStatus(*m, &why), why);
        });
  }
  server_ = std::make_unique<ViewerServer>(options_, &state_);
  heartbeat_ = std::make_unique<Heartbeat>(publisher, "viewer", [this] {
    return Heartbeat::Counts{received_.load(), open_pages(), subscriber_.rejected() + server_->requests_refused()};
  });
}

ViewerService::~ViewerService() {
  Stop();
}

void ViewerService::Start() {
  if (running_.exchange(true)) return;
  pusher_ = std::thread([this] { PushLoop(); });
  heartbeat_->Start();
  heartbeat_->SetState(stitch::service_status_t::STATE_RUNNING);
}

void ViewerService::Stop() {
  if (!running_.exchange(false)) return;
  if (pusher_.joinable()) pusher_.join();
  heartbeat_->SetState(stitch::service_status_t::STATE_FINISHED);
  heartbeat_->Stop();
}

void ViewerService::PushLoop() {
  const auto period = std::chrono::duration<double>(1.0 / options_.updates_per_s);
  auto next = std::chrono::steady_clock::now();
  while (running_.load()) {
    try {
      server_->Push(MonotonicSeconds());
    } catch (const std::exception& e) {  // never the end of the viewer: the next push tries again
      STITCH_LOG(ERROR) << "a push to the pages failed: " << e.what();
    }
    next += std::chrono::duration_cast<std::chrono::steady_clock::duration>(period);
    const auto now = std::chrono::steady_clock::now();
    if (next < now) next = now;
    // Sleep in short steps so Stop() is quick.
    while (running_.load() && std::chrono::steady_clock::now() < next) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
  }
}

}  // namespace stitch
