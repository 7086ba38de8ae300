#include "services/viewer/viewer_server.h"

#include <sodium.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <charconv>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <list>
#include <mutex>
#include <optional>
#include <set>
#include <sstream>
#include <thread>
#include <vector>

#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>

#include "services/common/secret_file.h"
#include "services/viewer/web_assets.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"
#include "stitch/util/time.h"

namespace stitch {

namespace {

namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
namespace net = boost::asio;
using tcp = net::ip::tcp;
using Request = http::request<http::string_body>;

constexpr size_t kMaxRequestHeaderBytes = 8 * 1024;
constexpr size_t kMaxRequestBodyBytes = 4 * 1024;
constexpr size_t kMaxPageMessageBytes = 64 * 1024;
constexpr auto kRequestTimeout = std::chrono::seconds(10);
constexpr auto kPageWriteTimeout = std::chrono::seconds(10);
constexpr auto kPageSilenceTimeout = std::chrono::seconds(60);  // a ping at half of it

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

std::string Lower(std::string text) {
  for (char& c : text) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return text;
}

std::string Header(const Request& request, http::field field) {
  const auto found = request.find(field);
  return found == request.end() ? std::string() : std::string(found->value());
}

// The page's own origin, as the browser names it in a WebSocket's Origin header (a browser always
// sends one; a client without one is refused).
bool SameOrigin(const Request& request) {
  const std::string origin = Header(request, http::field::origin), host = Header(request, http::field::host);
  return !origin.empty() && !host.empty() && origin == "http://" + host;
}

constexpr char kTokenCookie[] = "stitch_viewer_token";

// Whether `text` holds `key`=`value` among its `separator`-separated pairs (a query, a Cookie
// header), compared in constant time.
bool HasPair(const std::string& text, char separator, const std::string& key, const std::string& value) {
  std::stringstream pairs(text);
  bool found = false;
  for (std::string pair; std::getline(pairs, pair, separator);) {
    pair.erase(0, pair.find_first_not_of(' '));
    if (pair.size() != key.size() + 1 + value.size() || pair.compare(0, key.size() + 1, key + "=") != 0) continue;
    found |= sodium_memcmp(pair.data() + key.size() + 1, value.data(), value.size()) == 0;
  }
  return found;
}

std::string RemoteAddress(const tcp::socket& socket) {
  beast::error_code error;
  const tcp::endpoint remote = socket.remote_endpoint(error);
  return error ? "?" : remote.address().to_string();
}

}  // namespace

class ViewerServer::Impl {
 public:
  Impl(const ViewerOptions& options, const ViewerState* state);
  ~Impl();

  int Push(double now_s);
  std::string url() const {
    return "http://" + options_.bind_address + ":" + std::to_string(options_.port) + "/" +
           (token_.empty() ? "" : "?token=" + token_);
  }
  int open_pages() const {
    std::lock_guard<std::mutex> lock(pages_mutex_);
    return static_cast<int>(pages_.size());
  }
  int64_t requests_refused() const { return refused_.load(); }
  int64_t pages_given_up() const { return given_up_.load(); }
  int64_t connections_displaced() const { return displaced_.load(); }

 private:
  struct Updates {
    std::shared_ptr<const std::string> live, map, cloud;
    int64_t map_revision = -1, cloud_revision = -1;
  };
  class Connection;
  class Page;

  void Accept();
  // Makes room for a new connection where kMaxConnections are held: the oldest that has not
  // finished its request is closed. False when every connection is a page or being answered.
  bool MakeRoom();
  // Answers a whole request (io thread): a file, the state, a refusal, or a page's WebSocket.
  void Answer(const std::shared_ptr<Connection>& connection, Request request);
  // Why a request is refused ("" when it is not): its host, its token.
  enum class Token { kNotNeeded, kNone, kInQuery, kInCookie };
  bool HostAllowed(const Request& request) const;
  Token TokenOf(const Request& request, const std::string& query) const;
  void Refresh(double now_s);
  Updates Latest() const;
  void PageOpened(const std::shared_ptr<Page>& page);
  void PageClosed(const Page* page, bool given_up);

  ViewerOptions options_;
  std::set<std::string> allowed_hosts_;  // viewer.allowed_hosts, lower case
  std::string token_;                    // 64 hex digits; empty: none needed
  const ViewerState* state_;
  std::map<std::string, Asset> assets_;

