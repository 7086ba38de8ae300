#pragma once
// Settings of the link bridge (the `link:` section of a stitch config): which channels cross
// from this side's LCM network to the other side's, over which UDP addresses, under which budget.

#include <string>

namespace stitch {

struct LinkOptions {
  // LCM channels (a regular expression, as LCM subscribes) sent to the peer. The aircraft sends
  // its features and state down; the ground sends the merger's requests up.
  std::string forward = "uav0/(SUBMAP|SEQUENCE|TRACKING_STATUS|POSE|GNSS|SERVICE|LINK_STATUS|KEYFRAME_IMAGE)";
  // Of those, the channels sent only when nothing else waits: the first to wait, and to be
  // dropped, when the budget is short (the keyframes' pictures for the ground's mosaic).
  std::string background = ".*/KEYFRAME_IMAGE";
  // LCM channels (a regular expression) this bridge publishes from the other side: what the
  // other side's `forward` names, so a datagram for any other channel (a FRAME sent up to the
  // aircraft) is refused. ".*": whatever the other side sends.
  std::string accept = ".*";
  std::string listen = "0.0.0.0:7720";  // UDP address this bridge receives on
  std::string peer = "127.0.0.1:7721";  // UDP address of the bridge on the other side
  double budget_bytes_per_s = 0;        // 0: no limit; else datagrams (with UDP/IP headers) are paced to it
  int max_datagram_bytes = 1200;        // fits a 1280-byte MTU (IPv6 minimum, most radios and VPNs)
  double max_queue_s = 60;              // with a budget: messages waiting longer than this are dropped, oldest first
  int small_message_bytes = 2048;       // messages up to this size overtake larger waiting ones
  double retain_s = 30;                 // sent messages are kept this long to repair their lost datagrams
  double repair_after_ms = 150;         // ask for a message's lost datagrams after this long without progress
  int repair_rounds = 30;               // then give up on it (the merger's own re-send path is behind)
  double status_interval_s = 0.25;      // how often each side says how far it has sent
  double report_interval_s = 10;        // log the link's figures this often (0: never)
  // Injected impairments, for tests and rehearsals: each datagram sent is dropped with
  // probability `loss` and held for `delay_ms` (+ uniform jitter, which reorders).
  // Every datagram is authenticated (link_auth.h) with the key both sides share, made by
  // `stitch link keygen FILE` (mode 0600); without one the bridge refuses to start unless
  // `insecure` says to run unauthenticated (a closed network, a tunnel that authenticates).
  std::string key_file;
  bool insecure = false;
  // Which bridge of the pair this is, "aircraft" or "ground" (required with a key): each
  // direction seals with its own key, derived from the pair's (a datagram reflected back to the
  // bridge that sent it cannot be opened there).
  std::string side;
  double loss = 0;
  double delay_ms = 0;
  double jitter_ms = 0;
  int seed = 1;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("forward", forward, "LCM channels sent to the other side (regular expression)");
    v("background", background,
      "of the forwarded channels, those sent only when nothing else waits (regular expression; first to be dropped "
      "when the budget is short)");
    v("accept", accept, "LCM channels published from the other side (regular expression: the other side's forward)");
    v("listen", listen, "UDP address:port this bridge receives the other side on");
    v("peer", peer, "UDP address:port of the other side's bridge");
    v("budget_bytes_per_s", budget_bytes_per_s,
      "bandwidth budget of what this side sends, bytes/s with headers (0: none)");
    v("max_datagram_bytes", max_datagram_bytes, "largest UDP payload sent (messages are split into datagrams)");
    v("max_queue_s", max_queue_s, "with a budget: drop messages that waited longer than this, oldest first, seconds");
    v("small_message_bytes", small_message_bytes, "messages up to this size overtake larger waiting ones");
    v("retain_s", retain_s, "keep sent messages this long to repair lost datagrams, seconds");
    v("repair_after_ms", repair_after_ms, "ask for lost datagrams after this long without progress, ms");
    v("repair_rounds", repair_rounds, "requests for one message's datagrams before giving up on it");
    v("status_interval_s", status_interval_s, "how often each side says how far it has sent, seconds");
    v("report_interval_s", report_interval_s, "log the link's figures this often, seconds (0: never)");
    v("key_file", key_file, "key both bridges share, from `stitch link keygen FILE` (every datagram authenticated)");
    v("insecure", insecure, "run without a key: datagrams unauthenticated, anyone who reaches the port is believed");
    v("side", side,
      "aircraft or ground: which bridge of the pair this is (each direction has its own key, derived from key_file)");
    v("loss", loss, "injected: probability that a datagram sent is dropped (tests, rehearsals)");
    v("delay_ms", delay_ms, "injected: delay of every datagram sent, ms");
    v("jitter_ms", jitter_ms, "injected: extra uniform delay in [0, jitter_ms], which reorders datagrams");
    v("seed", seed, "seed of the injected loss and jitter");
  }

  bool Check(std::string* why) const {
    auto fail = [&](const std::string& m) {
      if (why) *why = m;
      return false;
    };
    if (forward.empty()) return fail("link.forward must name at least one channel");
    if (accept.empty()) return fail("link.accept must name at least one channel (.* for any)");
    if (listen.find(':') == std::string::npos) return fail("link.listen must be ADDRESS:PORT");
    if (peer.find(':') == std::string::npos) return fail("link.peer must be ADDRESS:PORT");
    if (!(budget_bytes_per_s >= 0)) return fail("link.budget_bytes_per_s must be >= 0");
    if (budget_bytes_per_s > 0 && budget_bytes_per_s < 2000) {
      return fail("link.budget_bytes_per_s must be 0 (none) or at least 2000");
    }
    if (max_datagram_bytes < 256 || max_datagram_bytes > 65000)
      return fail("link.max_datagram_bytes must be in [256, 65000]");
    if (!(max_queue_s > 0)) return fail("link.max_queue_s must be > 0");
    if (small_message_bytes < 0) return fail("link.small_message_bytes must be >= 0");
    if (!(retain_s > 0)) return fail("link.retain_s must be > 0");
    if (!(repair_after_ms > 0)) return fail("link.repair_after_ms must be > 0");
    if (repair_rounds < 0) return fail("link.repair_rounds must be >= 0");
    if (!(status_interval_s > 0)) return fail("link.status_interval_s must be > 0");
    if (!(report_interval_s >= 0)) return fail("link.report_interval_s must be >= 0");
    if (!side.empty() && side != "aircraft" && side != "ground") return fail("link.side must be aircraft or ground");
    if (!(loss >= 0 && loss < 1)) return fail("link.loss must be in [0, 1)");
    if (!(delay_ms >= 0 && delay_ms <= 60000)) return fail("link.delay_ms must be in [0, 60000]");
    if (!(jitter_ms >= 0 && jitter_ms <= 60000)) return fail("link.jitter_ms must be in [0, 60000]");
    return true;
  }
};

}  // namespace stitch
