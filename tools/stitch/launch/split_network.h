#pragma once
// Two network namespaces joined by a veth pair: the aircraft's side and the ground's, as on a
// routed radio link (multicast does not cross; only the link bridges' UDP does). Each side has
// its own loopback with a multicast route for its LCM bus. Needs root (CAP_NET_ADMIN) and `ip`.

#include <string>

namespace stitch {

class SplitNetwork {
 public:
  // Creates "stitch-<pid>-air" and "stitch-<pid>-gnd"; commands' output goes to `log_path`.
  // Throws stitch::Error with the reason (not root, no `ip`, namespaces not permitted).
  explicit SplitNetwork(const std::string& log_path);
  ~SplitNetwork();  // deletes both namespaces
  SplitNetwork(const SplitNetwork&) = delete;
  SplitNetwork& operator=(const SplitNetwork&) = delete;

  // Moves the calling thread into a side's namespace: processes it starts afterwards and
  // sockets it opens are on that side.
  void EnterAircraft() const { Enter(aircraft_); }
  void EnterGround() const { Enter(ground_); }

  static constexpr char kAircraftAddress[] = "10.213.0.1";
  static constexpr char kGroundAddress[] = "10.213.0.2";
  std::string Describe() const;

 private:
  void Ip(const std::string& arguments) const;
  void Enter(const std::string& name) const;

  std::string ip_;
  std::string log_path_;
  std::string aircraft_, ground_;
  bool created_aircraft_ = false, created_ground_ = false;
};

}  // namespace stitch
