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

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>

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

  // Makes the state into what pages are sent (the live and map updates, the points) and sends
  // each open page what changed since its last push: the live state always, the map and the
  // points when newer. Returns the pages pushed to. Call it from a thread of the caller's: the
  // server's own threads only copy out what the last push made (their stacks are small).
  int Push(double now_s);
  // The page's address, with its access token when it has one.
  std::string url() const;
  int open_pages() const;
  int64_t requests_refused() const;

 private:
  struct Socket {
    int64_t map_revision = -1, cloud_revision = -1;
  };
  struct Updates {
    std::shared_ptr<const std::string> live, map, cloud;
    int64_t map_revision, cloud_revision;
  };
  // What the last Refresh made.
  Updates Latest() const;
  // Sends one page the live state and what it has not had of the map and the points; false when
  // the socket failed.
  static bool SendTo(mg_connection* connection, const Updates& updates, Socket& socket);
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
  std::map<const mg_connection*, Socket> sockets_;
  int pending_sockets_ = 0;  // accepted, not ready yet
  int64_t refused_ = 0;
  // What the last Refresh made: shared, never copied, by the pushes and the requests.
  mutable std::mutex updates_mutex_;
  std::shared_ptr<const std::string> live_, map_, cloud_;
  int64_t map_revision_ = -1, cloud_revision_ = -1;
};

}  // namespace stitch
