#include "services/common/udp_address.h"

#include <arpa/inet.h>
#include <netdb.h>
#include <sys/socket.h>

#include <cstring>

#include "stitch/util/error.h"

namespace stitch {

sockaddr_in ResolveIpv4(const std::string& text, const char* what) {
  const size_t colon = text.rfind(':');
  if (colon == std::string::npos) throw Error(std::string(what) + " '" + text + "' is not ADDRESS:PORT");
  const std::string host = text.substr(0, colon), port = text.substr(colon + 1);
  addrinfo hints{};
  hints.ai_family = AF_INET;
  hints.ai_socktype = SOCK_DGRAM;
  addrinfo* found = nullptr;
  const int status = getaddrinfo(host.empty() ? "0.0.0.0" : host.c_str(), port.c_str(), &hints, &found);
  if (status != 0 || !found) {
    throw Error(std::string(what) + " '" + text + "' does not resolve to an IPv4 address: " + gai_strerror(status));
  }
  sockaddr_in address{};
  std::memcpy(&address, found->ai_addr, sizeof(address));
  freeaddrinfo(found);
  return address;
}

std::string FormatAddress(const sockaddr_in& address) {
  char text[INET_ADDRSTRLEN] = "?";
  inet_ntop(AF_INET, &address.sin_addr, text, sizeof(text));
  return std::string(text) + ":" + std::to_string(ntohs(address.sin_port));
}

}  // namespace stitch
