#pragma once
// The viewer's web server (Boost.Beast over Asio, one thread): serves the page, three.js from
// Debian's libjs-three, the state as JSON and the points as binary over HTTP, and pushes updates
// to each open page over a WebSocket (/live).
//
// What it answers: only GET and HEAD of the fixed paths (nothing is served from a folder a
// request could name), and only for a Host that names this machine (localhost, an IP address,
// viewer.allowed_hosts: a page of another site whose name was made to resolve here is refused);
// a WebSocket only from the page's own origin, stated (another site open in the same browser
// cannot read the map), and only while fewer than max_pages are open. With an access token
// (always off loopback: viewer_options.h) every request must carry it, in the address's query
// (?token=..., answered with a cookie holding it) or that cookie, or it is refused (401) and
// counted.
//
// What a client can cost it (any byte stream, docs/security.md): a request's header at most
// 8 kB and its body 4 kB, read within 10 s; a page's WebSocket message at most 64 kB (a page
// sends nothing the viewer reads); at most kMaxConnections connections at once, and when they
// are all held, a new one takes the place of the oldest that has not finished its request (230
// slow connections locked the operator out of civetweb's eight threads); a page that leaves a
// push unread for 10 s is closed and gives its place up; a page that answers no ping for 60 s
// (its machine gone) is closed too.

#include <cstdint>
#include <memory>
#include <string>

#include "services/viewer/viewer_state.h"
#include "stitch/config/viewer_options.h"

namespace stitch {

class ViewerServer {
 public:
  struct Asset {
    std::string content_type;
    std::string body;
  };
  // Connections held at once (pages, requests being read or answered).
  static constexpr int kMaxConnections = 64;

  // Listens at once; throws stitch::Error when three.js is missing or the address cannot be had.
  // `state` must outlive the server.
  ViewerServer(const ViewerOptions& options, const ViewerState* state);
  ~ViewerServer();
  ViewerServer(const ViewerServer&) = delete;
  ViewerServer& operator=(const ViewerServer&) = delete;

  // Makes the state into what pages are sent (the live and map updates, the points) and hands
  // it to each open page, which is sent what changed since its last update: the live state
  // always, the map and the points when newer. Never waits for a page: one that reads slowly
  // gets the newest state when it has taken the last. Returns the pages handed the update.
  int Push(double now_s);
  // The page's address, with its access token when it has one.
  std::string url() const;
  int open_pages() const;  // WebSockets open now
  int64_t requests_refused() const;
  int64_t pages_given_up() const;         // pages closed for leaving an update unread, or silent
  int64_t connections_displaced() const;  // unfinished requests closed for a newer connection

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stitch
