#pragma once
// The vocabulary shipped with stitch, loaded once per test program. For tests only (the source
// tree's copy, through the STITCH_SOURCE_DIR that stitch_add_test defines).

#include <string>

#include "stitch/features/vocabulary.h"

namespace stitch::testing {

inline const Vocabulary& DefaultVocabulary() {
  static const Vocabulary* vocabulary =
      new Vocabulary(Vocabulary::Load(std::string(STITCH_SOURCE_DIR) + "/vocabulary/default.stitchvoc"));
  return *vocabulary;
}

}  // namespace stitch::testing
