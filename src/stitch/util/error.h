#pragma once
// Library errors. Library code throws stitch::Error with a message that says what was wrong and
// what to do; only main() turns it into an exit status.

#include <sstream>
#include <stdexcept>
#include <string>

namespace stitch {

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& what) : std::runtime_error(what) {}
};

// Builds a message from stream pieces: throw Error(Str() << path << ": " << why);
class Str {
 public:
  template <typename T>
  Str& operator<<(const T& value) {
    stream_ << value;
    return *this;
  }
  operator std::string() const { return stream_.str(); }
  std::string str() const { return stream_.str(); }

 private:
  std::ostringstream stream_;
};

}  // namespace stitch
