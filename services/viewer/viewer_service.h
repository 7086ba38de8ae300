#pragma once
// The ground's live viewer (stitch-viewer): listens to the merger's <station>/GLOBAL_MAP and
// <station>/MAP_CLOUD and to each aircraft's <agent>/TRACKING_STATUS, <agent>/POSE and
// <agent>/LINK_STATUS, and serves a web page that shows them, pushed a few times a second
// (ViewerServer). Works the same on a live flight and on an lcm-logplayer replay.

#include <atomic>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "services/common/bus.h"
#include "services/common/service.h"
#include "services/viewer/viewer_server.h"
#include "services/viewer/viewer_state.h"
#include "stitch/config/viewer_options.h"

namespace stitch {

class ViewerService {
 public:
  // Subscribes and listens at once (construct before the Dispatcher starts); throws stitch::Error
  // when the web server cannot start. `agents`: the aircraft shown (empty: the publisher's agent).
  ViewerService(lcm::LCM* lcm, bus::Publisher* publisher, const ViewerOptions& options,
                std::vector<std::string> agents = {});
  ~ViewerService();

  void Start();
  void Stop();
  std::string url() const { return server_->url(); }
  const ViewerState& state() const { return state_; }
  int open_pages() const { return server_->open_pages(); }

 private:
  void PushLoop();

  ViewerOptions options_;
  ViewerState state_;
  bus::Subscriber subscriber_;
  std::unique_ptr<ViewerServer> server_;
  std::unique_ptr<Heartbeat> heartbeat_;
  std::atomic<int64_t> received_{0};
  std::atomic<bool> running_{false};
  std::thread pusher_;
};

}  // namespace stitch
