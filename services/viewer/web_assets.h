#pragma once
// The viewer's page (services/viewer/web/), compiled into the program so a deployed viewer needs
// no folder of its own beside it: path ("/index.html") -> (content type, bytes).

#include <map>
#include <string>
#include <utility>

namespace stitch {

std::map<std::string, std::pair<std::string, std::string>> ViewerWebAssets();

}  // namespace stitch
