#include "stitch/util/flat_id_set.h"

#include <gtest/gtest.h>

#include <set>

#include "stitch/util/rng.h"

namespace stitch {
namespace {

TEST(FlatIdSet, AgreesWithStdSetAcrossClearsAndGrowth) {
  FlatIdSet set;
  Rng rng(7);
  for (int round = 0; round < 20; ++round) {
    set.Clear(round % 3 == 0 ? 0 : 100);
    std::set<uint64_t> expected;
    const int count = 50 + round * 300;  // past the initial table: it grows
    for (int i = 0; i < count; ++i) {
      const uint64_t id = (static_cast<uint64_t>(round % 4) << 40) + rng.UniformInt(1, 3 * count);
      ASSERT_EQ(set.Insert(id), expected.insert(id).second);
    }
    EXPECT_EQ(set.size(), expected.size());
    for (uint64_t id = 1; id < 3u * count; id += 7) {
      const uint64_t probe = (static_cast<uint64_t>(round % 4) << 40) + id;
      EXPECT_EQ(set.Contains(probe), expected.count(probe) > 0);
    }
  }
}

}  // namespace
}  // namespace stitch
