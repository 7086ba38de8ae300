#pragma once
// IPv4 UDP addresses as the services' settings write them: "ADDRESS:PORT" (an empty address:
// every interface, 0.0.0.0).

#include <netinet/in.h>

#include <string>

namespace stitch {

// Throws stitch::Error naming `what` and the text when it is not ADDRESS:PORT or does not resolve.
sockaddr_in ResolveIpv4(const std::string& text, const char* what);
std::string FormatAddress(const sockaddr_in& address);

}  // namespace stitch
