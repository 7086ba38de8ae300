#pragma once
// The viewer's web server (civetweb): serves the page, three.js from Debian's libjs-three, the
// state as JSON and the points as binary over HTTP, and pushes updates to each open page over a
// WebSocket (/live). Only GET and HEAD of the fixed paths are answered (nothing is served from a
// folder a request could name), and only for a Host that names this machine (localhost, an IP
// address, viewer.allowed_hosts: a page of another site whose name was made to resolve here is
// refused); a WebSocket is accepted only from the page's own origin, stated (another site open in
// the same browser cannot read the map), and only while fewer than max_pages are open. With an
// access token (always off loopback: viewer_options.h) every request must carry it, in the
// address's query (?token=..., answered with a cookie holding it) or that cookie, or it is refused
// (401) and counted.

#include <condition_variable>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>

#include "services/viewer/viewer_state.h"
#include "stitch/config/viewer_options.h"

struct mg_context;
struct mg_connection;

namespace stitch {

class ViewerServer {
 public:
  struct Asset {
    std::string content_type;
    std::string body;
  };
  // Listens at once; throws stitch::Error when three.js is missing or the address cannot be had.
  // `state` must outlive the server.
  ViewerServer(const ViewerOptions& options, const ViewerState* state);
  ~ViewerServer();
  ViewerServer(const ViewerServer&) = delete;
  ViewerServer& operator=(const ViewerServer&) = delete;

  // Makes the state into what pages are sent (the live and map updates, the points) and hands
  // it to each open page's sender, which sends what changed since that page's last update: the
  // live state always, the map and the points when newer. Never waits for a page: one that reads
  // slowly (or not at all) gets the newest state when it has taken the last, and one whose
  // writes failed (civetweb's request_timeout_ms) gets nothing more and no longer counts against
  // max_pages. Returns the pages handed the update.
  int Push(double now_s);
  // The page's address, with its access token when it has one.
  std::string url() const;
  int open_pages() const;  // pages whose sockets are open and whose writes have not failed
  int64_t requests_refused() const;
  int64_t pages_given_up() const;  // pages whose writes failed

 private:
  struct Updates {
    std::shared_ptr<const std::string> live, map, cloud;
    int64_t map_revision, cloud_revision;
  };
  // One open page: a thread of its own writes the newest updates offered to it, so a page that
  // does not read holds up only itself.
  class PageSender {
   public:
    explicit PageSender(mg_connection* connection);
    ~PageSender();                       // waits for a write under way (it ends within civetweb's request timeout)
    void Offer(const Updates& updates);  // replaces what was offered and not sent yet
    bool failed() const;

   private:
    void Run();
    // Sends the live state and what the page has not had of the map and the points; false when
    // the socket failed.
    bool SendTo(const Updates& updates);

    mg_connection* connection_;
    int64_t map_revision_ = -1, cloud_revision_ = -1;  // the sender thread's
    mutable std::mutex mutex_;
    std::condition_variable offered_;
    std::optional<Updates> pending_;
    bool stopping_ = false, failed_ = false;
    std::thread thread_;
  };
  // What the last Refresh made.
  Updates Latest() const;
  // Open pages whose writes have not failed; sockets_mutex_ held.
  int LivePages() const;
  static int HandleRequest(mg_connection* connection, void* self);
  static int OnSocketConnect(const mg_connection* connection, void* self);
  static void OnSocketReady(mg_connection* connection, void* self);
  static int OnSocketData(mg_connection* connection, int bits, char* data, size_t length, void* self);
  static void OnSocketClose(const mg_connection* connection, void* self);
  int Serve(mg_connection* connection);
  // Whether the request's Host names this machine (above).
  bool HostAllowed(const mg_connection* connection) const;
  // How the request carries the access token: kNone (or none is needed: kNotNeeded), in its
  // query, in its cookie.
  enum class Token { kNotNeeded, kNone, kInQuery, kInCookie };
  Token TokenOf(const mg_connection* connection) const;
  // The updates as the state is now, kept for requests and pushes.
  void Refresh(double now_s);

  ViewerOptions options_;
  std::set<std::string> allowed_hosts_;  // viewer.allowed_hosts, lower case
  std::string token_;                    // 64 hex digits; empty: none needed
  const ViewerState* state_;
  std::map<std::string, Asset> assets_;
  mg_context* context_ = nullptr;
  mutable std::mutex sockets_mutex_;
  std::map<const mg_connection*, std::unique_ptr<PageSender>> sockets_;
  int pending_sockets_ = 0;  // accepted, not ready yet
  int64_t refused_ = 0;
  int64_t given_up_ = 0;
  // What the last Refresh made: shared, never copied, by the pushes and the requests.
  mutable std::mutex updates_mutex_;
  std::shared_ptr<const std::string> live_, map_, cloud_;
  int64_t map_revision_ = -1, cloud_revision_ = -1;
};

}  // namespace stitch