  net::io_context io_;
  tcp::acceptor acceptor_{io_};
  // The io thread's: connections reading or answering a request, oldest first.
  std::list<std::weak_ptr<Connection>> connections_;
  int pending_pages_ = 0;  // the io thread's: WebSockets accepted, handshake under way
  mutable std::mutex pages_mutex_;
  std::vector<std::shared_ptr<Page>> pages_;
  std::atomic<int64_t> refused_{0}, given_up_{0}, displaced_{0};
  // What the last Refresh made: shared, never copied, by the pushes and the requests.
  mutable std::mutex updates_mutex_;
  std::shared_ptr<const std::string> live_, map_, cloud_;
  int64_t map_revision_ = -1, cloud_revision_ = -1;
  std::thread thread_;
};

// One HTTP connection: reads one request (bounded in size and time), answers it and closes, or
// hands its socket to a page.
class ViewerServer::Impl::Connection : public std::enable_shared_from_this<Connection> {
 public:
  Connection(Impl* server, tcp::socket socket) : server_(server), stream_(std::move(socket)) {}

  void Start() {
    parser_.emplace();
    parser_->header_limit(kMaxRequestHeaderBytes);
    parser_->body_limit(kMaxRequestBodyBytes);
    stream_.expires_after(kRequestTimeout);
    http::async_read(stream_, buffer_, *parser_, [self = shared_from_this()](beast::error_code error, size_t) {
      self->reading_ = false;
      if (error) return self->Close();  // cut off, too large, too slow or not HTTP: no answer
      self->server_->Answer(self, self->parser_->release());
    });
  }
  bool reading() const { return reading_; }
  void Close() {
    beast::error_code ignored;
    stream_.socket().shutdown(tcp::socket::shutdown_both, ignored);
    stream_.socket().close(ignored);
  }
  void Send(int status, const std::string& content_type, const std::string& body, bool head,
            const std::string& cookie = "") {
    auto response = std::make_shared<http::response<http::string_body>>(static_cast<http::status>(status), 11);
    response->set(http::field::content_type, content_type);
    response->set(http::field::cache_control, "no-store");
    response->set("X-Content-Type-Options", "nosniff");
    response->set("X-Frame-Options", "DENY");
    response->set("Referrer-Policy", "no-referrer");
    response->set("Content-Security-Policy", "default-src 'self'; img-src 'self' data:");
    if (!cookie.empty()) response->set(http::field::set_cookie, cookie);
    response->keep_alive(false);
    if (!head) response->body() = body;
    response->content_length(body.size());
    stream_.expires_after(kPageWriteTimeout);
    http::async_write(stream_, *response, [self = shared_from_this(), response](beast::error_code, size_t) {
      beast::error_code ignored;
      self->stream_.socket().shutdown(tcp::socket::shutdown_send, ignored);
      self->stream_.socket().close(ignored);
    });
  }
  beast::tcp_stream TakeStream() { return std::move(stream_); }

 private:
  Impl* server_;
  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  bool reading_ = true;
};

// One open page's WebSocket (io thread): what it is offered is written one message after the
// other, the newest offer replacing one not started; what it sends is read and dropped.
class ViewerServer::Impl::Page : public std::enable_shared_from_this<Page> {
 public:
  Page(Impl* server, beast::tcp_stream stream)
      : server_(server),
        remote_(RemoteAddress(stream.socket())),
        socket_(std::move(stream)),
        write_deadline_(socket_.get_executor()) {}

  void Open(Request request) {
    beast::get_lowest_layer(socket_).expires_never();  // the WebSocket's own timeouts from here
    websocket::stream_base::timeout timeouts{};
    timeouts.handshake_timeout = kRequestTimeout;
    timeouts.idle_timeout = kPageSilenceTimeout;
    timeouts.keep_alive_pings = true;
    socket_.set_option(timeouts);
    socket_.read_message_max(kMaxPageMessageBytes);
    socket_.async_accept(request, [self = shared_from_this()](beast::error_code error) {
      --self->server_->pending_pages_;
      if (error) return self->Close(false, "");
      self->open_ = true;
      self->server_->PageOpened(self);
      self->Read();
    });
  }
  // Any thread: replaces what was offered and not started yet.
  void Offer(Updates updates) {
    net::post(socket_.get_executor(), [self = shared_from_this(), updates = std::move(updates)]() mutable {
      self->offered_ = std::move(updates);
      self->WriteOffered();
    });
  }

