#pragma once
// Secrets kept in files (the link's pair key, the viewer's access token): 32 random bytes
// written as 64 hex digits to a file only its owner may read (mode 0600), never overwritten, and
// read back only from such a file. `what` names the secret in errors ("link key").

#include <array>
#include <cstdint>
#include <string>

namespace stitch {

using Secret = std::array<uint8_t, 32>;

// A new random secret.
Secret RandomSecret();
// Writes a new random secret to `path`; throws stitch::Error when the file exists or cannot be
// written (a half-written file is removed).
void GenerateSecretFile(const std::string& path, const std::string& what);
// Reads a secret written by GenerateSecretFile; throws stitch::Error saying what is wrong
// (missing, readable by others, not 64 hex digits). `how_to_make` ends the missing file's error.
Secret LoadSecretFile(const std::string& path, const std::string& what, const std::string& how_to_make);
// The secret as 64 lower-case hex digits.
std::string SecretHex(const Secret& secret);

}  // namespace stitch
