#pragma once
// Settings of the ground's live viewer (the `viewer:` section of a stitch config): where its web
// page is served, how often it is updated, and how much it may send.

#include <string>

namespace stitch {

struct ViewerOptions {
  std::string bind_address = "127.0.0.1";  // localhost only by default; any other needs the access token
  int port = 8080;
  double updates_per_s = 4;      // pushes to each open page
  int max_page_points = 500000;  // points sent to a page (the merger thins to merger.map_cloud_points)
  int max_pages = 4;             // pages open at once (each holds a server thread)
  // Host names the page may be asked for by, besides localhost and any IP address (comma
  // separated, e.g. "ground.local"): a request naming any other host (a page of another site
  // whose name was made to resolve here, DNS rebinding) is refused.
  std::string allowed_hosts;
  // The page's access token: a file of 64 hex digits, mode 0600 (`stitch run --viewer` makes one
  // beside its outputs). Every request must carry it (?token= in the page's address, then a
  // cookie). Empty: none on a loopback bind_address, a new random one for any other (the page's
  // address with it is logged).
  std::string access_token_file;
  // Where Debian's libjs-three put three.js (build/three.min.js, examples/js/controls/OrbitControls.js).
  std::string three_dir = "/usr/share/javascript/three";

  // Whether bind_address is this machine's loopback only (127.0.0.0/8, ::1, localhost).
  bool Loopback() const {
    return bind_address.rfind("127.", 0) == 0 || bind_address == "localhost" || bind_address == "[::1]" ||
           bind_address == "::1";
  }

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("bind_address", bind_address,
      "address the viewer's web server listens on (127.0.0.1: this machine only; 0.0.0.0: every interface, each "
      "request then needs the page's access token)");
    v("port", port, "TCP port of the viewer's page: http://ADDRESS:PORT/");
    v("updates_per_s", updates_per_s, "updates pushed to each open page per second");
    v("max_page_points", max_page_points, "map points sent to a page at most");
    v("max_pages", max_pages, "pages open at once; more are refused");
    v("allowed_hosts", allowed_hosts,
      "host names the page may be asked for by besides localhost and IP addresses, comma separated (e.g. "
      "ground.local); requests naming another host are refused (DNS rebinding)");
    v("access_token_file", access_token_file,
      "file of the page's access token (64 hex digits, mode 0600); empty: none on 127.0.0.1, a new random one "
      "(logged in the page's address) on any other bind_address");
    v("three_dir", three_dir, "folder of three.js (Debian's libjs-three), served to the page");
  }

  bool Check(std::string* why) const {
    auto fail = [&](const std::string& m) {
      if (why) *why = m;
      return false;
    };
    if (bind_address.empty()) return fail("viewer.bind_address must not be empty");
    if (bind_address.find_first_of(",: ") != std::string::npos && bind_address.front() != '[') {
      return fail("viewer.bind_address must be one IPv4 address (e.g. 127.0.0.1)");
    }
    if (port < 1 || port > 65535) return fail("viewer.port must be in [1, 65535]");
    if (!(updates_per_s > 0 && updates_per_s <= 60)) return fail("viewer.updates_per_s must be in (0, 60]");
    if (max_page_points < 0 || max_page_points > 5'000'000)
      return fail("viewer.max_page_points must be in [0, 5000000]");
    if (max_pages < 1 || max_pages > 64) return fail("viewer.max_pages must be in [1, 64]");
    if (allowed_hosts.find_first_of(":/[]") != std::string::npos)
      return fail("viewer.allowed_hosts: names only, comma separated, without ports (e.g. ground.local)");
    if (three_dir.empty()) return fail("viewer.three_dir must name the folder of three.js");
    return true;
  }
};

}  // namespace stitch
