#include "services/viewer/viewer_server.h"

#include <arpa/inet.h>
#include <civetweb.h>
#include <dlfcn.h>
#include <pthread.h>
#include <sodium.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <vector>

#include "services/common/secret_file.h"
#include "services/viewer/web_assets.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"
#include "stitch/util/time.h"

// civetweb as Debian builds it (CIVETWEB_THREAD_STACK_SIZE, 100 kB) gives each of its threads a
// 100 kB stack, and in this process the libraries' thread-local storage takes much of it: a
// WebSocket frame cut off by its client sent the reading thread into civetweb's error log (an
// 8 kB buffer and vsnprintf), past the end of its stack, and the viewer died (SIGSEGV, within 2 s
// of the attack). The threads this process starts with a stated stack size get at least 1 MB:
// this definition comes before the C library's for every library in the process (the
// executable's symbols are searched first).
extern "C" int pthread_attr_setstacksize(pthread_attr_t* attributes, size_t bytes) {
  using SetStackSize = int (*)(pthread_attr_t*, size_t);
  static const auto set_stack_size = reinterpret_cast<SetStackSize>(dlsym(RTLD_NEXT, "pthread_attr_setstacksize"));
  constexpr size_t kMinThreadStackBytes = size_t{1} << 20;
  return set_stack_size ? set_stack_size(attributes, std::max(bytes, kMinThreadStackBytes)) : EINVAL;
}