 private:
  void Read() {
    socket_.async_read(incoming_, [self = shared_from_this()](beast::error_code error, size_t) {
      if (error) {
        // Closed by the page, cut off, more than a page may send, or silent past the pings.
        const bool silent = error == beast::error::timeout;
        return self->Close(silent, silent ? "answered no ping for 60 s" : "");
      }
      self->incoming_.clear();  // the page sends nothing the viewer reads
      self->Read();
    });
  }
  void WriteOffered() {
    if (writing_ || closed_ || !offered_) return;
    const Updates updates = std::move(*offered_);
    offered_.reset();
    queue_.clear();
    queue_.push_back({updates.live, false});
    if (map_revision_ != updates.map_revision) queue_.push_back({updates.map, false});
    if (cloud_revision_ != updates.cloud_revision) queue_.push_back({updates.cloud, true});
    writing_ = true;
    WriteNext(0, updates.map_revision, updates.cloud_revision);
  }
  void WriteNext(size_t next, int64_t map_revision, int64_t cloud_revision) {
    if (next == queue_.size()) {
      writing_ = false;
      map_revision_ = map_revision;
      cloud_revision_ = cloud_revision;
      return WriteOffered();
    }
    const auto& [body, binary] = queue_[next];
    socket_.binary(binary);
    write_deadline_.expires_after(kPageWriteTimeout);
    write_deadline_.async_wait([weak = weak_from_this()](beast::error_code error) {
      if (error) return;  // the write ended first
      if (auto self = weak.lock()) self->Close(true, "left an update unread for 10 s");
    });
    socket_.async_write(net::buffer(*body), [self = shared_from_this(), next, map_revision, cloud_revision](
                                                beast::error_code error, size_t) {
      self->write_deadline_.cancel();
      if (error) return self->Close(!self->closed_, "a write failed");
      self->WriteNext(next + 1, map_revision, cloud_revision);
    });
  }
  // Closes the socket (what is under way ends with an error); `given_up`: the page is closed for
  // what it did not do, not by itself.
  void Close(bool given_up, const std::string& why) {
    if (closed_) return;
    closed_ = true;
    if (given_up && !why.empty()) {
      STITCH_LOG(WARNING) << "a page at " << remote_ << " " << why << ": closed, it gets no more";
    }
    beast::error_code ignored;
    beast::get_lowest_layer(socket_).socket().shutdown(tcp::socket::shutdown_both, ignored);
    beast::get_lowest_layer(socket_).socket().close(ignored);
    write_deadline_.cancel();
    if (open_) server_->PageClosed(this, given_up);
  }

