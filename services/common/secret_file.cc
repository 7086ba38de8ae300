#include "services/common/secret_file.h"

#include <fcntl.h>
#include <sodium.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <fstream>

#include "stitch/util/error.h"

namespace stitch {
namespace {

void InitSodium() {
  if (sodium_init() < 0) throw Error("libsodium cannot be initialized");
}

}  // namespace

Secret RandomSecret() {
  InitSodium();
  Secret secret;
  randombytes_buf(secret.data(), secret.size());
  return secret;
}

std::string SecretHex(const Secret& secret) {
  char hex[2 * sizeof(Secret) + 1];
  sodium_bin2hex(hex, sizeof(hex), secret.data(), secret.size());
  std::string text(hex);
  sodium_memzero(hex, sizeof(hex));
  return text;
}

void GenerateSecretFile(const std::string& path, const std::string& what) {
  Secret secret = RandomSecret();
  const std::string text = SecretHex(secret) + "\n";
  sodium_memzero(secret.data(), secret.size());
  const int fd = open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
  if (fd < 0) {
    throw Error(path + ": cannot create the " + what + " file (" + std::strerror(errno) +
                (errno == EEXIST ? "; a " + what + " is never overwritten: remove it first if you mean to" : "") + ")");
  }
  const bool written = write(fd, text.data(), text.size()) == static_cast<ssize_t>(text.size()) && fsync(fd) == 0;
  const int write_error = errno;
  close(fd);
  if (!written) {
    unlink(path.c_str());
    throw Error(path + ": writing the " + what + " failed (" + std::strerror(write_error) + ")");
  }
}

Secret LoadSecretFile(const std::string& path, const std::string& what, const std::string& how_to_make) {
  InitSodium();
  struct stat info {};
  if (stat(path.c_str(), &info) != 0) throw Error(path + ": no " + what + " file (" + how_to_make + ")");
  if ((info.st_mode & 077) != 0) {
    throw Error(path + ": the " + what +
                " is readable by others; chmod 600 it (and make a new one if it may have leaked)");
  }
  std::ifstream file(path);
  std::string hex;
  if (!(file >> hex)) throw Error(path + ": cannot read the " + what);
  Secret secret;
  size_t length = 0;
  if (hex.size() != 2 * secret.size() ||
      sodium_hex2bin(secret.data(), secret.size(), hex.data(), hex.size(), nullptr, &length, nullptr) != 0 ||
      length != secret.size()) {
    throw Error(path + ": not a " + what + " (64 hex digits)");
  }
  return secret;
}

}  // namespace stitch
