#include "services/link/link_auth.h"

#include <sys/stat.h>

#include <fstream>

#include <gtest/gtest.h>

#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace stitch::link {
namespace {

LinkKey Key(uint8_t fill) {
  LinkKey key;
  key.fill(fill);
  return key;
}

Opener::Verdict Open(Opener* opener, const std::string& sealed, std::string* datagram = nullptr) {
  std::string ignored;
  return opener->Open(reinterpret_cast<const uint8_t*>(sealed.data()), sealed.size(), datagram ? datagram : &ignored);
}

TEST(LinkAuth, ASealedDatagramOpensOnceWithTheKeyAndNeverAfterAByteChanged) {
  Sealer sealer(Key(1), 1000);
  Opener opener(Key(1));
  const std::string sealed = sealer.Seal("a datagram");
  EXPECT_EQ(sealed.size(), std::string("a datagram").size() + kSealOverheadBytes);
  for (size_t i = 0; i < sealed.size(); ++i) {
    std::string tampered = sealed;
    tampered[i] = static_cast<char>(tampered[i] ^ 0x20);
    EXPECT_EQ(Open(&opener, tampered), Opener::Verdict::kUnauthenticated) << "byte " << i;
  }
  std::string opened;
  EXPECT_EQ(Open(&opener, sealed, &opened), Opener::Verdict::kOpened);
  EXPECT_EQ(opened, "a datagram");
  EXPECT_EQ(Open(&opener, sealed), Opener::Verdict::kReplayed);
  Opener other_key(Key(2));
  EXPECT_EQ(Open(&other_key, sealer.Seal("x")), Opener::Verdict::kUnauthenticated);
  EXPECT_EQ(Open(&opener, "STL1 an unsealed datagram of the wire format"), Opener::Verdict::kUnauthenticated);
  EXPECT_EQ(Open(&opener, ""), Opener::Verdict::kUnauthenticated);
}

TEST(LinkAuth, TheReplayWindowTakesReorderedDatagramsOnceAndRefusesOldOnes) {
  Sealer sealer(Key(3), 50);
  Opener opener(Key(3));
  std::vector<std::string> sealed;
  for (int i = 0; i < 5000; ++i) sealed.push_back(sealer.Seal(std::to_string(i)));
  EXPECT_EQ(Open(&opener, sealed[10]), Opener::Verdict::kOpened);
  EXPECT_EQ(Open(&opener, sealed[3]), Opener::Verdict::kOpened);  // reordered: behind, in the window
  EXPECT_EQ(Open(&opener, sealed[3]), Opener::Verdict::kReplayed);
  EXPECT_EQ(Open(&opener, sealed[10]), Opener::Verdict::kReplayed);
  EXPECT_EQ(Open(&opener, sealed[4999]), Opener::Verdict::kOpened);
  EXPECT_EQ(Open(&opener, sealed[4999 - Opener::kWindow + 1]), Opener::Verdict::kOpened);
  EXPECT_EQ(Open(&opener, sealed[4999 - Opener::kWindow]), Opener::Verdict::kReplayed);  // out of the window
  EXPECT_EQ(Open(&opener, sealed[11]), Opener::Verdict::kReplayed);
}

TEST(LinkAuth, OnlyAnAuthenticNewerSessionReplacesTheSessionAndAnEarlierRunsAreRefused) {
  Sealer earlier(Key(4), 100), later(Key(4), 200);
  const std::string from_earlier = earlier.Seal("old run");
  Opener opener(Key(4));
  EXPECT_EQ(Open(&opener, later.Seal("new run")), Opener::Verdict::kOpened);
  EXPECT_EQ(Open(&opener, from_earlier), Opener::Verdict::kReplayed);  // replayed from before the restart
  Sealer forger(Key(5), ~uint64_t{0});                                 // the session 2^64-1, without the key
  EXPECT_EQ(Open(&opener, forger.Seal("take over")), Opener::Verdict::kUnauthenticated);
  EXPECT_EQ(Open(&opener, later.Seal("still the same session")), Opener::Verdict::kOpened);
}

TEST(LinkAuth, EachDirectionHasItsOwnKeySoAReflectedDatagramDoesNotOpen) {
  const LinkKey pair = Key(7);
  const LinkKey down = DirectionKey(pair, "aircraft"), up = DirectionKey(pair, "ground");
  EXPECT_NE(down, up);
  EXPECT_NE(down, pair);
  EXPECT_EQ(down, DirectionKey(pair, "aircraft")) << "both sides derive the same";
  EXPECT_NE(down, DirectionKey(Key(8), "aircraft"));
  EXPECT_THROW(DirectionKey(pair, "satellite"), Error);
  EXPECT_EQ(OtherSide("aircraft"), "ground");
  EXPECT_EQ(OtherSide("ground"), "aircraft");
  // The aircraft seals with its key; the ground opens with it, the aircraft itself (opening
  // with the ground's) does not.
  Sealer aircraft(down, 1000);
  Opener at_ground(down), at_aircraft(up);
  const std::string sealed = aircraft.Seal("down");
  EXPECT_EQ(Open(&at_aircraft, sealed), Opener::Verdict::kUnauthenticated);
  EXPECT_EQ(Open(&at_ground, sealed), Opener::Verdict::kOpened);
}

TEST(LinkAuth, KeyFilesAreMadeForTheOwnerOnlyAndCheckedWhenRead) {
  testing::TempDir dir;
  const std::string path = dir / "uav0.key";
  GenerateKeyFile(path);
  struct stat info {};
  ASSERT_EQ(stat(path.c_str(), &info), 0);
  EXPECT_EQ(info.st_mode & 0777, 0600u);
  const LinkKey key = LoadKeyFile(path);
  EXPECT_NE(key, Key(0));
  EXPECT_THROW(GenerateKeyFile(path), Error);  // never overwritten
  EXPECT_EQ(LoadKeyFile(path), key);
  GenerateKeyFile(dir / "other.key");
  EXPECT_NE(LoadKeyFile(dir / "other.key"), key);
  chmod(path.c_str(), 0644);
  EXPECT_THROW(LoadKeyFile(path), Error);  // readable by others
  const std::string bad = dir / "bad.key";
  std::ofstream(bad) << "not a key\n";
  chmod(bad.c_str(), 0600);
  EXPECT_THROW(LoadKeyFile(bad), Error);
  EXPECT_THROW(LoadKeyFile(dir / "absent.key"), Error);
}

}  // namespace
}  // namespace stitch::link