namespace stitch {

namespace {

ViewerServer::Asset ThreeFile(const std::string& three_dir, const std::string& relative) {
  const std::string path = (std::filesystem::path(three_dir) / relative).string();
  if (!std::filesystem::is_regular_file(path)) {
    throw Error("the viewer needs three.js: " + path +
                " is missing (install Debian's libjs-three, or set viewer.three_dir)");
  }
  std::ifstream in(path, std::ios::binary);
  std::string body((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (!in && !in.eof()) throw Error(path + ": cannot read");
  return {"text/javascript; charset=utf-8", std::move(body)};
}

// The page's own origin, as the browser names it in a WebSocket's Origin header (a browser always
// sends one; a client without one is refused).
bool SameOrigin(const mg_connection* connection) {
  const char* origin = mg_get_header(connection, "Origin");
  const char* host = mg_get_header(connection, "Host");
  if (!origin || !host) return false;
  return std::string(origin) == "http://" + std::string(host);
}

std::string Lower(std::string text) {
  for (char& c : text) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return text;
}

constexpr char kTokenCookie[] = "stitch_viewer_token";

// Whether `text` holds `key`=`value` among its `separator`-separated pairs (a query, a Cookie
// header), compared in constant time.
bool HasPair(const char* text, char separator, const std::string& key, const std::string& value) {
  if (!text) return false;
  std::stringstream pairs(text);
  bool found = false;
  for (std::string pair; std::getline(pairs, pair, separator);) {
    pair.erase(0, pair.find_first_not_of(' '));
    if (pair.size() != key.size() + 1 + value.size() || pair.compare(0, key.size() + 1, key + "=") != 0) continue;
    found |= sodium_memcmp(pair.data() + key.size() + 1, value.data(), value.size()) == 0;
  }
  return found;
}

int SendBody(mg_connection* connection, int status, const char* status_text, const std::string& content_type,
             const std::string& body, bool head, const std::string& extra_headers = "") {
  // Written without mg_printf: its 8 kB buffer and vsnprintf overflow civetweb's small thread
  // stacks under AddressSanitizer.
  const std::string headers =
      "HTTP/1.1 " + std::to_string(status) + " " + status_text + "\r\nContent-Type: " + content_type +
      "\r\nContent-Length: " + std::to_string(body.size()) +
      "\r\nCache-Control: no-store\r\nX-Content-Type-Options: nosniff\r\nX-Frame-Options: DENY\r\n"
      "Referrer-Policy: no-referrer\r\n"
      "Content-Security-Policy: default-src 'self'; img-src 'self' data:\r\nConnection: close\r\n" +
      extra_headers + "\r\n";
  mg_write(connection, headers.data(), headers.size());
  if (!head) mg_write(connection, body.data(), body.size());
  return status;
}

}  // namespace

ViewerServer::ViewerServer(const ViewerOptions& options, const ViewerState* state) : options_(options), state_(state) {
  std::stringstream names(options_.allowed_hosts);
  for (std::string name; std::getline(names, name, ',');) {
    name.erase(0, name.find_first_not_of(' '));
    name.erase(name.find_last_not_of(' ') + 1);
    if (!name.empty()) allowed_hosts_.insert(Lower(name));
  }
  if (!options_.access_token_file.empty()) {
    token_ = SecretHex(LoadSecretFile(options_.access_token_file, "viewer access token",
                                      "`stitch run --viewer` makes one beside its outputs"));
  } else if (!options_.Loopback()) {
    token_ = SecretHex(RandomSecret());
  }
  for (const auto& [path, asset] : ViewerWebAssets()) assets_[path] = {asset.first, asset.second};
  assets_["/"] = assets_.at("/index.html");
  assets_["/three/three.min.js"] = ThreeFile(options_.three_dir, "build/three.min.js");
  assets_["/three/OrbitControls.js"] = ThreeFile(options_.three_dir, "examples/js/controls/OrbitControls.js");

  mg_init_library(0);
  const std::string ports = options_.bind_address + ":" + std::to_string(options_.port);
  const std::string threads = std::to_string(options_.max_pages + 4);
  const char* settings[] = {"listening_ports",
                            ports.c_str(),
                            "num_threads",
                            threads.c_str(),
                            "request_timeout_ms",
                            "10000",
                            "websocket_timeout_ms",
                            "30000",
                            "enable_keep_alive",
                            "no",
                            "enable_directory_listing",
                            "no",
                            nullptr};
  mg_callbacks callbacks{};
  context_ = mg_start(&callbacks, this, settings);
  if (!context_) {
    mg_exit_library();
    throw Error("the viewer cannot listen on " + ports + " (in use, or not this machine's address?)");
  }
  Refresh(MonotonicSeconds());
  mg_set_request_handler(context_, "/", &ViewerServer::HandleRequest, this);
  mg_set_websocket_handler(context_, "/live", &ViewerServer::OnSocketConnect, &ViewerServer::OnSocketReady,
                           &ViewerServer::OnSocketData, &ViewerServer::OnSocketClose, this);
}

ViewerServer::~ViewerServer() {
  if (context_) {
    mg_stop(context_);
    mg_exit_library();
  }
}

std::string ViewerServer::url() const {
  return "http://" + options_.bind_address + ":" + std::to_string(options_.port) + "/" +
         (token_.empty() ? "" : "?token=" + token_);
}

int ViewerServer::open_pages() const {
  std::lock_guard<std::mutex> lock(sockets_mutex_);
  return LivePages();
}

int ViewerServer::LivePages() const {
  return static_cast<int>(
      std::count_if(sockets_.begin(), sockets_.end(), [](const auto& s) { return !s.second->failed(); }));
}

int64_t ViewerServer::pages_given_up() const {
  std::lock_guard<std::mutex> lock(sockets_mutex_);
  int64_t failed = given_up_;
  for (const auto& s : sockets_) failed += s.second->failed();
  return failed;
}

int64_t ViewerServer::requests_refused() const {
  std::lock_guard<std::mutex> lock(sockets_mutex_);
  return refused_;
}

int ViewerServer::HandleRequest(mg_connection* connection, void* self) {
  return static_cast<ViewerServer*>(self)->Serve(connection);
}

bool ViewerServer::HostAllowed(const mg_connection* connection) const {
  const char* header = mg_get_header(connection, "Host");
  if (!header) return false;  // HTTP/1.1 requires one; browsers always send it
  const std::string host = Lower(header);
  if (!host.empty() && host.front() == '[') return host.find(']') != std::string::npos;  // an IPv6 address
  const std::string name = host.substr(0, host.find(':'));  // any port: an SSH tunnel maps it
  in_addr address{};
  if (inet_pton(AF_INET, name.c_str(), &address) == 1) return true;  // an address is no DNS name to rebind
  return name == "localhost" || allowed_hosts_.count(name) > 0;
}

ViewerServer::Token ViewerServer::TokenOf(const mg_connection* connection) const {
  if (token_.empty()) return Token::kNotNeeded;
  if (HasPair(mg_get_request_info(connection)->query_string, '&', "token", token_)) return Token::kInQuery;
  if (HasPair(mg_get_header(connection, "Cookie"), ';', kTokenCookie, token_)) return Token::kInCookie;
  return Token::kNone;
}

int ViewerServer::Serve(mg_connection* connection) {
  const mg_request_info* request = mg_get_request_info(connection);
  const std::string method = request->request_method ? request->request_method : "";
  const std::string path = request->local_uri ? request->local_uri : "";
  const bool head = method == "HEAD";
  const auto refuse = [&](int status, const char* text) {
    {
      std::lock_guard<std::mutex> lock(sockets_mutex_);
      ++refused_;
    }
    return SendBody(connection, status, text, "text/plain; charset=utf-8", std::string(text) + "\n", head);
  };
  if (!HostAllowed(connection)) return refuse(403, "Forbidden");
  const Token token = TokenOf(connection);
  if (token == Token::kNone) return refuse(401, "Unauthorized");
  // The token of the page's address, kept by the browser for the page's own requests and socket.
  const std::string cookie = token != Token::kInQuery ? ""
                                                      : std::string("Set-Cookie: ") + kTokenCookie + "=" + token_ +
                                                            "; Path=/; HttpOnly; SameSite=Strict\r\n";
  if (method != "GET" && !head) return refuse(405, "Method Not Allowed");
  if (path == "/live") return refuse(400, "Bad Request");  // a WebSocket only
  if (path == "/state.json" || path == "/cloud.bin") {
    std::shared_ptr<const std::string> live, map, cloud;
    {
      std::lock_guard<std::mutex> lock(updates_mutex_);
      live = live_;
      map = map_;
      cloud = cloud_;
    }
    if (path == "/cloud.bin") return SendBody(connection, 200, "OK", "application/octet-stream", *cloud, head, cookie);
    return SendBody(connection, 200, "OK", "application/json", "{\"live\":" + *live + ",\"map\":" + *map + "}", head,
                    cookie);
  }
  const auto asset = assets_.find(path);
  if (asset == assets_.end()) return refuse(404, "Not Found");
  return SendBody(connection, 200, "OK", asset->second.content_type, asset->second.body, head, cookie);
}

int ViewerServer::OnSocketConnect(const mg_connection* connection, void* self) {
  auto* server = static_cast<ViewerServer*>(self);
  std::lock_guard<std::mutex> lock(server->sockets_mutex_);
  if (!server->HostAllowed(connection) || !SameOrigin(connection)) {
    ++server->refused_;
    const char* origin = mg_get_header(connection, "Origin");
    const char* host = mg_get_header(connection, "Host");
    STITCH_LOG(WARNING) << "refused a WebSocket from origin '" << (origin ? origin : "(none)") << "' for host '"
                        << (host ? host : "(none)") << "' (the page's own origin and a host of this machine only)";
    return 1;
  }
  if (server->TokenOf(connection) == Token::kNone) {
    ++server->refused_;
    STITCH_LOG(WARNING) << "refused a WebSocket without the page's access token";
    return 1;
  }
  // A page whose writes failed (it stopped reading) holds a socket until its client lets go, but
  // not a place: the operator's page still opens.
  if (server->LivePages() + server->pending_sockets_ >= server->options_.max_pages) {
    ++server->refused_;
    STITCH_LOG(WARNING) << "refused a page: " << server->options_.max_pages << " are open (viewer.max_pages)";
    return 1;
  }
  ++server->pending_sockets_;
  return 0;
}

void ViewerServer::OnSocketReady(mg_connection* connection, void* self) {
  auto* server = static_cast<ViewerServer*>(self);
  // A page that opens gets what the last push made at once, not at the next push: a page loaded
  // after the flight (or between pushes) shows the map without waiting.
  const Updates updates = server->Latest();
  std::lock_guard<std::mutex> lock(server->sockets_mutex_);
  --server->pending_sockets_;
  auto& sender = server->sockets_[connection] = std::make_unique<PageSender>(connection);
  sender->Offer(updates);
}

int ViewerServer::OnSocketData(mg_connection*, int bits, char*, size_t, void*) {
  // The page sends nothing but pings and the close: keep the socket open unless it closes.
  return (bits & 0x0f) == MG_WEBSOCKET_OPCODE_CONNECTION_CLOSE ? 0 : 1;
}

void ViewerServer::OnSocketClose(const mg_connection* connection, void* self) {
  auto* server = static_cast<ViewerServer*>(self);
  std::unique_ptr<PageSender> sender;
  {
    std::lock_guard<std::mutex> lock(server->sockets_mutex_);
    const auto found = server->sockets_.find(connection);
    if (found == server->sockets_.end()) {
      if (server->pending_sockets_ > 0) --server->pending_sockets_;
      return;
    }
    sender = std::move(found->second);
    server->sockets_.erase(found);
    server->given_up_ += sender->failed();
  }
  sender.reset();  // outside the lock: a write under way ends first
}

void ViewerServer::Refresh(double now_s) {
  auto live = std::make_shared<const std::string>(state_->LiveJson(now_s));
  const int64_t map_revision = state_->map_revision(), cloud_revision = state_->cloud_revision();
  bool new_map, new_cloud;
  {
    std::lock_guard<std::mutex> lock(updates_mutex_);
    new_map = map_revision != map_revision_;
    new_cloud = cloud_revision != cloud_revision_;
  }
  // Made outside the lock (a large cloud takes milliseconds); a revision that moved meanwhile is
  // made again at the next push.
  auto map = new_map ? std::make_shared<const std::string>(state_->MapJson()) : nullptr;
  auto cloud = new_cloud ? std::make_shared<const std::string>(state_->CloudBinary()) : nullptr;
  std::lock_guard<std::mutex> lock(updates_mutex_);
  live_ = std::move(live);
  if (map) {
    map_ = std::move(map);
    map_revision_ = map_revision;
  }
  if (cloud) {
    cloud_ = std::move(cloud);
    cloud_revision_ = cloud_revision;
  }
}

ViewerServer::Updates ViewerServer::Latest() const {
  std::lock_guard<std::mutex> lock(updates_mutex_);
  return {live_, map_, cloud_, map_revision_, cloud_revision_};
}

ViewerServer::PageSender::PageSender(mg_connection* connection) : connection_(connection), thread_([this] { Run(); }) {}

ViewerServer::PageSender::~PageSender() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  offered_.notify_all();
  thread_.join();
}

void ViewerServer::PageSender::Offer(const Updates& updates) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    pending_ = updates;
  }
  offered_.notify_all();
}

