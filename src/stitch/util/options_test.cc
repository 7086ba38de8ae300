#include "stitch/util/options.h"

#include <gtest/gtest.h>

namespace stitch {
namespace {

struct Inner {
  double ratio = 0.5;
  template <class V>
  void VisitFields(V& v) {
    v("ratio", ratio, "a ratio");
  }
  bool Check(std::string* why) const {
    if (ratio < 0 || ratio > 1) {
      *why = "ratio must be in [0, 1]";
      return false;
    }
    return true;
  }
};

struct Outer {
  int count = 3;
  std::string name = "x";
  bool enabled = false;
  Inner inner;
  template <class V>
  void VisitFields(V& v) {
    v("count", count, "how many");
    v("name", name);
    v("enabled", enabled);
    v("inner", inner, "nested");
  }
  bool Check(std::string* why) const { return inner.Check(why); }
};

TEST(Options, MissingKeysKeepDefaults) {
  const Outer o = ReadOptions<Outer>(YAML::Load("count: 7"), "test");
  EXPECT_EQ(o.count, 7);
  EXPECT_EQ(o.name, "x");
  EXPECT_DOUBLE_EQ(o.inner.ratio, 0.5);
}

TEST(Options, NestedValuesAreRead) {
  const Outer o = ReadOptions<Outer>(YAML::Load("inner: {ratio: 0.25}\nenabled: true"), "test");
  EXPECT_DOUBLE_EQ(o.inner.ratio, 0.25);
  EXPECT_TRUE(o.enabled);
}

TEST(Options, UnknownKeyIsAnErrorNamingIt) {
  try {
    ReadOptions<Outer>(YAML::Load("inner: {ratoi: 0.25}"), "run.yaml");
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("run.yaml.inner.ratoi"), std::string::npos) << e.what();
  }
}

TEST(Options, WrongTypeIsAnError) {
  EXPECT_THROW(ReadOptions<Outer>(YAML::Load("count: many"), "t"), Error);
  EXPECT_THROW(ReadOptions<Outer>(YAML::Load("count: 1.5"), "t"), Error);
  EXPECT_THROW(ReadOptions<Outer>(YAML::Load("inner: 3"), "t"), Error);
}

TEST(Options, CheckRunsAfterLoading) {
  EXPECT_THROW(ReadOptions<Outer>(YAML::Load("inner: {ratio: 2}"), "t"), Error);
}

TEST(Options, DumpRoundTrips) {
  Outer o;
  o.count = 11;
  o.inner.ratio = 0.125;
  o.name = "hello world";
  const Outer back = ReadOptions<Outer>(YAML::Load(DumpOptions(o)), "dump");
  EXPECT_EQ(back.count, 11);
  EXPECT_EQ(back.name, "hello world");
  EXPECT_DOUBLE_EQ(back.inner.ratio, 0.125);
}

TEST(Options, MissingFileIsAClearError) {
  try {
    LoadYamlFile("/nonexistent/stitch.yaml");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("no such file"), std::string::npos);
  }
}

}  // namespace
}  // namespace stitch