  Impl* server_;
  std::string remote_;
  websocket::stream<beast::tcp_stream> socket_;
  net::steady_timer write_deadline_;
  beast::flat_buffer incoming_;
  std::optional<Updates> offered_;
  std::vector<std::pair<std::shared_ptr<const std::string>, bool>> queue_;  // (message, binary)
  int64_t map_revision_ = -1, cloud_revision_ = -1;                         // what the page has
  bool open_ = false, writing_ = false, closed_ = false;
};

ViewerServer::Impl::Impl(const ViewerOptions& options, const ViewerState* state) : options_(options), state_(state) {
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

  const std::string where = options_.bind_address + ":" + std::to_string(options_.port);
  beast::error_code error;
  const std::string host = options_.bind_address == "localhost" ? "127.0.0.1" : options_.bind_address;
  std::string bare = host;
  if (bare.size() > 2 && bare.front() == '[' && bare.back() == ']') bare = bare.substr(1, bare.size() - 2);
  const net::ip::address address = net::ip::make_address(bare, error);
  if (error) throw Error("the viewer cannot listen on " + where + ": not an IP address (viewer.bind_address)");
  const tcp::endpoint endpoint(address, static_cast<uint16_t>(options_.port));
  acceptor_.open(endpoint.protocol(), error);
  if (!error) acceptor_.set_option(net::socket_base::reuse_address(true), error);
  if (!error) acceptor_.bind(endpoint, error);
  if (!error) acceptor_.listen(net::socket_base::max_listen_connections, error);
  if (error) {
    throw Error("the viewer cannot listen on " + where + ": " + error.message() +
                " (in use, or not this machine's address?)");
  }
  Refresh(MonotonicSeconds());
  Accept();
  thread_ = std::thread([this] {
    for (;;) {
      try {
        io_.run();
        return;
      } catch (const std::exception& e) {
        STITCH_LOG(ERROR) << "the viewer's web server: " << e.what() << "; serving on";
      }
    }
  });
}

ViewerServer::Impl::~Impl() {
  io_.stop();
  if (thread_.joinable()) thread_.join();
  std::lock_guard<std::mutex> lock(pages_mutex_);
  pages_.clear();
}

void ViewerServer::Impl::Accept() {
  acceptor_.async_accept([this](beast::error_code error, tcp::socket socket) {
    if (!error) {
      if (MakeRoom()) {
        auto connection = std::make_shared<Connection>(this, std::move(socket));
        connections_.push_back(connection);
        connection->Start();
      } else {
        ++refused_;
        beast::error_code ignored;
        socket.close(ignored);
      }
    }
    if (acceptor_.is_open()) Accept();
  });
}

bool ViewerServer::Impl::MakeRoom() {
  connections_.remove_if([](const std::weak_ptr<Connection>& c) { return c.expired(); });
  const int held = static_cast<int>(connections_.size()) + open_pages() + pending_pages_;
  if (held < kMaxConnections) return true;
  for (const auto& weak : connections_) {
    const auto oldest = weak.lock();
    if (oldest && oldest->reading()) {
      oldest->Close();
      ++displaced_;
      return true;
    }
  }
  return false;
}

bool ViewerServer::Impl::HostAllowed(const Request& request) const {
  const std::string host = Lower(Header(request, http::field::host));
  if (host.empty()) return false;  // HTTP/1.1 requires one; browsers always send it
  if (host.front() == '[') return host.find(']') != std::string::npos;  // an IPv6 address
  const std::string name = host.substr(0, host.find(':'));              // any port: an SSH tunnel maps it
  beast::error_code error;
  net::ip::make_address_v4(name, error);
  if (!error) return true;  // an address is no DNS name to rebind
  return name == "localhost" || allowed_hosts_.count(name) > 0;
}

ViewerServer::Impl::Token ViewerServer::Impl::TokenOf(const Request& request, const std::string& query) const {
  if (token_.empty()) return Token::kNotNeeded;
  if (HasPair(query, '&', "token", token_)) return Token::kInQuery;
  if (HasPair(Header(request, http::field::cookie), ';', kTokenCookie, token_)) return Token::kInCookie;
  return Token::kNone;
}

void ViewerServer::Impl::Answer(const std::shared_ptr<Connection>& connection, Request request) {
  const std::string target(request.target());
  const size_t question = target.find('?');
  const std::string path = target.substr(0, question);
  const std::string query = question == std::string::npos ? "" : target.substr(question + 1);
  const bool head = request.method() == http::verb::head;
  const auto refuse = [&](int status, const std::string& why) {
    ++refused_;
    connection->Send(status, "text/plain; charset=utf-8", why + "\n", head);
  };
  const Token token = TokenOf(request, query);
  if (websocket::is_upgrade(request)) {
    if (path != "/live") return refuse(404, "Not Found");
    if (!HostAllowed(request) || !SameOrigin(request)) {
      STITCH_LOG(WARNING) << "refused a WebSocket from origin '" << Header(request, http::field::origin)
                          << "' for host '" << Header(request, http::field::host)
                          << "' (the page's own origin and a host of this machine only)";
      return refuse(403, "Forbidden");
    }
    if (token == Token::kNone) {
      STITCH_LOG(WARNING) << "refused a WebSocket without the page's access token";
      return refuse(401, "Unauthorized");
    }
    if (open_pages() + pending_pages_ >= options_.max_pages) {
      STITCH_LOG(WARNING) << "refused a page: " << options_.max_pages << " are open (viewer.max_pages)";
      return refuse(503, "Service Unavailable");
    }
    ++pending_pages_;
    connections_.remove_if([&](const std::weak_ptr<Connection>& c) { return c.lock() == connection; });
    std::make_shared<Page>(this, connection->TakeStream())->Open(std::move(request));
    return;
  }
  if (!HostAllowed(request)) return refuse(403, "Forbidden");
  if (token == Token::kNone) return refuse(401, "Unauthorized");
  // The token of the page's address, kept by the browser for the page's own requests and socket.
  const std::string cookie =
      token != Token::kInQuery ? "" : std::string(kTokenCookie) + "=" + token_ + "; Path=/; HttpOnly; SameSite=Strict";
  if (request.method() != http::verb::get && !head) return refuse(405, "Method Not Allowed");
  if (path == "/live") return refuse(400, "Bad Request");  // a WebSocket only
  if (path == "/state.json" || path == "/cloud.bin") {
    const Updates updates = Latest();
    if (path == "/cloud.bin") return connection->Send(200, "application/octet-stream", *updates.cloud, head, cookie);
    return connection->Send(200, "application/json", "{\"live\":" + *updates.live + ",\"map\":" + *updates.map + "}",
                            head, cookie);
  }
  if (path.rfind("/mosaic/", 0) == 0) {  // /mosaic/COL_ROW.png: a tile of the live mosaic
    int col = 0, row = 0;
    const char* end = path.data() + path.size();
    const auto [after_col, col_error] = std::from_chars(path.data() + 8, end, col);
    bool named = col_error == std::errc() && after_col < end && *after_col == '_';
    if (named) {
      const auto [after_row, row_error] = std::from_chars(after_col + 1, end, row);
      named = row_error == std::errc() && std::string(after_row, end) == ".png" &&
              path == "/mosaic/" + std::to_string(col) + "_" + std::to_string(row) + ".png";
    }
    if (!named) return refuse(404, "Not Found");
    const std::shared_ptr<const std::string> png = state_->MosaicTilePng(col, row);
    // A tile the mosaic no longer holds (it started over since the page's index): nothing, and
    // no refusal (the page's next index no longer names it).
    if (!png) return connection->Send(204, "image/png", "", head);
    return connection->Send(200, "image/png", *png, head, cookie);
  }
  const auto asset = assets_.find(path);
  if (asset == assets_.end()) return refuse(404, "Not Found");
  connection->Send(200, asset->second.content_type, asset->second.body, head, cookie);
}

void ViewerServer::Impl::PageOpened(const std::shared_ptr<Page>& page) {
  {
    std::lock_guard<std::mutex> lock(pages_mutex_);
    pages_.push_back(page);
  }
  // A page that opens gets what the last push made at once, not at the next push: a page loaded
  // after the flight (or between pushes) shows the map without waiting.
  page->Offer(Latest());
}

void ViewerServer::Impl::PageClosed(const Page* page, bool given_up) {
  given_up_ += given_up;
  std::shared_ptr<Page> last_reference;  // released outside the lock
  std::lock_guard<std::mutex> lock(pages_mutex_);
  const auto found = std::find_if(pages_.begin(), pages_.end(), [&](const auto& p) { return p.get() == page; });
  if (found == pages_.end()) return;
  last_reference = std::move(*found);
  pages_.erase(found);
}

void ViewerServer::Impl::Refresh(double now_s) {
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

ViewerServer::Impl::Updates ViewerServer::Impl::Latest() const {
  std::lock_guard<std::mutex> lock(updates_mutex_);
  return {live_, map_, cloud_, map_revision_, cloud_revision_};
}

int ViewerServer::Impl::Push(double now_s) {
  Refresh(now_s);
  const Updates updates = Latest();
  std::lock_guard<std::mutex> lock(pages_mutex_);
  for (const auto& page : pages_) page->Offer(updates);
  return static_cast<int>(pages_.size());
}

ViewerServer::ViewerServer(const ViewerOptions& options, const ViewerState* state)
    : impl_(std::make_unique<Impl>(options, state)) {}
ViewerServer::~ViewerServer() = default;
int ViewerServer::Push(double now_s) {
  return impl_->Push(now_s);
}
std::string ViewerServer::url() const {
  return impl_->url();
}
int ViewerServer::open_pages() const {
  return impl_->open_pages();
}
int64_t ViewerServer::requests_refused() const {
  return impl_->requests_refused();
}
int64_t ViewerServer::pages_given_up() const {
  return impl_->pages_given_up();
}
int64_t ViewerServer::connections_displaced() const {
  return impl_->connections_displaced();
}

}  // namespace stitch