bool ViewerServer::PageSender::failed() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return failed_;
}

void ViewerServer::PageSender::Run() {
  while (true) {
    Updates updates;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      offered_.wait(lock, [this] { return stopping_ || pending_.has_value(); });
      if (stopping_) return;
      updates = std::move(*pending_);
      pending_.reset();
    }
    if (SendTo(updates)) continue;
    const mg_request_info* request = mg_get_request_info(connection_);
    STITCH_LOG(WARNING) << "a page at " << (request ? request->remote_addr : "?")
                        << " stopped taking updates (a write failed or timed out): it gets no more";
    std::unique_lock<std::mutex> lock(mutex_);
    failed_ = true;
    offered_.wait(lock, [this] { return stopping_; });
    return;
  }
}

bool ViewerServer::PageSender::SendTo(const Updates& updates) {
  mg_lock_connection(connection_);
  bool ok = mg_websocket_write(connection_, MG_WEBSOCKET_OPCODE_TEXT, updates.live->data(), updates.live->size()) > 0;
  if (ok && map_revision_ != updates.map_revision) {
    ok = mg_websocket_write(connection_, MG_WEBSOCKET_OPCODE_TEXT, updates.map->data(), updates.map->size()) > 0;
    if (ok) map_revision_ = updates.map_revision;
  }
  if (ok && cloud_revision_ != updates.cloud_revision) {
    ok = mg_websocket_write(connection_, MG_WEBSOCKET_OPCODE_BINARY, updates.cloud->data(), updates.cloud->size()) > 0;
    if (ok) cloud_revision_ = updates.cloud_revision;
  }
  mg_unlock_connection(connection_);
  return ok;
}

int ViewerServer::Push(double now_s) {
  Refresh(now_s);
  const Updates updates = Latest();
  std::lock_guard<std::mutex> lock(sockets_mutex_);
  int pushed = 0;
  for (auto& [connection, sender] : sockets_) {
    if (sender->failed()) continue;
    sender->Offer(updates);
    ++pushed;
  }
  return pushed;
}

}  // namespace stitch
