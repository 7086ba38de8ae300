#include "stitch/util/time.h"

#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <ctime>

#include "stitch/util/error.h"

namespace stitch {

std::string FormatSeconds(int64_t t_ns) {
  const bool negative = t_ns < 0;
  const uint64_t magnitude = negative ? static_cast<uint64_t>(-t_ns) : static_cast<uint64_t>(t_ns);
  char text[48];
  std::snprintf(text, sizeof(text), "%s%llu.%09llu", negative ? "-" : "",
                static_cast<unsigned long long>(magnitude / 1000000000ULL),
                static_cast<unsigned long long>(magnitude % 1000000000ULL));
  return text;
}

int64_t ParseSecondsToNs(const std::string& text) {
  size_t i = 0;
  bool negative = false;
  if (i < text.size() && (text[i] == '-' || text[i] == '+')) negative = text[i++] == '-';
  int64_t whole = 0;
  int64_t fraction = 0;
  int whole_digits = 0;
  int fraction_digits = 0;
  for (; i < text.size() && std::isdigit(static_cast<unsigned char>(text[i])); ++i, ++whole_digits) {
    if (whole_digits >= 11) throw Error("timestamp '" + text + "' is out of range");
    whole = whole * 10 + (text[i] - '0');
  }
  if (i < text.size() && text[i] == '.') {
    for (++i; i < text.size() && std::isdigit(static_cast<unsigned char>(text[i])); ++i) {
      if (fraction_digits < 9) {
        fraction = fraction * 10 + (text[i] - '0');
        ++fraction_digits;
      }
    }
  }
  if (i != text.size() || (whole_digits == 0 && fraction_digits == 0)) {
    throw Error("'" + text + "' is not a timestamp in decimal seconds");
  }
  for (int d = fraction_digits; d < 9; ++d) fraction *= 10;
  const int64_t ns = whole * 1000000000LL + fraction;
  return negative ? -ns : ns;
}

std::string LocalTimestamp(const char* format) {
  const std::time_t now = std::time(nullptr);
  std::tm local{};
  localtime_r(&now, &local);
  char text[64];
  std::strftime(text, sizeof(text), format, &local);
  return text;
}

}  // namespace stitch
